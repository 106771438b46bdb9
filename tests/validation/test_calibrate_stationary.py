"""validation/calibrate_stationary.py: the stationary error per axis recovered from drives whose pose error has
one, and none where the error is a random walk."""

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.validation import replayed_states as rs
from rodo.validation.calibrate_stationary import axis_growth, fit_stationary_error, grid_growth, same_change, \
    stationary_of
from rodo.validation.error_growth import error_growth
from tests.validation.synthetic_drives import stated_run, straight_drive

DT, N, RUNS = 0.1, 300, 4
SIGMA = np.array([3e-3, 3e-3, 3e-3, 2e-4, 2e-4, 5e-4])  # per scan, as the states say
YAW, SHARE, TIME = 5, 0.9, 1.0  # the yaw's one-scan variance: 90 % the change of an error correlated over 1 s


def _run(seed: int):
    """(states, truth) of a drive whose yaw error is a random walk of 10 % of its stated one-scan variance plus
    an exponentially correlated error s (V from SHARE and TIME, sampled exactly) carried as the model carries it
    (s_k - Ad s_0 on the absolute pose), the other axes' a random walk of their stated variance."""
    rng = np.random.default_rng(np.random.SeedSequence([2026, 47, seed]))
    T_true = straight_drive(rng, N, step_range=(0.06, 0.1))
    steps = SIGMA.copy()
    steps[YAW] *= np.sqrt(1 - SHARE)
    V = SHARE * SIGMA[YAW] ** 2 / (2 * -np.expm1(-DT / TIME))
    rho = np.exp(-DT / TIME)
    x, s = np.zeros(6), np.zeros(6)
    s[YAW] = rng.normal() * np.sqrt(V)
    s0, errors = s.copy(), [np.zeros(6)]
    for k in range(1, N):
        x = se3.adjoint(T_true[k] @ se3.inverse(T_true[k - 1])) @ x + rng.normal(size=6) * steps
        s[YAW] = rho * s[YAW] + rng.normal() * np.sqrt(V * (1 - rho**2))
        errors.append(x + s - se3.adjoint(T_true[k] @ se3.inverse(T_true[0])) @ s0)
    states, truth = stated_run(DT, T_true, errors, np.diag(SIGMA**2))
    return rs.replayed(states, 0.0, None), truth


@pytest.fixture(scope="module")
def fitted():
    runs = [_run(seed) for seed in range(RUNS)]
    return fit_stationary_error([r[0] for r in runs], [r[1] for r in runs], axes=(YAW, 0))


def test_the_fit_finds_the_yaws_stationary_error_and_none_in_a_random_walk(fitted):
    """The yaw: a share of 0.8-0.95 at 0.5-2 s (the grid's points around the truth, 0.9 and 1 s), its cost below
    the one without; the forward position, a random walk: off."""
    s, report = fitted
    yaw, x = report["axes"]["yaw"], report["axes"]["x"]
    assert 0.8 <= yaw["share"] <= 0.95 and 0.5 <= yaw["time"] <= 2.0, yaw
    assert yaw["cost"] < 0.5 * yaw["cost_without"]
    assert x["share"] == 0.0 and s[0, 0] == 0.0
    assert np.all(s[0, 1:5] == 0.0)  # the axes not fitted stay off
    np.testing.assert_allclose(report["one_scan_variance"], SIGMA**2, rtol=1e-9)
    np.testing.assert_allclose(s[:, YAW], stationary_of({YAW: (yaw["share"], yaw["time"])}, SIGMA**2, DT)[:, YAW])


def test_one_shares_times_composed_once_equal_each_composed_alone():
    """`grid_growth` over the times of one share (the same one-scan change on a steady scan interval: the runs'
    drift composed once, each error's change over a span added) equals `axis_growth` of each (1e-9), with an
    earlier axis's error on and the roll and pitch jitter in; scan intervals that are not steady take another
    change per T, and the grid then measures each alone, as `axis_growth` does."""
    runs = [_run(seed) for seed in (7, 8)]
    runs = [(dict(s, attitude_jitter=np.array([1e-7, 0.5])), t) for s, t in runs]
    spans = (0.5, 1.0, 5.0)
    grid = [stationary_of({YAW: (0.9, 1.0), 0: (0.8, time)}, SIGMA**2, DT) for time in (0.25, 1.0, 10.0)]
    assert same_change(runs, grid)
    for shared, alone in zip(grid_growth(runs, grid, spans), [axis_growth(runs, s, spans) for s in grid]):
        np.testing.assert_allclose(shared, alone, rtol=1e-9)
    assert not np.allclose(grid_growth(runs, grid, spans)[0], grid_growth(runs, grid, spans)[2])  # T tells
    rng = np.random.default_rng(np.random.SeedSequence([2026, 48]))
    uneven = [(dict(s, t=s["t"] + np.r_[0.0, rng.uniform(-0.02, 0.02, len(s["t"]) - 1)]), t) for s, t in runs]
    assert not same_change(uneven, grid)


def test_a_span_of_one_scan_at_a_slow_radar_composes_the_unreduced_inputs():
    """At a 1 Hz radar the fit's shortest span (0.5 s) is one scan: its row is the one-scan span's, the run's
    inputs without the error's change taken out (as `error_growth`'s own one-scan row), where it raised."""
    states, truth = _run(9)
    slow = dict(states, t=states["t"] * 10.0), dict(truth, t=truth["t"] * 10.0)
    on = stationary_of({YAW: (0.9, 10.0)}, SIGMA**2, 1.0)
    r = axis_growth([slow], on, (0.5, 5.0))
    one = error_growth(dict(slow[0], stationary_error=on), slow[1], (0.0,))
    np.testing.assert_allclose(r[0], one["z2"][0] / one["count"][0], rtol=1e-12)
    assert np.all(np.isfinite(r)) and not np.allclose(r[1], axis_growth([slow], None, (0.5, 5.0))[1])
