"""The registration's correlation per axis (`[uncertainty] registration_axis_correlation`) from drives with ground
truth, after tau and the common share alpha: `rodo calibrate` with truth, by default (`--no-axis-correlation` keeps
the config's).

One alpha (`registration_correlation`) carries the same share of every axis's one-scan relative pose covariance
correlated over tau. The registration's errors are not correlated alike on every axis: on city, CV/C's forward
position over 1 s and 5 s is 2.2-2.4 times as far off as its covariance says while its lateral position and yaw
are cautious (docs/consistency.md, "The registration's correlation per axis"). So, per axis in AXIS_ORDER (the
rotations first: their lever arm moves the position), the share a of the grid SHARES of what alpha leaves
independent that is carried correlated as well (alpha_i = alpha + (1 - alpha) a, `estimator.uncertainty.
registration_shares`) under which the axis's error grows as its covariance says over the relative poses of
`error_growth`'s spans from MIN_SPAN to 20 s (the runs pooled): the least `tau_cost` of that axis's E[e^2 /
sigma^2] there, the axes before it at their choice, where it lies MIN_GAIN or more below the cost without (else
0). The one-scan span is not among the costs (one scan composes the same covariance at every share, but for the
smoothing over tau), nor the absolute pose (one drive's is one slowly varying path).

Checked by: tests/validation/test_calibrate_axis_correlation.py
"""

from __future__ import annotations

import numpy as np

from .calibrate_stationary import AXIS_ORDER, MIN_GAIN, MIN_SPAN, axis_cost, growth_ratios
from .error_growth import AXES, GROWTH_SPANS
from .run_consistency import runs_of

SHARES = (0.1, 0.25, 0.5, 1.0)  # a: the share of an axis's independent registration covariance carried correlated


def growth_at(runs: list, shares: np.ndarray, spans) -> np.ndarray:
    """(S, 6) E[e^2 / sigma^2] per span of `spans` and axis over the runs' relative poses, their recursion composed
    with the per-axis shares `shares` (6,) (NaN where no run reaches a span)."""
    return growth_ratios(runs, spans, registration_axis_correlation=np.asarray(shares, dtype=float))


def fit_axis_correlation(states, truth, axes=AXIS_ORDER, shares=SHARES) -> tuple[np.ndarray, dict]:
    """The per-axis shares a (6,) of one run's states (or several runs', pooled), each at its own tau, drift rate,
    heading reversion, jitter and alpha (`replayed_states.replayed` records them), fitted on `axes` in that order
    (the others 0), and the report: per axis name the chosen share, its cost and the cost without."""
    runs = runs_of(states, truth)
    spans = tuple(L for L in GROWTH_SPANS if L >= MIN_SPAN)
    chosen, report = np.zeros(6), {}
    current = growth_at(runs, chosen, spans)  # the growth at the shares chosen so far, every axis
    for axis in axes:
        costs, growths = {0.0: axis_cost(current[:, axis])}, {0.0: current}
        for a in shares:
            trial = chosen.copy()
            trial[axis] = a
            growths[a] = growth_at(runs, trial, spans)
            costs[a] = axis_cost(growths[a][:, axis])
        best = min(costs, key=costs.get)
        if costs[0.0] - costs[best] < MIN_GAIN:
            best = 0.0
        chosen[axis], current = best, growths[best]
        report[AXES[axis]] = {"share": best, "cost": costs[best], "cost_without": costs[0.0]}
    return chosen, {"fitted": True, "shares": chosen.tolist(), "axes": report}
