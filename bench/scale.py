"""Scale: time per scan and peak memory against the length of the drive. `city` seed 0, ca-polar, simulated scan by
scan and run as the scans come (`validation.streamed`: the sequence is never whole in memory, the run keeps only
its per-scan arrays). Full: 5, 15 and 60 minutes of driving; quick: 1 and 3 minutes.

Each length runs in a fresh child process, so its peak RSS (VmHWM of /proc/self/status) is its own.

Run: `python -m bench.scale [--quick]`, or through `python -m bench --only scale`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

MODEL = "ca-polar"
SCENARIO = "city"


def _vm(key: str) -> float:
    """A /proc/self/status memory figure in MB (VmHWM: peak resident set, VmRSS: current)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024
    return float("nan")


class _Progress:
    """A line on stderr every 1000 scans: scans done, RSS now and at its peak (a long run says where it is)."""

    def __init__(self, total: int):
        self.total, self.done, self.tic = total, 0, time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.done += n
        if self.done % 1000 == 0 or self.done == self.total:
            print(f"scale: {self.done}/{self.total} scans, {time.perf_counter() - self.tic:.0f} s, RSS "
                  f"{_vm('VmRSS'):.0f} MB, peak {_vm('VmHWM'):.0f} MB", file=sys.stderr, flush=True)


def child(minutes: float) -> dict:
    """One length, in this process: stream the drive, run the estimator, report times and memory."""
    import numpy as np

    from rodo.estimator.config import OdometryConfig
    from rodo.validation.streamed import run_streamed, stream_scenario

    # load the compiled kernels first (numba's cache), so that neither time nor memory counts a first-run compile
    run_streamed(stream_scenario(SCENARIO, 0, 1.0), OdometryConfig.for_model(MODEL))
    rss_start = _vm("VmRSS")
    tic = time.perf_counter()
    sim = stream_scenario(SCENARIO, 0, 60.0 * minutes)
    setup_s = time.perf_counter() - tic
    rss_setup = _vm("VmRSS")
    tic = time.perf_counter()
    result = run_streamed(sim, OdometryConfig.for_model(MODEL), progress=_Progress(len(sim)))
    run_s = time.perf_counter() - tic
    ms = result.wall_ms
    T = result.columns["T_vehicle_world"]
    return {"minutes": minutes, "scans": result.n_scans, "median ms/scan": float(np.median(ms)),
            "mean ms/scan": float(np.mean(ms)), "p95 ms/scan": float(np.percentile(ms, 95)),
            "simulation ms/scan": 1e3 * (run_s - ms.sum() / 1e3) / result.n_scans, "setup s": setup_s,
            "wall s": setup_s + run_s, "peak RSS MB": _vm("VmHWM"), "RSS before MB": rss_start,
            "world + movers MB": rss_setup - rss_start, "kept per-scan arrays MB":
            sum(a.nbytes for a in result.columns.values()) / 2**20, "finite": bool(np.all(np.isfinite(T)))}


def _run_child(minutes: float) -> dict:
    out = subprocess.run([sys.executable, "-m", "bench.scale", "--child", str(minutes)], check=True,
                         stdout=subprocess.PIPE, text=True)  # the child's progress goes to stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool, lengths: tuple[float, ...] | None = None) -> str:
    lengths = lengths or ((1.0, 3.0) if quick else (5.0, 15.0, 60.0))
    load_before = os.getloadavg()
    rows = [_run_child(m) for m in lengths]
    load_after = os.getloadavg()
    keys = list(rows[0])
    lines = ["## Scale: time per scan and peak memory against drive length", "",
             f"`{SCENARIO}` seed 0, {MODEL}, streamed (`validation.streamed`: simulated scan by scan, run as the "
             "scans come, only the per-scan arrays kept); each length in a fresh process. "
             f"{'Quick mode: 1 and 3 minutes (full: 5, 15, 60). ' if quick and lengths == (1.0, 3.0) else ''}"
             "ms/scan is the estimator's time per scan; simulation ms/scan the rest of the loop (the streamed "
             "simulator); setup builds the world and the movers' states. Load average (1, 5, 15 min) "
             f"before: {', '.join(f'{x:.2f}' for x in load_before)}; after: "
             f"{', '.join(f'{x:.2f}' for x in load_after)} ({os.cpu_count()} cores).", "",
             "| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.scale", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 and 3 minutes instead of 5, 15 and 60")
    ap.add_argument("--lengths", metavar="MINUTES,...", help="other drive lengths in minutes, e.g. 60 or 5,15")
    ap.add_argument("--child", type=float, metavar="MINUTES", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        print(json.dumps(child(args.child)))
        return 0
    lengths = tuple(float(x) for x in args.lengths.split(",")) if args.lengths else None
    sys.stdout.write(run(args.quick, lengths))
    return 0


if __name__ == "__main__":
    sys.exit(main())
