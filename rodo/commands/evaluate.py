"""`rodo evaluate --gt groundtruth.txt --est estimate.txt [--states states.npz] [--truth truth.npz] [--json OUT]
[--lengths 100,200,...] [--step 10] [--tolerance 0.001]`: KITTI, ATE, RPE, drift, NEES and velocity errors of
an estimate against ground truth (docs/evaluation.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.sim.sequence import read_tum
from rodo.sim.simulate import read_npz
from rodo.validation.association import DEFAULT_TOLERANCE, associate
from rodo.outputs import check_not_input, check_output_file, write_text_atomic
from rodo.validation.metrics import evaluate, jsonable


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="evaluate an estimated trajectory against ground truth (KITTI, ATE, ...)",
                       description="Evaluate a TUM trajectory (t tx ty tz qx qy qz qw of T_world_vehicle, any "
                                   "tool) against ground truth; with --states and --truth also NEES and velocity "
                                   "errors. Prints a table; --json writes the full report.")
    p.add_argument("--gt", required=True, metavar="FILE", help="ground truth TUM file (groundtruth.txt)")
    p.add_argument("--est", required=True, metavar="FILE", help="estimated TUM file (estimate.txt)")
    p.add_argument("--states", metavar="FILE", help="states.npz of `rodo run` (NEES, NIS, velocity, runtime)")
    p.add_argument("--truth", metavar="FILE", help="truth.npz of the simulator (NEES, velocity errors)")
    p.add_argument("--json", metavar="OUT", help="write the report as JSON")
    p.add_argument("--lengths", default="100,200,300,400,500,600,700,800",
                   help="KITTI segment lengths in metres (%(default)s)")
    p.add_argument("--step", type=int, default=10, help="KITTI first-frame step (%(default)s)")
    p.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE,
                   help="time association tolerance in seconds (%(default)s)")
    p.set_defaults(func=main)


def parse_lengths(text: str) -> tuple[float, ...]:
    try:
        lengths = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError(f"--lengths: expected comma-separated metres like 100,200, got {text!r}") from None
    if not lengths or not all(np.isfinite(v) and v > 0 for v in lengths):
        raise InputError(f"--lengths: need positive finite lengths, got {text!r}")
    return lengths


NPZ_NAMES = {"--states": "the states.npz `rodo run` writes", "--truth": "the truth.npz `rodo simulate` writes"}


def load_npz(path: str, option: str, required: tuple[str, ...]) -> dict:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{option} {path}: file not found")
    arrays = read_npz(p, f"{option} {path}", NPZ_NAMES.get(option, "an .npz archive"))
    missing = [k for k in required if k not in arrays]
    if missing:
        raise InputError(f"{option} {path}: missing array(s) {', '.join(missing)} (has {', '.join(arrays)})")
    check_state_shapes(arrays, f"{option} {path}")
    return arrays


def check_state_shapes(arrays: dict, where: str) -> None:
    """InputError naming the array unless t is (N,) and T_vehicle_world (N, 4, 4), varpi (N, 6), P (N, d, d)
    with d >= 6, numeric, as states.npz and truth.npz hold them."""
    t = np.asarray(arrays["t"])
    n = len(t) if t.ndim == 1 else -1
    want = {"t": (n,), "T_vehicle_world": (n, 4, 4), "varpi": (n, 6)}
    P = arrays.get("P")
    if P is not None and np.ndim(P) == 3:
        want["P"] = (n, max(P.shape[1], 6), max(P.shape[1], 6))
    elif P is not None:
        want["P"] = (n, "d", "d")
    for key, shape in want.items():
        a = np.asarray(arrays[key])
        if a.shape != shape or not np.issubdtype(a.dtype, np.number):
            shown = "(" + ", ".join("N" if i == 0 else str(s) for i, s in enumerate(shape)) + ")"
            raise InputError(f"{where}: array {key} has shape {a.shape} and dtype {a.dtype}, expected {shown} "
                             f"numbers{' with N = len(t)' if key != 't' else ''}")


def number(v, spec: str = ".4g") -> str:
    """A number as the report's table prints it: "-" where it is undefined (None, NaN, infinite); `rodo run`'s
    accuracy line and `rodo demo`'s table print theirs the same way."""
    return "-" if v is None or not np.isfinite(v) else format(v, spec)


def _skipped(nees: dict) -> str:
    """What the NEES leaves out: scans whose NEES is not finite (a NaN or infinite covariance, no truth)."""
    k = nees["scans"] - nees["finite"]
    return f"; {k} skipped: NEES not finite (NaN or inf in P or the state)" if k else ""


def table(rep: dict) -> str:
    rows = [("matched poses", f"{rep['matched']} (gt {rep['gt_poses']}, est {rep['est_poses']})"),
            ("path length", f"{number(rep['path_length_m'], '.1f')} m"),
            ("KITTI t_err", f"{number(rep['kitti_t_err_pct'])} %  ({rep['kitti_segments']} segments)"),
            ("KITTI r_err", f"{number(rep['kitti_r_err_deg_per_m'])} deg/m"),
            ("ATE rmse / max", f"{number(rep['ate_rmse_m'])} / {number(rep['ate_max_m'])} m"),
            ("RPE per frame", f"{number(rep['rpe']['rpe_trans_rmse_m'])} m, {number(rep['rpe']['rpe_rot_rmse_deg'])} "
                              "deg (rmse)"),
            (f"RPE per {rep['rpe']['rpe_delta_m']:g} m", f"{number(rep['rpe']['rpe_trans_pct'])} %, "
                                                       f"{number(rep['rpe']['rpe_rot_deg_per_m'])} deg/m"),
            ("final drift x y z", " ".join(number(rep["drift"]["final"][a], ".3f") for a in "xyz") + " m"),
            ("final drift r p y", " ".join(number(rep["drift"]["final"][a], ".3f") for a in ("roll", "pitch", "yaw"))
             + " deg"),
            ("max |z| |roll| |pitch|", f"{number(rep['drift']['max_abs']['z'], '.3f')} m "
                                       f"{number(rep['drift']['max_abs']['roll'], '.3f')} "
                                       f"{number(rep['drift']['max_abs']['pitch'], '.3f')} deg")]
    for L, s in ((s["length_m"], s) for s in rep["segments"]):
        rows.append((f"  {L:g} m", f"{number(s['t_err_pct'])} %, {number(s['r_err_deg_per_m'])} deg/m ({s['count']})"))
    if "nees" in rep:
        n = rep["nees"]
        rows.append((f"NEES (d={n['dim']})", f"mean {number(n['mean'])}, per-scan bounds "
                                             f"[{number(n['per_scan_bounds'][0])}, {number(n['per_scan_bounds'][1])}], "
                                             f"{number(100 * n['fraction_within'], '.0f')} % of scans within "
                                             f"(over {n['finite']} of {n['scans']} scans{_skipped(n)})"))
    if "consistency" in rep:
        c = rep["consistency"]
        lo, hi = c["bounds_per_dof"]
        rows.append(("NEES / dof per measure", f"per-scan 95 % bounds [{number(lo)}, {number(hi)}]"))
        for name in ("pose", "relative_scan", "relative_span", "velocity", "acceleration", "pose_window"):
            m = c[name]
            if m["scans"]:
                rows.append((f"  {name}", f"mean {number(m['mean_per_dof'])}, {number(100 * m['within'], '.0f')} % of "
                                          f"scans within ({m['scans']} scans)"))
    if any(r["ratio"] for r in rep.get("error_growth", [])):
        rows.append(("error growth E[e^2/sigma^2]", "per axis x y z roll pitch yaw (1: right, < 1 cautious; "
                                                    "velocity, acceleration: vx vy vz and the rates)"))
        rows += [(f"  {r['label']}", " ".join(number(x, ".2f") for x in r["ratio"]) + f" ({r['count']})")
                 for r in rep["error_growth"] if r["ratio"]]
    if "nis" in rep:
        n = rep["nis"]
        rows.append(("NIS per pair (dof 4)", f"mean {number(n['mean'])} over {n['pairs']} pairs, bounds "
                                             f"[{number(n['bounds'][0])}, {number(n['bounds'][1])}]"))
    if "velocity" in rep:
        v = rep["velocity"]
        rows.append(("velocity rmse", f"{number(v['nu_rmse_mps'])} m/s, {number(v['omega_rmse_degps'])} deg/s"))
    if rep.get("ms_per_scan"):
        rows.append(("ms per scan", f"median {number(rep['ms_per_scan']['median'])}, p95 "
                                    f"{number(rep['ms_per_scan']['p95'])}"))
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def _check(fn, what: str) -> None:
    try:
        fn()
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None


def load_inputs(gt_path, est_path, states_path=None, truth_path=None, tolerance: float = DEFAULT_TOLERANCE):
    """(gt, est, states, truth) read from `rodo evaluate`'s files and checked as files: readable, the arrays
    there, times that associate. That the states are this estimate's and the truth this ground truth's,
    `evaluate` checks (validation/evaluation_inputs.py, naming the files: `report`). InputError names the option
    and file."""
    gt = read_tum(gt_path)
    est = read_tum(est_path)
    states = load_npz(states_path, "--states", ("t", "T_vehicle_world", "varpi", "P")) if states_path else None
    truth = load_npz(truth_path, "--truth", ("t", "T_vehicle_world", "varpi")) if truth_path else None
    if truth is not None and states is None:  # the truth serves the NEES alone, which needs the run's states
        raise InputError("--truth: give it with --states (the run's states.npz); alone it would be ignored")
    if truth is not None and "P" in truth:
        raise InputError(f"--truth {truth_path}: has a covariance P, as a run's states.npz does; give the "
                         "sequence's truth.npz")
    _check(lambda: associate(gt.t, est.t, tolerance), f"--gt {gt_path} and --est {est_path}")
    if states is not None and truth is not None:
        _check(lambda: associate(states["t"], truth["t"], tolerance),
               f"--states {states_path} and --truth {truth_path}")
    return gt, est, states, truth


def report(gt_path, est_path, states_path=None, truth_path=None, lengths=None, step: int = 10,
           tolerance: float = DEFAULT_TOLERANCE) -> dict:
    """`rodo evaluate`'s report of these files (default lengths: the KITTI devkit's, validation.kitti.LENGTHS):
    what `rodo demo` writes as evaluation.json, the same numbers by construction."""
    gt, est, states, truth = load_inputs(gt_path, est_path, states_path, truth_path, tolerance)
    labels = {"gt": f"--gt {gt_path}", "est": f"--est {est_path}", "states": f"--states {states_path}",
              "truth": f"--truth {truth_path}"}
    return evaluate(gt, est, lengths, step, states, truth, tolerance, labels=labels)


def main(args) -> int:
    lengths = parse_lengths(args.lengths)
    if args.step < 1:
        raise InputError(f"--step: must be >= 1, got {args.step}")
    if not (np.isfinite(args.tolerance) and args.tolerance >= 0):
        raise InputError(f"--tolerance: must be >= 0 seconds, got {args.tolerance}")
    if args.json:
        check_output_file(args.json, "--json")  # before any work
        check_not_input(args.json, "--json", [f for f in (args.gt, args.est, args.states, args.truth) if f])
    rep = report(args.gt, args.est, args.states, args.truth, lengths, args.step, args.tolerance)
    print(table(rep))
    if args.json:
        write_text_atomic(args.json, json.dumps(jsonable(rep), indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0
