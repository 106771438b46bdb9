"""Odometry consistency measures (rodo.validation.odometry_consistency) on synthetic runs whose errors are
drawn from the covariances they report: every measure is chi-square; a run that reports a quarter of its
covariance is caught."""

import numpy as np
import pytest

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.uncertainty import DriftCovariance
from rodo.validation.consistency import chi2_bounds
from rodo.validation.odometry_consistency import MEASURES, odometry_nees, summarise

N_SCANS, N_RUNS = 16, 300


def _cov(rng, scale):
    A = rng.normal(size=(6, 6)) * scale
    return A @ A.T + 0.2 * scale**2 * np.eye(6)


def _run(rng, report_scale=1.0):
    """Truth turning at 10 m/s; the estimate chains relative poses with errors drawn from Sigma_rel and
    velocities with errors drawn from P_varpi; the states report those covariances times report_scale."""
    t = np.arange(N_SCANS) / 13.0
    T_true = np.stack([se3.exp(np.array([-10.0 * s, 0.0, 0.0, 0.0, 0.0, 0.3 * s])) for s in t])
    varpi = np.tile([-10.0, 0, 0, 0, 0, 0.3], (N_SCANS, 1))
    Sigma = np.stack([_cov(rng, 2e-3) for _ in t])
    Sigma[0] = np.nan
    P = np.stack([np.eye(18) * 1e-4 for _ in t])
    P[:, 6:12, 6:12] = np.stack([_cov(rng, 1e-2) for _ in t])
    T_est, P_abs = [T_true[0]], [np.zeros((6, 6))]
    drift = DriftCovariance(np.zeros((6, 6)), P[0, 6:12, 6:12], 0.0)
    for k in range(1, N_SCANS):
        R_true = T_true[k] @ se3.inverse(T_true[k - 1])
        delta = rng.multivariate_normal(np.zeros(6), Sigma[k])
        T_est.append(se3.exp(-delta) @ R_true @ T_est[-1])
        P_abs.append(drift.update(T_est[-2], T_est[-1], t[k] - t[k - 1], report_scale * Sigma[k],
                                  report_scale * P[k, 6:12, 6:12]))
    e_varpi = np.stack([rng.multivariate_normal(np.zeros(6), C) for C in P[:, 6:12, 6:12]])
    vd_err = rng.normal(size=(N_SCANS, 6)) * 1e-2
    states = {"t": t, "T_vehicle_world": np.stack(T_est), "varpi": varpi - e_varpi, "varpi_dot": -vd_err,
              "P": report_scale * P, "P_relative": report_scale * Sigma, "P_pose_absolute": np.stack(P_abs)}
    truth = {"t": t, "T_vehicle_world": T_true, "varpi": varpi, "varpi_dot": np.zeros((N_SCANS, 6))}
    return states, truth


def _averages(report_scale):
    rng = np.random.default_rng(np.random.SeedSequence(21))
    runs = [odometry_nees(*_run(rng, report_scale), span=0.5, tau=0.0) for _ in range(N_RUNS)]
    return {m: np.mean([r[m][-1] for r in runs]) for m in ("velocity", "relative_scan", "relative_span", "pose")}


def test_measures_are_chi_square_on_consistent_synthetic_runs():
    lo, hi = chi2_bounds(N_RUNS, 6, alpha=0.001)
    for name, mean in _averages(1.0).items():
        assert lo <= mean <= hi, (name, mean, (lo, hi))


def test_measures_detect_an_overconfident_run():
    lo, hi = chi2_bounds(N_RUNS, 6, alpha=0.001)
    for name, mean in _averages(0.25).items():
        assert mean > hi, (name, mean, hi)


def test_summary_and_missing_inputs():
    states, truth = _run(np.random.default_rng(3))
    m = odometry_nees(states, truth, span=0.5, tau=0.0)
    s = summarise(m)
    assert set(MEASURES) <= set(s) and s["pose"]["scans"] == N_SCANS - 1  # the first pose is exact (P = 0)
    assert np.isnan(m["relative_scan"][0]) and np.isfinite(m["relative_scan"][1:]).all()
    del states["P_relative"], states["P_pose_absolute"]
    m = odometry_nees(states, truth)  # an older states.npz: the drift measures are missing, the rest works
    assert np.isnan(m["pose"]).all() and np.isnan(m["relative_span"]).all() and np.isfinite(m["velocity"]).all()
    with pytest.raises(InputError, match="P"):
        odometry_nees({k: v for k, v in states.items() if k != "P"}, truth)
    # a velocity factor with a Doppler term needs the per-scan Doppler NIS to be divided out of the spans
    rng = np.random.default_rng(4)
    states["P_relative"] = np.stack([_cov(rng, 0.01) for _ in range(N_SCANS)])
    with pytest.raises(InputError, match="doppler_nis"):
        odometry_nees(dict(states, velocity_inflation=np.array([1.0, 0.0, 0.5])), truth)
    two = odometry_nees(dict(states, velocity_inflation=np.array([1.0, 0.0])), truth)
    three = odometry_nees(dict(states, velocity_inflation=np.array([1.0, 0.0, 0.0])), truth)
    assert np.isfinite(two["relative_scan"][1:]).all()
    np.testing.assert_array_equal(two["relative_scan"], three["relative_scan"])  # [a, b] is [a, b, 0]


@pytest.mark.slow
def test_the_second_scan_counts_the_revision_of_the_first_emitted_pose():
    """A drive that starts moving (hills, the 20-run campaign's trial 1): at scan 1 the second pose is barely
    constrained and scan 2 moves it by millimetres. The one-scan relative pose between the emitted poses has
    NEES/dof over 50 at scan 2 with the smoothed pair's covariance alone, and a plausible one (< 8) with the
    run's revision term (`P_revision`); over a 0.5 s span it is added once, at the span's first scan."""
    from rodo import scenarios
    from rodo.estimator.config import OdometryConfig
    from rodo.validation.driver import run_sequence

    seq, truth = scenarios.get("hills").simulate(2021251017632032385, duration=1.5)
    states = run_sequence(seq, OdometryConfig.for_model("ca-polar")).state_arrays()
    with_revision = odometry_nees(states, truth, span=0.5)
    without = odometry_nees({k: v for k, v in states.items() if k != "P_revision"}, truth, span=0.5)
    assert without["relative_scan"][2] / 6 > 50 and with_revision["relative_scan"][2] / 6 < 8
    assert np.all(with_revision["relative_scan"][1:] <= without["relative_scan"][1:])
    n = int(round(0.5 / np.median(np.diff(with_revision["t"]))))
    assert np.all(with_revision["relative_span"][n:] < without["relative_span"][n:])
    assert states["P_revision"].shape == states["P_relative"].shape and np.all(states["P_revision"][0] == 0)
