"""Monte Carlo campaign throughput: trials per minute of a `city` trial (simulate once, run ca-polar and
cv-cartesian on that sequence, evaluate), on a local process pool and on a Dask LocalCluster (processes, one
thread per worker), both with as many workers as cores. Full: 60 s trials; quick: 5 s trials (stated in the
table). Also: where one serial trial's seconds go (simulate, run, evaluate) and the load average, since the
machine may be shared.

Run: `python -m bench.campaign [--quick]`, or through `python -m bench --only campaign`.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from rodo.validation.campaign import Trial, make_executor, make_trials, read_results, run_campaign
from rodo.validation.trial import ScenarioTrial

MODELS = ("ca-polar", "cv-cartesian")


def _campaign(executor_kind: str, jobs: int, trials, trial_fn, root: Path) -> dict:
    out = root / executor_kind
    tic = time.perf_counter()
    with make_executor(jobs, None if executor_kind == "process pool" else "local") as ex:
        start = time.perf_counter()
        rep = run_campaign(trial_fn, trials, ex, out)
        run_s = time.perf_counter() - start
    total_s = time.perf_counter() - tic
    rows = read_results(out / "results.csv")
    ok = sum(r["status"] == "ok" for r in rows)
    ms = sorted(float(r["ms_per_scan"]) for r in rows if r["status"] == "ok")
    return {"executor": executor_kind, "workers": jobs, "trials": len(trials), "ok rows": f"{ok}/{len(rows)}",
            "wall s (run)": run_s, "start-up + shut-down s": total_s - run_s,
            "trials/min": 60 * len(trials) / run_s, "median ms/scan": ms[len(ms) // 2] if ms else float("nan"),
            "rows written": rep.ran,
            "errors": "; ".join(sorted({r["error"].replace("|", "/") for r in rows if r["status"] == "error"})[:2])
            or "-"}


def _load(avg) -> str:
    return ", ".join(f"{x:.2f}" for x in avg)


def _phases(outcomes) -> str:
    """Where a trial's seconds went: simulate (once), then run and evaluate per model (TrialOutcome.timings)."""
    parts = [f"simulate {outcomes[0].timings.get('simulate', float('nan')):.1f} s"]
    for o in outcomes:
        parts.append(f"{o.model} run {o.timings.get('run', float('nan')):.1f} s (median "
                     f"{o.metrics.get('ms_per_scan', float('nan')):.1f} ms/scan) + evaluate "
                     f"{o.timings.get('evaluate', float('nan')):.2f} s")
    return ", ".join(parts)


def run(quick: bool) -> str:
    jobs = os.cpu_count() or 1
    duration = 5.0 if quick else 60.0
    n = 2 * jobs
    trials = make_trials(0, n, MODELS)
    trial_fn = ScenarioTrial("city", duration)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        ScenarioTrial("city", 1.0)(Trial(0, 0, MODELS))  # load the kernels from numba's cache, untimed
        tic = time.perf_counter()
        outcomes = trial_fn(trials[0])  # serial reference; the pool's workers are forked with its kernels loaded
        serial_s = time.perf_counter() - tic
        rows = [_campaign(kind, jobs, trials, trial_fn, Path(tmp)) for kind in ("process pool", "dask local")]
    load_after = os.getloadavg()
    keys = list(rows[0])
    lines = ["## Monte Carlo campaign throughput", "",
             f"`city` trials of {duration:g} s simulated time{' (quick mode: shortened from 60 s)' if quick else ''}"
             f", each = simulate once + {' + '.join(MODELS)} on that sequence + evaluation; {n} trials on {jobs} "
             f"workers ({os.cpu_count()} cores). One trial run serially in the same process: {serial_s:.1f} s "
             f"({60 / serial_s:.2f} trials/min): {_phases(outcomes)}. Load average (1, 5, 15 min) before: "
             f"{_load(load_before)}; after: {_load(load_after)}.", "",
             "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys) + " |")
    lines += ["", "Wall times on a machine shared with other jobs vary; the ratio between the two executors in the "
                  "same run is the figure to compare. The pool's workers are forked from this process, which holds "
                  "the compiled numba kernels after the serial trial; Dask's worker processes start fresh (cluster "
                  "start-up is listed apart) and load the kernels from numba's cache in their first trial, a cost "
                  "that longer trials amortise."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.campaign", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 s trials instead of 60 s")
    args = ap.parse_args(argv)
    sys.stdout.write(run(args.quick))
    return 0


if __name__ == "__main__":
    sys.exit(main())
