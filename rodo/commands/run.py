"""`rodo run SEQ_DIR --model ca-polar|cv-cartesian --out OUT_DIR [--config FILE]`: odometry on a sequence."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.errors import InputError
from rodo.outputs import check_output_file
from rodo.progress import Progress
from rodo.sim.sequence import read_sequence
from rodo.sim.simulate import TRUTH_NPZ, load_truth
from rodo.validation.driver import run_sequence, scan_times, write_run


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the estimator on a sequence directory and write estimate.txt, "
                                   "states.npz, summary.json",
                       description="Run radar odometry on a sequence (docs/sequence_format.md). Writes "
                                   "OUT/estimate.txt (TUM, T_world_vehicle), OUT/states.npz and OUT/summary.json.")
    p.add_argument("sequence", metavar="SEQ_DIR", help="sequence directory (radar.csv, sensor.toml)")
    p.add_argument("--model", choices=MODELS, default=None,
                   help="ca-polar (the paper's method, default) or cv-cartesian (its baseline)")
    p.add_argument("--out", required=True, metavar="OUT_DIR", help="output directory (created)")
    p.add_argument("--config", metavar="FILE", help="TOML file overriding the estimator defaults")
    p.add_argument("--rerun", metavar="OUT.rrd", help="also write a Rerun recording of the run")
    p.set_defaults(func=main)


def load_config(args) -> OdometryConfig:
    if args.config:
        cfg = OdometryConfig.from_toml(args.config, model=args.model)
        if args.model and cfg.model != args.model:  # the command line wins over the file
            cfg = cfg.replace(model=args.model)
        return cfg
    return OdometryConfig.for_model(args.model or "ca-polar")


def check_out_dir(path, create: bool = True) -> Path:
    """Check (and create) the output directory before the work, so a bad --out fails early, not after."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a directory")
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"--out: cannot create {out} ({parent} is not a directory)")
            break
    if create:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--out: cannot create {out} ({exc.strerror})") from None
    return out


def input_warnings(seq, summary: dict) -> list[str]:
    """Degenerate input that runs but cannot give odometry: said on stderr, the run still writes its output."""
    import numpy as np

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
    check_out_dir(args.out, create=False)
    if args.rerun:
        check_output_file(args.rerun, "--rerun", parents=True)  # before the run, not after the estimate is written
    seq = read_sequence(args.sequence)
    check_out_dir(args.out)
    with Progress(len(scan_times(seq)), f"rodo run {config.model}") as bar:
        result = run_sequence(seq, config, progress=bar, record_detail=bool(args.rerun))
    write_run(args.out, result)
    if args.rerun:
        from rodo.viz.recording import record_run  # viz is the only package importing rerun

        truth_path = Path(args.sequence) / TRUTH_NPZ
        truth = load_truth(args.sequence) if truth_path.exists() else None
        details = [e.detail for e in result.estimates]
        record_run(args.rerun, seq, result, truth=truth, detail=details)
        print(f"wrote {args.rerun} (open it with: rodo view {args.rerun})")
    s = result.summary()
    for text in input_warnings(seq, s):
        print(f"rodo run: warning: {text}", file=sys.stderr)
    print(json.dumps({k: s[k] for k in ("model", "scans", "median_associations", "median_ms_per_scan",
                                        "p95_ms_per_scan")}))
    print(f"wrote {args.out}/estimate.txt, states.npz, summary.json")
    return 0
