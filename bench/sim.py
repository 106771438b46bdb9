"""Simulator speed: scans per second of the radar model per scenario (goal: >= 500 scans/s for `city`;
wall clock and per CPU second, as the machine may be shared), plus the time to build the scene, the first scan
(it loads the radar model's compiled kernels, sim/radar_kernels.py, from numba's cache: not in scans/s) and the
time to write the sequence directory.

Run: `python -m bench.sim [--scenarios city,highway] [--duration 20] [--seed 0]`. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def bench_scenario(name: str, seed: int, duration: float) -> dict:
    from rodo import scenarios
    from rodo.sim.simulate import simulate, write_simulation

    sc = scenarios.get(name)
    t0 = time.perf_counter()
    parts = sc.build(seed, duration)
    t_first = time.perf_counter()
    simulate(parts.world, parts.profile, parts.radar, np.random.default_rng(seed), 1e-3)  # one scan: kernels loaded
    t1, c1 = time.perf_counter(), time.process_time()
    seq, truth = simulate(parts.world, parts.profile, parts.radar, np.random.default_rng(seed), parts.duration)
    t2, c2 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        write_simulation(Path(tmp) / "seq", seq, truth)
    t3 = time.perf_counter()
    counts = np.diff(truth["scan_offsets"])
    return {"scenario": name, "scans": len(counts), "median detections": float(np.median(counts)),
            "build s": t_first - t0, "first scan s": t1 - t_first, "scans/s": len(counts) / (t2 - t1),
            "scans/cpu-s": len(counts) / max(c2 - c1, 1e-9), "write s": t3 - t2,
            "us/detection": 1e6 * (t2 - t1) / max(counts.sum(), 1)}


def table(names, seed: int, duration: float) -> str:
    rows = [bench_scenario(n, seed, duration) for n in names]
    keys = list(rows[0])
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        out.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys) + " |")
    return "\n".join(out) + "\n"


def run(quick: bool) -> str:
    """Markdown section for `python -m bench` (goal: >= 500 scans/s for city)."""
    duration = 10.0 if quick else 20.0
    names = ["city", "highway", "hills", "stop_and_go", "blockage", "yaw_accel"]
    return (f"## Simulator speed ({duration:.0f} s of each scenario, seed 0; goal >= 500 scans/s for city)\n\n"
            + table(names, 0, duration))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.sim", description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", default="city,highway,hills,stop_and_go,blockage,yaw_accel")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    sys.stdout.write(table(args.scenarios.split(","), args.seed, args.duration))
    return 0


if __name__ == "__main__":
    sys.exit(main())
