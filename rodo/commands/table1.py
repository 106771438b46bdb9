"""`rodo table1 [--runs N] [--scenarios city,highway,hills,stop_and_go,blockage] [--fault NAME=VALUE] [--profile NAME]
[--jobs J] [--dask ADDRESS|local [--dashboard [ADDR]]] [--duration S] [--seed S] --out DIR [--resume]`:
the paper's Table I on the simulated suite (validation/table1.py).

One resumable campaign per scenario in DIR/<scenario>/ (both models, N seeds from SeedSequence(seed)), then
DIR/table1.md and DIR/table1.json, and the table on stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import os
from concurrent.futures import BrokenExecutor

from rodo.estimator.errors import InputError
from rodo.progress import Progress
from rodo.commands.montecarlo import (add_campaign_options, add_fault_option, add_profile_option,
                                      check_campaign_options, check_faults, check_profile, option_meta,
                                      worker_died)
from rodo.validation.campaign_dir import campaign_lock
from rodo.validation.campaign import make_executor, make_trials, remaining, run_campaign
from rodo.validation.table1 import MODELS, SCENARIOS, Table1Trial, build_table, load_runs, write_table


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("table1", help="the paper's Table I (KITTI drift, runtime; CV/C vs CA/P) on the simulated "
                                      "suite",
                       description="Run N seeded trials of each scenario with both models (a resumable campaign "
                                   "per scenario in DIR/<scenario>/), then write DIR/table1.md and table1.json.")
    p.add_argument("--runs", type=int, default=1, help="trials per scenario (default 1)")
    p.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated scenarios (%(default)s)")
    add_fault_option(p)
    add_profile_option(p)
    add_campaign_options(p)
    p.set_defaults(func=main)


def parse_scenarios(text: str) -> list[str]:
    from rodo import scenarios

    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise InputError("--scenarios: no scenario given")
    known = scenarios.names()
    bad = [s for s in names if s not in known]
    if bad:
        raise InputError(f"--scenarios: unknown scenario(s) {', '.join(bad)}; choose from {', '.join(known)}")
    if len(set(names)) != len(names):
        raise InputError(f"--scenarios: a scenario is listed twice: {text}")
    return names


def main(args) -> int:
    try:
        return run_table1(args)
    except BrokenExecutor as exc:
        return worker_died("table1", args.out, exc)


def run_table1(args) -> int:
    check_campaign_options(args)
    names = parse_scenarios(args.scenarios)
    faults = check_faults(args.fault, "table1")
    check_profile(args.profile)
    trials = make_trials(args.seed, args.runs, MODELS)
    out = args.out
    if not args.resume:
        taken = [s for s in names if os.path.exists(os.path.join(out, s, "results.csv"))]
        if taken:  # checked before any work, so a refused run leaves nothing half done
            raise InputError(f"--out: {os.path.join(out, taken[0], 'results.csv')} exists; pass --resume to "
                             "continue, or choose another directory")
    with contextlib.ExitStack() as locks:  # DIR and every DIR/<scenario>, held over the whole run
        for d in [out] + [os.path.join(out, s) for s in names]:
            locks.enter_context(campaign_lock(d))
        ran, skipped, errors = _run_campaigns(args, names, trials, faults)
        table = build_table(load_runs(out, names), names)
        meta = {"scenarios": ",".join(names), "runs": args.runs, "seed": args.seed, "duration": args.duration}
        meta.update(option_meta(faults, args.profile))
        text = write_table(out, table, meta)
    print(text)
    print(f"ran {ran} (trial, model) runs, skipped {skipped} already done, {errors} errors")
    print(f"wrote {os.path.join(out, 'table1.md')} and table1.json")
    return 0


def _run_campaigns(args, names: list[str], trials, faults: tuple[str, ...]) -> tuple[int, int, int]:
    """One campaign per scenario in DIR/<scenario>/ on one executor, each trial simulated with `faults`;
    (rows ran, rows skipped, error rows)."""
    out = args.out
    total = sum(remaining(trials, os.path.join(out, s)) for s in names) if args.resume \
        else len(names) * len(trials) * len(MODELS)
    ran = skipped = errors = 0
    with Progress(total, "table1", unit="run") as bar, make_executor(
            args.jobs, args.dask, dashboard=args.dashboard,
            on_dashboard=lambda link: bar.print(f"Dask dashboard: {link}")) as executor:
        for s in names:
            meta = {"scenario": s, "runs": args.runs, "models": list(MODELS), "seed": args.seed,
                    "duration": args.duration, "table": "table1"}
            meta.update(option_meta(faults, args.profile))
            trial_fn = Table1Trial(s, args.duration, faults=faults, profile=args.profile)
            rep = run_campaign(trial_fn, trials, executor, os.path.join(out, s),
                               resume=args.resume, progress=bar, meta=meta)
            ran, skipped = ran + rep.ran, skipped + rep.skipped
            errors += sum(r["status"] == "error" for r in rep.rows)
            for r in rep.rows:
                if r["status"] == "error":
                    print(f"error in {s} trial {r['trial']} ({r['model']}): {r['error']}")
    return ran, skipped, errors
