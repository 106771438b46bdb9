"""Fair baselines for the odometry bench: open3d ICP tuned over a grid, and KISS-ICP with radar settings.

Protocol (so no baseline is tuned on the data it is scored on): every setting is scored on ONE tuning sequence,
`city` seed TUNE_SEED (TUNE_DURATION s), by its KITTI translational error (ties: rotational error, then time); the
best one is then run on the bench sequences, which use seed 0 (`bench.odometry.SEED`).

- open3d ICP (`validation.icp_baseline.run_icp`): ICP_GRID, scan-to-scan (window 1) and scan-to-map (windows 5,
  10, 20 scans) x voxel none / 0.3 / 0.5 m x max correspondence 0.5 / 1 / 2 m x point-to-point / point-to-plane
  (72 settings), then the winner with the Doppler filter; all with the Doppler initial velocity (`doppler_init`).
- KISS-ICP (`validation.kiss_baseline.run_kiss`): KISS_VOXELS, everything else as `radar_config` sets it.

The full bench (`python -m bench.odometry`) runs the tuning; the quick one uses ICP_TUNED and KISS_TUNED, the
winners of the last full run (recorded in docs/benchmarks.md with the grid), and says so.

Checked by: tests/validation/test_icp_baseline.py (the grid), tests/validation/test_kiss_baseline.py
"""

from __future__ import annotations

import itertools

import numpy as np

TUNE_SCENARIO = "city"
TUNE_SEED = 1
TUNE_DURATION = 20.0
WINDOWS = (1, 5, 10, 20)           # map_scans: 1 is scan-to-scan
VOXELS = (None, 0.3, 0.5)          # m, None: no filter
CORRESPONDENCES = (0.5, 1.0, 2.0)  # m
ICP_METHODS = ("point_to_point", "point_to_plane")
KISS_VOXELS = (0.5, 1.0, 1.5, 2.0)  # m

# Winners of the last full run's tuning (docs/benchmarks.md), used by the quick bench.
ICP_TUNED = {"method": "point_to_point", "map_scans": 20, "voxel": None, "max_correspondence": 0.5,
             "doppler_filter": False, "doppler_init": True}
KISS_TUNED = 1.5


def icp_grid() -> list[dict]:
    """The open3d settings of the grid, as run_icp keyword arguments (Doppler filter off; every setting starts
    from the first scan's Doppler ego velocity, as the estimator does)."""
    return [{"method": m, "map_scans": w, "voxel": v, "max_correspondence": c, "doppler_filter": False,
             "doppler_init": True}
            for m, w, v, c in itertools.product(ICP_METHODS, WINDOWS, VOXELS, CORRESPONDENCES)]


def describe_icp(kw: dict) -> str:
    """A short label: 'point-to-plane, scan-to-map 10 scans, voxel 0.3 m, max corr. 1 m'."""
    method = kw["method"].replace("_", "-")
    window = "scan-to-scan" if kw["map_scans"] == 1 else f"scan-to-map {kw['map_scans']} scans"
    voxel = "no voxel" if kw["voxel"] is None else f"voxel {kw['voxel']:g} m"
    doppler = ", Doppler-filtered" if kw.get("doppler_filter") else ""
    return f"{method}, {window}, {voxel}, max corr. {kw['max_correspondence']:g} m{doppler}"


def _score(row: dict) -> tuple:
    """Sort key: t_err, then r_err, then median time; NaN (a diverged or too short run) last."""
    def key(x):
        return x if np.isfinite(x) else np.inf
    return (key(row["t_err"]), key(row["r_err"]), key(row["median_ms"]))


def _scored(seq, traj, ms, accuracy, skip: int) -> dict:
    a = accuracy(seq, traj)
    return {"t_err": a["t_err"], "r_err": a["r_err"], "median_ms": float(np.median(ms[skip:]))}


def tune_icp(seq, accuracy, skip: int = 5, progress=None) -> tuple[dict, list[dict]]:
    """Score every ICP_GRID setting on `seq`, then the winner with the Doppler filter.

    Args:
        seq: the tuning sequence.
        accuracy: callable (seq, trajectory) -> dict with "t_err", "r_err" (bench.odometry._accuracy).
        skip: first scans left out of the timing.
        progress: optional callable(str) told each setting's result.

    Returns:
        (the best setting as run_icp keyword arguments; every row {"setting", "t_err", "r_err", "median_ms"},
        best first).
    """
    from rodo.validation.icp_baseline import run_icp

    rows = []
    for kw in icp_grid():
        traj, ms = run_icp(seq, **kw)
        rows.append({"setting": kw, **_scored(seq, traj, ms, accuracy, skip)})
        if progress is not None:
            progress(describe_icp(kw), rows[-1])
    best = min(rows, key=_score)["setting"]
    doppler = {**best, "doppler_filter": True}
    traj, ms = run_icp(seq, **doppler)
    rows.append({"setting": doppler, **_scored(seq, traj, ms, accuracy, skip)})
    rows.sort(key=_score)
    return rows[0]["setting"], rows


def icp_alternatives(rows: list[dict]) -> list[dict]:
    """Settings worth checking on the bench sequences beside the winner (reported, not used to choose): the
    winner with the Doppler filter, the best point-to-plane and the best scan-to-scan setting of the grid."""
    best = rows[0]["setting"]
    out = [best, {**best, "doppler_filter": True}]
    for pick in (lambda s: s["method"] == "point_to_plane", lambda s: s["map_scans"] == 1):
        out.append(next(r["setting"] for r in rows if pick(r["setting"]) and not r["setting"]["doppler_filter"]))
    unique = []
    for s in out:
        if s not in unique:
            unique.append(s)
    return unique


def tune_kiss(seq, accuracy, skip: int = 5) -> tuple[float, list[dict]]:
    """Score KISS-ICP at each of KISS_VOXELS on `seq`; (best voxel, rows {"voxel", "t_err", ...} best first)."""
    from rodo.validation.kiss_baseline import run_kiss

    rows = []
    for vx in KISS_VOXELS:
        traj, ms = run_kiss(seq, vx)
        rows.append({"voxel": vx, **_scored(seq, traj, ms, accuracy, skip)})
    rows.sort(key=_score)
    return rows[0]["voxel"], rows


def available() -> dict[str, str]:
    """{"open3d": note, "kiss_icp": note}: an empty note when the package imports, else why it is missing."""
    notes = {}
    for name, extra in (("open3d", "open3d"), ("kiss_icp", "kiss-icp")):
        try:
            __import__(name)
            notes[name] = ""
        except ImportError as exc:
            notes[name] = f"{extra} is not installed (pip install 'rodo[icp]'): {exc.__class__.__name__}"
    return notes
