"""`rodo export ply|kitti-bin SEQ_DIR --out DIR`: a sequence's scans as point clouds for other tools.

Parse, call `sim.export`, print. Nothing else. Docs: docs/export.md.

Checked by: tests/sim/test_export.py
"""

from __future__ import annotations

import argparse
import sys

from rodo.estimator.errors import InputError

FORMATS = ("ply", "kitti-bin")

HELP = """\
Export the scans of a sequence directory as point clouds.

Formats:
  ply        DIR/scans/<scan>.ply, one per scan in the sensor frame (binary little-endian; properties x, y, z,
             radial_velocity, scan_time, scan, range, azimuth, elevation and the sequence's extra columns).
             With --run RUN_DIR (a `rodo run` output) also DIR/map.ply: all scans in the world frame placed by
             the estimated poses (estimate.txt), the aggregated map. The run must be of SEQ_DIR: a pose at
             every scan time and, from its states.npz, the same number of detections in every scan.
  kitti-bin  the KITTI odometry layout: DIR/sequences/00/velodyne/<k>.bin (float32 x, y, z, intensity),
             times.txt, calib.txt (Tr identity) and DIR/poses/00.txt from groundtruth.txt when it has a pose at
             every scan. kiss-icp reads it unchanged: kiss_icp_pipeline DIR/sequences/00/velodyne
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("export", help="export a sequence's scans as .ply or KITTI .bin point clouds",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("format", choices=FORMATS, metavar="FORMAT", help=" | ".join(FORMATS))
    p.add_argument("sequence", metavar="SEQ_DIR", help="sequence directory (radar.csv, sensor.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--run", default=None, metavar="RUN_DIR",
                   help="ply: a `rodo run` output directory (or its estimate.txt): also write map.ply")
    p.add_argument("--intensity", default=None, metavar="COLUMN",
                   help="kitti-bin: the column written as intensity: radial_velocity or an extra column "
                        "(default snr when present, else 0)")
    p.set_defaults(func=run)


def _estimate(run_dir: str):
    """(trajectory, estimate path, states.npz path or None) of --run: a `rodo run` directory, or its estimate.txt
    (then its directory's states.npz); another TUM file has no states.npz of its run."""
    from pathlib import Path

    from rodo.sim.sequence import read_tum

    path = Path(run_dir)
    if path.is_dir():
        path = path / "estimate.txt"
    if not path.is_file():
        raise InputError(f"--run: {path} not found (expected a `rodo run` output directory with estimate.txt)")
    states = path.parent / "states.npz" if path.name == "estimate.txt" else None
    return read_tum(path), str(path), states if states is not None and states.is_file() else None


def run(args) -> int:
    from rodo.sim.export import check_run_of_sequence, export_kitti, export_ply
    from rodo.sim.sequence import read_sequence

    for option, value, owner in (("--run", args.run, "ply"), ("--intensity", args.intensity, "kitti-bin")):
        if value is not None and args.format != owner:
            raise InputError(f"{option}: only for the {owner} format, not {args.format}")
    trajectory, where, states = _estimate(args.run) if args.run is not None else (None, "", None)
    seq = read_sequence(args.sequence)
    if states is not None:  # the run's detection counts: a run of another sequence on the same clock is refused
        check_run_of_sequence(seq, states, str(args.run), str(args.sequence))
    if args.format == "ply":
        done = export_ply(seq, args.out, trajectory=trajectory, where=where)
        print(f"wrote {done['scans']} scans ({done['points']} points) to {args.out}/scans/")
        if done["map"] is not None:
            print(f"wrote {done['map']} (all scans in the world frame, poses from {where})")
        if args.run is not None and states is None:
            print(f"rodo export: warning: {where} has no states.npz beside it: only its times were checked against "
                  f"{args.sequence} (a run of another sequence on the same scan times would pass)", file=sys.stderr)
        return 0
    done = export_kitti(seq, args.out, intensity=args.intensity)
    print(f"wrote {done['scans']} scans ({done['points']} points) to {args.out}/sequences/00/velodyne/ "
          f"(intensity: {done['intensity'] or 'zeros'})")
    if done["poses"] is not None:
        print(f"wrote {done['poses']} (ground truth, KITTI poses of the sensor)")
    elif seq.groundtruth is not None:
        print("no poses/00.txt: groundtruth.txt has no pose at every scan time")
    print(f"run kiss-icp on it: kiss_icp_pipeline {args.out}/sequences/00/velodyne")
    return 0
