"""Shared plumbing of the sequence readers and writers: the error type, text decoding, atomic writes.

Format description: docs/sequence_format.md. Checked by: tests/sim/test_sequence.py,
tests/sim/test_sequence_fuzz.py, tests/sim/test_tum.py.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from rodo.estimator.errors import InputError, naming

UNIT_QUATERNION_TOL = 1e-6


class SequenceFormatError(InputError):
    """A file of a sequence is malformed.

    The message names the file, the 1-based line (as an editor shows it; a CSV header is line 1) when there is
    one, and the field (CSV column, TOML key) when there is one:
    ``/data/seq/radar.csv, line 12, field 'range': negative value -1.5 (must be >= 0)``.

    Attributes:
        path: the file, as given.
        line: 1-based line number or None.
        field: column or key name or None.
        reason: the message without the location prefix.
    """

    def __init__(self, path, reason: str, line: int | None = None, field: str | None = None):
        self.path = str(path)
        self.line = line
        self.field = field
        self.reason = reason
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field '{field}'"
        super().__init__(f"{where}: {reason}")


def decode_text(path, data: bytes) -> str:
    """UTF-8 bytes of a text file -> str with '\\n' line endings; BOM and CRLF tolerated.

    Raises:
        SequenceFormatError: the file is empty (or only a BOM/whitespace) or not UTF-8 (names the line).
    """
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise SequenceFormatError(path, f"not UTF-8 text (byte 0x{data[exc.start]:02x})", line=line) from None
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            line = text[: text.index("\r")].count("\n") + 1
            raise SequenceFormatError(path, "stray carriage return (use LF or CRLF line endings)", line=line)
    if not text.strip():
        raise SequenceFormatError(path, "the file is empty")
    if "\x00" in text:
        line = text[: text.index("\x00")].count("\n") + 1
        raise SequenceFormatError(path, "NUL byte in a text file", line=line)
    return text


def read_text(path) -> str:
    """Read and decode a text file of a sequence (see `decode_text`); a missing file is an InputError."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise SequenceFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise SequenceFormatError(path, "is a directory, expected a file") from None
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read ({exc.strerror})") from None
    return decode_text(path, data)


def create_temp(directory, name: str) -> tuple[int, str]:
    """A new, uniquely named file `.NAME.<random>.tmp` in `directory`, opened for writing: O_EXCL and
    O_NOFOLLOW (never an existing file or a symlink), mode 0666 less the umask (the permissions open() gives,
    not mkstemp's 0600). Returns (fd, path)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = os.path.join(directory, f".{name}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name for {name} in {directory}")


def temporary_beside(path) -> Path:
    """A uniquely named empty file beside `path` (`create_temp`), for a writer that opens files by name (Rerun's
    recordings); finish with `replace_synced`."""
    path = Path(path)
    fd, tmp = create_temp(path.parent, path.name)
    os.close(fd)
    return Path(tmp)


def replace_synced(tmp, path) -> None:
    """The written temporary file `tmp` on disk (fsync), then renamed to `path`; on failure `tmp` is removed."""
    try:
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise naming(exc, path, tmp)
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    """Write `data` to `path` atomically: a temporary file in the same directory, fsync, then os.replace.

    The temporary file has a unique name (`create_temp`: O_EXCL, no symlink followed) and is removed on any
    failure; the result has the permissions of a file created by open() (0666 less the umask, e.g. 0644).
    Checked by: tests/cli/test_output_paths.py::test_sequence_files_respect_the_umask
    """
    path = Path(path)
    fd, tmp = create_temp(path.parent, path.name)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):  # the file being written, not its temporary name (nor none, from fsync)
            raise naming(exc, path, tmp)
        raise


def float_text(x: float) -> str:
    """Shortest text that reads back to exactly the same float64 (Python's repr)."""
    return repr(float(x))
