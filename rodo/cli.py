"""`rodo` command line: parse, call, print. Each command lives in rodo/commands/<name>.py and is
listed explicitly in COMMANDS (no discovery by magic). Scenarios and sensor profiles of your own come from plugin
modules named explicitly too: `rodo --plugin MODULE` or RODO_PLUGINS (`rodo.validation.plugins`), imported before
the command runs."""

from __future__ import annotations

import argparse
import errno
import os
import sys

from rodo.estimator.errors import InputError, is_environment_error
from rodo.validation import plugins

from . import extras
from .commands import (calibrate, config, convert, demo, ego_velocity, evaluate, export, figures, montecarlo, prior,
                       realism, run, simulate, table1, verdict, view)
from .entry import INTERRUPTED

COMMANDS = [demo, simulate, run, evaluate, montecarlo, table1, verdict, convert, ego_velocity, prior, figures, view,
            calibrate, export, config, realism]  # modules with register(subparsers); see rodo/commands/


def build_parser(commands=None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rodo", description="Radar odometry on SE(3): a testbed.")
    parser.add_argument("--version", action="version", version=f"rodo {version()}")
    parser.add_argument("--plugin", metavar="MODULE", action="append", default=[],
                        help="import MODULE before the command, so the scenarios and sensor profiles it registers "
                             "are known to it (repeatable; also the comma-separated RODO_PLUGINS environment "
                             "variable; docs/simulator.md, Custom scenarios and sensor profiles)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS if commands is None else commands:
        module.register(sub)
    return parser


def version() -> str:
    """The installed distribution's version (importlib.metadata), the one pyproject.toml declares."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("rodo")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "unknown (not installed)"


def main(argv: list[str] | None = None, commands=None) -> int:
    """Entry point; `commands` restricts the parser to some command modules (tests use it)."""
    parser = build_parser(commands)
    args = parser.parse_args(argv)
    try:  # RODO_PLUGINS, then --plugin; their names stay in RODO_PLUGINS for the workers the command spawns
        plugins.load(args.plugin)
    except InputError as exc:
        print(f"rodo: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # a plugin's import interrupted
        print("rodo: interrupted", file=sys.stderr)
        return INTERRUPTED
    try:
        extras.check_command(args)  # a missing optional dependency fails before any work
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a reader gone early (`| head`) shows here, not in Python's own flush at exit
        return code
    except BrokenPipeError:  # stdout's reader went away: stop as a pipeline's writer does, without a traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # the exit's flush then has nowhere to fail
        return 141  # 128 + SIGPIPE
    except InputError as exc:
        print(f"rodo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:  # an optional dependency reached past check_command
        extra = extras.extra_for(exc.name)
        if extra is None:
            raise
        print(f"rodo {args.command}: error: {extras.message(extra, f'rodo {args.command}', [exc.name])}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rodo {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED
    except OSError as exc:  # the machine's, not the input's: a full disk, a read-only or forbidden output place
        if not is_environment_error(exc):
            raise
        print(f"rodo {args.command}: error: {environment_message(exc)}", file=sys.stderr)
        return 1


def environment_message(exc: OSError) -> str:
    """One line for an environment error (`estimator.errors.is_environment_error`): what failed, on which file when
    the error names one, and for a full disk, a quota or a file-size limit what to do (every output is written to a
    temporary file and renamed, so what a command finished is whole and nothing half-written is left)."""
    where = f" ({exc.filename})" if exc.filename else ""
    said = f"{exc.strerror or exc}{where}"
    again = "run it again (the files already written are whole; a campaign or a verdict continues with --resume)"
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"{said}: free some space and {again}"
    if exc.errno == errno.EFBIG:
        return f"{said}: a file larger than this place allows (ulimit -f, or the file system's limit); {again}"
    return said


if __name__ == "__main__":
    sys.exit(main())
