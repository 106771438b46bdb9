"""`rodo calibrate`'s jitter fit (rodo.validation.calibrate_jitter): on runs whose pose errors follow the drift
model plus a smooth roll and pitch jitter of known variance, the fit recovers that variance, whatever the other
axes do; on runs without one it finds none worth the name; the span measures then read the run's own jitter."""

import numpy as np
import pytest

from rodo.estimator.attitude_jitter import absolute_excess, span_variance
from rodo.estimator.lie import se3
from rodo.validation import calibrate_jitter as cj
from rodo.validation import replayed_states as rs
from rodo.validation.odometry_consistency import odometry_nees
from tests.validation.synthetic_drives import stated_run, straight_drive

DT, N, T_JITTER = 0.1, 800, 1.0
SIGMA = np.array([3e-3, 3e-3, 3e-3, 2e-4, 2e-4, 5e-4])  # per scan


def _path(rng, V: float) -> np.ndarray:
    """(N, 2) a roll and pitch path of the stationary process Cov(j(s), j(s + L)) = V exp(-(L / T)^2)."""
    t = DT * np.arange(N)
    w, U = np.linalg.eigh(V * np.exp(-np.square((t[:, None] - t[None, :]) / T_JITTER)))
    return (U * np.sqrt(np.clip(w, 0.0, None))) @ rng.standard_normal((N, 2))


def _run(seed: int, V: float, scale=np.ones(6)):
    """(states, truth) of a drive whose pose error is the drift recursion's (tau 0, no drift rate,
    xi_k = Ad(R_k) xi_{k-1} + delta_k, delta_k ~ N(0, diag(SIGMA^2))) plus the jitter's roll and pitch, measured
    from the first scan (where the truth is aligned), the states carrying the one-scan covariance as P_relative
    (delta's and the jitter's change over one scan).
    Driven slowly (0.6-1 m/s): a pose's rotation error, carried over a span by the distance, moves the span's
    position, which the jitter leaves out (it is the registration's tilt, which does not move the position it
    solves: docs/consistency.md); at 0.8 m per span that is 2 % of the position's variance here. `scale`: the
    per-scan errors' sigmas over the ones P_relative states (ones: as stated)."""
    rng = np.random.default_rng(np.random.SeedSequence([2026, 31, seed]))
    T_true = straight_drive(rng, N, step_range=(0.06, 0.1))
    j = _path(rng, V)
    j -= j[0]
    x, errors = np.zeros(6), [np.zeros(6)]
    for k in range(1, N):
        x = se3.adjoint(T_true[k] @ se3.inverse(T_true[k - 1])) @ x + rng.normal(size=6) * SIGMA * scale
        errors.append(x + np.r_[0.0, 0.0, 0.0, j[k], 0.0])
    stated = np.diag(SIGMA**2)
    stated[3:5, 3:5] += np.eye(2) * span_variance(DT, (V, T_JITTER))  # the one-scan change, as f would fit it
    states, truth = stated_run(DT, T_true, errors, stated)
    return rs.replayed(states, 0.0, None), truth


@pytest.mark.parametrize("seed", [1, 2])
def test_the_fit_recovers_the_jitters_variance(seed):
    """Four runs pooled with a jitter of V = 4e-6 rad^2 (2 mrad) at T = 1 s: the relative pose over 1 s is
    over-confident without it (mean NEES/dof > 1.3), the fitted V is within 30 % of the true one (about 300
    independent seconds of jitter) and brings the mean to 1."""
    V = 4e-6
    runs = [_run(4 * seed + i, V) for i in range(4)]
    fit = cj.fit_attitude_jitter(runs, 1.0, 0.0, T_JITTER)
    assert fit["mean_without"] > 1.3, fit
    assert fit["variance"] == pytest.approx(V, rel=0.3), fit
    assert fit["mean_with"] == pytest.approx(1.0, abs=1e-6) and fit["time"] == T_JITTER
    assert fit["outcome"] == "fitted"


def test_the_other_axes_do_not_move_the_fit():
    """The same runs with the position and yaw errors three times what their covariance states: the 6-dof
    relative pose over 1 s is far over-confident, but V, fitted to the roll and pitch alone, stays within 30 % of
    the true one (fitted to all six axes it would absorb the position's over-confidence)."""
    V = 4e-6
    runs = [_run(4 + i, V, scale=np.array([3.0, 3.0, 3.0, 1.0, 1.0, 3.0])) for i in range(4)]
    fit = cj.fit_attitude_jitter(runs, 1.0, 0.0, T_JITTER)
    assert fit["variance"] == pytest.approx(V, rel=0.3), fit
    on = [odometry_nees(rs.replayed(s, 0.0, None, jitter=(fit["variance"], T_JITTER)), t, tau=0.0) for s, t in runs]
    assert np.nanmean(np.concatenate([m["relative_span"] for m in on])) / 6 > 2.0  # the position's, not fitted


def test_a_jitter_out_of_reach_is_not_written(monkeypatch):
    """Where even the top of V_RANGE leaves the roll and pitch over-confident, V is 0 and the outcome says why."""
    monkeypatch.setattr(cj, "V_RANGE", (1e-12, 1e-8))
    fit = cj.fit_attitude_jitter([_run(5, 4e-6)], 1.0, 0.0, T_JITTER)
    assert fit["outcome"] == "out of reach" and fit["variance"] == 0.0 and fit["mean_at_top"] > 1.0


def test_without_a_jitter_the_fit_finds_none_worth_the_name():
    """The same runs without a jitter: V is 0 (the mean at or below 1) or below a tenth of what the runs above
    had (a mean a little above 1 by chance)."""
    runs = [_run(20 + i, 0.0) for i in range(4)]
    fit = cj.fit_attitude_jitter(runs, 1.0, 0.0, T_JITTER)
    assert fit["variance"] < 4e-7, fit
    if fit["mean_without"] <= 1.0:
        assert fit["variance"] == 0.0 and fit["mean_with"] == fit["mean_without"]
        assert fit["outcome"] == "consistent without"
    # made consistent-or-cautious outright (every stated covariance doubled): V 0, without a search
    cautious = [(dict(s, P_relative=2 * s["P_relative"]), t) for s, t in runs]
    fit = cj.fit_attitude_jitter(cautious, 1.0, 0.0, T_JITTER)
    assert fit["outcome"] == "consistent without" and fit["variance"] == 0.0 and fit["mean_without"] < 0.8


def test_the_span_measures_read_the_runs_own_jitter():
    """`replayed` records the jitter it composed the absolute pose with (the jitter since the first scan on roll
    and pitch), and the span measures use the run's own when not told otherwise."""
    states, truth = _run(3, 4e-6)
    on = rs.replayed(states, 0.0, None, jitter=(4e-6, T_JITTER))
    np.testing.assert_array_equal(on["attitude_jitter"], [4e-6, T_JITTER])
    added = on["P_pose_absolute"] - states["P_pose_absolute"]
    np.testing.assert_allclose(added[:, 3, 3], absolute_excess(states["t"], (4e-6, T_JITTER)), rtol=1e-6, atol=1e-16)
    assert added[10, 3, 3] > 1e-6  # 1 s in
    own = odometry_nees(on, truth, tau=0.0)
    given = odometry_nees(on, truth, tau=0.0, jitter=(4e-6, T_JITTER))
    off = odometry_nees(on, truth, tau=0.0, jitter=(0.0, 1.0))
    np.testing.assert_array_equal(own["relative_span"], given["relative_span"])
    assert np.nanmean(own["relative_span"]) < np.nanmean(off["relative_span"])
    np.testing.assert_array_equal(own["relative_scan"], off["relative_scan"])  # no excess over one scan
    assert np.nanmean(own["relative_span"]) / 6 == pytest.approx(1.0, abs=0.25)  # the model the errors follow
    assert np.nanmean(off["relative_span"]) / 6 > 1.3


def test_runs_without_spans_keep_the_jitter_off():
    """No spans (runs too short for one): V 0, the means NaN, the outcome saying so."""
    states, truth = _run(4, 0.0)
    short = {k: (v[:5] if np.ndim(v) and len(v) == N else v) for k, v in states.items()}
    fit = cj.fit_attitude_jitter([(short, {k: v[:5] for k, v in truth.items()})], 1.0, 0.0, T_JITTER)
    assert fit["variance"] == 0.0 and np.isnan(fit["mean_without"]) and fit["outcome"] == "no spans"
