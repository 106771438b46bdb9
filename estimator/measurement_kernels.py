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
    """(C, t, C_vs, r_vs, nu, omega): the views of a pose T (4, 4), its velocity varpi (6,)
    and the radar's extrinsics Tvs (4, 4)."""
    return T[:3, :3], T[:3, 3], Tvs[:3, :3], Tvs[:3, 3], varpi[:3], varpi[3:]


@njit(cache=True, inline="always")
def polar_jacobian(r, ca, sa, ce, se):
    """d[x, y, z]/d[r, az, el] (3, 3) at range r with the azimuth's and the elevation's cosines and sines
    (`radar_geometry.polar_to_cartesian_jacobian`), row by row as a tuple of 9 floats."""
    return (ce * ca, -r * ce * sa, -r * se * ca,
            ce * sa, r * ce * ca, -r * se * sa,
            se, 0.0, r * ce)


@njit(cache=True, inline="always")
def frame_values(T, varpi, Tvs):
    """`frames`' views as tuples of floats, C and Cvs row by row, for `point_geometry`: values a kernel's loop
    holds in registers (read from arrays, they would be read again after every store the loop makes, which
    might alias them)."""
    C, t, Cvs, rvs, nu, om = frames(T, varpi, Tvs)
    return ((C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2]), (t[0], t[1], t[2]),
            (Cvs[0, 0], Cvs[0, 1], Cvs[0, 2], Cvs[1, 0], Cvs[1, 1], Cvs[1, 2], Cvs[2, 0], Cvs[2, 1], Cvs[2, 2]),
            (rvs[0], rvs[1], rvs[2]), (nu[0], nu[1], nu[2]), (om[0], om[1], om[2]))


@njit(cache=True, inline="always")
def point_geometry(F, p0, p1, p2):
    """The scalars of one map point's model (p0, p1, p2) for a state (C, t, nu, om) and extrinsics (Cvs, rvs)
    given as `frame_values` F, shared by `state_pairs`, `point_prediction` and `prepare_kernels`: (ps (3,), r,
    vr, arot (9,), am (6,), j3 (12,)) as tuples of floats.

    ps is the point in the sensor frame and r its range; vr its radial velocity. A = dp_s/dxi = C_vs^T
    [I, -p_v^] has row i [column i of C_vs, p_v x column i of C_vs]: arot[3 i + j] = A[i, 3 + j]. am holds
    dv_r/dp_s = (q - u vr)^T / r and dv_r/dp_v through the point's velocity, m = w x omega with w = C_vs u;
    j3 = dv_r/d[xi, varpi], the Doppler row of J. For r below 1e-9 (a point at the sensor) everything but ps
    and r is meaningless but finite; the callers check r. Inlined: it compiles with its caller's flags.
    """
    C, t, Cvs, rvs, nu, om = F
    pv0 = C[0] * p0 + C[1] * p1 + C[2] * p2 + t[0]
    pv1 = C[3] * p0 + C[4] * p1 + C[5] * p2 + t[1]
    pv2 = C[6] * p0 + C[7] * p1 + C[8] * p2 + t[2]
    d0, d1, d2 = pv0 - rvs[0], pv1 - rvs[1], pv2 - rvs[2]
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = Cvs
    ps0 = c00 * d0 + c10 * d1 + c20 * d2
    ps1 = c01 * d0 + c11 * d1 + c21 * d2
    ps2 = c02 * d0 + c12 * d1 + c22 * d2
    r = math.sqrt(ps0 * ps0 + ps1 * ps1 + ps2 * ps2)
    rr = max(r, 1e-9)  # r itself wherever the callers use the result
    u0, u1, u2 = ps0 / rr, ps1 / rr, ps2 / rr
    o0, o1, o2 = om[0], om[1], om[2]
    # velocity of the point in the vehicle frame: nu + omega x p_v, then rotated into the sensor frame
    g0 = nu[0] + o1 * pv2 - o2 * pv1
    g1 = nu[1] + o2 * pv0 - o0 * pv2
    g2 = nu[2] + o0 * pv1 - o1 * pv0
    q0 = c00 * g0 + c10 * g1 + c20 * g2
    q1 = c01 * g0 + c11 * g1 + c21 * g2
    q2 = c02 * g0 + c12 * g1 + c22 * g2
    vr = u0 * q0 + u1 * q1 + u2 * q2
    a03, a04, a05 = -(c10 * pv2 - c20 * pv1), -(-c00 * pv2 + c20 * pv0), -(c00 * pv1 - c10 * pv0)
    a13, a14, a15 = -(c11 * pv2 - c21 * pv1), -(-c01 * pv2 + c21 * pv0), -(c01 * pv1 - c11 * pv0)
    a23, a24, a25 = -(c12 * pv2 - c22 * pv1), -(-c02 * pv2 + c22 * pv0), -(c02 * pv1 - c12 * pv0)
    b0, b1, b2 = (q0 - u0 * vr) / rr, (q1 - u1 * vr) / rr, (q2 - u2 * vr) / rr
    w0 = c00 * u0 + c01 * u1 + c02 * u2
    w1 = c10 * u0 + c11 * u1 + c12 * u2
    w2 = c20 * u0 + c21 * u1 + c22 * u2
    m0 = w1 * o2 - w2 * o1
    m1 = w2 * o0 - w0 * o2
    m2 = w0 * o1 - w1 * o0
    # dv_r/dxi = (dv_r/dp_s) A + m^T [I, -p_v^]; dv_r/dvarpi = u^T A
    j3 = (b0 * c00 + b1 * c01 + b2 * c02 + m0, b0 * c10 + b1 * c11 + b2 * c12 + m1,
          b0 * c20 + b1 * c21 + b2 * c22 + m2, b0 * a03 + b1 * a13 + b2 * a23 + (pv1 * m2 - pv2 * m1),
          b0 * a04 + b1 * a14 + b2 * a24 + (pv2 * m0 - pv0 * m2),
          b0 * a05 + b1 * a15 + b2 * a25 + (pv0 * m1 - pv1 * m0),
          u0 * c00 + u1 * c01 + u2 * c02, u0 * c10 + u1 * c11 + u2 * c12, u0 * c20 + u1 * c21 + u2 * c22,
          u0 * a03 + u1 * a13 + u2 * a23, u0 * a04 + u1 * a14 + u2 * a24, u0 * a05 + u1 * a15 + u2 * a25)
    return ((ps0, ps1, ps2), r, vr, (a03, a04, a05, a13, a14, a15, a23, a24, a25), (b0, b1, b2, m0, m1, m2), j3)


@njit(cache=True, inline="always")
def polar_rows(ps0, ps1, ps2, r):
    """Rows 1 and 2 of d[r, az, el]/dp_s at the sensor-frame point ps, range r (row 0 is ps / r):
    (s10, s11, s20, s21, s22), the entries that are not 0 (finite for any r > 0)."""
    rho = max(math.sqrt(ps0 * ps0 + ps1 * ps1), 1e-12 * r)
    rho2 = rho * rho
    dd = r * r * rho
    return -ps1 / rho2, ps0 / rho2, -ps0 * ps2 / dd, -ps1 * ps2 / dd, rho2 / dd


@njit(cache=True, inline="always")
def wrap_angle(x):
    """x wrapped to [-pi, pi)."""
    return x - 2.0 * math.pi * math.floor((x + math.pi) / (2.0 * math.pi))


@njit(cache=True, inline="always")
def polar_angles(ps0, ps1, ps2, r):
    """(azimuth, elevation) of a point at ps (sensor frame), range r > 0."""
    return math.atan2(ps1, ps0), math.asin(min(1.0, max(-1.0, ps2 / r)))


@njit(cache=True, inline="always")
def predicted_z(polar, ps0, ps1, ps2, r, vr, z):
    """z (4,) = [r, az, el, v_r] (polar) or [x, y, z, v_r] (Cartesian) of a point at ps (sensor frame), range
    r > 0, radial velocity vr."""
    if polar:
        z[0] = r
        z[1], z[2] = polar_angles(ps0, ps1, ps2, r)
    else:
        z[0], z[1], z[2] = ps0, ps1, ps2
    z[3] = vr


@njit(cache=True, inline="always")
def point_prediction(polar, F, p, z):
    """z (4,) = the predicted measurement of map point p (3,) for `frame_values` F (`point_geometry`'s, without
    its Jacobians, which the compiler then leaves out); returns the range, or 0.0 for a point at the sensor
    origin (z not written then)."""
    (ps0, ps1, ps2), r, vr, _, _, _ = point_geometry(F, p[0], p[1], p[2])
    if r < 1e-9:
        return 0.0
    predicted_z(polar, ps0, ps1, ps2, r, vr, z)
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
        e[1] = wrap_angle(e[1])
    d2 = 0.0
    for i in range(4):
        s = 0.0
        for l in range(4):
            s += M[i, l] * e[l]
        d2 += e[i] * s
    return d2


@njit(cache=True, inline="always")
def geometry_rows(polar, F, X, n, J, Y, point_jacobian):
    """`point_geometry` of the points X[0:3, :n] (positions in rows, a block of `state_pairs` or of
    `prepare_kernels`) for `frame_values` F, in rows: J (30, n), dz/d[xi, varpi] (entry (r, j) of the pose columns
    in row 6 r + j, the Doppler row's velocity columns in rows 24-29); Y (20, n): ps (rows 0-2), r (3), vr (4)
    and, with point_jacobian (a literal, so the compiler keeps only one side of its tests), Js = dz[:3]/dp_s
    (5-13, row by row) and am (14-19), `point_geometry`'s. Each step one loop over the points (SIMD code); r
    below 1e-9 (a point at the sensor) leaves J finite, its values meaningless."""
    cv = F[2]
    for i in range(n):  # rows 0-2 of J the Cartesian model's (A), the polar model's below
        ps, r, vr, arot, bm, j3 = point_geometry(F, X[0, i], X[1, i], X[2, i])
        for k in range(3):
            J[6 * k, i], J[6 * k + 1, i], J[6 * k + 2, i] = cv[k], cv[3 + k], cv[6 + k]
            J[6 * k + 3, i], J[6 * k + 4, i], J[6 * k + 5, i] = arot[3 * k], arot[3 * k + 1], arot[3 * k + 2]
            Y[k, i] = ps[k]
        for k in range(12):
            J[18 + k, i] = j3[k]
        Y[3, i], Y[4, i] = r, vr
        if point_jacobian:
            for k in range(6):
                Y[14 + k, i] = bm[k]
            for k in range(9):
                Y[5 + k, i] = 1.0 if k % 4 == 0 else 0.0  # Js = I (Cartesian; the polar model's below)
    if polar:
        for i in range(n):
            ps0, ps1, ps2, r = Y[0, i], Y[1, i], Y[2, i], max(Y[3, i], 1e-9)
            s10, s11, s20, s21, s22 = polar_rows(ps0, ps1, ps2, r)
            if point_jacobian:
                Y[5, i], Y[6, i], Y[7, i] = ps0 / r, ps1 / r, ps2 / r
                Y[8, i], Y[9, i], Y[10, i] = s10, s11, 0.0
                Y[11, i], Y[12, i], Y[13, i] = s20, s21, s22
            for j in range(6):
                a0, a1, a2 = J[j, i], J[6 + j, i], J[12 + j, i]
                J[j, i] = J[24 + j, i]  # d r/dxi = u^T A = dv_r/dvarpi
                J[6 + j, i] = s10 * a0 + s11 * a1
                J[12 + j, i] = s20 * a0 + s21 * a1 + s22 * a2


BLOCK = 64  # pairs per block of `state_pairs`: its scratch rows stay in the L1 cache


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def state_pairs(model, T, varpi, lo, hi, p_world, z, W, Tvs, weights, d2_out, robust_c, Hk, bk):
    """The pairs lo:hi of one state (T, varpi), measured by the radar with extrinsics Tvs, added to its
    normal equations Hk (12, 12), bk (12,) (Hk's lower triangle mirrored from the upper after); returns their
    cost 1/2 sum_a w_a d2_a.

    W[a] are information matrices, symmetric (their upper triangles are read). Each pair's squared Mahalanobis
    distance is written to d2_out; its term is weighted by weights[a] (robust weights held fixed during a solve,
    see `SlidingWindow.optimize`). A negative weights[a] is replaced first by the Cauchy weight
    1 / (1 + d2_a / robust_c^2) of the current residual (1 when robust_c is 0), so a solve sets its weights in
    its first linearisation. A map point at the sensor makes the cost NaN (its d2 NaN, its weight kept, no term):
    the step that put it there is rejected.

    The pairs go in blocks of BLOCK, each pass over a block a loop over its pairs with the pairs' quantities in
    rows (one row per entry of J, of W J, ...), so that the passes without a transcendental function compile to
    SIMD code over the pairs: the geometry (`point_geometry`), the polar Jacobian, the weighted Jacobians and
    the sums into H and b. The azimuth's and the elevation's residuals and the weights are the scalar passes.
    H and b sum the pairs in another order than a pair at a time: equal to rounding.

    Checked by: tests/estimator/test_window_kernels.py::test_kernel_matches_numpy_linearisation,
        ::test_kernel_over_blocks_with_cauchy_weights_and_a_point_at_the_sensor
    """
    polar = model == POLAR
    F = frame_values(T, varpi, Tvs)
    X = np.empty((17, BLOCK))  # inputs: p (3), z (4), W's upper triangle (10)
    J, Y = np.empty((30, BLOCK)), np.empty((20, BLOCK))  # `geometry_rows`' (J[r, j] in row 6 r + j, ...)
    WJ = np.empty((24, BLOCK))  # w W J, pose columns, as J
    E = np.empty((6, BLOCK))  # e (4), w, w W_33
    Fe = np.empty((4, BLOCK))  # w W e
    H = np.zeros((12, 12))
    b = np.zeros(12)
    cost = 0.0
    rc2 = robust_c * robust_c
    for s in range(lo, hi, BLOCK):
        m = min(BLOCK, hi - s)
        for i in range(m):
            a = s + i
            X[0, i], X[1, i], X[2, i] = p_world[a, 0], p_world[a, 1], p_world[a, 2]
            X[3, i], X[4, i], X[5, i], X[6, i] = z[a, 0], z[a, 1], z[a, 2], z[a, 3]
            X[7, i], X[8, i], X[9, i], X[10, i] = W[a, 0, 0], W[a, 0, 1], W[a, 0, 2], W[a, 0, 3]
            X[11, i], X[12, i], X[13, i] = W[a, 1, 1], W[a, 1, 2], W[a, 1, 3]
            X[14, i], X[15, i], X[16, i] = W[a, 2, 2], W[a, 2, 3], W[a, 3, 3]
        geometry_rows(polar, F, X, m, J, Y, False)
        for i in range(m):  # the residuals: z - the prediction (the angles below for the polar model)
            E[0, i] = X[3, i] - (Y[3, i] if polar else Y[0, i])
            E[1, i] = X[4, i] - Y[1, i]
            E[2, i] = X[5, i] - Y[2, i]
            E[3, i] = X[6, i] - Y[4, i]
        if polar:
            for i in range(m):
                az, el = polar_angles(Y[0, i], Y[1, i], Y[2, i], Y[3, i])
                E[1, i] = wrap_angle(X[4, i] - az)
                E[2, i] = X[5, i] - el
        for i in range(m):  # d2, the weights, the cost
            a = s + i
            e0, e1, e2, e3 = E[0, i], E[1, i], E[2, i], E[3, i]
            f0 = X[7, i] * e0 + X[8, i] * e1 + X[9, i] * e2 + X[10, i] * e3
            f1 = X[8, i] * e0 + X[11, i] * e1 + X[12, i] * e2 + X[13, i] * e3
            f2 = X[9, i] * e0 + X[12, i] * e1 + X[14, i] * e2 + X[15, i] * e3
            f3 = X[10, i] * e0 + X[13, i] * e1 + X[15, i] * e2 + X[16, i] * e3
            d2 = e0 * f0 + e1 * f1 + e2 * f2 + e3 * f3
            at_sensor = Y[3, i] < 1e-9
            wa = weights[a]
            if wa < 0.0 and not at_sensor:
                wa = 1.0 / (1.0 + d2 / rc2) if robust_c > 0.0 else 1.0
                weights[a] = wa
            wgt = 0.0 if at_sensor else wa
            d2_out[a] = np.nan if at_sensor else d2
            cost += np.nan if at_sensor else 0.5 * wgt * d2
            if at_sensor:  # no term (its e is NaN)
                f0, f1, f2, f3 = 0.0, 0.0, 0.0, 0.0
            Fe[0, i], Fe[1, i], Fe[2, i], Fe[3, i] = wgt * f0, wgt * f1, wgt * f2, wgt * f3
            E[4, i] = wgt
            E[5, i] = wgt * X[16, i]
        for i in range(m):  # w W J, pose columns
            wgt = E[4, i]
            for j in range(6):
                x0, x1, x2, x3 = J[j, i], J[6 + j, i], J[12 + j, i], J[18 + j, i]
                WJ[j, i] = wgt * (X[7, i] * x0 + X[8, i] * x1 + X[9, i] * x2 + X[10, i] * x3)
                WJ[6 + j, i] = wgt * (X[8, i] * x0 + X[11, i] * x1 + X[12, i] * x2 + X[13, i] * x3)
                WJ[12 + j, i] = wgt * (X[9, i] * x0 + X[12, i] * x1 + X[14, i] * x2 + X[15, i] * x3)
                WJ[18 + j, i] = wgt * (X[10, i] * x0 + X[13, i] * x1 + X[15, i] * x2 + X[16, i] * x3)
        # J's velocity columns are zero but in the Doppler row: H_pv = (w W J)[3, :6]^T J[3, 6:],
        # H_vv = w W_33 J[3, 6:]^T J[3, 6:], b_v = -J[3, 6:] (w W e)_3; the residual's derivative is -J
        for j in range(6):
            sp = 0.0
            sv = 0.0
            for i in range(m):
                sp += J[j, i] * Fe[0, i] + J[6 + j, i] * Fe[1, i] + J[12 + j, i] * Fe[2, i] + J[18 + j, i] * Fe[3, i]
                sv += J[24 + j, i] * Fe[3, i]
            b[j] -= sp
            b[6 + j] -= sv
            for l in range(j, 6):
                acc = 0.0
                for i in range(m):
                    acc += (J[j, i] * WJ[l, i] + J[6 + j, i] * WJ[6 + l, i] + J[12 + j, i] * WJ[12 + l, i]
                            + J[18 + j, i] * WJ[18 + l, i])
                H[j, l] += acc
                acc = 0.0
                for i in range(m):
                    acc += E[5, i] * J[24 + j, i] * J[24 + l, i]
                H[6 + j, 6 + l] += acc
            for l in range(6):
                acc = 0.0
                for i in range(m):
                    acc += WJ[18 + j, i] * J[24 + l, i]
                H[j, 6 + l] += acc
    for i in range(12):
        bk[i] += b[i]
        for j in range(i, 12):
            Hk[i, j] += H[i, j]
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
    M = np.empty((3, 3))
    s2 = np.empty(3)
    for k in range(3):
        s2[k] = sigmas[k] * sigmas[k]
    for i in range(polar.shape[0]):
        r, az, el = polar[i, 0], polar[i, 1], polar[i, 2]
        ca, sa, ce, se = math.cos(az), math.sin(az), math.cos(el), math.sin(el)
        J = polar_jacobian(r, ca, sa, ce, se)
        for a in range(3):
            for k in range(3):
                M[a, k] = C[a, 0] * J[k] + C[a, 1] * J[3 + k] + C[a, 2] * J[6 + k]
        for a in range(3):
            for b in range(a, 3):
                v = M[a, 0] * s2[0] * M[b, 0] + M[a, 1] * s2[1] * M[b, 1] + M[a, 2] * s2[2] * M[b, 2]
                out[i, a, b] = v
                out[i, b, a] = v
