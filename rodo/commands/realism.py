"""`rodo profiles` (list the sensor profiles) and `rodo realism PROFILE [--realdata DIR] [--out DIR]
[--seeds 0,1] [--duration S]`: a profile's simulation against the real recording it was calibrated on, as a table
(statistic, sim, real, distance, within 20 %) and a figure. Parse, call `validation.realism`, print.

Checked by: tests/cli/test_realism_cli.py
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rodo.estimator.errors import InputError
from rodo.outputs import check_output_dir, write_text_atomic

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"

HELP = """\
Simulate a sensor profile (see `rodo profiles`) in the set-up of its real recording and compare ground-truth-free
statistics of both, each with a distance: points per scan, static Doppler residual spread and non-static
fraction as relative differences; range, azimuth, elevation and RCS (or SNR) distributions by the
Kolmogorov-Smirnov distance. Goal: every distance <= 0.2. The simulation's multipath ghost rate is reported (the
real data carry no ghost labels). Writes realism_PROFILE.md (table), .json (numbers) and .png (histograms,
needs matplotlib) into --out. Details: docs/realism.md.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser("profiles", help="list the sensor profiles",
                              description="List the registered sensor profiles: name, version, description.")
    p.set_defaults(func=run_profiles)
    p = subparsers.add_parser("realism", help="compare a sensor profile's simulation with real data",
                              description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("profile", metavar="PROFILE", help="sensor profile with real data (lrr30f, iwr6843aop, corner2d)")
    p.add_argument("--realdata", metavar="DIR", default=str(REALDATA),
                   help=f"the real recordings (default {REALDATA})")
    p.add_argument("--out", metavar="DIR", default=None, help="write the table, numbers and figure here")
    p.add_argument("--seeds", metavar="S,S,...", default="0,1,2", help="simulation seeds (default 0,1,2)")
    p.add_argument("--duration", type=float, default=None, help="seconds simulated per seed (default: the set-up's)")
    p.set_defaults(func=run_realism)


def run_profiles(args: argparse.Namespace) -> int:
    from rodo.sim import profiles

    for name in profiles.names():
        print(profiles.get(name).summary())
    return 0


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(","))
    except ValueError:
        seeds = ()
    if not seeds or min(seeds) < 0:
        raise InputError(f"--seeds: expected integers >= 0 separated by commas, got {text!r}")
    return seeds


def report_json(profile: str, report) -> str:
    """The report's numbers as strict JSON: a statistic that is not computable (NaN) or infinite is null."""
    from rodo.validation import realism
    from rodo.validation.metrics import jsonable

    rows = [dict(statistic=r.name, sim=r.sim, real=r.real, distance=r.distance, measure=r.measure, ok=r.ok)
            for r in report.rows]
    return json.dumps(jsonable({"profile": profile, "goal": realism.GOAL, "rows": rows, "notes": report.notes}),
                      indent=1, allow_nan=False) + "\n"


def run_realism(args: argparse.Namespace) -> int:
    from rodo import extras
    from rodo.validation import realism

    seeds = _seeds(args.seeds)
    if args.duration is not None and not (0 < args.duration <= 600):
        raise InputError(f"--duration: must be in (0, 600] s, got {args.duration}")
    out = None if args.out is None else check_output_dir(args.out, create=False)  # before the work
    report = realism.realism(args.profile, Path(args.realdata), seeds, args.duration)
    table = realism.format_table(report)
    print(table)
    for note in report.notes:
        print(f"note: {note}")
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        stem = out / f"realism_{args.profile}"
        write_text_atomic(stem.with_suffix(".md"), table + "\n\n" + "\n".join(f"- {n}" for n in report.notes) + "\n")
        write_text_atomic(stem.with_suffix(".json"), report_json(args.profile, report))
        if extras.is_installed("matplotlib"):
            from rodo.viz.realism import plot_realism  # viz is the only package importing matplotlib

            print(f"wrote {plot_realism(stem.with_suffix('.png'), report)}")
        else:
            print(f"no figure: matplotlib is not installed ({extras.install_hint('viz')} adds it)")
        print(f"wrote {stem.with_suffix('.md')} and {stem.with_suffix('.json')}")
    return 0
