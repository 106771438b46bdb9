"""`rodo run SEQ_DIR --model MODEL --out DIR [--config FILE] [--rerun OUT.rrd]`: odometry on a sequence, or on a
rig of several radars (SEQ_DIR with rig.toml, docs/sequence_format.md: every radar in one estimator).

Writes DIR/estimate.txt (TUM), estimate.kitti.txt (the same poses, KITTI layout), states.npz and summary.json;
on a sequence with groundtruth.txt it ends with the KITTI drift and ATE that `rodo evaluate` reports for them.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.errors import InputError
from rodo.outputs import check_not_input, check_output_dir, check_output_file, sequence_inputs
from rodo.progress import Progress
from rodo.sim.kitti_poses import write_kitti_poses
from rodo.sim.rig import is_rig
from rodo.sim.sequence import GROUNDTRUTH_TXT, read_sequence, read_tum, write_tum
from rodo.sim.simulate import TRUTH_NPZ, load_truth
from rodo.validation.driver import run_sequence, scan_times, write_run


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the estimator on a sequence directory and write estimate.txt, "
                                   "states.npz, summary.json",
                       description="Run radar odometry on a sequence (docs/sequence_format.md). Writes "
                                   "DIR/estimate.txt (TUM, T_world_vehicle), DIR/estimate.kitti.txt (the same poses "
                                   "as KITTI 3x4 rows), DIR/states.npz and DIR/summary.json; with groundtruth.txt "
                                   "in SEQ_DIR it prints the KITTI drift and ATE (as `rodo evaluate`).")
    p.add_argument("sequence", metavar="SEQ_DIR", help="sequence directory (radar.csv, sensor.toml), or a rig of "
                                                       "several radars (rig.toml: all fused in one estimator)")
    p.add_argument("--model", choices=MODELS, default=None, metavar="MODEL",
                   help="motion prior / measurement model: ca-polar (the paper's method, default), cv-cartesian "
                        "(its baseline), ca-cartesian, cv-polar (the two other combinations)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--config", metavar="FILE", help="TOML file overriding the estimator defaults")
    p.add_argument("--rerun", metavar="OUT.rrd", help="also write a Rerun recording of the run")
    p.add_argument("--connect", nargs="?", const="", default=None, metavar="URL",
                   help="stream the run live to a running Rerun viewer (default rerun+http://127.0.0.1:9876/proxy; "
                        "a port or HOST:PORT also works)")
    p.add_argument("--serve", action="store_true",
                   help="stream the run live to a web viewer served by this process (stops with Ctrl-C)")
    p.set_defaults(func=main)


def load_config(args) -> OdometryConfig:
    if args.config:
        cfg = OdometryConfig.from_toml(args.config, model=args.model)  # --model fills in a file without one
        if args.model and cfg.model != args.model:  # its noise and learned terms belong to its own model
            raise InputError(f"--model {args.model}: {args.config} is a {cfg.model} config (its model key); drop "
                             f"--model to run it, or give a {args.model} config")
        return cfg
    return OdometryConfig.for_model(args.model or "ca-polar")


def wait_for_interrupt() -> None:
    """Keep the process (and its web viewer) alive until Ctrl-C."""
    import time

    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass


def input_warnings(seq, summary: dict) -> list[str]:
    """Degenerate input that runs but cannot give odometry: said on stderr, the run still writes its output."""
    ranges = np.concatenate([sc.range for sc in seq.scans]) if seq.scans else np.zeros(0)
    out = []
    if ranges.size == 0:
        out.append("radar.csv holds no detections: the estimate is the initial state carried by the motion prior")
    elif not np.any(ranges > 0):
        out.append(f"every detection in radar.csv has range 0 m ({ranges.size} detections): no geometry to "
                   "estimate motion from")
    if len(seq.scans) < 2:
        out.append(f"radar.csv has {len(seq.scans)} scan(s): odometry needs at least 2")
    elif ranges.size and not summary.get("median_associations", 0) > 0:
        out.append("the median scan associated no detection with the map: the estimate is mostly dead reckoning "
                   "(check radar.csv units and sensor.toml extrinsics, noise and field of view)")
    return out


def main(args) -> int:
    config = load_config(args)
    check_output_dir(args.out, create=False)
    if args.connect is not None and args.serve:
        raise InputError("--connect and --serve: give one of them")
    live_stream = args.connect is not None or args.serve
    if args.connect is not None:
        from rodo.viz.live import check_viewer, grpc_url

        check_viewer(grpc_url(args.connect))  # a bad address, or no viewer there, fails before the work
    if args.rerun:
        check_output_file(args.rerun, "--rerun", parents=True)  # before the run, not after the estimate is written
        check_not_input(args.rerun, "--rerun", sequence_inputs(args.sequence) + [Path(args.out) / name
                                                                                 for name in RUN_FILES])
    if is_rig(args.sequence):
        return _run_rig(args, config)
    seq = read_sequence(args.sequence)
    gt_path = Path(args.sequence) / GROUNDTRUTH_TXT
    no_accuracy = None if seq.groundtruth is None else accuracy_problem(seq.groundtruth, scan_times(seq), gt_path)
    truth_path = Path(args.sequence) / TRUTH_NPZ  # the recording's truth, read before the run
    truth = load_truth(truth_path) if args.rerun and truth_path.exists() else None
    check_output_dir(args.out)
    live = None
    if live_stream:
        from rodo.viz.live import LiveRun  # viz is the only package importing rerun

        live = LiveRun(seq, connect=args.connect, serve=args.serve)
        print(f"streaming live to {live.url}" if args.connect is not None else
              f"serving the web viewer (gRPC {live.url})")
    with Progress(len(scan_times(seq)), f"rodo run {config.model}", unit="scan") as bar:
        result = run_sequence(seq, config, progress=bar, record_detail=bool(args.rerun) or live_stream,
                              on_scan=live.on_scan if live is not None else None,
                              keep_estimates=bool(args.rerun))  # else per-scan arrays only (a long drive)
    _write(args.out, result)  # before the live stream closes: the files never wait for a viewer
    if live is not None and (problem := live.close()) is not None:
        print(f"rodo run: warning: {problem}", file=sys.stderr)
    if args.rerun:
        from rodo.viz.recording import record_run  # viz is the only package importing rerun

        details = [e.detail for e in result.estimates]
        record_run(args.rerun, seq, result, truth=truth, detail=details)
        print(f"wrote {args.rerun} (open it with: {rodo_command()} view {args.rerun})")
    s = result.summary()
    for text in input_warnings(seq, s):
        print(f"rodo run: warning: {text}", file=sys.stderr)
    _report(args.out, s)
    if seq.groundtruth is not None:
        print_accuracy(gt_path, Path(args.out) / "estimate.txt", no_accuracy)
    if args.serve:
        print("the web viewer keeps serving the run: Ctrl-C to stop")
        wait_for_interrupt()
    return 0


KITTI_POSES = "estimate.kitti.txt"
RUN_FILES = ("estimate.txt", KITTI_POSES, "states.npz", "summary.json")  # what --out receives


def _write(out, result) -> None:
    """estimate.txt, states.npz, summary.json and estimate.kitti.txt of a run."""
    write_run(out, result)
    write_kitti_poses(Path(out) / KITTI_POSES, result.trajectory().T_world_vehicle)


def _report(out, summary: dict, extra: dict | None = None) -> None:
    """The run's one-line summary (JSON) and what was written."""
    keys = ("model", "scans", "median_associations", "median_ms_per_scan", "p95_ms_per_scan")
    print(json.dumps({k: summary[k] for k in keys} | (extra or {})))
    print(f"wrote {out}/estimate.txt, {KITTI_POSES}, states.npz, summary.json")


def _run_rig(args, config: OdometryConfig) -> int:
    """`rodo run RIG_DIR`: every radar of the rig in one estimator (docs/sequence_format.md, Rigs)."""
    from rodo.sim.rig import merged_groundtruth, read_rig
    from rodo.validation.driver import run_rig

    for flag, given in (("--rerun", args.rerun), ("--connect", args.connect is not None), ("--serve", args.serve)):
        if given:
            raise InputError(f"{flag}: not available for a rig yet (run one radar: {args.sequence}/RADAR)")
    rig = read_rig(args.sequence)
    gt = merged_groundtruth(rig)
    gt_path = Path(args.sequence) / GROUNDTRUTH_TXT if rig.groundtruth is not None else Path(args.out) / GROUNDTRUTH_TXT
    gt_name = gt_path if rig.groundtruth is not None else f"the radars' groundtruth.txt merged ({gt_path})"
    no_accuracy = None if gt is None else accuracy_problem(gt, np.array([t for t, _, _ in rig.scans()]), gt_name)
    check_output_dir(args.out)
    if rig.groundtruth is None:  # the radars' ground truths merged are written to --out: not over one of them
        check_not_input(Path(args.out) / GROUNDTRUTH_TXT, "--out", sequence_inputs(args.sequence))
    with Progress(sum(len(s.scans) for s in rig.sequences), f"rodo run {config.model}, {len(rig.names)} radars",
                  unit="scan") as bar:
        result = run_rig(rig, config, progress=bar, keep_estimates=False)
    _write(args.out, result)
    s = result.summary()
    _report(args.out, s, {"radars": rig.names})
    if gt is not None:
        if rig.groundtruth is None:  # the radars' own ground truths merged: written beside the estimate
            write_tum(gt_path, gt)
        print_accuracy(gt_path, Path(args.out) / "estimate.txt", no_accuracy)
    return 0


def accuracy_problem(gt, times: np.ndarray, gt_name) -> str | None:
    """Why the KITTI drift and ATE against the ground truth `gt` (named gt_name) cannot be computed for an estimate
    at `times`, or None: `rodo evaluate` associates the two (`validation.association.associate`, at its
    defaults), and too few of gt's poses fall on a scan's time. Checked before the run, said after it.

    Checked by: tests/cli/test_command_defects_run.py
    """
    from rodo.validation.association import DEFAULT_TOLERANCE, associate

    try:
        associate(gt.t, times, DEFAULT_TOLERANCE)
        return None
    except InputError:
        matched = len(associate(gt.t, times, DEFAULT_TOLERANCE, min_matches=0, min_fraction=0.0)[0])
    return (f"{gt_name}: accuracy not computed: {matched} of its {len(gt.t)} poses fall on a scan's time (within "
            f"{DEFAULT_TOLERANCE:g} s); the KITTI drift and ATE need 2 or more, and half of the shorter "
            "trajectory's poses")


def print_accuracy(gt_path: Path, est_path: Path, problem: str | None) -> None:
    """The accuracy line, or (a ground truth that does not associate) a warning on stderr: the run's outputs
    are written and stay valid, the run succeeds."""
    if problem is None:
        try:
            print(accuracy_line(gt_path, est_path))
            return
        except InputError as exc:  # e.g. an estimate that left the finite numbers: said, not a lost run
            problem = f"{gt_path}: accuracy not computed: {exc}"
    print(f"rodo run: warning: {problem}", file=sys.stderr)


def accuracy_line(gt_path: Path, est_path: Path) -> str:
    """KITTI drift and ATE of the written estimate against the ground truth: `rodo evaluate`'s numbers for the
    same files at its defaults (validation.metrics.evaluate, formatted as its table)."""
    from rodo.commands.evaluate import number
    from rodo.validation.kitti import LENGTHS
    from rodo.validation.metrics import evaluate

    rep = evaluate(read_tum(gt_path), read_tum(est_path))
    if rep["kitti_segments"]:
        kitti = (f"KITTI t_err {number(rep['kitti_t_err_pct'])} %, r_err {number(rep['kitti_r_err_deg_per_m'])} "
                 f"deg/m ({rep['kitti_segments']} segments)")
    else:
        kitti = f"KITTI -: the path ({number(rep['path_length_m'], '.1f')} m) is shorter than {LENGTHS[0]:g} m"
    return (f"against {gt_path} ({rep['matched']} poses): {kitti}; ATE rmse {number(rep['ate_rmse_m'])} m "
            f"(all metrics: rodo evaluate --gt {gt_path} --est {est_path})")


def rodo_command(name: str = "rodo") -> str:
    """How to call the installed script `name` (rodo, or rerun-sdk's `rerun` viewer) from the user's shell:
    `name` when that is this installation's on PATH, else the path of the script next to this interpreter
    (e.g. .venv/bin/rodo after `make demo`, where .venv/bin is not on PATH)."""
    script = Path(sys.executable).parent / name
    found = shutil.which(name)
    if found and Path(found).resolve() == script.resolve():
        return name
    if not script.is_file():
        return f"{sys.executable} -m rodo" if name == "rodo" else name
    try:
        return str(script.relative_to(Path.cwd()))
    except ValueError:
        return str(script)
