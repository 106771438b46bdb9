"""Odometry speed and accuracy: CV/C and CA/P (the paper's Table I pair) against an open3d ICP baseline.

Speed on `city` (seed 0; quick 20 s, full 90 s): median and p95 ms per scan from `RunResult.wall_ms`, skipping
the first SKIP scans (numba compilation / cache loading), the median per stage (predict, associate, solve, map),
the median number of associations and of map points; the ICP baselines (`validation.icp_baseline.run_icp`) on
the same sequence. Accuracy on `city`, `hills` and `stop_and_go` (quick 20 s each; full 90, 60, 60 s): KITTI
translational / rotational error on the lengths of LENGTHS shorter than the driven path (devkit formula,
first frame every STEP scans), and the final z / roll / pitch drift (both trajectories relative to their first
pose). Ratios are against CV/C measured in the same run. BLAS (and open3d's pool) run on one thread for every
method. The machine is shared, so the load average before and after is part of the section.

Run: `python -m bench.odometry [--quick]`; `run(quick) -> str` returns the Markdown section.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

SEED = 0
SKIP = 5                       # first scans left out of the timing statistics (compilation)
LENGTHS = (50.0, 100.0, 200.0)  # KITTI segment lengths, those shorter than the path are used
STEP = 1                       # KITTI first-frame step (the devkit uses 10; our sequences are short)
ESTIMATORS = (("CV/C", "cv-cartesian"), ("CA/P", "ca-polar"))
ICP_VARIANTS = (("ICP point-to-plane", {}),
                ("ICP point-to-plane, Doppler-filtered", {"doppler_filter": True}),
                ("ICP point-to-point", {"method": "point_to_point"}))


def _durations(quick: bool) -> dict[str, float]:
    return {"city": 20.0, "hills": 20.0, "stop_and_go": 20.0} if quick else \
        {"city": 90.0, "hills": 60.0, "stop_and_go": 60.0}


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
              for key in ("predict", "associate", "solve", "map")}
    speed = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "stages": stages,
             "assoc": float(np.median([e.n_associated for e in est])),
             "map": float(np.median([len(e.detail.map_points) for e in est]))}
    return speed, res.trajectory()


def _run_icp(seq, kwargs: dict) -> tuple[dict, object]:
    from rodo.validation.icp_baseline import run_icp

    traj, ms = run_icp(seq, **kwargs)
    ms = ms[SKIP:]
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95))}, traj


def _table(header, rows) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return out


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if np.isfinite(a) and np.isfinite(b) and b > 0 else "-"


def _methods(icp_ok: bool):
    out = [(label, "est", model) for label, model in ESTIMATORS]
    if icp_ok:
        out += [(label, "icp", kw) for label, kw in ICP_VARIANTS]
    return out


def run(quick: bool = False) -> str:
    """The Markdown section (see the module docstring)."""
    from rodo import scenarios

    try:
        import open3d  # noqa: F401
        icp_ok, icp_note = True, ""
    except ImportError:  # pragma: no cover - open3d is a declared dependency
        icp_ok, icp_note = False, " open3d is not installed: no ICP baseline."
    load_before = _load()
    tic = time.perf_counter()
    durations = _durations(quick)
    speed, acc = {}, {}
    for name, duration in durations.items():
        seq, _ = scenarios.get(name).simulate(SEED, duration=duration)
        acc[name] = {}
        for label, kind, arg in _methods(icp_ok):
            sp, traj = _run_estimator(seq, arg) if kind == "est" else _run_icp(seq, arg)
            if name == "city":
                speed[label] = sp
            acc[name][label] = _accuracy(seq, traj)
    elapsed = time.perf_counter() - tic

    base = speed["CV/C"]["median"]
    lines = [f"## Odometry (`python -m bench.odometry{' --quick' if quick else ''}`)", "",
             f"`city`, seed {SEED}, {durations['city']:.0f} s ({acc['city']['CV/C']['path']:.0f} m), scans "
             f"after the first {SKIP}; all methods single-threaded (BLAS and open3d limited to 1 thread). "
             f"ICP: scan-to-map (last 10 scans, voxel 0.3 m), max correspondence 1 m, constant-velocity initial "
             f"guess, all detections unless Doppler-filtered.{icp_note} Machine load average (1/5/15 min) "
             f"before {load_before}, after {_load()} on 2 cores (shared: absolute times are inflated by the "
             f"load, ratios less so).", ""]
    rows = []
    for label, sp in speed.items():
        st = sp.get("stages")
        stage_cells = [f"{st[k]:.2f}" for k in ("predict", "associate", "solve", "map")] if st else ["-"] * 4
        rows.append([label, f"{sp['median']:.1f}", f"{sp['p95']:.1f}", _ratio(sp["median"], base), *stage_cells,
                     f"{sp['assoc']:.0f}" if "assoc" in sp else "-", f"{sp['map']:.0f}" if "map" in sp else "-"])
    lines += _table(["method", "median ms/scan", "p95 ms/scan", "time vs CV/C", "predict ms", "associate ms",
                     "solve ms", "map ms", "median associations", "median map points"], rows)

    lines += ["", f"Accuracy (seed {SEED}; KITTI devkit formula, first frame every {STEP} scan(s), on the "
              f"lengths listed; drift at the last pose, relative to the first). Ratios: KITTI error / CV/C's.", ""]
    rows = []
    for name, by_method in acc.items():
        b = by_method["CV/C"]
        for label, a in by_method.items():
            rows.append([f"{name} {durations[name]:.0f} s, {a['path']:.0f} m", label, f"{a['t_err']:.2f}",
                         _ratio(a["t_err"], b["t_err"]), f"{a['r_err']:.4f}", _ratio(a["r_err"], b["r_err"]),
                         f"{a['z']:+.2f}", f"{a['roll']:+.2f}", f"{a['pitch']:+.2f}",
                         ", ".join(f"{L:.0f}" for L in a["lengths"]) or "none fits"])
    lines += _table(["sequence", "method", "t_err %", "vs CV/C", "r_err deg/m", "vs CV/C", "final z m",
                     "final roll deg", "final pitch deg", "KITTI lengths m"], rows)
    lines += ["", "ICP point-to-plane leans on normals estimated from sparse radar points; where the radar sees "
              "mostly vertical surfaces (hills) z is barely constrained and it can diverge, and then its numbers "
              "change with round-off (different processes gave 96 % and 172 % on hills, 20 s): read such a row "
              "as 'diverged'. Point-to-point stays bounded there.", "", f"Total {elapsed:.0f} s."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.odometry", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 s sequences instead of 90 / 60 s")
    args = ap.parse_args(argv)
    sys.stdout.write(run(args.quick))
    return 0


if __name__ == "__main__":
    sys.exit(main())
