"""Output files of the commands: checked before any work starts, written atomically with the usual permissions.

- `check_output_file(path, option)`: an InputError naming the option unless `path` can be written: it is not a
  directory, its directory exists, and a file can be created there (probed by creating and removing one, which
  also catches read-only file systems, where permission bits say nothing to root).
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
    try:
        fd, probe = tempfile.mkstemp(dir=parent, prefix=f".{out.name}.", suffix=".probe")
    except OSError as exc:
        raise InputError(f"{option}: cannot write {out}: directory {parent} is not writable "
                         f"({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)
    return out


def write_text_atomic(path, text: str) -> None:
    """Write text to `path` atomically (module docstring)."""
    atomic_write_bytes(path, text.encode("utf-8"))
