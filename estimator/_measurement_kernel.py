"""Fused, compiled linearisation of the measurement terms of all window states (the solver's hot path).

For every associated pair (state k, map point p, detection z, information W) it evaluates the same model as
`estimator.measurements.predict` (paper eq. 76-85, radial velocity with the lever arm), the residual
e = z - g(x_k, p) (azimuth wrapped), its squared Mahalanobis distance, and accumulates

    H_k += w J^T W J,   b_k += w J^T W e,   J = -[dz/dxi, dz/dvarpi]  (4 x 12),

without building any per-pair temporaries. `measurements.predict` stays the readable reference.

Checked by: tests/estimator/test_window.py::test_kernel_matches_numpy_linearisation
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

POLAR, CARTESIAN = 0, 1


@njit(cache=True, fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
def linearize_pairs(model, T, varpi, offsets, p_world, z, W, Tvs, weights, d2_out, robust_c):
    """H (K, 12, 12), b (K, 12), cost for K states; pairs offsets[k]:offsets[k+1] belong to state k.

    Each pair's squared Mahalanobis distance is written to d2_out; its term is weighted by weights[a]
    (robust weights held fixed during a solve, see `SlidingWindow.optimize`): cost = 1/2 sum_a w_a d2_a.
    A negative weights[a] is replaced first by the Cauchy weight 1 / (1 + d2_a / robust_c^2) of the current
    residual (1 when robust_c is 0), so a solve sets its weights in its first linearisation.
    """
    K = T.shape[0]
    H = np.zeros((K, 12, 12))
    b = np.zeros((K, 12))
    cost = 0.0
    J = np.zeros((4, 12))
    WJ = np.zeros((4, 12))
    A = np.empty((3, 6))
    e = np.zeros(4)
    Cvs = Tvs[:3, :3]
    rvs = Tvs[:3, 3]
    for k in range(K):
        C = T[k, :3, :3]
        t = T[k, :3, 3]
        nu = varpi[k, :3]
        om = varpi[k, 3:]
        for a in range(offsets[k], offsets[k + 1]):
            pv0 = C[0, 0] * p_world[a, 0] + C[0, 1] * p_world[a, 1] + C[0, 2] * p_world[a, 2] + t[0]
            pv1 = C[1, 0] * p_world[a, 0] + C[1, 1] * p_world[a, 1] + C[1, 2] * p_world[a, 2] + t[1]
            pv2 = C[2, 0] * p_world[a, 0] + C[2, 1] * p_world[a, 1] + C[2, 2] * p_world[a, 2] + t[2]
            d0, d1, d2 = pv0 - rvs[0], pv1 - rvs[1], pv2 - rvs[2]
            ps0 = Cvs[0, 0] * d0 + Cvs[1, 0] * d1 + Cvs[2, 0] * d2
            ps1 = Cvs[0, 1] * d0 + Cvs[1, 1] * d1 + Cvs[2, 1] * d2
            ps2 = Cvs[0, 2] * d0 + Cvs[1, 2] * d1 + Cvs[2, 2] * d2
            r = math.sqrt(ps0 * ps0 + ps1 * ps1 + ps2 * ps2)
            u0, u1, u2 = ps0 / r, ps1 / r, ps2 / r
            # velocity of the point in the vehicle frame: nu + omega x p_v, then rotated into the sensor frame
            g0 = nu[0] + om[1] * pv2 - om[2] * pv1
            g1 = nu[1] + om[2] * pv0 - om[0] * pv2
            g2 = nu[2] + om[0] * pv1 - om[1] * pv0
            q0 = Cvs[0, 0] * g0 + Cvs[1, 0] * g1 + Cvs[2, 0] * g2
            q1 = Cvs[0, 1] * g0 + Cvs[1, 1] * g1 + Cvs[2, 1] * g2
            q2 = Cvs[0, 2] * g0 + Cvs[1, 2] * g1 + Cvs[2, 2] * g2
            vr = u0 * q0 + u1 * q1 + u2 * q2
            # dp_s/dxi = C_vs^T [I, -p_v^]: column j of C_vs^T is row j of C_vs
            # A (3x6) stored implicitly: A[:, :3] = C_vs^T; A[:, 3:] = -C_vs^T p_v^
            for i in range(3):
                A[i, 0] = Cvs[0, i]
                A[i, 1] = Cvs[1, i]
                A[i, 2] = Cvs[2, i]
                # -(C_vs^T p_v^)[i, :] = -(sum_j Cvs[j, i] * hat(p_v)[j, :])
                A[i, 3] = -(Cvs[1, i] * pv2 - Cvs[2, i] * pv1)
                A[i, 4] = -(-Cvs[0, i] * pv2 + Cvs[2, i] * pv0)
                A[i, 5] = -(Cvs[0, i] * pv1 - Cvs[1, i] * pv0)
            # dv_r/dp_s = (q - u vr)^T / r ; dv_r/dp_v (via q) = u^T C_vs^T omega^
            a0, a1, a2 = (q0 - u0 * vr) / r, (q1 - u1 * vr) / r, (q2 - u2 * vr) / r
            w0 = Cvs[0, 0] * u0 + Cvs[0, 1] * u1 + Cvs[0, 2] * u2  # (C_vs u)
            w1 = Cvs[1, 0] * u0 + Cvs[1, 1] * u1 + Cvs[1, 2] * u2
            w2 = Cvs[2, 0] * u0 + Cvs[2, 1] * u1 + Cvs[2, 2] * u2
            # (C_vs u)^T omega^ = (w x omega)^T... row vector w^T omega^ = (omega x w)^T * -1 = (w x omega)^T
            m0 = w1 * om[2] - w2 * om[1]
            m1 = w2 * om[0] - w0 * om[2]
            m2 = w0 * om[1] - w1 * om[0]
            for j in range(12):
                J[3, j] = 0.0
            for j in range(6):
                J[3, j] = a0 * A[0, j] + a1 * A[1, j] + a2 * A[2, j]
                J[3, 6 + j] = u0 * A[0, j] + u1 * A[1, j] + u2 * A[2, j]
            # + dv_r/dp_v dp_v/dxi = m^T [I, -p_v^] = [m, (p_v x m)]
            J[3, 0] += m0
            J[3, 1] += m1
            J[3, 2] += m2
            J[3, 3] += pv1 * m2 - pv2 * m1
            J[3, 4] += pv2 * m0 - pv0 * m2
            J[3, 5] += pv0 * m1 - pv1 * m0
            if model == POLAR:
                rho2 = ps0 * ps0 + ps1 * ps1
                rho = max(math.sqrt(rho2), 1e-12 * r)
                rho2 = rho * rho
                s0, s1, s2 = ps0 / r, ps1 / r, ps2 / r
                t0, t1 = -ps1 / rho2, ps0 / rho2
                dd = r * r * rho
                v0, v1, v2 = -ps0 * ps2 / dd, -ps1 * ps2 / dd, rho2 / dd
                for j in range(6):
                    J[0, j] = s0 * A[0, j] + s1 * A[1, j] + s2 * A[2, j]
                    J[1, j] = t0 * A[0, j] + t1 * A[1, j]
                    J[2, j] = v0 * A[0, j] + v1 * A[1, j] + v2 * A[2, j]
                for i in range(3):
                    for j in range(6, 12):
                        J[i, j] = 0.0
                e[0] = z[a, 0] - r
                az = z[a, 1] - math.atan2(ps1, ps0)
                e[1] = az - 2.0 * math.pi * math.floor((az + math.pi) / (2.0 * math.pi))
                e[2] = z[a, 2] - math.asin(min(1.0, max(-1.0, ps2 / r)))
            else:
                for i in range(3):
                    for j in range(6):
                        J[i, j] = A[i, j]
                    for j in range(6, 12):
                        J[i, j] = 0.0
                e[0] = z[a, 0] - ps0
                e[1] = z[a, 1] - ps1
                e[2] = z[a, 2] - ps2
            e[3] = z[a, 3] - vr
            # residual derivative is -J; H, b are invariant to that sign pair (b flips with it)
            d2 = 0.0
            for i in range(4):
                s = 0.0
                for l in range(4):
                    s += W[a, i, l] * e[l]
                d2 += e[i] * s
            d2_out[a] = d2
            if weights[a] < 0.0:
                weights[a] = 1.0 / (1.0 + d2 / (robust_c * robust_c)) if robust_c > 0.0 else 1.0
            wgt = weights[a]
            cost += 0.5 * wgt * d2
            # J has zeros in rows 0-2 of the velocity columns: WJ[:, :6] = W J[:, :6], WJ[:, 6:] = W[:, 3] J[3, 6:]
            for i in range(4):
                for j in range(6):
                    s = 0.0
                    for l in range(4):
                        s += W[a, i, l] * J[l, j]
                    WJ[i, j] = wgt * s
                for j in range(6, 12):
                    WJ[i, j] = wgt * W[a, i, 3] * J[3, j]
            for i in range(12):
                bi = 0.0
                for l in range(4):
                    bi += WJ[l, i] * e[l]
                b[k, i] -= bi  # J_residual = -J
            for i in range(6):
                for j in range(i, 12):
                    s = 0.0
                    for l in range(4):
                        s += J[l, i] * WJ[l, j]
                    H[k, i, j] += s
            for i in range(6, 12):
                for j in range(i, 12):
                    H[k, i, j] += J[3, i] * WJ[3, j]
    for k in range(K):
        for i in range(12):
            for j in range(i + 1, 12):
                H[k, j, i] = H[k, i, j]
    return H, b, cost
