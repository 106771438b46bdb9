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
  consistent);
- `spread_between_runs`: how widely the runs disagree at a scan, against chi-square's: the mean over the scans
  every run reaches of var_runs(NEES) / mean_runs(NEES)^2, divided by 2 / 6 (chi-square's); 1 when the runs
  spread as chi-square(6) draws do, whatever the mean;
- `fraction_within_at_best`: the fraction of scans a per-scan factor (one number per scan, the same for every
  run: the best a calibration can do) would bring within the bounds, given that spread: each run's NEES taken as
  chi-square with 6 / spread degrees of freedom scaled to mean 6, so the N-run average is
  chi-square(N 6 / spread) / (N / spread). 1 - alpha at spread 1; below the acceptance's 90 % the runs disagree
  too much for any factor.

Checked by: tests/validation/test_campaign_consistency.py::test_campaign_consistency_per_measure_consistent_and_overconfident
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from .consistency import average_nees, chi2_bounds, fraction_within
from .odometry_consistency import DOF, MEASURES


def spread_between_runs(runs: list[np.ndarray]) -> float | None:
    """Mean over the scans with a finite value in every run of var(NEES) / mean(NEES)^2 across the runs (ddof
    1), divided by chi-square(6)'s 2 / 6; None with fewer than two runs or no such scan."""
    K = min((len(r) for r in runs), default=0)
    if len(runs) < 2 or K == 0:
        return None
    X = np.array([np.asarray(r, dtype=float)[:K] for r in runs])
    X = X[:, np.all(np.isfinite(X), axis=0) & (np.mean(X, axis=0) > 0)]
    if not X.shape[1]:
        return None
    return float(np.mean(X.var(axis=0, ddof=1) / X.mean(axis=0) ** 2) / (2.0 / DOF))


def fraction_within_at_best(spread: float | None, n_runs: int, alpha: float = 0.05) -> float | None:
    """The probability that an N-run average falls within `chi2_bounds(N, 6, alpha)` when each run's NEES is
    chi-square with 6 / spread degrees of freedom scaled to mean 6 (module docstring); None where undefined."""
    if spread is None or not spread > 0 or n_runs < 1:
        return None
    lo, hi = chi2_bounds(n_runs, DOF, alpha) / DOF  # bounds of the average NEES, per dof
    nu = n_runs * DOF / spread
    return float(chi2.cdf(hi * nu, nu) - chi2.cdf(lo * nu, nu))


def measure_summary(runs: list[np.ndarray], alpha: float = 0.05) -> tuple[dict, dict]:
    """Summary and curve of one measure over runs (each (K_i,) per-scan NEES; runs without a finite value are
    not counted). Returns (summary, curve): summary with dof, runs, mean_per_dof, median_per_dof,
    bounds_for_runs, bounds_per_dof, fraction_scans_within, spread_between_runs, fraction_within_at_best (None
    where undefined); curve with mean, count,
    lower, upper (per scan, NEES, not per dof)."""
    runs = [np.asarray(r, dtype=float) for r in runs if np.isfinite(np.asarray(r, dtype=float)).any()]
    n = len(runs)
    bounds = chi2_bounds(n, DOF, alpha)
    summary = {"dof": DOF, "runs": n, "mean_per_dof": None, "median_per_dof": None,
               "bounds_for_runs": bounds.tolist(), "bounds_per_dof": (bounds / DOF).tolist(),
               "fraction_scans_within": None, "spread_between_runs": None, "fraction_within_at_best": None}
    if not n:
        return summary, {}
    mean, count = average_nees(runs)
    b = chi2_bounds(count, DOF, alpha)
    fin = np.isfinite(mean)
    within = fraction_within(mean, b)
    summary.update({"mean_per_dof": float(np.mean(mean[fin]) / DOF), "median_per_dof": float(np.median(mean[fin]) / DOF),
                    "fraction_scans_within": None if np.isnan(within) else within})
    spread = spread_between_runs(runs)
    summary.update({"spread_between_runs": spread, "fraction_within_at_best": fraction_within_at_best(spread, n, alpha)})
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
             "of the measure; spread: the runs' disagreement at a scan against chi-square's, and the share of scans a "
             "per-scan factor could bring within at that spread):", "",
             "| measure | runs | mean NEES/dof | median | bounds/dof | scans within | spread | within at best |",
             "| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: |"]
    for name in MEASURES:
        c = consistency.get(name)
        if c is None:
            continue
        lo, hi = c["bounds_per_dof"]
        lines.append(f"| {name} | {c['runs']} | {fmt(c['mean_per_dof'])} | {fmt(c['median_per_dof'])} | "
                     f"[{fmt(lo)}, {fmt(hi)}] | {pct(c['fraction_scans_within'])} % | "
                     f"{fmt(c.get('spread_between_runs'))} | {pct(c.get('fraction_within_at_best'))} % |")
    return lines
