"""How a run's pose error grows with the span, per axis, against what its covariance says.

The consistency measures (`odometry_consistency`) test 6-dof NEES at three horizons: one scan, one span (1 s)
and the whole drive. Where one of them is off, the question is which axis and from which horizon on: the drift
recursion (`estimator.uncertainty`) composes one model of how the error grows, and a model that is right over
one second can be wrong over ten (docs/consistency.md, "How the error grows, per axis"). This is the odometry's
counterpart of an Allan-variance plot: per span L of GROWTH_SPANS and per axis i of the left perturbation of
T_vehicle_world (x forward, y left, z up, roll, pitch, yaw; the translation carries the rotation's error over
the distance, as the covariance does),

    E[e_i^2 / C_ii]   over the relative poses over L (their covariance as `relative_span`'s: the drift
                      recursion composed over the span, the revision at its first scan, the roll and pitch
                      jitter's excess), and over the absolute poses of the drive (`pose`'s);

1 where the covariance's variance is right on that axis at that horizon, below 1 cautious, above over-confident.
Beside the spans, the same per-axis view of the velocity and the acceleration at the scan (their error against the
window's reported covariance, as the `velocity` and `acceleration` measures take them: vx vy vz, then the roll, pitch
and yaw rates, and their derivatives): which of the 6-dof velocity NEES's components is off (docs/consistency.md,
"The vehicle's rate terms learned": the pitch rate at a road's bumps). The per-axis view leaves out the
correlations between axes, which the 6-dof NEES counts. A span of n scans
starts every max(1, n // STARTS_PER_SPAN) scans (overlapping spans repeat each other's errors; the long spans'
covariances are the costliest part). The result holds sums, so runs pool by adding (`pooled_growth`): a
campaign's table weighs every span of every run alike.

Checked by: tests/validation/test_error_growth.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.attitude_jitter import span_excess, with_roll_pitch_variance
from rodo.estimator.lie import se3

from .association import DEFAULT_TOLERANCE
from .consistency import require_arrays
from .odometry_consistency import matched_run, matched_span_terms, span_scans
from .run_consistency import DEFAULT_TAU

GROWTH_SPANS = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0)  # s; 0: one scan
STARTS_PER_SPAN = 8
AXES = ("x", "y", "z", "roll", "pitch", "yaw")
SUMS = ("count", "z2", "e2", "var")
RATE_ROWS = ("velocity", "acceleration")  # the rows after the drive's, their sums under "vel_<sum>"


def error_growth(states: dict, truth: dict, spans=GROWTH_SPANS, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """The per-axis sums of one run (module docstring): span (S,) seconds, scans (S,) each span's scans (0 where
    the run is too short for it), and for the S spans and then the absolute pose (S + 1 rows): count, the
    relative (or absolute) poses summed; z2 (S + 1, 6), sum e_i^2 / C_ii; e2, sum e_i^2; var, sum C_ii. Rows
    with a non-finite error or variance, or a variance <= 0, are left out; the first scan's absolute pose too
    (the truth is aligned there); and the velocity's and the acceleration's ("vel_<sum>", rows RATE_ROWS:
    `_rate_sums`). The velocity correlation time, drift rate, heading reversion and jitter are the run's own
    (states'; DEFAULT_TAU and none when absent). Zero span sums without P_relative."""
    m = growth_run(states, truth, spans, tolerance)
    out = empty_growth(spans)
    for row, n, _, e, C in span_rows(m, spans, states.get("attitude_jitter")):
        out["scans"][row] = n
        add_sums(out, row, e, np.einsum("kii->ki", C))
    if "P_pose_absolute" in m["sub"]:
        xi = se3.log(m["T_true"] @ se3.inverse(m["T_est"]))
        add_sums(out, len(spans), xi[1:], np.einsum("kii->ki", np.asarray(m["sub"]["P_pose_absolute"], float)[1:]))
    return {**out, **_rate_sums(m, truth)}


def _rate_sums(m: dict, truth: dict) -> dict:
    """The sums ("vel_<sum>", rows RATE_ROWS) of the velocity's and the acceleration's errors against the reported
    covariance's diagonal at every matched scan (the acceleration's zero for a CV run)."""
    out = _zero_sums(len(RATE_ROWS))
    P, sub, ib = m["P"], m["sub"], m["ib"]
    add_sums(out, 0, np.asarray(truth["varpi"], float)[ib] - sub["varpi"], np.einsum("kii->ki", P[:, 6:12, 6:12]))
    if P.shape[-1] == 18 and "varpi_dot" in truth and "varpi_dot" in sub:
        add_sums(out, 1, np.asarray(truth["varpi_dot"], float)[ib] - sub["varpi_dot"],
                 np.einsum("kii->ki", P[:, 12:18, 12:18]))
    return {f"vel_{k}": v for k, v in out.items()}


def growth_run(states: dict, truth: dict, spans, tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """The matched run (`matched_run`) whose growth over `spans` (s) `error_growth` sums: at the run's own tau,
    drift rate and heading reversion, with the one-scan inputs where a span is one scan long (0, or rounded to one
    scan: its covariance composes the inputs without the stationary error's change taken out)."""
    require_arrays(states, truth)
    tau = float(states.get("velocity_correlation_time", DEFAULT_TAU))
    t = np.asarray(states["t"], dtype=float)
    one_scan = any(L == 0 or span_scans(t, L) == 1 for L in np.asarray(spans, dtype=float))
    return matched_run(states, truth, tolerance, tau, None, None, one_scan=one_scan)


def empty_growth(spans) -> dict:
    """`error_growth`'s result with zero sums, for `spans`."""
    return {"span": np.asarray(spans, dtype=float), "scans": np.zeros(len(spans), int), **_zero_sums(len(spans) + 1)}


def _zero_sums(rows: int) -> dict:
    """SUMS for `rows` rows, zeros: count (rows,), the others (rows, 6)."""
    return {"count": np.zeros(rows), **{k: np.zeros((rows, 6)) for k in SUMS[1:]}}


def span_rows(m: dict, spans, jitter):
    """Per span of `spans` (s) that a matched run (`matched_run`) reaches: (row, n its scans, the first scans of
    its relative poses, one every max(1, n // STARTS_PER_SPAN), their errors (M, 6) and covariances (M, 6, 6), as
    `matched_span_terms` composes them, with the roll and pitch jitter [V, T] (None: off) added)."""
    K = len(m["t"])
    for row, span in enumerate(spans):
        n = 1 if span == 0 else span_scans(m["t"], span)
        if K < 2 or n >= K:
            continue
        starts = np.arange(0, K - n, max(1, n // STARTS_PER_SPAN))
        terms = matched_span_terms(m, n, starts)
        if terms is not None:
            yield row, n, starts, terms[0], with_roll_pitch_variance(terms[1], span_excess(m["t"], n, jitter)[starts])


def add_sums(out: dict, row: int, e: np.ndarray, v: np.ndarray) -> None:
    """Add the errors e (M, 6) and their variances v (M, 6) to `out`'s sums at `row` (the finite ones with v > 0)."""
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(v), axis=1) & np.all(v > 0, axis=1)
    e, v = e[ok], v[ok]
    out["count"][row] += len(e)
    out["z2"][row] += np.sum(e**2 / v, axis=0)
    out["e2"][row] += np.sum(e**2, axis=0)
    out["var"][row] += np.sum(v, axis=0)


def pooled_growth(growths: list[dict]) -> dict | None:
    """The sums of several runs' `error_growth` (the same spans), added; the scans of the first run that has
    each span; None without runs. ValueError where the runs' spans differ."""
    growths = [g for g in growths if g is not None]
    if not growths:
        return None
    span = np.asarray(growths[0]["span"], dtype=float)
    if any(not np.array_equal(np.asarray(g["span"], dtype=float), span) for g in growths):
        raise ValueError("error growth: the runs were measured over different spans")
    scans = np.zeros(len(span), int)
    for g in reversed(growths):
        scans = np.where(np.asarray(g["scans"]) > 0, g["scans"], scans)
    keys = [*SUMS, *(f"vel_{k}" for k in SUMS if all(f"vel_{k}" in g for g in growths))]  # runs before session 51
    return {"span": span, "scans": scans, **{k: sum(np.asarray(g[k], dtype=float) for g in growths) for k in keys}}


def growth_table(g: dict) -> list[dict]:
    """Per row (the spans, then "drive" for the absolute pose, then RATE_ROWS where the sums have them) of summed
    `error_growth`: label, scans (None but for the spans), count, and per axis the mean z^2 (`ratio`), the RMS error
    and the RMS sigma (lists of 6; None where nothing was counted)."""
    labels = ["1 scan" if s == 0 else f"{s:g} s" for s in g["span"]] + ["drive"]
    sums = [(i, "") for i in range(len(labels))]
    if "vel_count" in g:
        labels += list(RATE_ROWS)
        sums += [(0, "vel_"), (1, "vel_")]
    rows = []
    for label, (i, prefix) in zip(labels, sums):
        c = float(g[prefix + "count"][i])
        mean = {k: np.asarray(g[prefix + k][i], dtype=float) / c if c else None for k in SUMS[1:]}
        scans = int(g["scans"][i]) if not prefix and i < len(g["span"]) else None
        rows.append({"label": label, "scans": scans, "count": int(c), "ratio": _listed(mean["z2"]),
                     "rms_error": _listed(mean["e2"], np.sqrt),
                     "rms_sigma": _listed(mean["var"], np.sqrt)})
    return rows


def _listed(v, f=None) -> list[float] | None:
    """v (6,), or f(v), as a list of floats; None for None."""
    return None if v is None else [float(x) for x in (v if f is None else f(v))]


def growth_lines(g: dict | None, fmt) -> list[str]:
    """Markdown table of summed `error_growth` (summary.md, the calibration report); [] without it. `fmt`
    formats a number or None."""
    if g is None or not np.any(np.asarray(g["count"]) > 0):
        return []
    lines = ["", "Error growth per axis (E[e^2 / sigma^2] of the relative pose over each span, and of the absolute "
                 "pose over the drive, pooled over the runs' spans: 1 where the covariance's variance is right on "
                 "that axis at that horizon, below 1 cautious, above over-confident; docs/consistency.md, \"How the "
                 "error grows, per axis\")" + ("; then of the velocity and the acceleration at the scan (vx vy vz "
                                                "and the roll, pitch and yaw rates, and their derivatives)"
                                                if "vel_count" in g else "") + ":", "",
             "| span | scans | spans | " + " | ".join(AXES) + " |", "| --- | ---: | ---: |" + " ---: |" * len(AXES)]
    for r in growth_table(g):
        cells = [fmt(x) for x in r["ratio"]] if r["ratio"] else ["-"] * len(AXES)
        lines.append(f"| {r['label']} | {'-' if r['scans'] is None else r['scans']} | {r['count']} | "
                     + " | ".join(cells) + " |")
    return lines
