"""`rodo` command line: parse, call, print. Each command lives in rodo/commands/<name>.py and is
listed explicitly in COMMANDS (no discovery by magic)."""

from __future__ import annotations

import argparse
import sys

from rodo.estimator.errors import InputError

from .commands import (calibrate, convert, demo, ego_velocity, evaluate, export, figures, montecarlo, prior, run,
                       simulate, table1, view)

COMMANDS = [demo, simulate, run, evaluate, montecarlo, table1, convert, ego_velocity, prior, figures, view,
            calibrate, export]  # modules with register(subparsers); see rodo/commands/


def build_parser(commands=None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rodo", description="Radar odometry on SE(3): a testbed.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS if commands is None else commands:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None, commands=None) -> int:
    """Entry point; `commands` restricts the parser to some command modules (tests use it)."""
    parser = build_parser(commands)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"rodo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rodo {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
