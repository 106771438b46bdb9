"""`rodo demo --out DIR`: the main job end to end, in a few minutes on two cores.

1. the CA prior's Monte Carlo under pure yaw acceleration (the paper's Fig. 1), NEES against chi-square bounds;
2. a simulated `city` sequence (sim/), written in the documented format;
3. CA/P (the paper's method) and CV/C (its baseline) on it, evaluated against ground truth (KITTI drift, ATE,
   per-axis drift, NEES);
4. a Rerun recording of the CA/P run, the paper's figures and our Fig. 5 (out-of-plane drift).
It prints where everything is and how to open it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.outputs import write_text_atomic
from rodo.progress import Progress


def register(sub) -> None:
    p = sub.add_parser("demo", help="simulate, run CA/P and CV/C, evaluate, record, plot (the main job)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="results/demo", metavar="DIR", help="output directory (default results/demo)")
    p.add_argument("--scenario", default="city", help="scenario to simulate (default city; see rodo scenarios)")
    p.add_argument("--duration", type=float, default=45.0, help="simulated seconds (default 45)")
    p.add_argument("--seed", type=int, default=0, help="scenario seed (default 0)")
    p.add_argument("--no-figures", action="store_true", help="skip the paper figures")
    p.set_defaults(func=main)


def _step(msg: str) -> float:
    print(f"==> {msg}", flush=True)
    return time.perf_counter()


MODELS = ("ca-polar", "cv-cartesian")  # the paper's method and its baseline
ONE_DRIVE = ("One drive at the default noise: the two models' errors vary from drive to drive about as much as they "
             "differ, so one drive does not decide between them.\nThe comparison over 20 drives per scenario, each "
             "model at noise learned by `rodo calibrate`: docs/results.md (`rodo montecarlo`).")


def main(args) -> int:
    out = _check_args(args)
    report = {"prior_montecarlo": _prior_montecarlo(args, out)}
    seq_dir, seq, truth = _simulate(args, out)
    results = {model: _run_and_evaluate(model, seq, seq_dir, out) for model in MODELS}
    print("\n" + _table(results))
    print("\n" + ONE_DRIVE)
    report["runs"] = {m: {k: _jsonable(ev.get(k)) for k in ("kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m",
                                                             "drift")} for m, (_, ev) in results.items()}
    rrd = _record(out, seq, truth, results["ca-polar"][0])
    if not args.no_figures:
        _figures(out)
    write_text_atomic(out / "demo.json", json.dumps(_jsonable(report), indent=2) + "\n")
    from rodo.commands.run import rodo_command

    print(f"\nDone. Results in {out}/ (demo.json, per-model estimate.txt / states.npz / summary.json / "
          f"evaluation.json).\nOpen the recording with:  {rodo_command()} view {rrd}   (or: "
          f"{rodo_command('rerun')} {rrd})")
    return 0


def _check_args(args) -> Path:
    """Fail on a bad scenario, duration or output directory before any work; returns the output directory."""
    import numpy as np

    from rodo import scenarios
    from rodo.outputs import check_output_dir

    if args.scenario not in scenarios.names():
        scenarios.get(args.scenario)  # raises InputError listing the known names
    if not (np.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration: must be a positive number of seconds, got {args.duration}")
    return check_output_dir(args.out)


def _prior_montecarlo(args, out: Path) -> dict:
    """Step 1: the CA prior's Monte Carlo under pure yaw acceleration (`rodo prior`); returns its report."""
    from rodo.commands import prior

    tic = _step("prior Monte Carlo (paper Fig. 1): CA prior under pure yaw acceleration, 2000 samples")
    prior.run(argparse.Namespace(samples=2000, seed=args.seed, dt=1.0, substeps=200, magnus_order=3,
                                 noise="paper", out=out / "prior"))
    print(f"    {time.perf_counter() - tic:.1f} s")
    return json.loads((out / "prior" / "prior_montecarlo.json").read_text())


def _simulate(args, out: Path):
    """Step 2: simulate the scenario into out/<scenario>_seed<seed>; returns (its directory, sequence, truth)."""
    import numpy as np

    from rodo import scenarios
    from rodo.sim.sequence import read_sequence
    from rodo.sim.simulate import load_truth

    tic = _step(f"simulating {args.scenario} (seed {args.seed}, {args.duration:.0f} s)")
    seq_dir = out / f"{args.scenario}_seed{args.seed}"
    scenarios.simulate_to(args.scenario, args.seed, seq_dir, duration=args.duration)
    seq = read_sequence(seq_dir)
    truth = load_truth(seq_dir)
    print(f"    {len(seq.scans)} scans, median {np.median([len(s) for s in seq.scans]):.0f} detections per scan, "
          f"{time.perf_counter() - tic:.1f} s -> {seq_dir}")
    return seq_dir, seq, truth


def _run_and_evaluate(model: str, seq, seq_dir: Path, out: Path):
    """Step 3: run one model, write its run directory and evaluation.json: `rodo evaluate`'s report of the written
    files (`rodo evaluate --gt SEQ/groundtruth.txt --est MODEL/estimate.txt --states MODEL/states.npz --truth
    SEQ/truth.npz`, the KITTI devkit's lengths: no KITTI figure for a path under 100 m); returns (RunResult,
    evaluation)."""
    from rodo.commands.evaluate import report
    from rodo.sim.sequence import GROUNDTRUTH_TXT
    from rodo.sim.simulate import TRUTH_NPZ
    from rodo.validation.driver import run_sequence, scan_times, write_run

    tic = _step(f"running {model}")
    with Progress(len(scan_times(seq)), model, unit="scan") as bar:
        res = run_sequence(seq, OdometryConfig.for_model(model), progress=bar, record_detail=model == "ca-polar")
    run_dir = out / model
    write_run(run_dir, res)
    ev = report(seq_dir / GROUNDTRUTH_TXT, run_dir / "estimate.txt", run_dir / "states.npz", seq_dir / TRUTH_NPZ)
    write_text_atomic(run_dir / "evaluation.json", json.dumps(_jsonable(ev), indent=2) + "\n")
    print(f"    {time.perf_counter() - tic:.1f} s -> {run_dir}")
    return res, ev


def _record(out: Path, seq, truth: dict, res) -> Path:
    """Step 4a: the Rerun recording of the CA/P run (with its association detail); returns its path."""
    from rodo.viz.recording import record_run

    rrd = out / "ca-polar.rrd"
    tic = _step("writing the Rerun recording of the CA/P run")
    record_run(rrd, seq, res, truth=truth, detail=[e.detail for e in res.estimates])
    print(f"    {time.perf_counter() - tic:.1f} s -> {rrd}")
    return rrd


def _figures(out: Path) -> None:
    """Step 4b: the paper's figures and our Fig. 5, quick versions (`rodo figures --quick`)."""
    from rodo.commands.figures import write_figures

    tic = _step("paper figures (quick versions)")
    paths = list(write_figures(out / "figures", quick=True))
    print(f"    {time.perf_counter() - tic:.1f} s -> {', '.join(str(p) for p in paths)}")


def _table(results) -> str:
    """The runs' table: KITTI as `rodo evaluate` reports it ("-" where the path is shorter than 100 m, with a
    line saying so)."""
    from rodo.commands.evaluate import number
    from rodo.validation.kitti import LENGTHS

    rows = ["| model | KITTI t (%) | KITTI r (deg/m) | ATE (m) | drift z (m) | drift roll / pitch (deg) | ms/scan |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for model, (res, ev) in results.items():
        fin = (ev.get("drift") or {}).get("final", {})
        rows.append(f"| {model} | {number(ev['kitti_t_err_pct'], '.3f')} | "
                    f"{number(ev['kitti_r_err_deg_per_m'], '.4f')} | "
                    f"{number(ev['ate_rmse_m'], '.3f')} | {number(fin.get('z'), '.3f')} | "
                    f"{number(fin.get('roll'), '.3f')} / {number(fin.get('pitch'), '.3f')} | "
                    f"{res.summary()['median_ms_per_scan']:.1f} |")
    short = [ev["path_length_m"] for _, ev in results.values() if not ev["kitti_segments"]]
    if short:
        rows.append(f"\nKITTI -: the path ({short[0]:.1f} m) is shorter than the KITTI devkit's shortest segment "
                    f"({LENGTHS[0]:g} m); `rodo evaluate` reports no KITTI figure either")
    return "\n".join(rows)


def _jsonable(obj):
    from rodo.validation.metrics import jsonable

    return jsonable(obj)
