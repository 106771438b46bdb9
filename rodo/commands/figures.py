"""`rodo figures --out DIR [--quick]`: write the paper's figures 1-4 and our Fig. 5 (out-of-plane drift) as PNG
files and print their paths.

Parse, call, print: the numbers are computed in `validation.experiments`, drawn in `viz.figures`
(docs/visualisation.md).
--quick uses fewer Monte Carlo samples, a 12 s sequence for Fig. 4 and 30 s of city for Fig. 5 (about a minute
in all); the full run simulates 60 s for Fig. 4 and 90 s for Fig. 5 (a few minutes on two cores).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("figures", help="write the paper's figures 1-4 and Fig. 5 (PNG)",
                              description="Reproduce the paper's figures from simulation: 1 the CA prior under "
                                          "yaw acceleration, 2 polar vs Cartesian measurement noise, 3 association "
                                          "with and without acceleration, 4 CV/C vs CA/P trajectories; and 5 (ours) "
                                          "their out-of-plane drift with and without the roll and pitch rate terms.")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    p.add_argument("--quick", action="store_true", help="fewer samples and short sequences (about a minute)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from rodo.outputs import check_output_dir
    from rodo.progress import Progress

    out = check_output_dir(args.out)
    from rodo.viz.figures import FIGURES  # after the output check: a bad --out fails first

    with Progress(len(FIGURES), "figures", unit="figure") as bar:
        for path in write_figures(out, quick=args.quick):
            bar.update()
            bar.print(str(path))
    return 0


def write_figures(out_dir, quick: bool = False):
    """Compute each figure's data (`validation.experiments.figure_data`) and draw it (`viz.figures`); yields the
    paths one by one as they are written."""
    from rodo.validation import experiments
    from rodo.viz.figures import FIGURES  # viz is the only package importing matplotlib

    for number, name, draw in FIGURES:
        yield draw(Path(out_dir) / name, experiments.figure_data(number, quick=quick))
