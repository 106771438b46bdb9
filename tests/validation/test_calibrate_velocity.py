"""The velocity factor's fit (rodo.validation.calibrate_velocity, `rodo calibrate`'s uncertainty section): maximum
likelihood of velocity errors drawn with a known factor (speed, Doppler and rate terms) and known per-axis
factors recovers them, and the states it writes are a run at that factor."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rodo.validation import replayed_states as rs
from rodo.validation import calibrate_velocity as cv
from rodo.validation.calibrate_velocity import fit_velocity_inflation


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 15, *key]))  # test_calibrate_consistency's draws


@settings(max_examples=4, deadline=None)
@given(st.lists(st.floats(-1.5, 1.5), min_size=5, max_size=5), st.integers(0, 2**32 - 1))
def test_velocity_axis_inflation_recovers_known_factors(log_g, seed):
    """Velocity errors drawn from N(0, c D P_v D), D = diag(sqrt(g)) with per-axis factors g (prod g = 1, each
    within e^+-1.5 before the normalisation) and c = 0.7 + 0.05 |nu|, P_v random and correlated per scan: the
    maximum likelihood recovers every g_i within 10 % (5000 scans) and c as before; every axis's mean e_i^2 /
    P_ii is then 1 within 8 %, where it was off by up to e^1.5 without them. The scaled states record g and the
    replay divides it out again (a fit from them gives the same). Not asked for (the default), g is ones."""
    rng = _rng(seed)
    n = 5000
    t = 0.1 * np.arange(n)
    speed = rng.uniform(0.0, 20.0, n)
    varpi = np.concatenate([speed[:, None] * np.array([1.0, 0.0, 0.0]), rng.normal(0, 0.1, (n, 3))], axis=1)
    A = rng.normal(size=(n, 12, 12)) * 0.05
    P = A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(12)
    g = np.exp(np.r_[log_g, 0.0])
    g = g / np.exp(np.mean(np.log(g)))
    c = 0.7 + 0.05 * speed
    h = np.sqrt(g)
    L = np.linalg.cholesky(c[:, None, None] * P[:, 6:12, 6:12] * h[:, None] * h[None, :])
    e = np.einsum("kij,kj->ki", L, rng.normal(size=(n, 6)))
    states = {"t": t, "varpi": varpi, "P": P}
    fit = fit_velocity_inflation(states, {"t": t, "varpi": varpi + e}, per_axis=True)
    np.testing.assert_allclose(fit["per_axis"], g, rtol=0.1)
    assert fit_velocity_inflation(states, {"t": t, "varpi": varpi + e})["per_axis"] == [1.0] * 6  # not asked
    assert np.prod(fit["per_axis"]) == pytest.approx(1.0, rel=1e-9)
    for s in (3.0, 15.0):
        assert fit["inflation"] + fit["per_speed"] * s == pytest.approx(0.7 + 0.05 * s, rel=0.1), fit
    scaled = rs.velocity_inflated_states(states, fit["inflation"], fit["per_speed"], fit["per_doppler"],
                                         fit["per_axis"])
    Pv = scaled["P"][:, 6:12, 6:12]
    ratio = np.mean(e**2 / np.einsum("kii->ki", Pv), axis=0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.08)
    plain = np.mean(e**2 / np.einsum("kii->ki", c[:, None, None] * P[:, 6:12, 6:12]), axis=0)
    np.testing.assert_allclose(plain, g, rtol=0.15)  # without them each axis is off by its g
    np.testing.assert_array_equal(scaled["velocity_axis_inflation"], fit["per_axis"])
    again = fit_velocity_inflation(scaled, {"t": t, "varpi": varpi + e}, per_axis=True)
    np.testing.assert_allclose(again["per_axis"], fit["per_axis"], rtol=1e-5)


@given(a=st.floats(0.2, 5.0), b=st.floats(0.0, 0.3), d=st.floats(0.0, 2.0), seed=st.integers(0, 2**16))
@example(a=1.794498157570615, b=0.0, d=0.5264036804350504, seed=244)
@example(a=1.0, b=0.0, d=1.0, seed=23480)  # at rates 0, the range's edge, its intercept came out 11 % low
@example(a=0.25, b=0.0, d=2.0, seed=2409)  # the smallest factor (0.5, beside a large Doppler term) 12 % low
@example(a=1.0, b=0.25, d=1.0, seed=320)  # the y rate's coefficient 0.28 for 10, as the data say (session 55)
@settings(max_examples=15, deadline=None)
def test_velocity_inflation_recovers_a_known_factor(a, b, d, seed):
    """Velocity errors drawn from N(0, (a + b |nu| + d ln(1 + nis) + r . |omega|) P_v), P_v random per scan, speeds
    0-20 m/s, body rates up to 0.05 rad/s with r = (5, 10, 2) s/rad, Doppler NIS per dof chi-square(3) / 3 times 1
    or 20 (a manoeuvre on one scan in five; a tenth of the scans have none, NaN): the maximum likelihood factor is
    the true one within 15 % at 3 and 15 m/s, at rest and in a manoeuvre, at rates alike on every axis (0.01 and
    0.025 rad/s; 6000 scans; over 80 draws the largest error was 9 %: at the range's edge, rates 0, the intercept is
    less sure, 16 %; within 15 % where the factor is smallest beside a large Doppler term: a = 0.25, d = 2 read 12 %
    low at a factor of 0.5), within 6 of its standard errors there and at 0.05 rad/s about one axis (where one
    axis's coefficient alone decides and the data say little: seed 320, 18 % off), and after it the mean NEES/dof
    is 1 within 3 %."""
    rng = _rng(seed)
    n = 6000
    t = 0.1 * np.arange(n)
    speed = rng.uniform(0.0, 20.0, n)
    u = rng.normal(size=(n, 3))
    r = np.array([5.0, 10.0, 2.0])
    varpi = np.concatenate([speed[:, None] * u / np.linalg.norm(u, axis=1, keepdims=True),
                            rng.uniform(-0.05, 0.05, (n, 3))], axis=1)
    nis = rng.chisquare(3, n) / 3 * np.where(rng.random(n) < 0.2, 20.0, 1.0)
    nis[rng.random(n) < 0.1] = np.nan
    A = rng.normal(size=(n, 12, 12)) * 0.05
    P = A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(12)
    c = a + b * speed + d * np.log1p(np.nan_to_num(nis)) + np.abs(varpi[:, 3:]) @ r
    L = np.linalg.cholesky(c[:, None, None] * P[:, 6:12, 6:12])
    e = np.einsum("kij,kj->ki", L, rng.normal(size=(n, 6)))
    states = {"t": t, "varpi": varpi, "P": P, "doppler_nis": nis}
    fit = fit_velocity_inflation(states, {"t": t, "varpi": varpi + e})
    # every scan fitted: none is a gross failure at the drawn factor (NEES above 100 per dof)
    assert fit["scans"] == n and fit["gross_failures"] == {"scans": 0, "runs": [], "t": []}
    # the factor's standard error at a point, from the expected information of the six coefficients (e_k ~ N(0,
    # c_k P_k), 6 dof: I = 3 sum_k j_k j_k^T / c_k^2, j_k = dc_k / d(a, b, d, r); on 40 seeds the coefficients'
    # errors over it have standard deviations 0.8-1.1). The rate coefficients rest on rates of at most 0.05 rad/s,
    # so one axis's is known to a few s/rad. Hypothesis searches 65536 seeds for a failure, so the bound is 6 of
    # them (a draw beyond it about 1e-9 per point), not 4: seed 320, which its search found, has r_y 0.28 for 10,
    # 4.9 standard errors off, the likelihood 18 above the truth's, the factor at a single-axis rate 18 % off
    J = np.c_[np.ones(n), speed, np.log1p(np.nan_to_num(nis)), np.abs(varpi[:, 3:])]
    cov = np.linalg.inv(3.0 * (J / c[:, None] ** 2).T @ J)
    for s in (3.0, 15.0):
        for x in (0.0, 1.0, 20.0):
            for w in (np.full(3, 0.01), np.full(3, 0.025), *(0.04 * np.eye(3) + 0.01)):
                want = a + b * s + d * np.log1p(x) + w @ r
                got = fit["inflation"] + fit["per_speed"] * s + fit["per_doppler"] * np.log1p(x) + w @ fit["per_rate"]
                j = np.r_[1.0, s, np.log1p(x), w]
                assert abs(got - want) < 6.0 * np.sqrt(j @ cov @ j), fit
                if np.all(w == w[0]):  # the rates alike on every axis: what the drives' calibration leans on
                    assert got == pytest.approx(want, rel=0.15), fit
    assert fit["nees_per_dof"][1] == pytest.approx(1.0, abs=0.03)
    terms = (fit["inflation"], fit["per_speed"], fit["per_doppler"], None, fit["per_rate"])
    scaled = rs.velocity_inflated_states(states, *terms)
    c_fit = (fit["inflation"] + fit["per_speed"] * speed + fit["per_doppler"] * np.log1p(np.nan_to_num(nis))
             + np.abs(varpi[:, 3:]) @ fit["per_rate"])
    np.testing.assert_allclose(scaled["P"][:, 6:12, 6:12], c_fit[:, None, None] * P[:, 6:12, 6:12])
    # from states that already carry factors, the same fit: it is relative to the window's covariance (the same
    # factor on every scan to the optimiser's tolerance: with the rate terms six coefficients share a flat
    # likelihood, seed 609: 1.5e-5 of the factor; a coefficient near its bound 0 may differ by more than that of
    # itself, seed 244 below: 2.6e-9 in b = 0.0016)
    again = fit_velocity_inflation(scaled, {"t": t, "varpi": varpi + e})
    c_again = (again["inflation"] + again["per_speed"] * speed + again["per_doppler"] * np.log1p(np.nan_to_num(nis))
               + np.abs(varpi[:, 3:]) @ again["per_rate"])
    np.testing.assert_allclose(c_again, c_fit, rtol=1e-4)
    # without rate terms asked for, none
    assert fit_velocity_inflation(states, {"t": t, "varpi": varpi + e}, per_rate=False)["per_rate"] == [0.0] * 3
    # without the Doppler NIS (a run before it) the Doppler term cannot be learned, and is 0
    plain = fit_velocity_inflation({"t": t, "varpi": varpi, "P": P}, {"t": t, "varpi": varpi + e})
    assert plain["per_doppler"] == 0.0


@given(seed=st.integers(0, 2**16), with_bias=st.booleans())
@settings(max_examples=15, deadline=None)
def test_the_likelihood_gradient_matches_finite_differences(seed, with_bias):
    """The fit's -2 log-likelihood of e ~ N(0, c D P D + b b^T) (Sherman-Morrison in q_ee, q_eb, q_bb) equals the
    direct one, and its gradient in the factor's terms and the per-axis log factors matches central finite
    differences (with b = 0: the factor's likelihood alone)."""
    from rodo.validation.calibrate_velocity import _nll

    rng = _rng(seed, 3)
    n = 40
    A = rng.normal(size=(n, 6, 6))
    P = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(6)
    e, b = rng.normal(size=(n, 6)), rng.normal(size=(n, 6)) * with_bias
    X = np.column_stack([np.ones(n), rng.uniform(0, 2, (n, 5))])
    Pi = np.linalg.inv(P)
    M_ee = e[:, :, None] * e[:, None, :] * Pi
    M_eb = 0.5 * (e[:, :, None] * b[:, None, :] + b[:, :, None] * e[:, None, :]) * Pi
    M_bb = b[:, :, None] * b[:, None, :] * Pi
    x = np.r_[rng.uniform(0.5, 2.0), rng.uniform(0, 0.5, 5), rng.normal(0, 0.5, 5)]
    f, grad = _nll(x, X, M_ee, M_eb, M_bb)
    g = np.exp(np.r_[x[6:], -np.sum(x[6:])])
    S = (X @ x[:6])[:, None, None] * P * np.sqrt(g[:, None] * g[None, :]) + b[:, :, None] * b[:, None, :]
    direct = np.sum(np.linalg.slogdet(S)[1] + np.einsum("ki,kij,kj->k", e, np.linalg.inv(S), e))
    assert f == pytest.approx(direct - np.sum(np.linalg.slogdet(P)[1]), rel=1e-9)  # log |P|: a constant
    step = 1e-6
    numeric = [(_nll(x + step * u, X, M_ee, M_eb, M_bb)[0] - _nll(x - step * u, X, M_ee, M_eb, M_bb)[0]) / (2 * step)
               for u in np.eye(len(x))]
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-5 * np.abs(grad).max())


@given(seed=st.integers(0, 2**16))
@settings(max_examples=4, deadline=None)
def test_the_lag_and_the_factor_are_recovered_together(seed):
    """Velocity errors drawn as a bias L a_k, a_k the states' own smoothed forward and yaw acceleration
    (manoeuvres of 2-6 s at up to 3 m/s^2 and 0.25 rad/s^2 between 1 and 19 m/s, `lag_accelerations`), plus
    N(0, c P_k) with c = 0.6 +
    0.04 |nu|: the lag comes back as L within 10 % of its largest element, the factor within 10 % at 3 and 15 m/s,
    and the mean NEES/dof after the fit is 1 within 4 %. The factor fitted without the lag is larger (it takes up
    the bias); the states at the fit (`velocity_inflated_states`) refit to the same."""
    from rodo.estimator.uncertainty import fresh_starts
    from rodo.estimator.velocity_lag import lag_accelerations

    rng = _rng(seed, 4)
    n, dt = 6000, 0.077
    t = dt * np.arange(n)
    control = np.zeros((n, 2))
    k = 0
    while k < n:  # piecewise constant forward and yaw accelerations, half of the time none
        m = int(rng.uniform(2.0, 6.0) / dt)
        control[k:k + m] = np.array([rng.uniform(-3, 3), rng.uniform(-0.25, 0.25)]) * (rng.random() < 0.5)
        k += m
    varpi = np.zeros((n, 6))
    varpi[0, 0] = 8.0
    for k in range(1, n):  # the forward acceleration turns back at 1 and 19 m/s
        if not 1.0 < varpi[k - 1, 0] + control[k, 0] * dt < 19.0:
            control[k:, 0] *= -1.0
        varpi[k, 0] = varpi[k - 1, 0] + control[k, 0] * dt
    varpi[:, 5] = np.cumsum(control[:, 1]) * dt
    varpi[:, [1, 2, 3, 4]] = rng.normal(0, 0.01, (n, 4))
    A = rng.normal(size=(n, 12, 12)) * 0.005
    P = A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(12)
    a = lag_accelerations(varpi, t, fresh_starts(None, n), 0.3)
    L = np.array([[0.01, 0.0], [0.0, -0.1], [0.0, 0.0], [0.0, 0.02], [0.0, 0.0], [0.0, 0.03]])
    c = 0.6 + 0.04 * np.linalg.norm(varpi[:, :3], axis=1)
    e = a @ L.T + np.einsum("kij,kj->ki", np.linalg.cholesky(c[:, None, None] * P[:, 6:12, 6:12]),
                            rng.normal(size=(n, 6)))
    states, truth = {"t": t, "varpi": varpi, "P": P}, {"t": t, "varpi": varpi + e}
    fit = fit_velocity_inflation(states, truth, per_rate=False, lag=True, lag_time=0.3)
    got = np.column_stack([fit["lag_per_acceleration"], fit["lag_per_yaw_acceleration"]])
    np.testing.assert_allclose(got, L, atol=0.1 * np.abs(L).max())
    for s in (3.0, 15.0):
        assert fit["inflation"] + fit["per_speed"] * s == pytest.approx(0.6 + 0.04 * s, rel=0.1), fit
    assert fit["nees_per_dof"][1] == pytest.approx(1.0, abs=0.04)
    plain = fit_velocity_inflation(states, truth, per_rate=False)
    assert plain["lag_per_yaw_acceleration"] == [0.0] * 6
    assert plain["inflation"] + plain["per_speed"] * 8.0 > fit["inflation"] + fit["per_speed"] * 8.0
    replay = rs.velocity_inflated_states(states, fit["inflation"], fit["per_speed"], lag=got, lag_time=0.3)
    again = fit_velocity_inflation(replay, truth, per_rate=False, lag=True, lag_time=0.3)
    np.testing.assert_allclose(np.column_stack([again["lag_per_acceleration"], again["lag_per_yaw_acceleration"]]),
                               got, rtol=1e-6, atol=1e-9)
    assert again["inflation"] == pytest.approx(fit["inflation"], rel=1e-4)


@given(seed=st.integers(0, 2**16))
@settings(max_examples=5, deadline=None)
def test_a_gross_failure_is_left_out_of_the_velocity_fit(seed):
    """Velocity errors drawn from N(0, (a + d ln(1 + nis)) P_v) over two runs of 2000 scans, with a = 0.3, d = 0.3,
    and in the second run, for four scans at 12.5-12.8 s, an outright failure: the errors 300 times their
    covariance's size and the Doppler NIS 500, as at the mover of docs/calibration.md ("Gross failures"). Those
    four are the scans left out, named by run and time; the factor is the clean one within 15 % at NIS 0, 1 and
    20, where the plain fit, following the failures, reads the Doppler term several times too large."""
    rng = _rng(seed, 42)
    runs, truths = [], []
    for k in range(2):
        n = 2000
        t = 100.0 * k + 0.1 * np.arange(n)
        nis = rng.chisquare(3, n) / 3 * np.where(rng.random(n) < 0.2, 20.0, 1.0)
        varpi = np.concatenate([rng.uniform(0, 20, (n, 1)), np.zeros((n, 5))], axis=1)
        A = rng.normal(size=(n, 12, 12)) * 0.05
        P = A @ np.swapaxes(A, 1, 2) + 1e-4 * np.eye(12)
        c = 0.3 + 0.3 * np.log1p(nis)
        e = np.einsum("kij,kj->ki", np.linalg.cholesky(c[:, None, None] * P[:, 6:12, 6:12]), rng.normal(size=(n, 6)))
        if k == 1:
            bad = np.arange(125, 129)
            e[bad] *= 300.0
            nis[bad] = 500.0
        runs.append({"t": t, "varpi": varpi, "P": P, "doppler_nis": nis})
        truths.append({"t": t, "varpi": varpi + e})
    fit = fit_velocity_inflation(runs, truths)
    assert fit["gross_failures"] == {"scans": 4, "runs": [1] * 4, "t": [12.5, 12.6, 12.7, 12.8]}
    assert fit["scans"] == 3996
    for x in (0.0, 1.0, 20.0):
        got = fit["inflation"] + fit["per_doppler"] * np.log1p(x)
        assert got == pytest.approx(0.3 + 0.3 * np.log1p(x), rel=0.15), fit
    terms = cv._velocity_terms(runs, truths, 1e-6, None)
    plain = cv._fit(terms, np.ones(len(terms["e"]), bool), False, True)[0]
    assert plain[2] > 3 * 0.3, plain
