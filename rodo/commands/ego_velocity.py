"""`rodo ego-velocity SEQ_DIR --out FILE.csv [--seed 0]`: per-scan sensor velocity from Doppler alone.

Parse, call `estimator.ego_velocity.estimate_ego_velocity` per scan, write a CSV. Nothing else.

Checked by: tests/estimator/test_ego_velocity.py::test_cli_ego_velocity
"""

from __future__ import annotations

import argparse

import numpy as np

from rodo.estimator.ego_velocity import PLANAR_ELEVATION, estimate_ego_velocity
from rodo.estimator.errors import InputError, out_of_space
from rodo.progress import Progress

HEADER = "scan,t,vx,vy,vz,inliers"

HELP = """\
Estimate the instantaneous sensor velocity of every scan from the radial velocities alone (RANSAC over
minimal sets + least squares on the inliers; moving objects are rejected as outliers).

Output CSV columns: scan,t,vx,vy,vz,inliers
  vx, vy, vz  sensor velocity in the SENSOR frame (m/s; x boresight, y left, z up);
              vz = 0 when the scan is planar (every |elevation| < 1e-3 rad, or the sensor's elevation
              field of view is narrower than that): elevation then carries no information.
  inliers     number of detections consistent with the estimate (static world).
A scan whose fit fails (too few detections or no consensus) gets a row with vx, vy, vz = nan and inliers 0.
The result is deterministic for a given --seed (each scan uses its own stream derived from the seed).
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("ego-velocity", help="per-scan sensor velocity from Doppler alone",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("seq_dir", metavar="SEQ_DIR", help="sequence directory (radar.csv, sensor.toml)")
    p.add_argument("--out", required=True, metavar="FILE.csv", help="output CSV")
    p.add_argument("--seed", type=int, default=0, help="seed of the RANSAC sampling (default 0)")
    p.set_defaults(func=run)


def run(args) -> int:
    from rodo.sim.sequence import read_sequence

    if args.seed < 0:
        raise InputError(f"--seed: must be >= 0, got {args.seed}")
    from rodo.outputs import check_not_input, check_output_file, sequence_inputs, write_text_atomic

    out = check_not_input(check_output_file(args.out, "--out"), "--out", sequence_inputs(args.seq_dir))
    seq = read_sequence(args.seq_dir)
    sigma_vr = seq.sensor.noise.radial_velocity
    el_lo, el_hi = seq.sensor.elevation_fov
    sensor_planar = max(abs(el_lo), abs(el_hi)) < PLANAR_ELEVATION
    rows = [HEADER]
    with Progress(len(seq.scans), "ego-velocity", unit="scan") as bar:
        for scan in seq.scans:
            rng = np.random.default_rng(np.random.SeedSequence(args.seed, spawn_key=(scan.scan,)))
            est = estimate_ego_velocity(scan.azimuth, scan.elevation, scan.radial_velocity, rng,
                                        sigma_vr=sigma_vr, planar=True if sensor_planar else None)
            if est.ok:
                vx, vy, vz = (f"{v:.9g}" for v in est.v_sensor + 0.0)   # + 0.0: no '-0'
                n_in = int(est.inliers.sum())
            else:
                vx = vy = vz = "nan"
                n_in = 0
            rows.append(f"{scan.scan},{scan.t:.9f},{vx},{vy},{vz},{n_in}")
            bar.update()
    try:
        write_text_atomic(out, "\n".join(rows) + "\n")  # ASCII: numbers only
    except OSError as exc:
        if out_of_space(exc):  # the machine's: the CLI's one line and exit 1 (the atomic writer named the file)
            raise
        raise InputError(f"--out: cannot write {out} ({exc.strerror or exc})") from None
    return 0
