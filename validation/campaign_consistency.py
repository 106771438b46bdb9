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
- `spread_between_runs`: how widely the runs disagree at a scan, against chi-square's: var_runs(NEES) /
  mean_runs(NEES)^2 over 2 / 6 (chi-square's), averaged over the scans that at least half the runs (and two)
  reach, and corrected for its bias with few runs (`spread_between_runs`); 1 when the runs spread as chi-square
  draws do, whatever the mean;
- `fraction_within_per_scan_factor`: the fraction of scans that a per-scan factor common to all runs (one number
  per scan, the same for every run, as a calibration of the covariance's scale from the mean would give) brings
  within the bounds at that spread: each run's NEES taken as chi-square with 6 / spread degrees of freedom scaled
  to mean 6, so the N-run average is chi-square(6 N / spread) / (6 N / spread) times 6. 1 - alpha at spread 1,
  below 90 % from a spread of about 1.42. A model, not a bound: a factor that differs between runs (one that
  follows the speed or the Doppler innovation) can do better;
- `scans_below`, `scans_above`: the scans whose average lies below its bounds (the covariance cautious there) and
  above them (over-confident), and `scans_above_one_run`: those above that one run puts there, inside the bounds
  for the others without the largest run's value at that scan (a tail of one run, not a common factor);
- `mean_interval_per_dof`: the 95 % interval of the mean over runs of each run's mean NEES/dof over its scans
  (Cox's, the runs' means taken as lognormal: `mean_interval_per_dof`). The bounds are those of one scan's
  average under chi-square; where the runs disagree more than chi-square draws (a spread above 1: one drive's
  absolute pose is one slowly varying path) the mean over scans wanders further than they allow, and this
  interval says how far (20 prior-consistent CA/P drives with a mean absolute pose of 0.73 per dof: 0.52-1.04;
  docs/evaluation.md, "Consistency in campaigns").

Runs with a gross failure (`gross_failure_runs`: a scan whose velocity or one-scan relative pose NEES exceeds
`gross_failures.GROSS_NEES_PER_DOF` per dof, errors ten times their stated sigma) are named, and every measure is
summarised again without them (`consistency_without_gross`): one run that lost its way (before session 48's
fix of the restart, a prior SDE's vehicle pitched 50 degrees up, its radar seeing the sky) moves the means by
tens, which says nothing about the covariance where the estimator works. The first summary keeps every run.

Checked by: tests/validation/test_campaign_consistency.py::test_campaign_consistency_per_measure_consistent_and_overconfident,
    ::test_spread_between_runs_and_the_share_with_a_per_scan_factor, ::test_scans_outside_below_above_and_one_run,
    ::test_the_means_interval_holds_the_true_mean_about_as_often_as_it_claims,
    ::test_runs_with_a_gross_failure_are_named_and_summarised_without
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2
from scipy.stats import t as student_t

from .campaign_compare import mean_interval
from .consistency import average_nees, chi2_bounds, fraction_within, stacked_runs
from .error_growth import growth_table, pooled_growth
from .gross_failures import GROSS_NEES_PER_DOF
from .odometry_consistency import DOF, MEASURES

GROSS_MEASURES = ("velocity", "relative_scan")  # scan by scan: where the estimator fails, not where it drifts


def spread_between_runs(runs: list[np.ndarray]) -> float | None:
    """The runs' spread at a scan against chi-square(6)'s (module docstring); None with fewer than two runs or
    no scan that half of them (and two) reach with a positive mean.

    Per scan k with c_k finite values: S_k = var(NEES) / mean(NEES)^2 (ddof 1) / (2 / 6). For runs whose NEES is
    a scaled gamma (chi-square) with spread sigma, E[S_k] = sigma / (1 + sigma / (3 c_k)) (the Dirichlet moments
    of NEES / sum NEES), which reads low with few runs (0.86 for two chi-square runs); the mean S of S_k is
    returned as S / (1 - S mean_k(1 / (3 c_k))), unbiased for that model when every scan has the same count."""
    if len(runs) < 2:
        return None
    stack = stacked_runs(runs)
    count = np.sum(np.isfinite(stack), axis=0)
    enough = count >= max(2, (len(runs) + 1) // 2)
    X, c = stack[:, enough], count[enough]
    mean = np.nanmean(X, axis=0) if X.shape[1] else np.zeros(0)
    X, c, mean = X[:, mean > 0], c[mean > 0], mean[mean > 0]
    if not X.shape[1]:
        return None
    S = float(np.mean(np.nanvar(X, axis=0, ddof=1) / mean ** 2)) / (2.0 / DOF)
    shrink = 1.0 - S * float(np.mean(2.0 / (DOF * c)))
    return S / shrink if shrink > 0 else None


def fraction_within_per_scan_factor(spread: float | None, n_runs: int, alpha: float = 0.05) -> float | None:
    """The probability that an N-run average falls within `chi2_bounds(N, 6, alpha)` when each run's NEES is
    chi-square with 6 / spread degrees of freedom scaled to mean 6 (module docstring); None where undefined."""
    if spread is None or not spread > 0 or n_runs < 1:
        return None
    lo, hi = chi2_bounds(n_runs, DOF, alpha) / DOF  # bounds of the average NEES, per dof
    nu = n_runs * DOF / spread
    return float(chi2.cdf(hi * nu, nu) - chi2.cdf(lo * nu, nu))


def scans_outside(runs: list[np.ndarray], alpha: float = 0.05) -> dict:
    """{"scans_below", "scans_above", "scans_above_one_run"} of the runs' per-scan averages (module docstring)."""
    mean, count = average_nees(runs)
    return _outside(runs, mean, count, chi2_bounds(count, DOF, alpha), alpha)


def _outside(runs: list[np.ndarray], mean: np.ndarray, count: np.ndarray, b: np.ndarray, alpha: float) -> dict:
    """`scans_outside` given the runs' per-scan average, count and bounds."""
    stack = stacked_runs(runs)
    with np.errstate(invalid="ignore"):
        below, above = mean < b[:, 0], mean > b[:, 1]
        largest = np.nanmax(np.where(count > 0, stack, 0.0), axis=0) if stack.size else np.zeros(0)
        rest = (mean * count - largest) / np.maximum(count - 1, 1)
        br = chi2_bounds(np.maximum(count - 1, 0), DOF, alpha)
        one_run = above & (count > 1) & (rest >= br[:, 0]) & (rest <= br[:, 1])
    return {"scans_below": int(below.sum()), "scans_above": int(above.sum()), "scans_above_one_run": int(one_run.sum())}


def measure_summary(runs: list[np.ndarray], alpha: float = 0.05) -> tuple[dict, dict]:
    """Summary and curve of one measure over runs (each (K_i,) per-scan NEES; runs without a finite value are
    not counted). Returns (summary, curve): summary with dof, runs, mean_per_dof, median_per_dof,
    bounds_for_runs, bounds_per_dof, fraction_scans_within, spread_between_runs, fraction_within_per_scan_factor
    (None where undefined), scans_below, scans_above and scans_above_one_run (`scans_outside`),
    mean_interval_per_dof (`mean_interval_per_dof`); curve with mean, count, lower, upper (per scan, NEES, not per
    dof)."""
    runs = [np.asarray(r, dtype=float) for r in runs if np.isfinite(np.asarray(r, dtype=float)).any()]
    n = len(runs)
    bounds = chi2_bounds(n, DOF, alpha)
    summary = {"dof": DOF, "runs": n, "mean_per_dof": None, "median_per_dof": None,
               "bounds_for_runs": bounds.tolist(), "bounds_per_dof": (bounds / DOF).tolist(),
               "fraction_scans_within": None, "spread_between_runs": None,
               "fraction_within_per_scan_factor": None, "scans_below": 0, "scans_above": 0,
               "scans_above_one_run": 0, "mean_interval_per_dof": mean_interval_per_dof(runs)}
    if not n:
        return summary, {}
    mean, count = average_nees(runs)
    b = chi2_bounds(count, DOF, alpha)
    summary.update(_outside(runs, mean, count, b, alpha))
    fin = np.isfinite(mean)
    within = fraction_within(mean, b)
    summary.update({"mean_per_dof": float(np.mean(mean[fin]) / DOF), "median_per_dof": float(np.median(mean[fin]) / DOF),
                    "fraction_scans_within": None if np.isnan(within) else within})
    spread = spread_between_runs(runs)
    summary.update({"spread_between_runs": spread,
                    "fraction_within_per_scan_factor": fraction_within_per_scan_factor(spread, n, alpha)})
    return summary, {"mean": mean.tolist(), "count": count.tolist(), "lower": b[:, 0].tolist(),
                     "upper": b[:, 1].tolist()}


def mean_interval_per_dof(runs: list[np.ndarray], level: float = 0.95) -> list[float] | None:
    """[lower, upper], per dof, of the interval at `level` of the mean over runs of each run's mean NEES over its
    finite scans; None with fewer than two runs that have a scan. The runs' means are taken as lognormal (a
    scale per run times chi-square noise) and the interval is Cox's for a lognormal mean (Olsson 2005, "Confidence
    intervals for the mean of a log-normal distribution"): exp(m + s^2 / 2 +- t sqrt(s^2 / N + s^4 / (2 (N - 1))))
    of the logs' mean m and variance s^2. On runs whose scale spreads by a factor e it holds the mean in 95 % of
    campaigns of 20 runs, where the Student-t interval held it in 88 % (tests); with a mean of 0 (no log) the
    t interval, not below 0."""
    means = np.array([np.mean(r[np.isfinite(r)]) / DOF for r in map(np.asarray, runs) if np.isfinite(r).any()])
    if len(means) < 2:
        return None
    if np.any(means <= 0):
        _, lo, hi = mean_interval(means, level)
        return [max(lo, 0.0), hi]
    y = np.log(means)
    n, s2 = len(y), float(np.var(y, ddof=1))
    h = float(student_t.ppf(0.5 + level / 2, n - 1)) * np.sqrt(s2 / n + s2**2 / (2 * (n - 1)))
    centre = float(np.mean(y)) + s2 / 2
    return [float(np.exp(centre - h)), float(np.exp(centre + h))]


def gross_failure_runs(arrays: list[dict]) -> list[int]:
    """The indices of the runs (npz arrays, as `campaign_consistency` takes them) with a scan whose NEES of a
    GROSS_MEASURES measure exceeds GROSS_NEES_PER_DOF per dof."""
    limit = GROSS_NEES_PER_DOF * DOF
    return [i for i, a in enumerate(arrays)
            if any(np.nanmax(np.asarray(a[f"nees_{k}"], dtype=float), initial=-np.inf) > limit
                   for k in GROSS_MEASURES if f"nees_{k}" in a)]


def _summaries(arrays: list[dict], alpha: float) -> tuple[dict, dict]:
    """({measure: `measure_summary`}, {measure: curve}) over the runs' npz arrays."""
    summary, curves = {}, {}
    for name in MEASURES:
        key = f"nees_{name}"
        summary[name], curve = measure_summary([a[key] for a in arrays if key in a], alpha)
        if curve:
            curves[name] = curve
    return summary, curves


def campaign_consistency(arrays: list[dict], alpha: float = 0.05) -> dict:
    """Per measure (MEASURES) over the runs' npz arrays (dicts with `t` and `nees_<measure>`; runs written
    before the measures existed have none and are skipped), and the runs' error growth pooled (their
    `growth_<sum>` arrays, `error_growth`; None where no run has them). Returns {"consistency": {measure:
    measure_summary}, "consistency_curves": {"t": longest t, measure: curve}, "error_growth": {runs, the pooled
    sums, table: `growth_table`} or None, "gross_failure_runs": the runs with a gross failure (`gross_failure_runs`,
    named by each run's `trial` where the arrays hold it, else by index), "consistency_without_gross": {measure:
    measure_summary} over the other runs, or None where there is no such run}."""
    t = max((np.asarray(a["t"], dtype=float) for a in arrays), key=len, default=np.zeros(0))
    summary, curves = _summaries(arrays, alpha)
    curves = {"t": t.tolist(), **curves}
    gross = gross_failure_runs(arrays)
    without = _summaries([a for i, a in enumerate(arrays) if i not in gross], alpha)[0] if gross else None
    growths = [{k[len("growth_"):]: v for k, v in a.items() if k.startswith("growth_")} for a in arrays
               if "growth_count" in a]
    pooled = pooled_growth(growths)
    growth = None if pooled is None else {"runs": len(growths), **pooled, "table": growth_table(pooled)}
    named = [int(arrays[i].get("trial", i)) for i in gross]
    return {"consistency": summary, "consistency_curves": curves, "error_growth": growth, "gross_failure_runs": named,
            "consistency_without_gross": without}


def consistency_lines(entry: dict, fmt) -> list[str]:
    """Markdown table of a model's measures (summary.md: `entry` a model's summary, its `consistency` and, where
    runs had a gross failure, their trials and the table without them); `fmt` formats a number or None ("-")."""
    lines = ["", "Odometry consistency (average NEES over runs per scan, 6 dof, divided by 6; the 95 % interval of "
             "the mean over the runs' own means; bounds for the N runs of the measure; spread: the runs' disagreement "
             "at a scan against chi-square's, and the share of scans a per-scan factor common to all runs would bring "
             "within at that spread; outside: the scans below and above the bounds, and of those above, how many one "
             "run's value puts there):", ""] + _table(entry["consistency"], fmt)
    gross = entry.get("gross_failure_runs") or []
    if gross and entry.get("consistency_without_gross"):
        lines += ["", f"Runs with a gross failure (a scan's velocity or one-scan relative pose NEES above "
                      f"{GROSS_NEES_PER_DOF:g} per dof): trial{'s' if len(gross) > 1 else ''} "
                      f"{', '.join(map(str, gross))}. Without them:", ""]
        lines += _table(entry["consistency_without_gross"], fmt)
    return lines


def _table(consistency: dict, fmt) -> list[str]:
    """The rows of `consistency_lines`' table, with its header."""
    pct = lambda v: fmt(None if v is None else 100 * v)  # noqa: E731
    lines = ["| measure | runs | mean NEES/dof | 95 % interval | median | bounds/dof | scans within | spread "
             "| with a per-scan factor | below / above (one run) |",
             "| --- | ---: | ---: | --- | ---: | --- | ---: | ---: | ---: | ---: |"]
    for name in MEASURES:
        c = consistency.get(name)
        if c is None:
            continue
        lo, hi = c["bounds_per_dof"]
        ci = c.get("mean_interval_per_dof")
        lines.append(f"| {name} | {c['runs']} | {fmt(c['mean_per_dof'])} | "
                     f"{'-' if ci is None else f'[{fmt(ci[0])}, {fmt(ci[1])}]'} | {fmt(c['median_per_dof'])} | "
                     f"[{fmt(lo)}, {fmt(hi)}] | {pct(c['fraction_scans_within'])} % | "
                     f"{fmt(c.get('spread_between_runs'))} | {pct(c.get('fraction_within_per_scan_factor'))} % | "
                     f"{_outside_cell(c)} |")
    return lines


def _outside_cell(c: dict) -> str:
    """"below / above (one run)" of a measure's summary; "-" in summaries written before the counts."""
    if "scans_above" not in c:
        return "-"
    return f"{c['scans_below']} / {c['scans_above']} ({c['scans_above_one_run']})"
