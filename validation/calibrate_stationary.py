"""`rodo calibrate --stationary-error`: the bounded pose error per axis (`estimator.stationary_error`) from drives
with ground truth, after every other uncertainty term.

Per axis in AXIS_ORDER (the yaw first: its lever arm moves the lateral position; then roll, pitch and the
position), the share f and correlation time T of the grid SHARES x TIMES, or none, under which the axis's error
grows as its covariance says over the relative poses of `error_growth`'s spans from MIN_SPAN to 20 s (the runs
pooled): the least `tau_cost` of that axis's E[e^2 / sigma^2] there, the axes before it at their choice, where
it lies MIN_GAIN or more below the cost without (else none: the spans' noise). The error's variance is then

    V = f x the axis's mean one-scan relative pose variance over the runs' registered scans / (2 (1 - exp(-dt / T))),

dt the runs' median scan interval: f of the axis's one-scan variance is the error's one-scan change, which the
composition no longer carries. On a steady scan interval that change is f's alone, so the times T of one share
compose the runs' drift once and differ only in the error's change over each span (`grid_growth`: the fit about
five times faster, the same costs to 1e-15). The one-scan span is not among the costs (the model leaves it as it
is), nor the absolute pose: one drive's is one slowly varying path, where the growth pools every span of the drive (the
calibration drive's growth over 1 s and 5 s carries over to the campaigns within about 30 %, its absolute pose
does not: docs/consistency.md, "How the error grows, per axis").

Checked by: tests/validation/test_calibrate_stationary.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.stationary_error import is_on, one_scan_change, span_term, stationary_error_array

from .calibrate_relative import tau_cost
from .error_growth import AXES, GROWTH_SPANS, add_sums, empty_growth, error_growth, growth_run, pooled_growth, span_rows
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
    return growth_ratios(runs, spans, stationary_error=stationary)


def growth_ratios(runs: list, spans, **arrays) -> np.ndarray:
    """(S, 6) E[e^2 / sigma^2] per span of `spans` and axis over the runs' relative poses ([(states, truth), ...]),
    the states' `arrays` (e.g. stationary_error, registration_axis_correlation) in place of theirs (NaN where no
    run reaches a span): what the per-axis fits compare."""
    return _ratios(pooled_growth([error_growth(dict(s, **arrays), t, spans) for s, t in runs]), len(spans))


def _ratios(g: dict, S: int) -> np.ndarray:
    """(S, 6) z2 / count of pooled sums' first S rows (NaN where nothing was counted)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return g["z2"][:S] / g["count"][:S, None]


def same_change(runs: list, stationaries: list) -> bool:
    """Whether the stationary errors [V; T] take the same one-scan change (`one_scan_change`) out of every axis at
    every scan interval of the runs, to 1e-9: then the drift they leave composes alike (`grid_growth`). On a
    steady scan interval every T of one share does: V = f v / (2 (1 - exp(-dt / T))) changes by f v a scan."""
    dts = np.concatenate([np.diff(np.asarray(s["t"], dtype=float)) for s, _ in runs])
    first = one_scan_change(dts, stationaries[0])
    return all(np.allclose(one_scan_change(dts, x), first, rtol=1e-9, atol=0.0) for x in stationaries[1:])


def grid_growth(runs: list, stationaries: list, spans) -> list[np.ndarray]:
    """`axis_growth` of each stationary error of `stationaries`. Where they take the same one-scan change out
    (`same_change`), each run's drift is matched and composed over the spans once, and each error's change over a
    span with its lever arm (`span_term`) is added to those variances (the span covariances are two thirds of a
    growth's time: about five times faster over one share's times); else one by one."""
    if len(stationaries) < 2 or not same_change(runs, stationaries):
        return [axis_growth(runs, x, spans) for x in stationaries]
    sums = [empty_growth(spans) for _ in stationaries]
    for states, truth in runs:
        m = growth_run(dict(states, stationary_error=stationaries[0]), truth, spans)
        t, T = m["t"], m["T_est"]
        for row, n, starts, e, C in span_rows(dict(m, stationary=None), spans, states.get("attitude_jitter")):
            v = np.einsum("kii->ki", C)
            for out, x in zip(sums, stationaries):
                change = np.einsum("kii->ki", span_term(T[starts + n], T[starts], t[starts + n] - t[starts], x)) \
                    if n > 1 and is_on(x) else 0.0
                add_sums(out, row, e, v + change)
    return [_ratios(g, len(spans)) for g in sums]


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
            grid = [stationary_of({**choice, axis: (share, time)}, one_scan, dt) for time in TIMES]
            for time, r in zip(TIMES, grid_growth(runs, grid, spans)):
                costs[(share, time)] = axis_cost(r[:, axis])
        best = min(costs, key=costs.get)
        if costs[(0.0, 0.0)] - costs[best] < MIN_GAIN:
            best = (0.0, 0.0)
        if best[0] > 0:
            choice[axis] = best
        s = stationary_of(choice, one_scan, dt)
        report[AXES[axis]] = {"share": best[0], "time": float(s[1, axis]), "variance": float(s[0, axis]),
                              "cost": costs[best], "cost_without": costs[(0.0, 0.0)]}
    return stationary_of(choice, one_scan, dt), {"axes": report, "one_scan_variance": one_scan.tolist(), "dt": dt}
