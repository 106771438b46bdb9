"""Paired comparison of the models of a campaign: every model runs on the same trials (the same simulated
sequence), so their difference per trial removes the scenario's own variation.

For metric m and models a, b: d_i = m_a,i - m_b,i over the trials where both ran; the mean of d with its 95 %
Student-t interval, and how often a was lower (for error metrics: better). A difference whose interval
excludes 0 is one the campaign resolves; otherwise more trials are needed before a verdict.

Checked by: tests/validation/test_campaign_compare.py::test_paired_interval_covers_a_known_difference,
    ::test_table_lists_every_pair
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.stats import t as student_t

COMPARED = ("kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m")


def mean_interval(x: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    """(mean, lower, upper) of the mean of x with the Student-t interval; NaN bounds for fewer than 2 values."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    m = float(x.mean())
    if x.size < 2:
        return m, float("nan"), float("nan")
    h = float(student_t.ppf(0.5 + level / 2, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))
    return m, m - h, m + h


def paired(rows: list[dict], metric: str, a: str, b: str) -> dict:
    """The paired difference a - b of `metric` over the trials where both models ran ok."""
    def values(model):
        return {int(r["trial"]): float(r[metric]) for r in rows
                if r["model"] == model and r["status"] == "ok" and r[metric] not in ("", "None")}

    va, vb = values(a), values(b)
    common = sorted(set(va) & set(vb))
    d = np.array([va[i] - vb[i] for i in common])
    d = d[np.isfinite(d)]
    mean, lo, hi = mean_interval(d)
    return {"a": a, "b": b, "metric": metric, "trials": int(d.size), "mean_difference": mean, "lower": lo,
            "upper": hi, "a_lower": int(np.sum(d < 0)), "resolved": bool(np.isfinite(lo) and (hi < 0 or lo > 0))}


def compare_models(rows: list[dict], metrics=COMPARED) -> list[dict]:
    """`paired` for every pair of models (in campaign order) and metric."""
    models = list(dict.fromkeys(r["model"] for r in rows))
    return [paired(rows, m, a, b) for m in metrics for a, b in itertools.combinations(models, 2)]


def comparison_lines(comparisons: list[dict], fmt) -> list[str]:
    """summary.md lines: one table row per pair and metric."""
    if not comparisons:
        return []
    lines = ["## Paired comparison (same trials)", "",
             "| metric | a | b | trials | mean a - b | 95 % interval | a lower in | verdict |",
             "| --- | --- | --- | ---: | ---: | --- | ---: | --- |"]
    for c in comparisons:
        verdict = ("a lower" if c["upper"] < 0 else "b lower") if c["resolved"] else "not resolved"
        lines.append(f"| {c['metric']} | {c['a']} | {c['b']} | {c['trials']} | {fmt(c['mean_difference'])} | "
                     f"[{fmt(c['lower'])}, {fmt(c['upper'])}] | {c['a_lower']}/{c['trials']} | {verdict} |")
    return lines + [""]
