"""`rodo calibrate --attitude-jitter`: the roll and pitch jitter's variance V (`estimator.attitude_jitter`) from
a drive with ground truth.

At the jitter's correlation time T (the config's), V is the one that makes the relative pose over `span` seconds
consistent in MEAN over the drive's spans: mean NEES/dof = 1. The mean, not the median the other fits use: the
campaigns average the NEES over drives, and on the calibration drives the 1 s span's mean was 1.27-1.39 per dof
where its median ratio read 1.06-1.15 (CA/P, hills and city): a median fit chose V of 5e-7 rad^2 or none, where
the held-out drives wanted 1-4e-6 (docs/consistency.md, "Roll and pitch jitter"). The jitter only adds variance,
so where the mean is at or below 1 without it, V is 0; otherwise the mean falls monotonically with V and V is
found by bisection in log V. The span covariances are composed once (`odometry_consistency.span_terms`); only the
jitter's diagonal changes between the bisection's steps.

Checked by: tests/validation/test_calibrate_jitter.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.attitude_jitter import span_excess, with_roll_pitch_variance

from .consistency import nees
from .odometry_consistency import DOF, span_terms

V_RANGE = (1e-10, 1e-2)  # rad^2: sigma 10 urad to 0.1 rad
BISECTIONS = 60  # halvings of ln(V_RANGE[1] / V_RANGE[0]) = 18.4: V to within 1e-8 relative


def mean_nees_per_dof(terms: list, jitter) -> float:
    """The mean NEES/dof over the spans `terms` ([(e, C, t, n), ...], `span_terms` of each run) with the jitter
    [V, T] added (`attitude_jitter.span_excess`); NaN without finite values."""
    v = np.concatenate([nees(e, with_roll_pitch_variance(C, span_excess(t, n, jitter))) for e, C, t, n in terms])
    v = v[np.isfinite(v)]
    return float(v.mean() / DOF) if v.size else float("nan")


def fit_attitude_jitter(runs: list, span: float, tau: float, time: float, drift_rate_sigma=None) -> dict:
    """The jitter variance V (rad^2) at correlation time `time` (s) that brings the mean NEES/dof of the relative
    pose over `span` seconds to 1 over the runs pooled (runs: [(states, truth), ...], their states at the fitted
    heading reversion, without a jitter; tau and the drift rate those fitted, None: the runs' own); returns
    {variance, time, mean_without, mean_with}.
    V = 0 where the mean is at or below 1 without a jitter, or undefined; V_RANGE[1] where even that leaves it
    above 1."""
    terms = [x for x in (span_terms(s, t, span, tau, drift_rate_sigma=drift_rate_sigma) for s, t in runs)
             if x is not None]
    without = mean_nees_per_dof(terms, None) if terms else float("nan")
    report = {"variance": 0.0, "time": float(time), "mean_without": without, "mean_with": without}
    if not without > 1.0:
        return report
    lo, hi = np.log(V_RANGE[0]), np.log(V_RANGE[1])
    if mean_nees_per_dof(terms, (V_RANGE[1], time)) > 1.0:
        lo = hi
    for _ in range(BISECTIONS if lo < hi else 0):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mean_nees_per_dof(terms, (np.exp(mid), time)) > 1.0 else (lo, mid)
    V = float(np.exp(hi))
    return dict(report, variance=V, mean_with=mean_nees_per_dof(terms, (V, time)))


def attitude_jitter_report(uncertainty, fit: bool, span: float, tau: float, drift_rate_sigma, runs) -> dict:
    """The jitter `calibrate_consistency.fit_consistency` writes, {variance, time, fitted[, mean_without,
    mean_with]}: the config's (`uncertainty`, its UncertaintyConfig) kept, or, with `fit`, V fitted at its T
    (`fit_attitude_jitter` over runs(), a callable: the replay it needs is made only then). tau is chosen before
    it, without a jitter."""
    report = {"variance": uncertainty.attitude_jitter_variance, "time": uncertainty.attitude_jitter_time,
              "fitted": bool(fit)}
    if not fit:
        return report
    return dict(report, **fit_attitude_jitter(runs(), span, tau, report["time"], drift_rate_sigma))
