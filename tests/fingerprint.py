"""Fingerprints of simulated sequences that survive round-off: frozen-output tests compare these, not the files'
own hashes, whose last bits depend on the BLAS kernel OpenBLAS picks for the CPU (its SkylakeX and Zen kernels
give highway's 10 s different bits in 7 of ~1e5 values, by up to 4e-15)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from rodo.sim.sequence import read_sequence
from rodo.sim.tum import read_tum


def _rounded(x, decimals: int) -> bytes:
    return (np.round(np.asarray(x, dtype=float), decimals) + 0.0).tobytes()  # + 0.0: -0.0 -> 0.0


def fingerprint(seq_dir, decimals: int = 6) -> dict[str, str]:
    """sha256 per file of a simulated sequence directory: radar.csv (scan times and detections) and
    groundtruth.txt (times and poses) with floats rounded to `decimals` (m, rad, m/s), truth.npz (every array;
    integers exact, floats rounded), sensor.toml as it is."""
    seq_dir = Path(seq_dir)
    scans = hashlib.sha256()
    for scan in read_sequence(seq_dir, use_cache=False).scans:
        scans.update(np.float64(scan.t).tobytes() + _rounded(scan.polar, decimals))
    gt = read_tum(seq_dir / "groundtruth.txt")
    poses = hashlib.sha256(_rounded(gt.t, decimals) + _rounded(gt.T_world_vehicle, decimals))
    truth, arrays = np.load(seq_dir / "truth.npz"), hashlib.sha256()
    for key in sorted(truth.files):
        x = truth[key]
        arrays.update(key.encode() + (_rounded(x, decimals) if x.dtype.kind == "f" else np.ascontiguousarray(x).tobytes()))
    return {"radar.csv": scans.hexdigest(), "groundtruth.txt": poses.hexdigest(), "truth.npz": arrays.hexdigest(),
            "sensor.toml": hashlib.sha256((seq_dir / "sensor.toml").read_bytes()).hexdigest()}
