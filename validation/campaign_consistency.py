"""The odometry consistency measures of a Monte Carlo campaign (docs/evaluation.md, "Consistency in campaigns").

Each ok run stores in its trial npz the per-scan NEES of every measure of `odometry_consistency.MEASURES`
(`nees_<measure>`, 6 dof each; `validation.trial.consistency_of`). Per model and measure, over the N runs that
have it:

- the average over runs at each scan, with `chi2_bounds(count at that scan, 6, alpha)` (count = the runs with a
  finite value there: the first scans of a span, a singular covariance are left out);
- `mean_per_dof`: the mean over scans of that average, divided by 6 (1 when consistent);
- `bounds_for_runs` (and `/ 6`, `bounds_per_dof`): `chi2_bounds(N, 6, alpha)`, the bounds of a scan's average
  over all N runs;
- `fraction_scans_within`: the fraction of scans whose average lies within its bounds (about 1 - alpha when
  consistent).

Checked by: tests/validation/test_campaign_consistency.py::test_campaign_consistency_per_measure_consistent_and_overconfident
"""

from __future__ import annotations

import numpy as np

from .consistency import average_nees, chi2_bounds, fraction_within
from .odometry_consistency import DOF, MEASURES


def measure_summary(runs: list[np.ndarray], alpha: float = 0.05) -> tuple[dict, dict]:
    """Summary and curve of one measure over runs (each (K_i,) per-scan NEES; runs without a finite value are
    not counted). Returns (summary, curve): summary with dof, runs, mean_per_dof, median_per_dof,
    bounds_for_runs, bounds_per_dof, fraction_scans_within (None where undefined); curve with mean, count,
    lower, upper (per scan, NEES, not per dof)."""
    runs = [np.asarray(r, dtype=float) for r in runs if np.isfinite(np.asarray(r, dtype=float)).any()]
    n = len(runs)
    bounds = chi2_bounds(n, DOF, alpha)
    summary = {"dof": DOF, "runs": n, "mean_per_dof": None, "median_per_dof": None,
               "bounds_for_runs": bounds.tolist(), "bounds_per_dof": (bounds / DOF).tolist(),
               "fraction_scans_within": None}
    if not n:
        return summary, {}
    mean, count = average_nees(runs)
    b = chi2_bounds(count, DOF, alpha)
    fin = np.isfinite(mean)
    within = fraction_within(mean, b)
    summary.update({"mean_per_dof": float(np.mean(mean[fin]) / DOF), "median_per_dof": float(np.median(mean[fin]) / DOF),
                    "fraction_scans_within": None if np.isnan(within) else within})
    return summary, {"mean": mean.tolist(), "count": count.tolist(), "lower": b[:, 0].tolist(),
                     "upper": b[:, 1].tolist()}


def campaign_consistency(arrays: list[dict], alpha: float = 0.05) -> tuple[dict, dict]:
    """Per measure (MEASURES) over the runs' npz arrays (dicts with `t` and `nees_<measure>`; runs written
    before the measures existed have none and are skipped). Returns (summary {measure: measure_summary},
    curves {"t": longest t, measure: curve})."""
    t = max((np.asarray(a["t"], dtype=float) for a in arrays), key=len, default=np.zeros(0))
    summary, curves = {}, {"t": t.tolist()}
    for name in MEASURES:
        key = f"nees_{name}"
        summary[name], curve = measure_summary([a[key] for a in arrays if key in a], alpha)
        if curve:
            curves[name] = curve
    return summary, curves


def consistency_lines(consistency: dict, fmt) -> list[str]:
    """Markdown table of a model's measures (summary.md); `fmt` formats a number or None ("-")."""
    pct = lambda v: fmt(None if v is None else 100 * v)  # noqa: E731
    lines = ["", "Odometry consistency (average NEES over runs per scan, 6 dof, divided by 6; bounds for the N runs "
             "of the measure):", "", "| measure | runs | mean NEES/dof | median | bounds/dof | scans within |",
             "| --- | ---: | ---: | ---: | --- | ---: |"]
    for name in MEASURES:
        c = consistency.get(name)
        if c is None:
            continue
        lo, hi = c["bounds_per_dof"]
        lines.append(f"| {name} | {c['runs']} | {fmt(c['mean_per_dof'])} | {fmt(c['median_per_dof'])} | "
                     f"[{fmt(lo)}, {fmt(hi)}] | {pct(c['fraction_scans_within'])} % |")
    return lines
