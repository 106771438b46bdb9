"""`rodo montecarlo SCENARIO --runs N --models ca-polar,cv-cartesian [--qc Q] [--fault NAME=VALUE] [--profile NAME]
[--jobs J] [--dask ADDRESS|local [--dashboard [ADDR]]] [--duration S] [--seed S] --out DIR [--resume]`:
a Monte Carlo campaign (validation/campaign.py, docs/evaluation.md)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from concurrent.futures import BrokenExecutor

from rodo.estimator.config import MODELS
from rodo.estimator.errors import InputError, is_environment_error
from rodo.progress import Progress
from rodo.validation.campaign_dir import campaign_lock
from rodo.validation.campaign import make_executor, make_trials, remaining, run_campaign, summarize_campaign, write_summary
from rodo.validation.gross_failures import GROSS_NEES_PER_DOF
from rodo.validation.trial import ScenarioTrial

from .simulate import parse_qc


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("montecarlo", help="Monte Carlo campaign: seeded trials of a scenario, several models",
                       description="Simulate SCENARIO with N seeds (one SeedSequence(seed).spawn(N)), run each "
                                   "model, evaluate against truth. Writes DIR/results.csv (a row per trial and "
                                   "model, persisted at once), DIR/trials/*.npz, DIR/summary.md and summary.json.")
    p.add_argument("scenario", metavar="SCENARIO", help="scenario name (list them with `rodo scenarios`)")
    p.add_argument("--runs", type=int, required=True, help="number of trials")
    p.add_argument("--models", default="ca-polar,cv-cartesian",
                   help="comma-separated models (%(default)s), or LABEL=CONFIG.toml to run a config under a label "
                        "(e.g. ca-learned=ca.toml from rodo calibrate)")
    p.add_argument("--qc", metavar="X,Y,Z,RX,RY,RZ", default=None,
                   help="the prior-consistent scenarios' Qc (prior_ca, prior_cv, prior_*_points), as in `rodo "
                        "simulate --qc`: every trial's motion drawn from the prior's SDE with it (saved in "
                        "campaign.json)")
    add_fault_option(p)
    add_profile_option(p)
    add_campaign_options(p)
    p.set_defaults(func=main)


def add_profile_option(p) -> None:
    """--profile NAME, shared by the campaign commands (montecarlo, table1)."""
    p.add_argument("--profile", metavar="NAME", default=None,
                   help="sensor profile of every trial (see `rodo profiles`; default: the scenario's, normally "
                        "'generic'; saved in campaign.json)")


def check_profile(name: str | None) -> str | None:
    """--profile checked before any work: InputError listing the known profiles for an unknown name."""
    if name is not None:
        from rodo.sim import profiles

        try:
            profiles.get(name)
        except InputError as exc:
            raise InputError(f"--profile: {exc}") from None
    return name


def option_meta(faults: tuple[str, ...], profile: str | None) -> dict:
    """The campaign.json entries of --fault and --profile, only those given: older campaign.json files (without
    them) still resume."""
    meta = {}
    if faults:
        meta["faults"] = list(faults)
    if profile is not None:
        meta["profile"] = profile
    return meta


def add_fault_option(p) -> None:
    """--fault NAME=VALUE (repeatable), shared by the campaign commands (montecarlo, table1)."""
    p.add_argument("--fault", metavar="NAME=VALUE", action="append", default=[],
                   help="a sensor fault in every trial, as in `rodo simulate --fault` (clutter, ghosts, dropped, "
                        "outage, outages, doppler_common; repeatable; saved in campaign.json). jitter is refused: the evaluation "
                        "matches estimates to the true scan times")


def add_campaign_options(p) -> None:
    """The options every campaign command shares (montecarlo, table1): executor, trial length, seed, output."""
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel workers (default: cores)")
    p.add_argument("--dask", metavar="ADDRESS", help="'local' (a LocalCluster of --jobs workers) or a scheduler "
                                                     "address tcp://host:port; default: a local process pool. "
                                                     "Dask moves data by pickle: connect only to schedulers you "
                                                     "trust")
    p.add_argument("--dashboard", nargs="?", const=DASHBOARD_DEFAULT, default=None, type=parse_dashboard,
                   metavar="ADDR", help="with --dask local: serve Dask's dashboard at ADDR (default "
                                        f"{DASHBOARD_DEFAULT}; ':8787' listens on every interface) and print its "
                                        "link; needs bokeh (pip install 'dask[diagnostics]')")
    p.add_argument("--duration", type=float, help="seconds of each trial (default: each scenario's own)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="campaign directory")
    p.add_argument("--resume", action="store_true", help="continue the campaign in DIR (skip finished rows)")


DASHBOARD_DEFAULT = "localhost:8787"


def parse_dashboard(text: str) -> str:
    """--dashboard ADDR: '[HOST]:PORT' with PORT 0-65535 (0: any free port); argparse reports the error."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or int(port) > 65535 or any(c.isspace() or c == "/" for c in host):
        raise argparse.ArgumentTypeError(f"expected [HOST]:PORT such as {DASHBOARD_DEFAULT} or :8787, got {text!r}")
    return text


def parse_models(text: str) -> tuple[str, ...]:
    """The campaign's model labels: model names, or LABEL=CONFIG.toml entries (`parse_configs`)."""
    models = tuple(m.strip().split("=", 1)[0].strip() for m in text.split(",") if m.strip())
    bad = [m for m, entry in zip(models, text.split(",")) if m not in MODELS and "=" not in entry]
    if not models or bad:
        raise InputError(f"--models: unknown model(s) {', '.join(bad) or '(none given)'}; choose from "
                         f"{', '.join(MODELS)}, or give LABEL=CONFIG.toml")
    if len(set(models)) != len(models):
        raise InputError(f"--models: a model is listed twice: {text}")
    return models


def parse_configs(text: str) -> tuple[tuple[str, str], ...]:
    """(label, TOML text) of every LABEL=CONFIG.toml entry of --models: that label runs the config's model
    with its settings (e.g. noise learned by `rodo calibrate`). The text is checked here and saved in
    campaign.json, so a resume with an edited config is refused."""
    from pathlib import Path

    from rodo.estimator.config import OdometryConfig

    out = []
    for entry in (e.strip() for e in text.split(",") if "=" in e):
        label, path = (x.strip() for x in entry.split("=", 1))
        if not label or not all(c.isalnum() or c in "-_." for c in label):
            raise InputError(f"--models: label {label!r} of {entry!r}: use letters, digits, '-', '_', '.'")
        cfg = OdometryConfig.from_toml(path)  # a clear error naming the file, now rather than in a worker
        if label in MODELS and cfg.model != label:  # a built-in model's name must not label another model's run
            raise InputError(f"--models: label {label!r} of {entry!r} is a model's name, but {path} runs model "
                             f"{cfg.model!r}; label it {cfg.model!r} or a name of its own (e.g. {label}-tuned)")
        out.append((label, Path(path).read_text(encoding="utf-8")))
    return tuple(out)


def _nan(v):
    import numpy as np

    return np.array([np.nan if x is None else x for x in v], dtype=float)


def plot_summary(out_dir, summary: dict) -> str:
    """Plot the average NEES per model (nees_MODEL.png), its odometry consistency measures
    (consistency_MODEL.png, each measure divided by its 6 dof, with the band of its N runs) through
    viz.figures.plot_nees, and its error growth per axis (growth_MODEL.png, viz.figures.plot_growth); returns a
    note for summary.md (where the plots are, or why there are none)."""
    from rodo import extras

    if not extras.is_installed("matplotlib"):
        return f"No NEES plot: matplotlib is not installed ({extras.install_hint('viz')} adds the plots)."
    from rodo.viz.figures import plot_nees  # viz is the only package that imports matplotlib

    curves = {m: e for m, e in summary["models"].items() if "nees_curve" in e}
    if not curves:
        return "No NEES plot: no successful run."
    written = []
    for m, e in curves.items():  # one figure per model: the bounds depend on the state dimension
        c = e["nees_curve"]
        name = f"nees_{m}.png"
        try:
            plot_nees(os.path.join(out_dir, name), _nan(c["t"]), _nan(c["mean"]), (_nan(c["lower"]), _nan(c["upper"])),
                      f"{m} ({e['nees']['dim']} dof)")
            written += [name] + plot_consistency(out_dir, m, e, plot_nees) + plot_error_growth(out_dir, m, e)
        except Exception as exc:  # noqa: BLE001 - a plot is never worth losing the summary
            if is_environment_error(exc):  # but a full disk is not a plot's failure: stale figures would stay
                raise
            return f"No NEES plot: viz.figures.plot_nees failed ({type(exc).__name__}: {exc})."
    return "Plots (average NEES over time with its bounds; the error growth per axis): " + ", ".join(written) + "."


def plot_consistency(out_dir, model: str, entry: dict, plot_nees) -> list[str]:
    """consistency_MODEL.png: every measure with runs, average NEES / dof per scan, the band of N runs / dof
    (the widest: the runs of the measure with the most); [] when no measure has a run."""
    import numpy as np

    cons, curves = entry.get("consistency", {}), entry.get("consistency_curves", {})
    names = [k for k, c in cons.items() if c["runs"] and k in curves]
    if not names:
        return []
    t = _nan(curves["t"])
    y = np.full((len(t), len(names)), np.nan)
    for j, k in enumerate(names):
        mean = _nan(curves[k]["mean"]) / cons[k]["dof"]
        y[:len(mean), j] = mean
    runs = max(cons[k]["runs"] for k in names)
    lo, hi = next(cons[k]["bounds_per_dof"] for k in names if cons[k]["runs"] == runs)
    name = f"consistency_{model}.png"
    plot_nees(os.path.join(out_dir, name), t, y, (lo, hi), [f"{k} ({cons[k]['runs']} runs)" for k in names],
              title=f"{model}: odometry consistency ({runs} runs, 6 dof each)", ylabel="average NEES / dof")
    return [name]


def plot_error_growth(out_dir, model: str, entry: dict) -> list[str]:
    """growth_MODEL.png: the runs' error growth per axis (`viz.figures.plot_growth`); [] without it."""
    from rodo.viz.figures import plot_growth

    g = entry.get("error_growth")
    if not g or not any(r["ratio"] for r in g["table"]):
        return []
    name = f"growth_{model}.png"
    plot_growth(os.path.join(out_dir, name), g["table"], title=f"{model}: how the error grows ({g['runs']} runs)")
    return [name]


def _num(v, digits: int = 2) -> str:
    """`v` rounded to `digits` decimals, or "-" where it is undefined (None, nan, inf)."""
    return "-" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def print_consistency(summary: dict) -> None:
    """One line per model and measure: mean NEES/dof over scans of the run average (and the 95 % interval of the
    mean over the runs' own means), bounds for N runs, the fraction of scans inside their bounds, the runs' spread
    against chi-square's and the fraction a per-scan factor common to all runs could bring inside at that spread
    ("-" where undefined), and the scans below and above the bounds (those one run puts above in brackets); then
    a model's runs with a gross failure and its means without them."""
    pct = lambda v: None if v is None else 100 * v  # noqa: E731
    for m, e in summary["models"].items():
        for k, c in e.get("consistency", {}).items():
            lo, hi = c["bounds_per_dof"]
            ci = c.get("mean_interval_per_dof")
            print(f"  {m:<14} {k:<14} NEES/dof {_num(c['mean_per_dof']):>8} "
                  f"{'' if ci is None else f'[{_num(ci[0])}, {_num(ci[1])}]':<14} bounds/dof for {c['runs']} runs "
                  f"[{_num(lo)}, {_num(hi)}]  scans within {_num(pct(c['fraction_scans_within']), 0)} %  "
                  f"spread {_num(c.get('spread_between_runs'))} "
                  f"(with a per-scan factor {_num(pct(c.get('fraction_within_per_scan_factor')), 1)} %)"
                  + (f"  below / above {c['scans_below']} / {c['scans_above']} ({c['scans_above_one_run']} one "
                     "run's)" if "scans_above" in c else ""))
        if e.get("gross_failure_runs") and e.get("consistency_without_gross"):
            means = ", ".join(f"{k} {_num(c['mean_per_dof'])}" for k, c in e["consistency_without_gross"].items()
                              if c["runs"])
            print(f"  {m:<14} gross failures (a scan above {GROSS_NEES_PER_DOF:g} per dof) in trials "
                  f"{', '.join(map(str, e['gross_failure_runs']))}; NEES/dof without them: {means}")


def check_campaign_options(args) -> None:
    """InputError naming the option for a bad --runs, --jobs or --duration (montecarlo, table1)."""
    if args.runs < 1:
        raise InputError(f"--runs: must be >= 1, got {args.runs}")
    if args.jobs < 1:
        raise InputError(f"--jobs: must be >= 1, got {args.jobs}")
    if args.dashboard is not None and args.dask != "local":
        raise InputError("--dashboard: only with --dask local (a remote scheduler serves its own dashboard: "
                         "`dask scheduler --dashboard-address :8787`)")
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration: must be > 0 seconds, got {args.duration}")
    from rodo.scenarios.registry import MAX_DURATION

    if args.duration is not None and not args.duration <= MAX_DURATION:  # NaN and inf too
        raise InputError(f"--duration: at most {MAX_DURATION:g} s per trial, got {args.duration}")


def worker_died(command: str, out: str, exc: BaseException) -> int:
    """Exit code 1 and one line on stderr for a campaign whose worker process died (killed, out of memory):
    what happened and that --resume runs the rest (finished trials are saved, unfinished ones not recorded)."""
    print(f"rodo {command}: error: a worker process died ({type(exc).__name__}: {exc}; killed, or out of "
          f"memory?); the trials finished before are saved in {out}: run the same command with --resume to run "
          "the rest", file=sys.stderr)
    return 1


def main(args) -> int:
    try:
        return run_montecarlo(args)
    except BrokenExecutor as exc:
        return worker_died("montecarlo", args.out, exc)


def check_faults(texts, command: str = "montecarlo") -> tuple[str, ...]:
    """The --fault strings, checked before any work (InputError naming --fault NAME); jitter refused."""
    from rodo.sim.faults import parse_faults

    if parse_faults(texts).jitter > 0:
        raise InputError(f"--fault jitter: not supported by {command} (the evaluation matches estimates to the "
                         "true scan times); simulate with `rodo simulate --fault jitter=...` and `rodo run` instead")
    return tuple(texts)


def run_montecarlo(args) -> int:
    check_campaign_options(args)
    from rodo import scenarios

    scenario = scenarios.get(args.scenario)  # unknown names fail here, listing the known ones
    params = parse_qc(args.qc, scenario)
    models = parse_models(args.models)
    configs = parse_configs(args.models)
    faults = check_faults(args.fault)
    profile = check_profile(args.profile)
    trials = make_trials(args.seed, args.runs, models)
    meta = {"scenario": args.scenario, "runs": args.runs, "models": list(models), "seed": args.seed,
            "duration": args.duration}
    if configs:
        meta["configs"] = dict(configs)
    meta.update(option_meta(faults, profile))
    meta.update(params)  # "qc" only when given: older campaign.json files still resume
    trial_fn = ScenarioTrial(args.scenario, args.duration, configs=configs, faults=faults, profile=profile,
                             qc=tuple(params["qc"]) if params else None)
    with campaign_lock(args.out):  # held over the run and the summary: a second writer is refused
        total = remaining(trials, args.out) if args.resume else len(trials) * len(models)
        with Progress(total, f"montecarlo {args.scenario}", unit="run") as bar, \
                make_executor(args.jobs, args.dask, dashboard=args.dashboard,
                              on_dashboard=lambda link: bar.print(f"Dask dashboard: {link}")) as executor:
            report = run_campaign(trial_fn, trials, executor, args.out, resume=args.resume, progress=bar,
                                  meta=meta)
        summary = summarize_campaign(args.out)
        write_summary(args.out, summary, plot_summary(args.out, summary))
    errors = sum(r["status"] == "error" for r in report.rows)
    print(f"ran {report.ran} (trial, model) runs, skipped {report.skipped} already done, {errors} errors, "
          f"{report.wall_s:.1f} s")
    for m, e in summary["models"].items():
        k = e["metrics"]["kitti_t_err_pct"]
        nees = e.get("nees", {})
        lo, hi = nees.get("bounds_for_runs", (None, None))
        print(f"{m:<14} ok {e['ok']:>4}/{e['runs']:<4} t_err median {_num(k['median'])} %  "
              f"NEES mean {_num(nees.get('mean_over_scans'))} bounds [{_num(lo)}, {_num(hi)}]")
    print("odometry consistency (average over runs per scan; 6 dof each, shown per dof):")
    print_consistency(summary)
    print(f"wrote {args.out}/results.csv, summary.md, summary.json")
    return 0
