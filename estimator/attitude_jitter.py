"""The roll and pitch jitter beside the drift recursion (`uncertainty`; off by default, learned by `rodo calibrate`).

The registration's roll and pitch errors are correlated over a few scans to two seconds and bounded over the
drive (docs/consistency.md, "What is not yet right"): the ground and the near surfaces tilt the solution one
way for a while, then another. Every term of the drift recursion is a random walk, so a recursion tuned to the
drive's end over-states the roll and pitch over tens of seconds, and one tuned to a second under-states them over
that second (CA/P at learned noise, held-out drives: roll over 1 s 2.1-3.0, pitch 1.5-4.6 per axis).

So the reported covariances model a stationary error j = (j_roll, j_pitch) of variance V per axis, smooth in
time, with the squared-exponential correlation

    Cov(j(s), j(s + L)) = V exp(-(L / T)^2)    (per axis, the two axes independent),

on the roll and pitch of the vehicle frame, whose change over L seconds has the variance
2 V (1 - exp(-(L / T)^2)) (`span_variance`). The one-scan relative pose covariance already holds the jitter's
change over one scan: `rodo calibrate` fits it (`[uncertainty] inflation`) to the one-scan errors, which include
that change. Composing n of them counts the n changes as independent; what the jitter adds to a span is the
covariance between them, the change's variance over the span less the n one-scan variances composed,

    excess = 2 V (1 - exp(-(L / T)^2)) - sum_i 2 V (1 - exp(-(dt_i / T)^2)),   at least 0,

on the roll and pitch variances (`span_excess`; the absolute pose the same from the run's first scan, where the
truth is aligned: `absolute_excess`). It is 0 over one scan (the one-scan measure is the same with it), about
1.1 V over 1 s at T = 1 s and 13 scans per second, and 0 again past about (T / dt)^2 scans (13 s), where the
composed one-scan changes over-state the bounded jitter already (they are not taken away: a covariance is not
reduced for a model's sake). The smooth shape, not an exponential one: an exponential correlation's change
over one scan, 2 V dt / T, is far larger than the registration's one-scan roll and pitch variance (city CA/P
at V 4e-6 rad^2, T 1 s, added to the one-scan covariance: 1.77 -> 0.29 per axis on held-out drives).

Across a re-initialisation the dead-reckoned step counts as a step like any other (its covariance is large
anyway): an outage longer than about T leaves no excess for the rest of the run.

It is the rotation's alone: carried into the position by the distance driven (as the drift recursion does with a
pose error) it made the vertical position over 1 s cautious (city 1.11 -> 0.29 per axis): the registration's
tilt does not move the position it solves. Only the diagonal roll and pitch entries change, in the vehicle frame
of the span's last pose; the rotation between a span's ends (at most a few degrees in roll and pitch over a
second) is neglected. `rodo calibrate` learns V at a given T from the mean NEES of the roll and pitch of the
relative pose over 1 s (`validation.calibrate_jitter`).

Checked by: tests/estimator/test_attitude_jitter.py
"""

from __future__ import annotations

import numpy as np

AXES = (3, 4)  # roll, pitch of a 6-dof pose error [x, y, z, roll, pitch, yaw]


def attitude_jitter_array(jitter) -> np.ndarray:
    """(2,) [V, T] (rad^2, s), the jitter's variance per axis and correlation time; None: [0, 1], off.
    ValueError unless both are finite, V >= 0 and T > 0."""
    if jitter is None:
        return np.array([0.0, 1.0])
    j = np.asarray(jitter, dtype=float).reshape(2)
    if not (np.all(np.isfinite(j)) and j[0] >= 0 and j[1] > 0):
        raise ValueError(f"attitude jitter [V, T]: finite, V >= 0 and T > 0 expected, got {j.tolist()}")
    return j


def span_variance(L, jitter) -> np.ndarray:
    """2 V (1 - exp(-(L / T)^2)), the jitter's variance per axis (roll, pitch) in a relative pose over L >= 0
    seconds (a float or an array); 0 at L = 0, 2 V for L >> T."""
    V, T = attitude_jitter_array(jitter)
    return 2.0 * V * -np.expm1(-np.square(np.asarray(L, dtype=float) / T))


def span_excess(t: np.ndarray, n: int, jitter) -> np.ndarray:
    """(N - n,) the jitter's excess (module docstring) for the spans of n >= 1 scans ending at scans n .. N-1 of a
    run with scan times t (N,): span_variance(t_k - t_{k-n}) less the sum of span_variance over the span's steps,
    at least 0; zeros when off."""
    t = np.asarray(t, dtype=float)
    if n == 1:  # exactly: the difference of the cumulative sums below would leave rounding
        return np.zeros(max(len(t) - 1, 0))
    steps = _composed(t, jitter)
    return np.maximum(span_variance(t[n:] - t[:-n], jitter) - (steps[n:] - steps[:-n]), 0.0)


def absolute_excess(t: np.ndarray, jitter) -> np.ndarray:
    """(N,) the jitter's excess for the absolute pose at every scan of a run with scan times t (N,): that of the
    span from its first scan (0 there)."""
    t = np.asarray(t, dtype=float)
    return np.maximum(span_variance(t - t[0], jitter) - _composed(t, jitter), 0.0)


def _composed(t: np.ndarray, jitter) -> np.ndarray:
    """(N,) the one-scan changes' variances summed from the first scan to each (0 at the first): what composing
    the one-scan covariances counts of the jitter (`AbsoluteJitter` sums the same, scan by scan)."""
    return np.r_[0.0, np.cumsum(span_variance(np.diff(t), jitter))]


def with_roll_pitch_variance(P: np.ndarray, variance) -> np.ndarray:
    """P (6, 6) or (N, 6, 6) with `variance` (a float or (N,)) added to its roll and pitch variances: a new array;
    P itself where the variance is all 0 (the jitter off: bit for bit)."""
    if isinstance(variance, float) and variance == 0.0:  # the odometry's per-scan call with the jitter off
        return P
    variance = np.asarray(variance, dtype=float)
    if not np.any(variance):
        return P
    out = np.array(P, dtype=float)
    for a in AXES:
        out[..., a, a] += variance
    return out


class AbsoluteJitter:
    """The jitter's excess for the absolute pose of a run, scan by scan (`absolute_excess`, bit for bit): `start`
    at its first scan, then `at` each scan's time in order."""

    def __init__(self, jitter):
        self.jitter = attitude_jitter_array(jitter)
        self.t0 = self.t = self.steps = 0.0

    def start(self, t: float) -> None:
        self.t0 = self.t = float(t)
        self.steps = 0.0

    def at(self, t: float) -> float:
        """The excess at scan time t (0 at the first scan; 0.0 whenever the jitter is off)."""
        if self.jitter[0] == 0.0:  # off: nothing to add, at no cost per scan
            return 0.0
        self.steps += float(span_variance(t - self.t, self.jitter)) if t != self.t else 0.0
        self.t = float(t)
        return max(float(span_variance(t - self.t0, self.jitter)) - self.steps, 0.0)


def attitude_jitter_of(config) -> np.ndarray:
    """[V, T] (rad^2, s) of an `UncertaintyConfig`'s attitude jitter (V = 0: off)."""
    return attitude_jitter_array((config.attitude_jitter_variance, config.attitude_jitter_time))
