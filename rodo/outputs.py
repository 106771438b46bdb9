"""Output files of the commands: checked before any work starts, written atomically with the usual permissions.

- `check_output_file(path, option)`: an InputError naming the option unless `path` can be written: it is not a
  directory, its directory exists, and a file can be created there (probed by creating and removing one, which
  also catches read-only file systems, where permission bits say nothing to root).
- `check_output_dir(path, option)`: the same for an output directory (created unless told not to); one that does
  not exist yet is probed in its nearest existing parent.
- `check_not_input(path, option, inputs)`: an InputError unless the output file `path` is none of the command's
  input files (`sequence_inputs(dir)`: a sequence's or a rig's files), so an output never overwrites what it is
  made from, or another output of the same command.
- `write_text_atomic(path, text)`: `rodo.sim.sequence.atomic_write_bytes` of the UTF-8 text: a uniquely named
  temporary file in the target directory (O_EXCL, no symlink followed), fsync, rename; the temporary file is
  removed on any failure; the file gets 0666 less the umask, as from open().

Checked by: tests/cli/test_output_paths.py
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes


def check_output_file(path, option: str, parents: bool = False) -> Path:
    """The output file `path`, or an InputError naming `option` and why it cannot be written.

    parents: the writer creates missing directories (rodo run --rerun inside --out), so the nearest existing
    one must be a writable directory; otherwise the file's directory must exist.
    """
    out = Path(path)
    if out.is_dir():
        raise InputError(f"{option}: {out} is a directory; give a file name")
    parent = out.parent
    if parents:
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise InputError(f"{option}: cannot write {out}: {parent} {what}")
    _probe(parent, option, out)
    return out


def _probe(directory: Path, option: str, target: Path) -> None:
    try:
        fd, probe = tempfile.mkstemp(dir=directory, prefix=f".{target.name}.", suffix=".probe")
    except OSError as exc:
        raise InputError(f"{option}: cannot write {target}: directory {directory} is not writable "
                         f"({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_dir(path, option: str = "--out", create: bool = True) -> Path:
    """The output directory `path` (created with its parents when `create`), or an InputError naming `option`: it
    is not a file, nor below one, and a file can be written in it (or, not yet created, in its nearest existing
    parent). Checked before the work, so a bad directory fails early, not after."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option}: {out} exists and is not a directory")
    parent = out
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{option}: cannot create {out} ({parent} is not a directory)")
    _probe(parent, option, out)
    if create and not out.exists():
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{option}: cannot create {out} ({exc.strerror or exc})") from None
    return out


def sequence_inputs(seq_dir) -> list[Path]:
    """The input files of a sequence directory, or of a rig (rig.toml and each radar's sequence files), a
    converter's own files (odom.csv, conversion.json) among them."""
    from rodo.sim.sequence import CONVERTER_FILES, GROUNDTRUTH_TXT, RADAR_CSV, RIG_TOML, SENSOR_TOML
    from rodo.sim.simulate import TRUTH_NPZ

    root = Path(seq_dir)
    names = (RADAR_CSV, SENSOR_TOML, GROUNDTRUTH_TXT, TRUTH_NPZ, RIG_TOML) + CONVERTER_FILES
    dirs = [root] + ([d for d in root.iterdir() if d.is_dir()] if (root / RIG_TOML).is_file() else [])
    return [d / name for d in dirs for name in names]


def check_layout_target(path, option: str, rig: bool) -> Path:
    """The directory a sequence (rig False) or a rig (True) is to be written to, or an InputError naming `option`
    if it holds the other layout (a rig's rig.toml, a sequence's radar.csv): every reader refuses a directory that
    is both."""
    from rodo.sim.sequence import RADAR_CSV, RIG_TOML

    out = Path(path)
    other = out / (RADAR_CSV if rig else RIG_TOML)
    if other.is_file():
        what = "a single sequence" if rig else "a rig"
        raise InputError(f"{option}: {out} holds {what} ({other.name}); write the "
                         f"{'rig' if rig else 'sequence'} to another directory")
    return out


def check_not_input(path, option: str, inputs) -> Path:
    """The output file `path`, or an InputError naming `option` if it is one of `inputs`, the command's input
    files and its other outputs (the same path after resolving links and relative paths)."""
    out = Path(path)
    target = out.resolve()
    for given in inputs:
        if Path(given).resolve() == target:
            same = "" if Path(given) == out else f" (the same file as {given})"
            raise InputError(f"{option}: {out}{same} is a file this command reads or writes itself, which it would "
                             "overwrite; give another file name")
    return out


def write_text_atomic(path, text: str) -> None:
    """Write text to `path` atomically (module docstring)."""
    atomic_write_bytes(path, text.encode("utf-8"))
