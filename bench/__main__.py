"""`python -m bench [--quick] [--out bench/RESULTS.md] [--only NAME,...]`: run the benchmarks, write a table.

Each benchmark module exposes `run(quick: bool) -> str` (a markdown section). Figures are medians, with ratios
against a baseline measured in the same run. Listed explicitly (no discovery by magic).
"""

from __future__ import annotations

import argparse
import importlib
import platform
import sys
import time
from pathlib import Path

BENCHMARKS = ["priors", "sim", "odometry", "campaign", "scale"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer repeats and shorter sequences")
    ap.add_argument("--out", default="bench/RESULTS.md", help="markdown file to write")
    ap.add_argument("--only", default="", help="comma-separated subset of: " + ", ".join(BENCHMARKS))
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or BENCHMARKS
    unknown = sorted(set(names) - set(BENCHMARKS))
    if unknown:
        print(f"bench: unknown benchmark(s) {unknown}; known: {BENCHMARKS}", file=sys.stderr)
        return 2
    sections = []
    for name in names:
        try:
            module = importlib.import_module(f"bench.{name}")
        except ModuleNotFoundError:
            sections.append(f"## {name}\n\n(not available in this checkout)\n")
            continue
        print(f"bench: running {name} ...", file=sys.stderr, flush=True)
        tic = time.perf_counter()
        sections.append(module.run(args.quick).rstrip() + f"\n\n_{name}: {time.perf_counter() - tic:.0f} s_\n")
    import numpy

    header = (f"# rodo benchmark results\n\nMachine: {platform.machine()}, {platform.processor() or 'cpu'}, "
              f"Python {platform.python_version()}, numpy {numpy.__version__}; "
              f"{'quick' if args.quick else 'full'} run on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}."
              "\nAll times are medians; ratios are against a baseline measured in the same run.\n")
    out = Path(args.out)
    out.write_text(header + "\n" + "\n".join(sections))
    print(f"bench: wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
