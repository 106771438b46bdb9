"""Fused, compiled linearisation of the measurement terms of all window states (the solver's hot path).

For every associated pair (state k, map point p, detection z, information W) it evaluates the same model as
`estimator.measurements.predict` (paper eq. 76-85, radial velocity with the lever arm), the residual
e = z - g(x_k, p) (azimuth wrapped), its squared Mahalanobis distance, and accumulates

    H_k += w J^T W J,   b_k += w J^T W e,   J = -[dz/dxi, dz/dvarpi]  (4 x 12),

without building any per-pair temporaries. `measurements.predict` stays the readable reference.

Checked by: tests/estimator/test_window_kernels.py::test_kernel_matches_numpy_linearisation
"""

from __future__ import annotations

import math

import numpy as np

from .jit import FASTMATH, njit  # the IEEE-safe fast-math subset all kernels share

POLAR, CARTESIAN = 0, 1


@njit(cache=True, inline="always")
def frames(T, varpi, Tvs):
    """(C, t, C_vs, r_vs, nu, omega): the views `point_model` takes of a pose T (4, 4), its velocity varpi (6,)
    and the radar's extrinsics Tvs (4, 4)."""
    return T[:3, :3], T[:3, 3], Tvs[:3, :3], Tvs[:3, 3], varpi[:3], varpi[3:]


@njit(cache=True, inline="always")
def polar_jacobian(r, ca, sa, ce, se, J):
    """J (3, 3) = d[x, y, z]/d[r, az, el] at range r with the azimuth's and the elevation's cosines and sines
    (`radar_geometry.polar_to_cartesian_jacobian`)."""
    J[0, 0], J[1, 0], J[2, 0] = ce * ca, ce * sa, se
    J[0, 1], J[1, 1], J[2, 1] = -r * ce * sa, r * ce * ca, 0.0
    J[0, 2], J[1, 2], J[2, 2] = -r * se * ca, -r * se * sa, r * ce


@njit(cache=True, fastmath=FASTMATH, inline="always")
def point_model(polar, C, t, Cvs, rvs, nu, om, p, A, J, z, Js, am, ps):
    """The measurement model of one map point p (3,) for a state (C, t, nu, om) and extrinsics (Cvs, rvs),
    shared by `state_pairs` and `association_kernels.prepare`:

    z (4,) the predicted [r, az, el, v_r] (polar) or [x, y, z, v_r] (Cartesian); J (4, 12) = dz/d[xi, varpi]
    (rows 0-2 have zeros in the velocity columns); Js (3, 3) = dz[:3]/dp_s; am (2, 3) = (dv_r/dp_s,
    dv_r/dp_v through the point's velocity), from which the caller builds dz/dp; A (3, 6) = dp_s/dxi;
    ps (3,) the point in the sensor frame.
    Returns the range r, or 0.0 for a point at the sensor origin (nothing else is written then).

    Checked by: tests/estimator/test_window_kernels.py::test_kernel_matches_numpy_linearisation
    """
    pv0 = C[0, 0] * p[0] + C[0, 1] * p[1] + C[0, 2] * p[2] + t[0]
    pv1 = C[1, 0] * p[0] + C[1, 1] * p[1] + C[1, 2] * p[2] + t[1]
    pv2 = C[2, 0] * p[0] + C[2, 1] * p[1] + C[2, 2] * p[2] + t[2]
    d0, d1, d2 = pv0 - rvs[0], pv1 - rvs[1], pv2 - rvs[2]
    ps0 = Cvs[0, 0] * d0 + Cvs[1, 0] * d1 + Cvs[2, 0] * d2
    ps1 = Cvs[0, 1] * d0 + Cvs[1, 1] * d1 + Cvs[2, 1] * d2
    ps2 = Cvs[0, 2] * d0 + Cvs[1, 2] * d1 + Cvs[2, 2] * d2
    ps[0], ps[1], ps[2] = ps0, ps1, ps2
    r = math.sqrt(ps0 * ps0 + ps1 * ps1 + ps2 * ps2)
    if r < 1e-9:
        return 0.0
    u0, u1, u2 = ps0 / r, ps1 / r, ps2 / r
    # velocity of the point in the vehicle frame: nu + omega x p_v, then rotated into the sensor frame
    g0 = nu[0] + om[1] * pv2 - om[2] * pv1
    g1 = nu[1] + om[2] * pv0 - om[0] * pv2
    g2 = nu[2] + om[0] * pv1 - om[1] * pv0
    q0 = Cvs[0, 0] * g0 + Cvs[1, 0] * g1 + Cvs[2, 0] * g2
    q1 = Cvs[0, 1] * g0 + Cvs[1, 1] * g1 + Cvs[2, 1] * g2
    q2 = Cvs[0, 2] * g0 + Cvs[1, 2] * g1 + Cvs[2, 2] * g2
    vr = u0 * q0 + u1 * q1 + u2 * q2
    # dp_s/dxi = C_vs^T [I, -p_v^]: A[:, :3] = C_vs^T; A[:, 3:] = -C_vs^T p_v^ (column j of C_vs^T is row j of C_vs)
    for i in range(3):
        A[i, 0] = Cvs[0, i]
        A[i, 1] = Cvs[1, i]
        A[i, 2] = Cvs[2, i]
        A[i, 3] = -(Cvs[1, i] * pv2 - Cvs[2, i] * pv1)
        A[i, 4] = -(-Cvs[0, i] * pv2 + Cvs[2, i] * pv0)
        A[i, 5] = -(Cvs[0, i] * pv1 - Cvs[1, i] * pv0)
    # dv_r/dp_s = (q - u vr)^T / r ; dv_r/dp_v (via q) = u^T C_vs^T omega^ = (w x omega)^T with w = C_vs u
    a0, a1, a2 = (q0 - u0 * vr) / r, (q1 - u1 * vr) / r, (q2 - u2 * vr) / r
    w0 = Cvs[0, 0] * u0 + Cvs[0, 1] * u1 + Cvs[0, 2] * u2
    w1 = Cvs[1, 0] * u0 + Cvs[1, 1] * u1 + Cvs[1, 2] * u2
    w2 = Cvs[2, 0] * u0 + Cvs[2, 1] * u1 + Cvs[2, 2] * u2
    m0 = w1 * om[2] - w2 * om[1]
    m1 = w2 * om[0] - w0 * om[2]
    m2 = w0 * om[1] - w1 * om[0]
    am[0, 0], am[0, 1], am[0, 2] = a0, a1, a2
    am[1, 0], am[1, 1], am[1, 2] = m0, m1, m2
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
    if polar:
        rho = max(math.sqrt(ps0 * ps0 + ps1 * ps1), 1e-12 * r)
        rho2 = rho * rho
        dd = r * r * rho
        Js[0, 0], Js[0, 1], Js[0, 2] = ps0 / r, ps1 / r, ps2 / r
        Js[1, 0], Js[1, 1], Js[1, 2] = -ps1 / rho2, ps0 / rho2, 0.0
        Js[2, 0], Js[2, 1], Js[2, 2] = -ps0 * ps2 / dd, -ps1 * ps2 / dd, rho2 / dd
        z[0] = r
        z[1] = math.atan2(ps1, ps0)
        z[2] = math.asin(min(1.0, max(-1.0, ps2 / r)))
    else:
        for i in range(3):
            for j in range(3):
                Js[i, j] = 1.0 if i == j else 0.0
        z[0], z[1], z[2] = ps0, ps1, ps2
    z[3] = vr
    for i in range(3):
        for j in range(6):
            J[i, j] = Js[i, 0] * A[0, j] + Js[i, 1] * A[1, j] + Js[i, 2] * A[2, j]
        for j in range(6, 12):
            J[i, j] = 0.0
    return r


@njit(cache=True, inline="always")
def residual_d2(polar, z, zp, M, e):
    """e = z - zp (4,) with the azimuth wrapped to [-pi, pi) for the polar model, written to e; returns
    e^T M e. Inlined, so it compiles with its caller's flags (the linearisation's fast-math, the association's
    IEEE arithmetic).

    Checked by: tests/estimator/test_window_kernels.py::test_kernel_matches_numpy_linearisation,
        tests/estimator/test_association.py::test_grid_candidates_are_the_k_nearest_in_the_radius
    """
    for i in range(4):
        e[i] = z[i] - zp[i]
    if polar:
        e[1] = e[1] - 2.0 * math.pi * math.floor((e[1] + math.pi) / (2.0 * math.pi))
    d2 = 0.0
    for i in range(4):
        s = 0.0
        for l in range(4):
            s += M[i, l] * e[l]
        d2 += e[i] * s
    return d2


@njit(cache=True, fastmath=FASTMATH)
def state_pairs(model, T, varpi, lo, hi, p_world, z, W, Tvs, weights, d2_out, robust_c, Hk, bk):
    """The pairs lo:hi of one state (T, varpi), measured by the radar with extrinsics Tvs, added to its
    normal equations Hk (12, 12), bk (12,) (Hk's lower triangle mirrored from the upper after); returns their
    cost 1/2 sum_a w_a d2_a.

    W[a] are information matrices, symmetric (the pose-velocity block uses W[a, 3, :] for W[a, :, 3]).
    Each pair's squared Mahalanobis distance is written to d2_out; its term is weighted by weights[a]
    (robust weights held fixed during a solve, see `SlidingWindow.optimize`). A negative weights[a] is replaced
    first by the Cauchy weight 1 / (1 + d2_a / robust_c^2) of the current residual (1 when robust_c is 0), so a
    solve sets its weights in its first linearisation. A map point at the sensor makes the cost NaN (its d2
    NaN): the step that put it there is rejected.

    Checked by: tests/estimator/test_window_kernels.py::test_kernel_matches_numpy_linearisation
    """
    cost = 0.0
    J = np.zeros((4, 12))
    WJ = np.empty((4, 6))
    We = np.empty(4)
    A = np.empty((3, 6))
    e = np.zeros(4)
    zp = np.empty(4)
    Js = np.empty((3, 3))
    am = np.empty((2, 3))
    ps = np.empty(3)
    C, t, Cvs, rvs, nu, om = frames(T, varpi, Tvs)
    for a in range(lo, hi):
        if point_model(model == POLAR, C, t, Cvs, rvs, nu, om, p_world[a], A, J, zp, Js, am, ps) == 0.0:
            d2_out[a] = np.nan  # a map point at the sensor: the cost is undefined, the step is rejected
            cost = np.nan
            continue
        # residual derivative is -J; H, b are invariant to that sign pair (b flips with it)
        Wa = W[a]
        d2 = residual_d2(model == POLAR, z[a], zp, Wa, e)
        d2_out[a] = d2
        if weights[a] < 0.0:
            weights[a] = 1.0 / (1.0 + d2 / (robust_c * robust_c)) if robust_c > 0.0 else 1.0
        wgt = weights[a]
        cost += 0.5 * wgt * d2
        # J's velocity columns are zero but in row 3, so only w W e and w W J[:, :6] are needed:
        # H_pv = (w W J)[3, :6]^T J[3, 6:], H_vv = w W_33 J[3, 6:]^T J[3, 6:], b_v = J[3, 6:] (w W e)_3
        for i in range(4):
            We[i] = wgt * (Wa[i, 0] * e[0] + Wa[i, 1] * e[1] + Wa[i, 2] * e[2] + Wa[i, 3] * e[3])
            for j in range(6):
                WJ[i, j] = wgt * (Wa[i, 0] * J[0, j] + Wa[i, 1] * J[1, j] + Wa[i, 2] * J[2, j]
                                  + Wa[i, 3] * J[3, j])
        for i in range(6):
            bk[i] -= J[0, i] * We[0] + J[1, i] * We[1] + J[2, i] * We[2] + J[3, i] * We[3]  # J_residual = -J
        for i in range(6, 12):
            bk[i] -= J[3, i] * We[3]
        for i in range(6):
            for j in range(i, 6):
                Hk[i, j] += J[0, i] * WJ[0, j] + J[1, i] * WJ[1, j] + J[2, i] * WJ[2, j] + J[3, i] * WJ[3, j]
            c = WJ[3, i]  # W is symmetric: (w W J)[3, i] = (w J^T W)[i, 3]
            for j in range(6, 12):
                Hk[i, j] += c * J[3, j]
        w33 = wgt * Wa[3, 3]
        for i in range(6, 12):
            c = w33 * J[3, i]
            for j in range(i, 12):
                Hk[i, j] += c * J[3, j]
    for i in range(12):
        for j in range(i + 1, 12):
            Hk[j, i] = Hk[i, j]
    return cost


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def position_covariances(polar, sigmas, C, out):
    """out[i] = (C J_i) diag(s_r^2, s_az^2, s_el^2) (C J_i)^T: detection i's polar noise propagated to its
    Cartesian position (J_i = d[x, y, z]/d[r, az, el], `radar_geometry.cartesian_position_covariance`) and
    rotated by C (world from sensor): the covariance a new map point inherits (`PolarModel.
    world_position_covariance`).

    Checked by: tests/estimator/test_measurements.py::test_world_position_covariance_is_the_rotated_reference
    """
    J = np.empty((3, 3))
    M = np.empty((3, 3))
    s2 = np.empty(3)
    for k in range(3):
        s2[k] = sigmas[k] * sigmas[k]
    for i in range(polar.shape[0]):
        r, az, el = polar[i, 0], polar[i, 1], polar[i, 2]
        ca, sa, ce, se = math.cos(az), math.sin(az), math.cos(el), math.sin(el)
        polar_jacobian(r, ca, sa, ce, se, J)
        for a in range(3):
            for k in range(3):
                M[a, k] = C[a, 0] * J[0, k] + C[a, 1] * J[1, k] + C[a, 2] * J[2, k]
        for a in range(3):
            for b in range(a, 3):
                v = M[a, 0] * s2[0] * M[b, 0] + M[a, 1] * s2[1] * M[b, 1] + M[a, 2] * s2[2] * M[b, 2]
                out[i, a, b] = v
                out[i, b, a] = v
