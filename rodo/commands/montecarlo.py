"""`rodo montecarlo SCENARIO --runs N --models ca-polar,cv-cartesian [--jobs J] [--dask ADDRESS|local]
[--duration S] [--seed S] --out DIR [--resume]`: a Monte Carlo campaign (validation/campaign.py,
docs/evaluation.md)."""

from __future__ import annotations

import argparse
import os

from rodo.estimator.config import MODELS
from rodo.estimator.errors import InputError
from rodo.progress import Progress
from rodo.validation.campaign import make_executor, make_trials, remaining, run_campaign, summarize_campaign, write_summary
from rodo.validation.trial import ScenarioTrial


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("montecarlo", help="Monte Carlo campaign: seeded trials of a scenario, several models",
                       description="Simulate SCENARIO with N seeds (one SeedSequence(seed).spawn(N)), run each "
                                   "model, evaluate against truth. Writes DIR/results.csv (a row per trial and "
                                   "model, persisted at once), DIR/trials/*.npz, DIR/summary.md and summary.json.")
    p.add_argument("scenario", metavar="SCENARIO", help="scenario name (rodo simulate --list)")
    p.add_argument("--runs", type=int, required=True, help="number of trials")
    p.add_argument("--models", default="ca-polar,cv-cartesian", help="comma-separated models (%(default)s)")
    add_campaign_options(p)
    p.set_defaults(func=main)


def add_campaign_options(p) -> None:
    """The options every campaign command shares (montecarlo, table1): executor, trial length, seed, output."""
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel workers (default: cores)")
    p.add_argument("--dask", metavar="ADDRESS", help="'local' (a LocalCluster of --jobs workers) or a scheduler "
                                                     "address tcp://host:port; default: a local process pool")
    p.add_argument("--duration", type=float, help="seconds of each trial (default: each scenario's own)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="campaign directory")
    p.add_argument("--resume", action="store_true", help="continue the campaign in DIR (skip finished rows)")


def parse_models(text: str) -> tuple[str, ...]:
    models = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in models if m not in MODELS]
    if not models or bad:
        raise InputError(f"--models: unknown model(s) {', '.join(bad) or '(none given)'}; choose from "
                         f"{', '.join(MODELS)}")
    if len(set(models)) != len(models):
        raise InputError(f"--models: a model is listed twice: {text}")
    return models


def plot_summary(out_dir, summary: dict) -> str:
    """Plot the average NEES per model through viz.figures.plot_nees when it exists; returns a note for
    summary.md (where the plot is, or why there is none)."""
    try:
        from rodo.viz.figures import plot_nees  # viz is the only package that imports matplotlib
    except ImportError as exc:
        return f"No NEES plot: viz.figures.plot_nees is not available ({exc})."
    curves = {m: e for m, e in summary["models"].items() if "nees_curve" in e}
    if not curves:
        return "No NEES plot: no successful run."
    import numpy as np

    nan = lambda v: np.array([np.nan if x is None else x for x in v], dtype=float)  # noqa: E731
    written = []
    for m, e in curves.items():  # one figure per model: the bounds depend on the state dimension
        c = e["nees_curve"]
        name = f"nees_{m}.png"
        try:
            plot_nees(os.path.join(out_dir, name), nan(c["t"]), nan(c["mean"]), (nan(c["lower"]), nan(c["upper"])),
                      f"{m} ({e['nees']['dim']} dof)")
        except Exception as exc:  # noqa: BLE001 - a plot is never worth losing the summary
            return f"No NEES plot: viz.figures.plot_nees failed ({type(exc).__name__}: {exc})."
        written.append(name)
    return "Average NEES over time with its bounds: " + ", ".join(written) + "."


def check_campaign_options(args) -> None:
    """InputError naming the option for a bad --runs, --jobs or --duration (montecarlo, table1)."""
    if args.runs < 1:
        raise InputError(f"--runs: must be >= 1, got {args.runs}")
    if args.jobs < 1:
        raise InputError(f"--jobs: must be >= 1, got {args.jobs}")
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration: must be > 0 seconds, got {args.duration}")


def main(args) -> int:
    check_campaign_options(args)
    from rodo import scenarios

    scenarios.get(args.scenario)  # unknown names fail here, listing the known ones
    models = parse_models(args.models)
    trials = make_trials(args.seed, args.runs, models)
    meta = {"scenario": args.scenario, "runs": args.runs, "models": list(models), "seed": args.seed,
            "duration": args.duration}
    trial_fn = ScenarioTrial(args.scenario, args.duration)
    total = remaining(trials, args.out) if args.resume else len(trials) * len(models)
    with Progress(total, f"montecarlo {args.scenario}") as bar, \
            make_executor(args.jobs, args.dask) as executor:
        report = run_campaign(trial_fn, trials, executor, args.out, resume=args.resume, progress=bar, meta=meta)
    summary = summarize_campaign(args.out)
    write_summary(args.out, summary, plot_summary(args.out, summary))
    errors = sum(r["status"] == "error" for r in report.rows)
    print(f"ran {report.ran} (trial, model) runs, skipped {report.skipped} already done, {errors} errors, "
          f"{report.wall_s:.1f} s")
    for m, e in summary["models"].items():
        k = e["metrics"]["kitti_t_err_pct"]
        nees = e.get("nees", {})
        print(f"{m:<14} ok {e['ok']:>4}/{e['runs']:<4} t_err median {k['median']} %  "
              f"NEES mean {nees.get('mean_over_scans')} bounds {nees.get('bounds_for_runs')}")
    print(f"wrote {args.out}/results.csv, summary.md, summary.json")
    return 0
