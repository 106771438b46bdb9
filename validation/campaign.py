"""Monte Carlo campaigns: many seeded trials of a scenario, each run with several models, evaluated against truth.

One runner, `run_campaign(trial_fn, trials, executor, out_dir, resume)`, serves every executor that follows the
`concurrent.futures.Executor` interface: a local `ProcessPoolExecutor` or a Dask `Client.get_executor()`
(`validation.workers.make_executor`). Workers only compute; the calling process writes every file, so a remote
Dask worker needs no shared disk. Layout of out_dir (docs/evaluation.md):

- `.campaign.lock`: flock'ed while a writer runs (`validation.campaign_dir`: a second writer is refused);
- `campaign.json`: the campaign's parameters (checked on resume: resuming a different campaign is an error; a
  larger number of runs extends the campaign);
- `results.csv`: one row per (trial, model), appended, flushed and fsync'ed as soon as the trial finishes;
- `trials/trial_XXXX_MODEL.npz`: per-scan arrays of the run (t, nees, nis, n_associated, ms_per_scan, ...),
  written atomically *before* its row, so a row always has its arrays;
- `summary.json`, `summary.md` (`summarize_campaign`, `write_summary`).

The files themselves (format, atomic and fsync'ed writes, reading back a torn row) are `validation.campaign_files`.

Seeds: `trial_seeds(seed, n)` spawns n children of `SeedSequence(seed)`; trial i's integer seed is the first
64-bit word of child i's state, shifted right by one (so it is a non-negative int63):
`SeedSequence(seed).spawn(n)[i].generate_state(1, np.uint64)[0] >> 1`. The scenario then derives its own
streams from that integer. Same (seed, n) -> same seeds -> same bytes; a trial's seed does not depend on n.

Checked by: tests/validation/test_campaign.py
"""

from __future__ import annotations

import json
import time
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, CancelledError, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from rodo.estimator.errors import InputError, is_environment_error
from rodo.sim.sequence import atomic_write_bytes

from .campaign_dir import campaign_lock, check_and_save_meta
from .campaign_consistency import campaign_consistency, consistency_lines
from .error_growth import growth_lines
from .campaign_files import (CONSISTENCY_FIELDS, COVERAGE_FIELDS, FIELDS, METRICS, append_rows, cell,
                             load_trial_arrays, npz_path, read_results, rewrite_results, save_arrays, writes_arrays)
from .campaign_compare import compare_models, comparison_lines
from .consistency import average_nees, chi2_bounds, fraction_within
from .metrics import jsonable
from .workers import make_executor  # noqa: F401 (re-exported: its home until session 55)


@dataclass(frozen=True)
class Trial:
    """One trial: its index in the campaign, its integer seed, and the models still to run."""

    index: int
    seed: int
    models: tuple[str, ...]


@dataclass
class TrialOutcome:
    """The result of one model in one trial: a metrics row, per-scan arrays, or an error message; `timings`
    (seconds per phase of the trial, e.g. simulate, run, evaluate) are for benchmarks and not persisted."""

    model: str
    metrics: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)
    error: str | None = None
    timings: dict = field(default_factory=dict)

    @property
    def status(self) -> str:
        return "ok" if self.error is None else "error"


def trial_seeds(seed: int, n: int) -> list[int]:
    """Integer seeds of n trials from one `SeedSequence(seed).spawn(n)` (module docstring).

    Checked by: tests/validation/test_campaign.py::test_trial_seeds_reproducible
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0, got {seed!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"runs: expected an integer >= 1, got {n!r}")
    children = np.random.SeedSequence(int(seed)).spawn(int(n))
    return [int(c.generate_state(1, np.uint64)[0] >> np.uint64(1)) for c in children]


def make_trials(seed: int, runs: int, models: Iterable[str]) -> list[Trial]:
    models = tuple(models)
    if not models:
        raise InputError("models: at least one model is needed")
    return [Trial(i, s, models) for i, s in enumerate(trial_seeds(seed, runs))]


def error_text(exc: BaseException) -> str:
    """One line naming an exception: `Type: message` (campaign rows record failures with it)."""
    return f"{type(exc).__name__}: {exc}".strip()


def remaining(trials: list[Trial], out_dir) -> int:
    """How many (trial, model) runs of `trials` a resume runs (for a progress bar): those not yet in
    out_dir/results.csv, and those whose trial arrays are unreadable."""
    rows = read_results(Path(out_dir) / "results.csv")
    done = {(int(r["trial"]), r["model"]) for r in rows} - unreadable_runs(Path(out_dir), rows)
    return sum((tr.index, m) not in done for tr in trials for m in tr.models)


def unreadable_runs(out: Path, rows: list[dict]) -> set[tuple[int, str]]:
    """(trial, model) of the ok rows whose trials/*.npz cannot be read (truncated, corrupt), or is missing while
    other ok rows of its model have theirs (the campaign writes them): resume runs them again."""
    bad, with_arrays = set(), {m: writes_arrays(out, rows, m) for m in {r["model"] for r in rows}}
    for r in rows:
        p = npz_path(out, int(r["trial"]), r["model"])
        if r["status"] == "ok" and p.exists():
            try:
                load_trial_arrays(p)
            except InputError:
                bad.add((int(r["trial"]), r["model"]))
        elif r["status"] == "ok" and with_arrays[r["model"]]:
            bad.add((int(r["trial"]), r["model"]))
    return bad


@dataclass
class CampaignReport:
    rows: list[dict]  # all rows of results.csv after the run
    ran: int  # (trial, model) rows written by this call
    skipped: int  # rows already present (resume)
    wall_s: float


def run_campaign(trial_fn: Callable[[Trial], list[TrialOutcome]], trials: list[Trial], executor, out_dir,
                 resume: bool = False, progress=None, meta: dict | None = None) -> CampaignReport:
    """Run every (trial, model) not yet in out_dir/results.csv on `executor`, persisting each trial at once.

    Args:
        trial_fn: picklable callable Trial -> list[TrialOutcome] (one per model of trial.models). An exception
            raised by it is recorded as status=error for each of the trial's models; it never stops the campaign.
            A broken executor (a worker process died) is not the trial's failure: it stops the campaign with
            nothing recorded for the unfinished trials, so that resume runs them.
        trials: the campaign's trials (make_trials).
        executor: any concurrent.futures.Executor (ProcessPoolExecutor, Dask's Client.get_executor()).
        out_dir: campaign directory (created), locked for the call (`campaign_dir.campaign_lock`: a second
            writer in another process is refused).
        resume: continue a campaign in out_dir, skipping (trial, model) rows already written (ok or error),
            except ok rows whose trial arrays are unreadable or missing (the run is done again).
            Without it, an existing results.csv is an error (nothing is overwritten). A resumed row whose seed
            differs from its trial's is an error (another campaign).
        progress: optional object with update(n) (rodo.progress.Progress), called once per (trial, model).
        meta: the campaign's parameters, saved as campaign.json; on resume they must equal the saved ones,
            except meta["runs"], which may grow (the campaign is extended; trial seeds do not depend on the
            number of runs) but not shrink (`campaign_dir.check_and_save_meta`).

    Returns:
        CampaignReport. An interruption (KeyboardInterrupt, or an exception from `progress`) cancels the
        pending trials and propagates; every row written before it stays, and resume picks up the rest.

    Checked by: tests/validation/test_campaign.py
    """
    with campaign_lock(out_dir) as out:
        csv_path = out / "results.csv"
        check_and_save_meta(out, jsonable(meta or {}), resume)
        rows = read_results(csv_path) if resume else []
        _check_seeds(csv_path, rows, trials)
        broken = unreadable_runs(out, rows)
        for trial, model in broken:  # a truncated or corrupt trial file: the run is done again
            npz_path(out, trial, model).unlink(missing_ok=True)
        rows = [r for r in rows if (int(r["trial"]), r["model"]) not in broken]
        if resume and csv_path.exists():
            rewrite_results(csv_path, rows)  # drops a torn final row
        todo = _missing_runs(trials, rows)
        skipped = sum(len(tr.models) for tr in trials) - sum(len(tr.models) for tr in todo)
        t0 = time.perf_counter()
        ran = _run_and_persist(trial_fn, todo, executor, out, rows, progress)
    return CampaignReport(rows, ran, skipped, time.perf_counter() - t0)


def _check_seeds(csv_path: Path, rows: list[dict], trials: list[Trial]) -> None:
    """A resumed row must have been run with the seed its trial has now (else it is another campaign)."""
    seeds = {tr.index: tr.seed for tr in trials}
    for line, r in enumerate(rows, start=2):
        i = int(r["trial"])
        if i in seeds and r["seed"] != str(seeds[i]):
            raise InputError(f"resume: {csv_path}: line {line}: trial {i} was run with seed {r['seed']}, but this "
                             f"campaign gives it seed {seeds[i]} (another --seed?); resume with the campaign's "
                             "parameters or choose another directory")


def _missing_runs(trials: list[Trial], rows: list[dict]) -> list[Trial]:
    """The trials restricted to the models that have no row yet (trials with none left are dropped)."""
    done = {(int(r["trial"]), r["model"]) for r in rows}
    todo = []
    for tr in trials:
        missing = tuple(m for m in tr.models if (tr.index, m) not in done)
        if missing:
            todo.append(Trial(tr.index, tr.seed, missing))
    return todo


def _run_and_persist(trial_fn, todo: list[Trial], executor, out: Path, rows: list[dict], progress) -> int:
    """Submit every trial, append each one's rows (and arrays) as it finishes; returns the rows written.

    `rows` is extended in place. An interruption cancels the pending trials and propagates.
    """
    csv_path = out / "results.csv"
    ran = 0
    pending = {executor.submit(trial_fn, tr): tr for tr in todo}
    try:
        while pending:
            finished, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for fut in finished:
                tr = pending.pop(fut)
                new_rows = _collect(out, tr, fut)
                append_rows(csv_path, new_rows)
                rows.extend({k: str(cell(r.get(k, ""))) for k in FIELDS} for r in new_rows)
                ran += len(new_rows)
                if progress is not None:
                    progress.update(len(new_rows))
    except BaseException:
        for fut in pending:
            fut.cancel()
        raise
    return ran


def _collect(out: Path, tr: Trial, fut) -> list[dict]:
    """Rows (and saved arrays) for a finished future; any failure becomes status=error rows."""
    base = {"trial": tr.index, "seed": tr.seed}
    try:
        outcomes = fut.result()  # a broken pool or a cancelled future is no result of the trial: it propagates
        by_model = {o.model: o for o in outcomes}
        missing = [m for m in tr.models if m not in by_model]
        if missing:
            raise RuntimeError(f"trial function returned no outcome for model(s) {', '.join(missing)}")
    except (BrokenExecutor, CancelledError):
        raise
    except Exception as exc:  # noqa: BLE001 - a failed trial is data, not a reason to stop
        if is_environment_error(exc):  # but a full disk is not a failed trial: no row, so --resume runs it again
            raise
        text = error_text(exc)
        return [{**base, "model": m, "status": "error", "error": text} for m in tr.models]
    rows = []
    for m in tr.models:
        o = by_model[m]
        if o.error is None and o.arrays:
            save_arrays(npz_path(out, tr.index, m), o.arrays)
        rows.append({**base, "model": m, "status": o.status, **{k: o.metrics.get(k, "") for k in METRICS},
                     "error": o.error or ""})
    return rows


SUMMARY_METRICS = ("kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m", "rpe_trans_pct", "drift_z_m",
                   "max_abs_z_m", "max_abs_roll_deg", "max_abs_pitch_deg", "drift_yaw_deg", "nees_mean", "nis_mean",
                   "nu_rmse_mps", "ms_per_scan", "wall_s") + CONSISTENCY_FIELDS + COVERAGE_FIELDS


def _describe(x: np.ndarray) -> dict:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"n": 0, "mean": None, "median": None, "p2_5": None, "p97_5": None}
    lo, hi = np.percentile(x, [2.5, 97.5])
    return {"n": int(x.size), "mean": float(x.mean()), "median": float(np.median(x)), "p2_5": float(lo),
            "p97_5": float(hi)}


def summarize_campaign(out_dir, alpha: float = 0.05) -> dict:
    """Per model: mean, median and 95 % interval (2.5/97.5 percentiles) of every metric over the ok trials, the
    error count, the average NEES over runs per scan against chi2_bounds(runs at that scan, d, alpha), and the
    same per odometry consistency measure (`campaign_consistency`).

    Returns a JSON-ready dict; `nees_curve` per model holds t, mean, count, lower, upper (lists); `consistency`
    per model the summary of each measure and `consistency_curves` their curves (t, and per measure mean,
    count, lower, upper).

    Checked by: tests/validation/test_campaign.py::test_summary_statistics_and_nees_bounds
    """
    out = Path(out_dir)
    rows = read_results(out / "results.csv")
    models = list(dict.fromkeys(r["model"] for r in rows))
    summary = {"trials": len({r["trial"] for r in rows}), "alpha": alpha, "models": {}}
    for m in models:
        mine = [r for r in rows if r["model"] == m]
        ok = sorted((r for r in mine if r["status"] == "ok"), key=lambda r: int(r["trial"]))  # completion order
        # differs between a resumed and an uninterrupted campaign: sums in trial order make their summaries equal
        num = lambda k: np.array([float(r[k]) if r[k] not in ("", "None") else np.nan for r in ok])  # noqa: E731
        entry = {"runs": len(mine), "ok": len(ok), "errors": len(mine) - len(ok),
                 "error_examples": sorted({r["error"] for r in mine if r["status"] == "error"})[:3],
                 "metrics": {k: _describe(num(k)) for k in SUMMARY_METRICS}}
        runs, t, dim, arrays, with_arrays = [], np.zeros(0), None, [], writes_arrays(out, ok, m)
        for r in ok:
            p = npz_path(out, int(r["trial"]), m)
            if not p.exists() and with_arrays:  # not summarised over fewer runs than the table says
                raise InputError(f"{p}: missing (results.csv has the run as ok); run the campaign again with "
                                 "--resume to redo it")
            if not p.exists():
                continue
            z = load_trial_arrays(p, ("t", "nees", "nees_dim"))
            runs.append(z["nees"])
            dim = int(z["nees_dim"])
            t = z["t"] if len(z["t"]) > len(t) else t
            arrays.append({k: v for k, v in z.items() if k == "t" or k.startswith(("nees_", "growth_"))})
            arrays[-1]["trial"] = int(r["trial"])  # names a run with a gross failure
        entry.update(campaign_consistency(arrays, alpha))
        if runs:
            mean, count = average_nees(runs)
            b = chi2_bounds(count, dim, alpha)
            fin = np.isfinite(mean)
            within = fraction_within(mean, b)
            pooled = np.concatenate([r[np.isfinite(r)] for r in runs])
            entry["nees"] = {"dim": dim, "runs": len(runs), "mean_over_scans": float(np.mean(mean[fin])),
                             "median_over_scans": float(np.median(mean[fin])),
                             "bounds_for_runs": chi2_bounds(len(runs), dim, alpha).tolist(),
                             "fraction_scans_within": None if np.isnan(within) else within,
                             "pooled_mean": float(pooled.mean()) if pooled.size else None}
            entry["nees_curve"] = {"t": t.tolist(), "mean": mean.tolist(), "count": count.tolist(),
                                   "lower": b[:, 0].tolist(), "upper": b[:, 1].tolist()}
        summary["models"][m] = entry
    summary["comparisons"] = compare_models(rows)
    return jsonable(summary)


def write_summary(out_dir, summary: dict, plot_note: str = "") -> None:
    """Write summary.json and summary.md (a table per model; `plot_note` is added, e.g. where the NEES plot is)."""
    out = Path(out_dir)
    slim = {**summary, "models": {m: {k: v for k, v in e.items() if k not in ("nees_curve", "consistency_curves")}
                                  for m, e in summary["models"].items()}}
    atomic_write_bytes(out / "summary.json", (json.dumps(summary, indent=1) + "\n").encode())
    fmt = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
    lines = ["# Monte Carlo campaign", ""]
    meta_path = out / "campaign.json"
    if meta_path.exists():
        meta = json.loads(meta_path.read_text())
        shown = {k: (", ".join(f"{label} (config in campaign.json)" for label in v) if k == "configs" else v)
                 for k, v in meta.items()}
        lines += ["Parameters: " + ", ".join(f"{k}={v}" for k, v in sorted(shown.items())), ""]
    lines += [f"{summary['trials']} trials; intervals are the 2.5 and 97.5 percentiles over the ok runs; NEES "
              f"bounds are two-sided {100 * (1 - summary['alpha']):.0f} % chi-square bounds of the average.", ""]
    for m, e in slim["models"].items():
        lines += [f"## {m}", "", f"runs {e['runs']}, ok {e['ok']}, errors {e['errors']}", ""]
        for msg in e["error_examples"]:
            lines.append(f"- error: `{msg}`")
        lines += ["", "| metric | n | mean | median | 95 % interval |", "| --- | ---: | ---: | ---: | --- |"]
        for k, s in e["metrics"].items():
            lines.append(f"| {k} | {s['n']} | {fmt(s['mean'])} | {fmt(s['median'])} | "
                         f"[{fmt(s['p2_5'])}, {fmt(s['p97_5'])}] |")
        if "nees" in e:
            n = e["nees"]
            lo, hi = n["bounds_for_runs"]
            lines += ["", f"Average NEES (d = {n['dim']}, {n['runs']} runs): mean over scans "
                          f"{fmt(n['mean_over_scans'])}, median {fmt(n['median_over_scans'])}; bounds for "
                          f"{n['runs']} runs [{fmt(lo)}, {fmt(hi)}]; scans within their bounds: "
                          f"{fmt(None if n['fraction_scans_within'] is None else 100 * n['fraction_scans_within'])} %."]
        if any(c["runs"] for c in e.get("consistency", {}).values()):
            lines += consistency_lines(e, fmt) + growth_lines(e.get("error_growth"), fmt)
        lines.append("")
    lines += comparison_lines(summary.get("comparisons", []), fmt)
    if plot_note:
        lines += [plot_note, ""]
    atomic_write_bytes(out / "summary.md", "\n".join(lines).encode())
