"""The one-scan relative pose covariance's factor f + r . |omega| + d ln(1 + nis) + p pull
(rodo.validation.calibrate_relative, `rodo calibrate`'s uncertainty section): the fit recovers a factor the errors
were drawn with, a run at one factor is the replay of a run at another, and the one-scan terms the fit works on
give the measure's own NEES."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.validation import calibrate_relative as cr
from rodo.validation.gross_failures import gross_failures
from rodo.validation import replayed_states as rs
from rodo.validation.odometry_consistency import odometry_nees


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([2026, 36, *key]))


def _spd(rng, n, scale):
    L = rng.normal(size=(n, 6, 6)) * scale
    return L @ np.swapaxes(L, 1, 2) + 1e-3 * scale**2 * np.eye(6)


@settings(max_examples=6, deadline=None)
@given(f=st.floats(0.1, 2.0), r=st.tuples(*[st.floats(0.0, 60.0)] * 3), d=st.floats(0.0, 1.0),
       p=st.floats(0.0, 0.5), seed=st.integers(0, 2**32 - 1))
def test_the_fit_recovers_a_known_rate_factor(f, r, d, p, seed):
    """Errors drawn from N(0, c_k A_k + V_k), c_k = f + r . W_k + d D_k + p P_k (W the absolute rates, up to 0.03
    rad/s; D = ln(1 + nis), up to 1; P the pull, chi-square with 6 dof per dof; V a third of A's size): the
    maximum likelihood shape and the mean level recover f, r, d and p (each within 20 % of the factor's typical
    size, 3000 scans: the worst of 60 draws was 7 % before the pull), and the mean ratio after is 1."""
    rng = _rng(seed)
    k = 3000
    A, V = _spd(rng, k, 1.0), _spd(rng, k, 0.3)
    W = np.column_stack([rng.uniform(0.0, 0.03, size=(k, 3)), rng.uniform(0.0, 1.0, size=k),
                         rng.chisquare(6, size=k) / 6])
    c = f + W @ np.r_[r, d, p]
    L = np.linalg.cholesky(c[:, None, None] * A + V)
    e = (L @ rng.normal(size=(k, 6, 1)))[..., 0]
    fit = cr.fit_factor(e, A, V, W, 1.0, rates=True)
    typical = f + 0.015 * sum(r) + 0.5 * d + p
    assert fit["outcome"] == "fitted"
    assert fit["inflation"] == pytest.approx(f, abs=0.2 * typical), fit
    np.testing.assert_allclose(fit["per_rate"], r, atol=0.2 * typical / 0.015)
    assert fit["per_doppler"] == pytest.approx(d, abs=0.2 * typical / 0.5)
    assert fit["per_pull"] == pytest.approx(p, abs=0.2 * typical)
    assert fit["mean_ratio"][1] == pytest.approx(1.0, abs=2e-3)


@settings(max_examples=6, deadline=None)
@given(f=st.floats(0.1, 2.0), r=st.floats(0.0, 60.0), g=st.floats(0.05, 1.0), seed=st.integers(0, 2**32 - 1))
def test_the_fit_recovers_a_known_velocity_error_share(f, r, g, seed):
    """Errors drawn from N(0, c_k A_k + g V_velocity,k + V_k), c_k = f + r |omega_z,k| (V_velocity the size of A,
    V a tenth): the maximum likelihood learns g with the factor's shape (within 15 % of its size at 3000 scans
    from runs at g = 1, and from runs at g = 0.5, whose V_velocity is half as large), and the mean ratio after
    is 1."""
    rng = _rng(seed, 1)
    k = 3000
    A, V_velocity, V = _spd(rng, k, 1.0), _spd(rng, k, 1.0), _spd(rng, k, 0.1)
    W = np.column_stack([np.zeros((k, 2)), rng.uniform(0.0, 0.03, size=k)])
    c = f + r * W[:, 2]
    L = np.linalg.cholesky(c[:, None, None] * A + g * V_velocity + V)
    e = (L @ rng.normal(size=(k, 6, 1)))[..., 0]
    for ran in (1.0, 0.5):
        fit = cr.fit_factor(e, A, V, W, 1.0, rates=True, V_velocity=ran * V_velocity, share=ran)
        assert fit["outcome"] == "fitted"
        assert fit["velocity_error_share"] == pytest.approx(g, abs=0.15 * max(g, 0.3)), (fit, g)
        assert fit["inflation"] == pytest.approx(f, abs=0.2 * (f + 0.015 * r)), fit
        assert fit["mean_ratio"][1] == pytest.approx(1.0, abs=2e-3)


@settings(max_examples=6, deadline=None)
@given(f=st.floats(0.1, 2.0), g=st.floats(0.05, 0.8), g_v=st.floats(0.0, 0.15), seed=st.integers(0, 2**32 - 1))
def test_the_fit_recovers_a_share_growing_with_the_speed(f, g, g_v, seed):
    """Errors drawn from N(0, f A_k + (g + g_v v_k) V_velocity,k + V_k), the speed v_k from 0 to 10 m/s (a fifth of
    the scans at rest): the maximum likelihood learns g and g_v with the factor (within 15 % of the share's size at
    5 m/s, 3000 scans), and the mean ratio after is 1; without the speeds the fit has a share alone."""
    rng = _rng(seed, 2)
    k = 3000
    A, V_velocity, V = _spd(rng, k, 1.0), _spd(rng, k, 1.0), _spd(rng, k, 0.1)
    W = np.zeros((k, 3))
    speed = np.where(rng.uniform(size=k) < 0.2, 0.0, rng.uniform(0.0, 10.0, size=k))
    L = np.linalg.cholesky(f * A + (g + g_v * speed)[:, None, None] * V_velocity + V)
    e = (L @ rng.normal(size=(k, 6, 1)))[..., 0]
    fit = cr.fit_factor(e, A, V, W, 1.0, rates=True, V_velocity=V_velocity, speed=speed)
    size = g + 5.0 * g_v
    assert fit["outcome"] == "fitted"
    assert fit["velocity_error_share"] == pytest.approx(g, abs=0.15 * size), (fit, g, g_v)
    assert fit["velocity_error_share_per_speed"] == pytest.approx(g_v, abs=0.15 * size / 5.0), (fit, g, g_v)
    assert fit["mean_ratio"][1] == pytest.approx(1.0, abs=2e-3)
    alone = cr.fit_factor(e, A, V, W, 1.0, rates=True, V_velocity=V_velocity)
    assert alone["velocity_error_share_per_speed"] == 0.0


def test_without_rates_the_fit_is_a_mean_level():
    """Without the rates the fit scales f (and the run's r with it) to the mean ratio 1, or keeps them within
    the tolerance; an unscaled share alone too cautious is out of reach."""
    rng = _rng(1)
    k = 2000
    A, V = _spd(rng, k, 1.0), _spd(rng, k, 0.3)
    W = rng.uniform(0.0, 0.03, size=(k, 3))
    e = (np.linalg.cholesky(2.0 * A + V) @ rng.normal(size=(k, 6, 1)))[..., 0]
    fit = cr.fit_factor(e, A, V, W, 0.5, (10.0, 0.0, 20.0), 0.1)
    assert fit["outcome"] == "fitted" and fit["mean_ratio"][0] > 1.5
    assert fit["per_rate"][1] == 0.0
    assert fit["per_rate"][2] == pytest.approx(40.0 * fit["inflation"], rel=1e-12)  # the shape kept
    assert fit["mean_ratio"][1] == pytest.approx(1.0, abs=2e-3)
    same = cr.fit_factor(e, A, V, W, fit["inflation"], fit["per_rate"], 0.1)
    assert same["outcome"] == "within tolerance" and same["inflation"] == fit["inflation"]
    cautious = 1e3 * (V + 0.3 * np.eye(6))  # every direction: a mean is not reached through a near-singular V
    assert cr.fit_factor(e, A, cautious, W, 1.0, None, 0.1)["outcome"] == "out of reach"


@settings(max_examples=6, deadline=None)
@given(f=st.floats(0.1, 2.0), spread=st.floats(0.0, 0.9), seed=st.integers(0, 2**32 - 1))
def test_the_level_is_the_mean_where_the_nees_is_less_dispersed_than_chi_square(f, spread, seed):
    """Errors whose whitened length is less dispersed than a Gaussian's (NEES / 6 uniform on 1 -/+ spread at the
    true factor f, as where the factor follows each scan's own error): the level makes the mean NEES per dof 1,
    what the campaigns' N-run averages test, and so recovers f (a median level would put it 5-11 % cautious: the
    median of chi2(6) is 5.35); with or without the rates' shape fitted first. The share V is unscaled."""
    rng = _rng(seed, 3)
    k = 12000  # the mean NEES of 3000 scans at spread 0.9 was off by 2 % in one draw of a few dozen
    A, V = _spd(rng, k, 1.0), _spd(rng, k, 0.1)
    u = rng.normal(size=(k, 6))
    u *= np.sqrt(6.0 * rng.uniform(1.0 - spread, 1.0 + spread, size=k) / np.sum(u * u, axis=1))[:, None]
    e = (np.linalg.cholesky(f * A + V) @ u[..., None])[..., 0]
    W = rng.uniform(0.0, 0.03, size=(k, 3))
    for rates in (False, True):
        fit = cr.fit_factor(e, A, V, W, 1.0, None, 0.0, rates=rates)
        c = fit["inflation"] + W @ np.asarray(fit["per_rate"])
        nees = cr._nees(c, e, A, V)
        assert np.mean(nees) / 6.0 == pytest.approx(1.0, abs=2e-3), fit
        assert fit["mean_ratio"][1] == pytest.approx(1.0, abs=2e-3)
        assert np.median(nees) / 6.0 == pytest.approx(1.0, abs=0.03)  # the truth's median, not chi-square's
        assert fit["inflation"] == pytest.approx(f, rel=0.1 if rates else 0.02), fit


@pytest.fixture(scope="module")
def blockage_runs():
    """blockage (a re-initialisation at its 5-7 s blackout), CV/C at f 1, at f 0.4 with rate, Doppler and pull
    terms, at f 1 with a velocity error's share of 0.3, with that share and a registration's correlation of 0.6,
    and with a share of 0.2 + 0.05 s/m x speed and that correlation."""
    from rodo.validation.driver import run_sequence

    seq, truth = scenarios.get("blockage").simulate(0, 8.0)
    runs = {}
    factors = {"plain": (1.0, (0.0,) * 3, 0.0, 0.0, 1.0, 0.0), "rates": (0.4, (80.0, 120.0, 5.0), 0.3, 0.2, 1.0, 0.0),
               "share": (1.0, (0.0,) * 3, 0.0, 0.0, 0.3, 0.0), "correlated": (1.0, (0.0,) * 3, 0.0, 0.0, 0.3, 0.6),
               "speed": (1.0, (0.0,) * 3, 0.0, 0.0, 0.2, 0.6)}
    for key, (f, r, d, p, g, alpha) in factors.items():
        config = OdometryConfig.for_model("cv-cartesian")
        config = config.replace(uncertainty=dataclasses.replace(
            config.uncertainty, velocity_correlation_time=0.4, inflation=f, inflation_per_rate=r,
            inflation_per_doppler=d, inflation_per_pull=p, velocity_error_share=g, registration_correlation=alpha,
            velocity_error_share_per_speed=0.05 if key == "speed" else 0.0,
            drift_rate_sigma=(1e-4, 1e-4, 5e-4, 3e-5, 3e-5, 1e-5)))
        runs[key] = run_sequence(seq, config).state_arrays()
    return runs, truth


def test_a_run_at_a_rate_factor_is_the_replay_of_a_run_without(blockage_runs):
    """The rate, Doppler and pull terms change the report, not the estimate; the run at (0.4, r, d, p) writes what
    `relative_factor_states` makes of the run at (1, 0, 0, 0): every relative covariance scaled by its scan's factor
    but the re-initialisation's dead-reckoned one, and the same absolute covariances replayed."""
    runs, _ = blockage_runs
    plain, rated = runs["plain"], runs["rates"]
    np.testing.assert_array_equal(plain["T_vehicle_world"], rated["T_vehicle_world"])
    np.testing.assert_array_equal(plain["varpi"], rated["varpi"])
    np.testing.assert_array_equal(plain["pose_pull"], rated["pose_pull"])
    factor = cr.relative_factor(plain["varpi"], 0.4, (80.0, 120.0, 5.0), 0.3, plain["doppler_nis"], 0.2,
                                plain["pose_pull"])
    assert np.ptp(factor[1:]) > 0.05 * np.median(factor)  # the rates and the Doppler term move it
    assert np.ptp(factor[1:] - cr.relative_factor(plain["varpi"], 0.4, (80.0, 120.0, 5.0))[1:]) > 0.01
    without_pull = cr.relative_factor(plain["varpi"], 0.4, (80.0, 120.0, 5.0), 0.3, plain["doppler_nis"])
    assert np.ptp(factor[1:] - without_pull[1:]) > 0.01  # and the pull
    emulated = cr.relative_factor_states(plain, (1.0, (0.0,) * 3, 0.0, 0.0), (0.4, (80.0, 120.0, 5.0), 0.3, 0.2))
    for key in ("P_relative", "P_revision"):
        np.testing.assert_allclose(emulated[key][1:], rated[key][1:], rtol=1e-12, atol=1e-18)
    r = int(np.flatnonzero(plain["restarted"])[0])
    np.testing.assert_array_equal(rated["P_relative"][r], plain["P_relative"][r])
    np.testing.assert_allclose(rs.absolute_covariances(emulated, 0.4, plain["drift_rate_sigma"]),
                               rated["P_pose_absolute"], rtol=1e-9, atol=1e-15)


def test_the_one_scan_terms_give_the_measures_nees(blockage_runs):
    """e^T (c A + V)^-1 e of `relative_terms`, at the run's own factors, is `odometry_nees`'s one-scan relative
    pose NEES scan by scan (the restart left out); and the fitted factor, replayed, has the mean ratio 1 (its gross
    failures left out)."""
    runs, truth = blockage_runs
    states = runs["rates"]
    e, A, V, W = cr.relative_terms(states, truth, 0.4, (80.0, 120.0, 5.0), per_doppler=0.3, per_pull=0.2)
    c = 0.4 + W @ np.array([80.0, 120.0, 5.0, 0.3, 0.2])
    own = np.einsum("ki,ki->k", e, np.linalg.solve(c[:, None, None] * A + V, e[..., None])[..., 0])
    m = odometry_nees(states, truth, tau=0.4)["relative_scan"]
    m = m[np.isfinite(m)]
    assert len(own) == len(m) - 1  # the restart's step
    assert np.sum(np.isin(np.round(own, 9), np.round(m, 9))) == len(own)
    fit = cr.fit_relative_inflation(states, truth, 0.4, 0.1, per_rate=(80.0, 120.0, 5.0), rates=True, per_doppler=0.3,
                                    per_pull=0.2)
    replayed = cr.relative_factor_states(states, (0.4, (80.0, 120.0, 5.0), 0.3, 0.2),
                                         (fit["inflation"], fit["per_rate"], fit["per_doppler"], fit["per_pull"]))
    after = odometry_nees(replayed, truth, tau=0.4)["relative_scan"]  # every scan has truth: row k is scan k
    after[np.asarray(states["restarted"], dtype=bool)] = np.nan  # not the fit's
    assert cr.mean_ratio(after[~gross_failures(after, 6)]) == pytest.approx(1.0, abs=5e-3)


def test_a_run_at_a_velocity_error_share_is_the_replay_of_a_run_without(blockage_runs):
    """The velocity error's share and the registration's correlation change the drift recursion, not the estimate:
    the run at g = 0.3 (and alpha = 0.6) reports the absolute covariances the run at g = 1 (alpha = 0) replays with
    them (across its re-initialisation too), records them, and its one-scan terms split into g times the velocity
    error's share at g = 1 and the same rest."""
    runs, truth = blockage_runs
    plain, shared = runs["plain"], runs["share"]
    np.testing.assert_array_equal(plain["T_vehicle_world"], shared["T_vehicle_world"])
    np.testing.assert_array_equal(plain["P_relative"], shared["P_relative"])
    assert float(shared["velocity_error_share"]) == 0.3 and float(plain["velocity_error_share"]) == 1.0
    assert not np.allclose(plain["P_pose_absolute"][-1], shared["P_pose_absolute"][-1], rtol=0.05)
    np.testing.assert_allclose(rs.absolute_covariances(dict(plain, velocity_error_share=0.3), 0.4,
                                                       plain["drift_rate_sigma"]),
                               shared["P_pose_absolute"], rtol=1e-9, atol=1e-15)
    e1, A1, Vv1, Vr1, _ = cr.relative_terms_split(plain, truth, 1.0)
    e3, A3, Vv3, Vr3, _ = cr.relative_terms_split(shared, truth, 1.0)
    np.testing.assert_array_equal(e1, e3)
    np.testing.assert_allclose(Vv3, 0.3 * Vv1, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(Vr3, Vr1, rtol=1e-9, atol=1e-18)
    assert np.trace(Vv1, axis1=1, axis2=2).min() > 0  # the velocity error's share is there to scale
    correlated = runs["correlated"]  # the registration's correlation too: the recursion and its replay agree
    assert float(correlated["registration_correlation"]) == 0.6
    np.testing.assert_array_equal(plain["P_relative"], correlated["P_relative"])
    np.testing.assert_allclose(rs.absolute_covariances(dict(plain, velocity_error_share=0.3,
                                                            registration_correlation=0.6), 0.4,
                                                       plain["drift_rate_sigma"]),
                               correlated["P_pose_absolute"], rtol=1e-9, atol=1e-15)
    assert not np.allclose(shared["P_pose_absolute"][-1], correlated["P_pose_absolute"][-1], rtol=0.05)
    speed = runs["speed"]  # and the share's growth with the speed
    assert float(speed["velocity_error_share_per_speed"]) == 0.05
    np.testing.assert_array_equal(plain["P_relative"], speed["P_relative"])
    np.testing.assert_allclose(rs.absolute_covariances(dict(plain, velocity_error_share=0.2,
                                                            velocity_error_share_per_speed=0.05,
                                                            registration_correlation=0.6), 0.4,
                                                       plain["drift_rate_sigma"]),
                               speed["P_pose_absolute"], rtol=1e-9, atol=1e-15)
    assert not np.allclose(correlated["P_pose_absolute"][-1], speed["P_pose_absolute"][-1], rtol=0.05)
    _, _, Vv4, Vr4, _ = cr.relative_terms_split(correlated, truth, 1.0)
    _, _, Vv5, Vr5, _, v = cr.relative_terms_split(speed, truth, 1.0, with_speed=True)
    np.testing.assert_allclose(Vr5, Vr4, rtol=1e-9, atol=1e-18)  # the rest has no share of the velocity error
    assert np.all(v > 2.0) and np.ptp(v) > 0.3  # 3.0-3.4 m/s
    ratio = np.trace(Vv5, axis1=1, axis2=2) / np.trace(Vv4, axis1=1, axis2=2)  # (0.2 + 0.05 v) / 0.3, over tau
    np.testing.assert_allclose(ratio, (0.2 + 0.05 * v) / 0.3, rtol=0.1)
    fit = cr.fit_relative_inflation(shared, truth, 1.0, 0.1, rates=True, share=True)
    assert fit["rest_fraction"] == 0.0 and fit["velocity_error_share_per_speed"] == 0.0  # never at rest: no g_v
    again = cr.fit_relative_inflation(plain, truth, 1.0, 0.1, rates=True, share=True)
    assert fit["velocity_error_share"] == pytest.approx(again["velocity_error_share"], rel=1e-2)  # optimiser tol.


def test_the_share_grows_with_the_speed_only_where_the_drive_stops(blockage_runs, monkeypatch):
    """The speed term is learned from a drive with REST_FRACTION of its scans below REST_SPEED (`fit_factor` with
    the speeds), and left at 0 otherwise: blockage's drive (3.0-3.4 m/s) counts as stopping below 5 m/s."""
    runs, truth = blockage_runs
    states = runs["plain"]
    e, A, V_velocity, V_rest, W, speed = cr.relative_terms_split(states, truth, 1.0, with_speed=True)
    monkeypatch.setattr(cr, "REST_SPEED", 5.0)
    fit = cr.fit_relative_inflation(states, truth, 1.0, 0.1, rates=True, share=True)
    direct = cr.fit_factor(e, A, V_rest, W, 1.0, rates=True, V_velocity=V_velocity, speed=speed)
    assert fit["rest_fraction"] == 1.0
    assert fit["velocity_error_share_per_speed"] == direct["velocity_error_share_per_speed"]
    assert fit["velocity_error_share"] == direct["velocity_error_share"]
    monkeypatch.setattr(cr, "REST_FRACTION", 1.01)  # no drive stops that long
    gated = cr.fit_relative_inflation(states, truth, 1.0, 0.1, rates=True, share=True)
    alone = cr.fit_factor(e, A, V_rest, W, 1.0, rates=True, V_velocity=V_velocity)
    assert gated["velocity_error_share_per_speed"] == 0.0
    assert gated["velocity_error_share"] == alone["velocity_error_share"]


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_a_gross_failure_is_left_out_of_the_one_scan_fit(seed):
    """One-scan errors drawn from N(0, c_k A_k + V_k), c_k = 0.5 + 0.4 ln(1 + nis_k), 3000 scans, five of them an
    outright failure (errors 300 times their covariance's size, the Doppler NIS 500): those five are left out, the
    shape and level are the clean scans' (the factor within 15 % at NIS 0, 1 and 20), where the plain maximum
    likelihood reads a Doppler term several times too large."""
    rng = _rng(seed, 42)
    k = 3000
    A, V = _spd(rng, k, 1.0), _spd(rng, k, 0.3)
    nis = rng.chisquare(3, size=k) / 3 * np.where(rng.random(k) < 0.2, 20.0, 1.0)
    bad = rng.choice(k, 5, replace=False)
    nis[bad] = 500.0
    W = np.column_stack([np.zeros((k, 3)), np.log1p(nis), np.zeros(k)])
    c = 0.5 + 0.4 * W[:, 3]
    e = (np.linalg.cholesky(c[:, None, None] * A + V) @ rng.normal(size=(k, 6, 1)))[..., 0]
    e[bad] *= 300.0
    fit = cr.fit_factor(e, A, V, W, 1.0, rates=True)
    assert fit["outcome"] == "fitted" and fit["gross_failures"] == 5
    for x in (0.0, 1.0, 20.0):
        assert fit["inflation"] + fit["per_doppler"] * np.log1p(x) == pytest.approx(0.5 + 0.4 * np.log1p(x), rel=0.15)
    plain = cr._max_likelihood(e, A, V, W, 1.0)
    assert plain[4] > 3 * 0.4, plain
