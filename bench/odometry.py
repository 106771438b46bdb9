"""Odometry speed and accuracy: CV/C and CA/P (the paper's Table I pair) beside two fair baselines, in one run.

Methods: the estimator (CV/C, CA/P; `validation.driver.run_sequence`), open3d ICP at the best setting of a grid
(`validation.icp_baseline.run_icp`) and KISS-ICP with radar settings (`validation.kiss_baseline.run_kiss`). The
baselines are tuned on `city` seed 1 and scored on seed 0 (`bench.baselines`; the full run re-tunes, the quick
one uses the last full run's winners). On `city`, `highway`, `hills` and `stop_and_go` (seed 0; quick 20 s each;
full 90, 60, 60, 60 s), per method: median and p95 ms per scan (skipping the first SKIP scans: numba compilation /
cache loading), the estimator's median per stage (predict, associate, solve, map), KITTI translational /
rotational error on the lengths of LENGTHS shorter than the path (devkit formula, first frame every STEP scans),
the final z / roll / pitch drift (both trajectories relative to their first pose); ratios against CV/C measured in
the same run; and CA/P against CV/C run in turn on 20 s of each scenario, 5 times (`_alternating`: the ratio a
single run gives drifts with the machine's load). BLAS, open3d's pool and KISS-ICP run on one thread for every
method. The machine is shared, so the
load average before and after is part of the section. A missing open3d or kiss-icp leaves a note, not a traceback.

Run: `python -m bench.odometry [--quick]`; `run(quick) -> str` returns the Markdown section.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from bench import baselines

SEED = 0
SKIP = 5                       # first scans left out of the timing statistics (compilation)
LENGTHS = (50.0, 100.0, 200.0)  # KITTI segment lengths, those shorter than the path are used
STEP = 1                       # KITTI first-frame step (the devkit uses 10; our sequences are short)
ESTIMATORS = (("CV/C", "cv-cartesian"), ("CA/P", "ca-polar"))
ALTERNATE_S = 20.0             # CA/P against CV/C run in turn (`_alternating`): seconds of each scenario
ALTERNATE_REPEATS = 5          # and repeats (the quick run: 2)
STAGES = ("predict", "associate", "solve", "map")


def _durations(quick: bool) -> dict[str, float]:
    return {"city": 20.0, "highway": 20.0, "hills": 20.0, "stop_and_go": 20.0} if quick else \
        {"city": 90.0, "highway": 60.0, "hills": 60.0, "stop_and_go": 60.0}


def _load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def _accuracy(seq, traj) -> dict:
    """KITTI errors and final drift of `traj` (T_world_vehicle) against the sequence's ground truth."""
    from rodo.validation.kitti import kitti_errors, trajectory_distances
    from rodo.validation.metrics import associate, drift

    gt = seq.groundtruth
    ia, ib = associate(gt.t, traj.t)
    G = np.linalg.inv(gt.T_world_vehicle[ia[0]]) @ gt.T_world_vehicle[ia]
    E = traj.T_world_vehicle[ib]
    path = float(trajectory_distances(G)[-1])
    lengths = tuple(L for L in LENGTHS if L < path)
    k = kitti_errors(G, E, lengths=lengths, step=STEP) if lengths else None
    final = drift(G, E)["final"]
    return {"t_err": k.t_err_pct if k else float("nan"), "r_err": k.r_err_deg_per_m if k else float("nan"),
            "lengths": lengths, "path": path, "z": final["z"], "roll": final["roll"], "pitch": final["pitch"]}


def _run_estimator(seq, model: str) -> tuple[dict, object]:
    from rodo.estimator.config import OdometryConfig
    from rodo.validation.driver import run_sequence

    # record_detail only copies the map (<= 1500 x 3) and the scan per call: microseconds against milliseconds
    res = run_sequence(seq, OdometryConfig.for_model(model), record_detail=True)
    est = res.estimates[SKIP:]
    ms = res.wall_ms[SKIP:]
    stages = {key: 1e3 * float(np.median([e.timings.get(key, 0.0) for e in est]))
              for key in STAGES}
    speed = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "stages": stages,
             "assoc": float(np.median([e.n_associated for e in est])),
             "map": float(np.median([len(e.detail.map_points) for e in est]))}
    return speed, res.trajectory()


def _timing(ms: np.ndarray) -> dict:
    ms = ms[SKIP:]
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95))}


def _run_icp(seq, kwargs: dict) -> tuple[dict, object]:
    from rodo.validation.icp_baseline import run_icp

    traj, ms = run_icp(seq, **kwargs)
    return _timing(ms), traj


def _run_kiss(seq, voxel: float) -> tuple[dict, object]:
    from rodo.validation.kiss_baseline import run_kiss

    traj, ms = run_kiss(seq, voxel)
    return _timing(ms), traj


def _table(header, rows) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return out


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if np.isfinite(a) and np.isfinite(b) and b > 0 else "-"


def _tune(quick: bool, notes: dict) -> tuple[dict | None, float | None, list[str], list[dict]]:
    """The baselines' settings (tuned on the tuning sequence in a full run), the Markdown of the tuning and the
    open3d settings to check on the bench sequences (full run only)."""
    from rodo import scenarios

    icp_kw = baselines.ICP_TUNED if not notes["open3d"] else None
    kiss_vx = baselines.KISS_TUNED if not notes["kiss_icp"] else None
    where = f"`{baselines.TUNE_SCENARIO}` seed {baselines.TUNE_SEED}, {baselines.TUNE_DURATION:.0f} s"
    if quick:
        return icp_kw, kiss_vx, [f"Baseline settings: the winners of the last full run's tuning on {where} "
                                 "(bench/baselines.py ICP_TUNED, KISS_TUNED; the grid is in docs/benchmarks.md).",
                                 ""], []
    seq, _ = scenarios.get(baselines.TUNE_SCENARIO).simulate(baselines.TUNE_SEED, duration=baselines.TUNE_DURATION)
    lines = [f"### Baseline tuning on {where} (not a bench sequence)", "",
             "Score: KITTI t_err (ties: r_err, then time). Every setting of the grid, best first:", ""]
    alternatives = []
    if icp_kw is not None:
        icp_kw, rows = baselines.tune_icp(seq, _accuracy, SKIP)
        alternatives = baselines.icp_alternatives(rows)
        lines += _table(["open3d ICP setting", "t_err %", "r_err deg/m", "median ms/scan"],
                        [[baselines.describe_icp(r["setting"]), f"{r['t_err']:.2f}", f"{r['r_err']:.4f}",
                          f"{r['median_ms']:.1f}"] for r in rows]) + [""]
    if kiss_vx is not None:
        kiss_vx, rows = baselines.tune_kiss(seq, _accuracy, SKIP)
        lines += _table(["KISS-ICP voxel m", "t_err %", "r_err deg/m", "median ms/scan"],
                        [[f"{r['voxel']:g}", f"{r['t_err']:.2f}", f"{r['r_err']:.4f}", f"{r['median_ms']:.1f}"]
                         for r in rows]) + [""]
    return icp_kw, kiss_vx, lines, alternatives


def _methods(icp_kw, kiss_vx) -> list[tuple[str, str, object]]:
    out = [(label, "est", model) for label, model in ESTIMATORS]
    if icp_kw is not None:
        out.append(("open3d ICP", "icp", icp_kw))
    if kiss_vx is not None:
        out.append(("KISS-ICP", "kiss", kiss_vx))
    return out


def _run_method(seq, kind: str, arg) -> tuple[dict, object]:
    return {"est": _run_estimator, "icp": _run_icp, "kiss": _run_kiss}[kind](seq, arg)


def _sensitivity(seqs: dict, settings: list, label: str, describe, run, caption: str) -> list[str]:
    """t_err and median ms of `run(seq, setting)` for each setting on every bench sequence (full run only;
    reported, not used to choose)."""
    rows = []
    for setting in settings:
        row = [describe(setting)]
        for seq in seqs.values():
            sp, traj = run(seq, setting)
            row.append(f"{_accuracy(seq, traj)['t_err']:.2f} / {sp['median']:.1f}")
        rows.append(row)
    return ["", f"{caption} on the bench sequences (t_err % / median ms per scan; reported, not used to choose):",
            ""] + _table([label, *seqs], rows)


def _kiss_sensitivity(seqs: dict) -> list[str]:
    return _sensitivity(seqs, list(baselines.KISS_VOXELS), "voxel m", lambda vx: f"{vx:g}", _run_kiss,
                        "KISS-ICP voxel sensitivity")


def _icp_sensitivity(seqs: dict, settings: list[dict]) -> list[str]:
    return _sensitivity(seqs, settings, "setting", baselines.describe_icp, _run_icp,
                        "open3d ICP, the winner and alternatives")


def _alternating(names, repeats: int, duration: float = ALTERNATE_S) -> list[str]:
    """CA/P's time per scan against CV/C's where the machine's drift cannot decide it: on each scenario's first
    `duration` s (seed SEED) the two run in turn, `repeats` times each, and each repeat's ratio of the median
    ms/scan counts; the Markdown table of the median ratio and its range (one run per method, as the table above,
    moved by 0.84-1.27x between runs on a shared machine)."""
    from rodo import scenarios

    rows = []
    for name in names:
        seq, _ = scenarios.get(name).simulate(SEED, duration=duration)
        ms = {label: [] for label, _ in ESTIMATORS}
        for _ in range(repeats):
            for label, model in ESTIMATORS:
                ms[label].append(_run_estimator(seq, model)[0]["median"])
        ratio = np.array(ms["CA/P"]) / np.array(ms["CV/C"])
        rows.append([f"{name} {duration:.0f} s", str(repeats), f"{np.median(ms['CV/C']):.1f}",
                     f"{np.median(ms['CA/P']):.1f}", f"{np.median(ratio):.2f}x",
                     f"{ratio.min():.2f}-{ratio.max():.2f}x"])
    return ["", "CA/P against CV/C, run in turn (each repeat's ratio of median ms/scan):", ""] + \
        _table(["sequence", "repeats", "CV/C median ms", "CA/P median ms", "CA/P / CV/C median", "range"], rows)


def _result_rows(results: dict, durations: dict) -> list[list]:
    rows = []
    for name, by_method in results.items():
        base_sp, base_a = by_method["CV/C"]
        for label, (sp, a) in by_method.items():
            rows.append([f"{name} {durations[name]:.0f} s, {a['path']:.0f} m", label, f"{sp['median']:.1f}",
                         f"{sp['p95']:.1f}", _ratio(sp["median"], base_sp["median"]), f"{a['t_err']:.2f}",
                         _ratio(a["t_err"], base_a["t_err"]), f"{a['r_err']:.4f}", _ratio(a["r_err"], base_a["r_err"]),
                         f"{a['z']:+.2f}", f"{a['roll']:+.2f}", f"{a['pitch']:+.2f}",
                         ", ".join(f"{L:.0f}" for L in a["lengths"]) or "none fits"])
    return rows


def _stage_rows(results: dict) -> list[list]:
    rows = []
    for name, by_method in results.items():
        for label, (sp, _) in by_method.items():
            if "stages" in sp:
                rows.append([name, label, *(f"{sp['stages'][k]:.2f}" for k in STAGES), f"{sp['assoc']:.0f}",
                             f"{sp['map']:.0f}"])
    return rows


def run(quick: bool = False) -> str:
    """The Markdown section (see the module docstring)."""
    from rodo import scenarios

    notes = baselines.available()
    load_before = _load()
    tic = time.perf_counter()
    icp_kw, kiss_vx, tuning, alternatives = _tune(quick, notes)
    durations = _durations(quick)
    results, seqs = {}, {}
    for name, duration in durations.items():
        seqs[name], _ = scenarios.get(name).simulate(SEED, duration=duration)
        results[name] = {}
        for label, kind, arg in _methods(icp_kw, kiss_vx):
            sp, traj = _run_method(seqs[name], kind, arg)
            results[name][label] = (sp, _accuracy(seqs[name], traj))
    alternating = _alternating(durations, 2 if quick else ALTERNATE_REPEATS)
    sensitivity = _kiss_sensitivity(seqs) if kiss_vx is not None and not quick else []
    sensitivity += _icp_sensitivity(seqs, alternatives) if alternatives else []
    elapsed = time.perf_counter() - tic

    missing = " ".join(f"No {k} row: {v}." for k, v in notes.items() if v)
    lines = [f"## Odometry (`python -m bench.odometry{' --quick' if quick else ''}`)", "",
             f"Seed {SEED}, scans after the first {SKIP}; all methods single-threaded (BLAS, open3d and KISS-ICP "
             f"limited to 1 thread). open3d ICP: {baselines.describe_icp(icp_kw) if icp_kw else '-'}; constant-"
             f"velocity initial guess (the first from the Doppler ego velocity), 30 iterations. KISS-ICP {_kiss_version()}: voxel {kiss_vx} m, radar range "
             f"crop, deskew off, other settings the package's defaults (docs/benchmarks.md). {missing} Machine load "
             f"average (1/5/15 min) before {load_before}, after {_load()} on 2 cores (shared: absolute times are "
             f"inflated by the load, ratios less so).", "", *tuning,
             f"KITTI devkit formula, first frame every {STEP} scan(s), on the lengths listed; drift at the last "
             "pose, relative to the first. Ratios: against CV/C on the same sequence in this run.", ""]
    lines += _table(["sequence", "method", "median ms/scan", "p95 ms/scan", "time vs CV/C", "t_err %", "vs CV/C",
                     "r_err deg/m", "vs CV/C", "final z m", "final roll deg", "final pitch deg", "KITTI lengths m"],
                    _result_rows(results, durations))
    lines += ["", "Estimator stages (median ms per scan) and sizes:", ""]
    lines += _table(["sequence", "method", *(f"{k} ms" for k in STAGES), "median associations",
                     "median map points"], _stage_rows(results))
    lines += alternating + sensitivity + ["", f"Total {elapsed:.0f} s."]
    return "\n".join(lines) + "\n"


def _kiss_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("kiss-icp")
    except PackageNotFoundError:
        return "(not installed)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.odometry", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 s sequences instead of 90 / 60 s")
    args = ap.parse_args(argv)
    sys.stdout.write(run(args.quick))
    return 0


if __name__ == "__main__":
    sys.exit(main())
