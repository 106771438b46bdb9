"""`rodo view OUT.rrd`: open a Rerun recording in the viewer, or say how to when no display is available.

The viewer is rerun-sdk's own `rerun` executable (installed next to the Python interpreter). It needs a
display: DISPLAY (X11) or WAYLAND_DISPLAY (or macOS/Windows). Without one the command prints the command to run
on a machine with a display and exits 0.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

from rodo.estimator.errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser("view", help="open a Rerun recording (.rrd) in the viewer",
                              description="Open a recording written by `rodo run --rerun OUT.rrd` in the Rerun "
                                          "viewer; without a display, print how to open it elsewhere.")
    p.add_argument("recording", metavar="OUT.rrd", help="the .rrd file")
    p.set_defaults(func=main)


def find_viewer() -> str | None:
    """Path of the `rerun` executable: next to this interpreter (the venv), else on PATH."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file() and os.access(here, os.X_OK):
        return str(here)
    return shutil.which("rerun")


RRD_MAGIC = b"RRF"


def has_display(environ=None) -> bool:
    """True where a window can be shown: macOS, Windows, or an X11/Wayland display in the environment."""
    env = os.environ if environ is None else environ
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


WRITE_ONE = "write one with `rodo run SEQ --out DIR --rerun OUT.rrd`"  # a placeholder, never the path given
LISTED = 5  # .rrd files of a directory named in its error


def _directory_error(path: Path) -> InputError:
    """The error for a directory given as the recording: its .rrd files named, if it has any."""
    try:
        rrds = sorted(p.name for p in path.glob("*.rrd") if p.is_file())
    except OSError:
        rrds = []
    if not rrds:
        return InputError(f"{path}: is a directory and holds no .rrd recording; give a .rrd file ({WRITE_ONE})")
    more = f" and {len(rrds) - LISTED} more" if len(rrds) > LISTED else ""
    return InputError(f"{path}: is a directory, not a recording; it holds {', '.join(rrds[:LISTED])}{more}: give "
                      f"one, e.g. `rodo view {path / rrds[0]}`")


def main(args: argparse.Namespace) -> int:
    path = Path(args.recording)
    if path.is_dir():
        raise _directory_error(path)
    if not path.is_file():
        raise InputError(f"{path}: recording not found ({WRITE_ONE})")
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not head.startswith(RRD_MAGIC):  # an .rrd file starts with "RRF" and a format version
        raise InputError(f"{path}: not a Rerun recording (it starts with {head!r}, a recording with {RRD_MAGIC!r}); "
                         f"{WRITE_ONE}")
    viewer = find_viewer()
    if viewer is not None and has_display():
        return subprocess.call([viewer, str(path)])
    reason = "no display (DISPLAY/WAYLAND_DISPLAY unset)" if viewer else "the `rerun` viewer is not installed"
    print(f"rodo view: cannot open a window here: {reason}.")
    print("On a machine with a display (the viewer comes with pip install 'rodo[viz]'), run:")
    print(f"    rerun {path.resolve()}")
    print("or headless, for a screenshot: xvfb-run -a -s \"-screen 0 1600x1000x24\" rerun "
          f"{path} --window-size 1200x800 --screenshot-to shot.png")
    return 0
