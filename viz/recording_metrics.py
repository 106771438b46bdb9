"""Time series of a run recording (`viz.recording.record_run`): the sender they share, and the consistency
series, drawn from what `rodo.validation.run_consistency` computes (docs/visualisation.md, "NEES").

- `metrics/nees/<measure>` for every measure of `validation.odometry_consistency.MEASURES` (velocity,
  acceleration, relative_scan, relative_span, pose, pose_window): the scan's NEES (6 dof) with the per-scan
  95 % chi-square bounds chi2.ppf([0.025, 0.975], 6);
- `metrics/ellipsoid/fraction`: the fraction of the scans so far whose true position lies inside the 3-sigma
  ellipsoid drawn at `world/estimate/covariance`, and the fraction the ellipsoid claims (97.1 %);
  `metrics/ellipsoid/inside`: 1 inside, 0 outside, per scan.

Checked by: tests/viz/test_recording.py::test_recording_has_every_consistency_measure
"""

from __future__ import annotations

import numpy as np

from rodo.validation.consistency import chi2_bounds
from rodo.validation.odometry_consistency import DOF, MEASURES
from rodo.validation.run_consistency import ellipsoid_coverage, scan_measures

GREY = (150, 150, 150)
MEASURE_COLOURS = {"velocity": (220, 50, 50), "acceleration": (240, 150, 0), "relative_scan": (40, 170, 40),
                   "relative_span": (0, 150, 150), "pose": (40, 120, 255), "pose_window": (140, 80, 200)}
ELLIPSOID_SIGMA = 3.0


def send_series(rec, rr, path: str, frames, times, values, names, colours=None) -> bool:
    """Send a time series (N, c) as columns; rows whose first value is NaN are left out (gaps). Returns whether
    any row was sent."""
    values = np.asarray(values, dtype=float).reshape(len(frames), -1)
    keep = np.isfinite(values[:, 0])
    if not keep.any():
        return False
    style = {"names": list(names)}
    if colours is not None:
        style["colors"] = list(colours)
    rec.log(path, rr.SeriesLines(**style), static=True)
    rec.send_columns(path, indexes=[rr.TimeColumn("frame", sequence=frames[keep]),
                                    rr.TimeColumn("time", duration=times[keep])],
                     columns=rr.Scalars.columns(scalars=values[keep]))
    return True


def log_consistency(rec, rr, states: dict, truth: dict, frames, times, p_world_true) -> set[str]:
    """The NEES of every measure and the ellipsoid coverage (module docstring); returns the tab origins logged.

    Args:
        states: `validation.run_consistency.run_states` of the run.
        truth: t, T_vehicle_world (and varpi, varpi_dot when known) at the scans that have a truth.
        frames, times: (N,) the run's frame indices and scan times.
        p_world_true: (N, 3) true positions in the estimator's world frame (NaN: no truth).
    """
    logged = set()
    m = scan_measures(states, truth)
    lo, hi = chi2_bounds(1, DOF)
    n = len(frames)
    for name in MEASURES:
        if send_series(rec, rr, f"metrics/nees/{name}", frames, times, np.c_[m[name], np.full(n, lo), np.full(n, hi)],
                       [f"{name} NEES ({DOF} dof)", "2.5 % bound", "97.5 % bound"],
                       [MEASURE_COLOURS[name], GREY, GREY]):
            logged.add("metrics/nees")
    p_world_est = -np.einsum("nji,nj->ni", states["T_vehicle_world"][:, :3, :3], states["T_vehicle_world"][:, :3, 3])
    cov = ellipsoid_coverage(p_world_est, p_world_true, states["T_vehicle_world"],
                             np.nan_to_num(states["P_pose_absolute"]), ELLIPSOID_SIGMA)
    claimed = 100 * cov["claimed"]
    if send_series(rec, rr, "metrics/ellipsoid/fraction", frames, times,
                   np.c_[100 * cov["running_fraction"], np.full(n, claimed)],
                   [f"truth inside the {ELLIPSOID_SIGMA:g}-sigma ellipsoid, % of scans so far",
                    f"claimed ({claimed:.1f} %)"], [(40, 120, 255), GREY]):
        send_series(rec, rr, "metrics/ellipsoid/inside", frames, times, cov["inside"][:, None],
                    [f"truth inside the {ELLIPSOID_SIGMA:g}-sigma ellipsoid (1 yes, 0 no)"], [(20, 20, 20)])
        logged.add("metrics/ellipsoid")
    return logged
