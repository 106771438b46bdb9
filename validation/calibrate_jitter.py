"""`rodo calibrate`'s last uncertainty fit: the roll and pitch jitter's variance V (`estimator.attitude_jitter`)
from a drive with ground truth (on by default; `--no-attitude-jitter` keeps the base config's).

At the jitter's correlation time T (the config's), V is the one that makes the roll and pitch of the relative pose
over `span` seconds consistent in MEAN over the drive's spans: the mean NEES/dof of their 2-dof block is 1. Roll
and pitch alone, the axes the jitter adds to: over-confidence in the position or the yaw is not the jitter's to
absorb (fitted to all six axes, a drive's over-confident yaw raised V where its roll and pitch wanted less). The
mean, not the median the other fits use: the campaigns average the NEES over drives, and on the calibration
drives the 1 s span's mean was 1.27-1.39 per dof where its median ratio read 1.06-1.15 (CA/P, hills and city): a
median fit chose V of 5e-7 rad^2 or none, where the held-out drives wanted 1-4e-6 (docs/consistency.md, "Roll and
pitch jitter"). The jitter only adds variance, so where the mean is at or below 1 without it, V is 0; otherwise
the mean falls monotonically with V and V is found by bisection in log V within V_RANGE; where even its top leaves
the mean above 1 (roll and pitch errors of tenths of a radian: a broken run, not a jitter), V is 0 and the report
says so. The span covariances are composed once (`odometry_consistency.span_terms`); only the jitter's diagonal
changes between the bisection's steps.

Checked by: tests/validation/test_calibrate_jitter.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.attitude_jitter import AXES, span_excess

from .consistency import nees
from .odometry_consistency import span_terms

V_RANGE = (1e-10, 1e-2)  # rad^2: sigma 10 urad to 0.1 rad
BISECTIONS = 40  # halvings of ln(V_RANGE[1] / V_RANGE[0]) = 18.4: V to within 2e-11 relative


def roll_pitch_terms(terms: list, time: float) -> list:
    """[(e, C, x), ...]: of each run's spans (`span_terms`' (e, C, t, n)) the roll and pitch errors (M, 2), their
    covariance block (M, 2, 2) and the jitter's excess per unit V at correlation time `time` (M,): the excess is
    V times it (`attitude_jitter.span_excess`, linear in V), so the bisection needs no more than these."""
    return [(e[:, AXES], C[:, AXES][:, :, AXES], span_excess(t, n, (1.0, time))) for e, C, t, n in terms]


def mean_nees_per_dof(terms: list, V: float) -> float:
    """The mean NEES/dof of the roll and pitch over the spans `terms` (`roll_pitch_terms`) with the jitter's
    variance V added to their variances; NaN without finite values."""
    v = np.concatenate([nees(e, C + (V * x)[:, None, None] * np.eye(len(AXES))) for e, C, x in terms])
    v = v[np.isfinite(v)]
    return float(v.mean() / len(AXES)) if v.size else float("nan")


def fit_attitude_jitter(runs: list, span: float, tau: float, time: float, drift_rate_sigma=None,
                        heading=None) -> dict:
    """The jitter variance V (rad^2) at correlation time `time` (s) that brings the mean roll and pitch NEES/dof
    of the relative pose over `span` seconds to 1 over the runs pooled (runs: [(states, truth), ...]; tau, the
    drift rate and the heading reversion [T_r, T_a] those fitted, None: the runs' own); returns {variance, time,
    mean_without, mean_with, outcome}, outcome one of "fitted", "consistent without" (V 0), "no spans" (V 0),
    "out of reach" (V 0: the mean stays above 1 at V_RANGE's top)."""
    terms = roll_pitch_terms([x for x in (span_terms(s, t, span, tau, drift_rate_sigma=drift_rate_sigma,
                                                       heading=heading) for s, t in runs) if x is not None], time)
    without = mean_nees_per_dof(terms, 0.0) if terms else float("nan")
    report = {"variance": 0.0, "time": float(time), "mean_without": without, "mean_with": without}
    if not without > 1.0:
        return dict(report, outcome="consistent without" if terms and np.isfinite(without) else "no spans")
    top = mean_nees_per_dof(terms, V_RANGE[1])
    if top > 1.0:
        return dict(report, outcome="out of reach", mean_at_top=top)
    lo, hi = np.log(V_RANGE[0]), np.log(V_RANGE[1])
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mean_nees_per_dof(terms, np.exp(mid)) > 1.0 else (lo, mid)
    V = float(np.exp(hi))
    return dict(report, variance=V, mean_with=mean_nees_per_dof(terms, V), outcome="fitted")


def attitude_jitter_report(uncertainty, fit: bool, span: float, tau: float, drift_rate_sigma, heading,
                           runs: list) -> dict:
    """The jitter `calibrate_consistency.fit_consistency` writes, {variance, time, fitted[, mean_without,
    mean_with, outcome]}: the config's (`uncertainty`, its UncertaintyConfig) kept, or, with `fit`, V fitted at
    its T (`fit_attitude_jitter` over runs, [(states, truth), ...]). tau is chosen before it, without a jitter."""
    report = {"variance": uncertainty.attitude_jitter_variance, "time": uncertainty.attitude_jitter_time,
              "fitted": bool(fit)}
    if not fit:
        return report
    return dict(report, **fit_attitude_jitter(runs, span, tau, report["time"], drift_rate_sigma, heading))
