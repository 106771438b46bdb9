"""`rodo calibrate --stationary-error`: the bounded pose error per axis (`estimator.stationary_error`) from drives
with ground truth, after every other uncertainty term.

Per axis in AXIS_ORDER (the yaw first: its lever arm moves the lateral position; then roll, pitch and the
position), the share f and correlation time T of the grid SHARES x TIMES, or none, under which the axis's error
grows as its covariance says over the relative poses of `error_growth`'s spans from MIN_SPAN to 20 s (the runs
pooled): the least `tau_cost` of that axis's E[e^2 / sigma^2] there, the axes before it at their choice, where
it lies MIN_GAIN or more below the cost without (else none: the spans' noise). The error's variance is then

    V = f x the axis's mean one-scan relative pose variance over the runs' registered scans / (2 (1 - exp(-dt / T))),

dt the runs' median scan interval: f of the axis's one-scan variance is the error's one-scan change, which the
composition no longer carries. The one-scan span is not among the costs (the model leaves it as it is), nor the
absolute pose: one drive's is one slowly varying path, where the growth pools every span of the drive (the
calibration drive's growth over 1 s and 5 s carries over to the campaigns within about 30 %, its absolute pose
does not: docs/consistency.md, "How the error grows, per axis").

Checked by: tests/validation/test_calibrate_stationary.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.stationary_error import stationary_error_array

from .calibrate_relative import tau_cost
from .error_growth import AXES, GROWTH_SPANS, error_growth, pooled_growth
from .run_consistency import runs_of

SHARES = (0.5, 0.8, 0.9, 0.95)  # f: the share of an axis's mean one-scan variance that is the error's change
TIMES = (0.25, 0.5, 1.0, 2.0, 5.0, 10.0)  # s, T
AXIS_ORDER = (5, 3, 4, 0, 1, 2)  # yaw, roll, pitch, x, y, z
MIN_SPAN = 0.5  # s: the shortest span whose growth the fit reads
# the least fall of an axis's cost for which its error is taken on: the 95th percentile of the fall the grid finds
# on an axis without a stationary error (36 axes of twelve synthetic 180 s random-walk drives: median 0.06, 90th
# percentile 0.68, 95th 1.04, largest 1.44; docs/consistency_history.md, "Session 47"), about one span's ratio
# moved by a factor e
MIN_GAIN = 1.0


def one_scan_variances(runs: list) -> tuple[np.ndarray, float]:
    """(the mean one-scan relative pose variance per axis (6,) over the runs' registered scans, the median scan
    interval) of [(states, truth), ...]."""
    v, dt = [], []
    for states, _ in runs:
        P = np.asarray(states["P_relative"], dtype=float)
        ok = np.all(np.isfinite(P), axis=(1, 2)) & ~np.asarray(states.get("restarted", np.zeros(len(P), bool)), bool)
        v.append(np.einsum("kii->ki", P[ok]))
        dt.append(np.diff(np.asarray(states["t"], dtype=float)))
    return np.concatenate(v).mean(axis=0), float(np.median(np.concatenate(dt)))


def stationary_of(choice: dict, one_scan: np.ndarray, dt: float) -> np.ndarray:
    """[V; T] (2, 6) of {axis: (f, T)} (`module docstring`); the axes not in it off."""
    s = stationary_error_array(None)
    for axis, (share, time) in choice.items():
        s[0, axis] = share * one_scan[axis] / (2.0 * -np.expm1(-dt / time))
        s[1, axis] = time
    return s


def axis_growth(runs: list, stationary: np.ndarray, spans) -> np.ndarray:
    """(S, 6) E[e^2 / sigma^2] per span of `spans` and axis over the runs' relative poses, the stationary error
    [V; T] in place of theirs (NaN where no run reaches a span)."""
    g = pooled_growth([error_growth(dict(s, stationary_error=stationary), t, spans) for s, t in runs])
    with np.errstate(invalid="ignore", divide="ignore"):
        return g["z2"][:len(spans)] / g["count"][:len(spans), None]


def axis_cost(ratios) -> float:
    """`tau_cost` of an axis's ratios over the spans, the spans without a finite ratio left out."""
    r = np.asarray(ratios, dtype=float)
    return tau_cost(r[np.isfinite(r) & (r > 0)])


def fit_stationary_error(states, truth, axes=AXIS_ORDER) -> tuple[np.ndarray, dict]:
    """The stationary error [V; T] (2, 6) of one run's states (or several runs', pooled) with their own tau, drift
    rate, heading reversion and jitter recorded (`replayed_states.replayed`), fitted on `axes` in that order (the
    others off), and the report: per axis name the chosen share, time, variance, its cost and the cost without
    the error on that axis; the one-scan variances and dt."""
    runs = runs_of(states, truth)
    one_scan, dt = one_scan_variances(runs)
    spans = tuple(L for L in GROWTH_SPANS if L >= MIN_SPAN)
    choice, report = {}, {}
    for axis in axes:
        costs = {(0.0, 0.0): axis_cost(axis_growth(runs, stationary_of(choice, one_scan, dt), spans)[:, axis])}
        for share in SHARES:
            for time in TIMES:
                s = stationary_of({**choice, axis: (share, time)}, one_scan, dt)
                costs[(share, time)] = axis_cost(axis_growth(runs, s, spans)[:, axis])
        best = min(costs, key=costs.get)
        if costs[(0.0, 0.0)] - costs[best] < MIN_GAIN:
            best = (0.0, 0.0)
        if best[0] > 0:
            choice[axis] = best
        s = stationary_of(choice, one_scan, dt)
        report[AXES[axis]] = {"share": best[0], "time": float(s[1, axis]), "variance": float(s[0, axis]),
                              "cost": costs[best], "cost_without": costs[(0.0, 0.0)]}
    return stationary_of(choice, one_scan, dt), {"axes": report, "one_scan_variance": one_scan.tolist(), "dt": dt}
