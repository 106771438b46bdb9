"""The optional dependencies (pyproject's extras) and the commands and flags that need them.

The core (numpy, scipy, numba, threadpoolctl) imports rodo and runs `rodo simulate`, `rodo run`, `rodo evaluate`,
... The extras add the rest; `[all]` is all of them, and `make demo` / `make test` install it:

- `viz`: rerun-sdk and matplotlib, for Rerun recordings (`--rerun`, `rodo demo`), live streams (`rodo run
  --connect / --serve`) and figures (`rodo figures`);
- `icp`: open3d and kiss-icp, for the baselines of `make bench` (`rodo.validation.icp_baseline.run_icp`,
  `rodo.validation.kiss_baseline.run_kiss`);
- `dask`: dask.distributed, for campaigns on a Dask cluster (`--dask`);
- `ros`: rosbags, for `rodo convert rosbag` (its converter names the package itself when it is missing).

`check_command` runs before a command does its work, so a missing extra fails at once with exit code 2 and a
message naming it, not after minutes of simulation; `extra_for` names the extra of a module that failed to
import anywhere else (rodo.cli turns such a ModuleNotFoundError into the same message).

Checked by: tests/cli/test_extras.py
"""

from __future__ import annotations

import importlib.util

from rodo.estimator.errors import InputError

EXTRAS = {  # extra -> the top-level modules it provides
    "viz": ("rerun", "matplotlib"),
    "icp": ("open3d", "kiss_icp"),
    "dask": ("dask", "distributed"),
    "ros": ("rosbags",),
}

COMMAND_EXTRAS = {"demo": "viz", "figures": "viz"}  # commands that always need an extra
FLAG_EXTRAS = {"rerun": "viz", "connect": "viz", "serve": "viz", "dask": "dask"}  # flags (argparse dest) that
# need one when given: any value but None and False (`--connect` alone gives "")


def is_installed(module: str) -> bool:
    """True when the top-level `module` can be imported (found on the path, not blocked)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a blocked or broken entry counts as absent
        return False


def missing(extra: str) -> list[str]:
    """The modules of `extra` that are not installed ([] when it is complete)."""
    return [m for m in EXTRAS[extra] if not is_installed(m)]


def install_hint(extra: str) -> str:
    return f"pip install 'rodo[{extra}]'"


def message(extra: str, what: str, modules) -> str:
    return (f"{what} needs the optional dependencies of rodo[{extra}] ({', '.join(modules)} not installed): "
            f"{install_hint(extra)}")


def require(extra: str, what: str) -> None:
    """InputError naming `what`, the extra and how to install it, when a module of `extra` is missing."""
    absent = missing(extra)
    if absent:
        raise InputError(message(extra, what, absent))


def check_command(args) -> None:
    """Require the extras that the parsed command line `args` needs (COMMAND_EXTRAS, FLAG_EXTRAS)."""
    command = getattr(args, "command", None)
    if command in COMMAND_EXTRAS:
        require(COMMAND_EXTRAS[command], f"rodo {command}")
    for dest, extra in FLAG_EXTRAS.items():
        if getattr(args, dest, None) not in (None, False):
            require(extra, f"--{dest}")


def extra_for(module: str | None) -> str | None:
    """The extra that provides `module` (a dotted name, e.g. rerun.blueprint), or None."""
    top = (module or "").split(".")[0]
    return next((extra for extra, mods in EXTRAS.items() if top in mods), None)
