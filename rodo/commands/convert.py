"""`rodo convert FORMAT SOURCE --out SEQ_DIR [options]`: real radar recordings -> the sequence format.

Parse, call `sim.convert.<format>`, write, print the summary. Nothing else. Docs: docs/realdata.md.

Checked by: tests/sim/test_convert.py
"""

from __future__ import annotations

import argparse
import dataclasses

from rodo.estimator.errors import InputError
from rodo.estimator.sensor_values import RATE_RANGE
from rodo.outputs import check_layout_target, check_output_dir

FORMATS = ("radarscenes", "ti-mmwave", "vod", "rosbag", "raflow")

HELP = """\
Convert a real radar recording into a sequence directory (radar.csv, sensor.toml, groundtruth.txt when the
source has ground truth) plus conversion.json (what was kept, dropped and why, and the assumptions).

Formats:
  radarscenes  RadarScenes export folder (radar{N}_detections.csv.gz + radar{N}_timestamp_and_odom.csv).
               --radars 2 writes SEQ_DIR; --radars 2,3 writes one sequence per radar into SEQ_DIR/radarN
               and SEQ_DIR/rig.toml, which makes SEQ_DIR a rig (docs/sequence_format.md, Rigs). 2D radar:
               elevation 0 with sigma 10 deg. Extra columns label, rcs; odom.csv with the odometry speed and
               yaw rate; groundtruth.txt from the odometry pose.
  ti-mmwave    TI mmWave CSV export (radar_scans.csv, radar_detections.csv, calib yaml). 4D; vehicle frame =
               IMU body frame; no ground truth.
  vod          directory of View-of-Delft radar *.bin files (float32 N x 7: x,y,z,RCS,v_r,v_r_comp,time),
               one per scan in natural file-name order (2.bin before 10.bin), t = k / --rate.
  rosbag       ROS 1 .bag, ROS 2 bag directory (sqlite3 or mcap) or .mcap file (needs: pip install 'rodo[ros]');
               --topic names a sensor_msgs/PointCloud2 topic with x,y,z (--xyz) or range,azimuth,elevation
               (--polar) fields and a Doppler field (--doppler; negative = approaching, else --flip-doppler).
               Time: header stamps, or the bag's record time when the stamps are zero (--time). Vehicle frame
               = sensor frame, nominal noise, no ground truth.
  raflow       RaFlow demo_data folder (train/val/test radar_seqs-S_samples-K.json frame pairs, Hasco LRR30-F
               4D radar): the pairs chained into runs of consecutive frames, repeated raw scans dropped, one
               sequence per chain of >= --min-scans scans into SEQ_DIR/SPLIT_seqS_K (also when one chain
               qualifies); groundtruth.txt from the GNSS/INS poses (jitter ~0.3 m). Extra columns rcs, power.

Input that no sensor gives is refused (exit 2) naming the file, line and field, and nothing is written: scan
times whose median step is no scan rate (0.1-1000 Hz: milliseconds?), more than 1 % of the azimuths out of
[-pi, pi] (degrees?) or of the TI points beyond 2 km (millimetres?), RadarScenes odometry times more than 1 s
from the scan times, VoD files in another dtype or byte order, no detections at all.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("convert", help="convert real radar data into a sequence directory",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("format", choices=FORMATS, metavar="FORMAT", help=" | ".join(FORMATS))
    p.add_argument("source", metavar="SOURCE", help="source folder (rosbag: the bag)")
    p.add_argument("--out", required=True, metavar="SEQ_DIR", help="output sequence directory")
    p.add_argument("--radars", default=None, help="radarscenes: radar numbers 1-4, e.g. 2 or 2,3 (default 2)")
    p.add_argument("--t-max", type=float, default=None, help="radarscenes: keep scans with t <= T_MAX seconds")
    p.add_argument("--rate", type=float, default=None, help="vod: scan rate in Hz, 0.1-1000 (default 10)")
    p.add_argument("--min-scans", type=int, default=None, metavar="N",
                   help="raflow: write chains of at least N consecutive scans (default 5), each into "
                        "SEQ_DIR/SPLIT_seqS_K")
    p.add_argument("--sigma", default=None, metavar="R,AZ,EL,VR",
                   help="override the 1-sigma noise: range (m), azimuth (rad), elevation (rad), radial velocity (m/s)")
    _add_rosbag_options(p)
    p.set_defaults(func=run)


def _add_rosbag_options(p) -> None:
    p.add_argument("--topic", default=None, help="rosbag: the sensor_msgs/PointCloud2 topic (required)")
    p.add_argument("--xyz", default=None, metavar="X,Y,Z", help="rosbag: Cartesian field names (default x,y,z)")
    p.add_argument("--polar", default=None, metavar="R,AZ,EL",
                   help="rosbag: polar field names (m, rad) used instead of --xyz")
    p.add_argument("--doppler", default=None, metavar="FIELD",
                   help="rosbag: Doppler field (default: the first of velocity, doppler, radial_velocity, v_r, vr)")
    p.add_argument("--flip-doppler", action="store_true", default=None,
                   help="rosbag: negate the Doppler (sensors reporting positive when approaching)")
    p.add_argument("--time", default=None, choices=("auto", "header", "record"),
                   help="rosbag: scan time from the header stamps or the bag's record time (default auto: "
                        "header unless the stamps are zero)")


def _sigmas(text: str):
    from rodo.sim.sequence import NoiseSigmas

    try:
        values = [float(s) for s in text.split(",")]
    except ValueError:
        raise InputError(f"--sigma: expected 4 numbers R,AZ,EL,VR, got {text!r}") from None
    if len(values) != 4:
        raise InputError(f"--sigma: expected 4 numbers R,AZ,EL,VR, got {len(values)}")
    try:
        return NoiseSigmas(*values)
    except InputError as exc:
        raise InputError(f"--sigma: {exc}") from None


def _rosbag_options(args) -> list[tuple]:
    return [(option, getattr(args, option[2:].replace("-", "_")), "rosbag")
            for option in ("--topic", "--xyz", "--polar", "--doppler", "--flip-doppler", "--time")]


def _names(option: str, text: str | None, n: int):
    if text is None:
        return None
    names = [s.strip() for s in text.split(",")]
    if len(names) != n or not all(names):
        raise InputError(f"{option}: expected {n} comma-separated field names, got {text!r}")
    return tuple(names)


def _rosbag(args):
    from rodo.progress import Progress
    from rodo.sim.convert import rosbag

    if not args.topic:
        raise InputError("--topic: required for the rosbag format (a sensor_msgs/PointCloud2 topic)")
    if args.xyz is not None and args.polar is not None:
        raise InputError("--xyz and --polar: give one of them")
    xyz, polar = _names("--xyz", args.xyz, 3) or ("x", "y", "z"), _names("--polar", args.polar, 3)
    with Progress(None, f"reading {args.topic}", unit="msg") as bar:
        return rosbag.convert(args.source, args.topic, xyz=xyz, polar=polar, doppler=args.doppler,
                              flip_doppler=bool(args.flip_doppler), time=args.time or "auto", progress=bar)


def _conversions(args) -> list:
    """One function per output sequence that converts it (the slow part), run one by one under the bar."""
    from rodo.sim.convert import radarscenes, raflow, ti_mmwave, vod

    if args.format == "radarscenes":
        radars = radarscenes.parse_radars(args.radars if args.radars is not None else "2")
        return [lambda r=r: radarscenes.convert_radar(args.source, r, t_max=args.t_max) for r in radars]
    if args.format == "ti-mmwave":
        return [lambda: ti_mmwave.convert(args.source)]
    if args.format == "rosbag":
        return [lambda: _rosbag(args)]
    if args.format == "raflow":
        return [lambda: raflow.convert(args.source, raflow.MIN_SCANS if args.min_scans is None else args.min_scans)]
    return [lambda: vod.convert(args.source, rate_hz=10.0 if args.rate is None else args.rate)]


def run(args) -> int:
    import numpy as np

    from rodo.progress import Progress
    from rodo.sim.convert import write_conversion

    for option, value, owner in (("--radars", args.radars, "radarscenes"), ("--t-max", args.t_max, "radarscenes"),
                                 ("--rate", args.rate, "vod"), ("--min-scans", args.min_scans, "raflow"),
                                 *_rosbag_options(args)):
        if value is not None and args.format != owner:
            raise InputError(f"{option}: only for the {owner} format, not {args.format}")
    if args.t_max is not None and not (np.isfinite(args.t_max) and args.t_max > 0):
        raise InputError(f"--t-max: must be a positive finite number of seconds, got {args.t_max}")
    lo, hi = RATE_RANGE
    if args.rate is not None and not (np.isfinite(args.rate) and lo <= args.rate <= hi):
        raise InputError(f"--rate: must be > 0, a finite scan rate from {lo:g} to {hi:g} Hz, got {args.rate}")
    noise = _sigmas(args.sigma) if args.sigma is not None else None
    out = check_output_dir(args.out, create=False)  # before the conversion, not after it
    jobs = _conversions(args)
    with Progress(len(jobs), f"convert {args.format}", unit="sequence") as bar:
        convs = []
        for convert in jobs:  # all converted before anything is written: a failure leaves no partial output
            made = convert()
            convs += made if isinstance(made, list) else [made]
            bar.update()
    # one sequence into SEQ_DIR; several, or raflow's chains (however many), into SEQ_DIR/NAME
    targets = [out] if len(convs) == 1 and args.format != "raflow" else [out / conv.name for conv in convs]
    for target in targets:  # every target checked before anything is written: a file there fails here
        check_output_dir(target, "--out", create=False)
        check_layout_target(target, "--out", rig=False)
    if args.format == "radarscenes" and len(convs) > 1:
        check_layout_target(out, "--out", rig=True)
    for conv, target in zip(convs, targets):
        if noise is not None:
            conv.sequence.sensor = dataclasses.replace(conv.sequence.sensor, noise=noise)
            conv.report.notes.append(f"noise sigmas from --sigma {args.sigma}")
        write_conversion(target, conv)
        print(f"{conv.name} -> {target}")
        print(conv.report.summary())
    if args.format == "radarscenes" and len(convs) > 1:  # radars of one vehicle: a rig (`rodo run` fuses them)
        from rodo.sim.rig import RIG_TOML, write_rig_toml

        write_rig_toml(out, [c.name for c in convs])
        print(f"{out / RIG_TOML}: the {len(convs)} radars as one rig")
    return 0
