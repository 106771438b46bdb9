"""radar.csv of a sequence: a fast numpy parser with thorough validation, a binary cache, a bit-exact writer.

Format and rules: docs/sequence_format.md. The numeric body is parsed in one `np.loadtxt` call; only when
that fails is the text walked line by line to name the first bad line. Values are then checked vectorised
and the error names the earliest offending line (1-based, header = line 1) and its column.

Checked by: tests/sim/test_sequence.py, tests/sim/test_sequence_fuzz.py
"""

from __future__ import annotations

import hashlib
import io
import os
import re
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.sensor_values import ANGLE_BOUNDS, angle_hint

from ._seqio import SequenceFormatError, atomic_write_bytes, decode_text
from .sequence_types import REQUIRED_COLUMNS, RadarScan

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_CACHE_VERSION = 2  # 2: the signature hashes the whole file, and a loaded cache is re-validated
_HASH_CHUNK = 1 << 20


def cache_path(csv_path) -> Path:
    """The binary cache next to a radar.csv: `.radar.csv.npz` (a hidden file in the same directory)."""
    csv_path = Path(csv_path)
    return csv_path.with_name(f".{csv_path.name}.npz")


# ----------------------------------------------------------------------------------------------- parsing


def _parse_header(path, header: str) -> list[str]:
    names = [name.strip() for name in header.split(",")]
    for k, name in enumerate(names):
        if not name:
            raise SequenceFormatError(path, f"empty column name (column {k + 1} of the header)", line=1)
        if not _NAME.match(name):
            first = "; the first line must be the header " + ",".join(REQUIRED_COLUMNS) if k == 0 else ""
            raise SequenceFormatError(path, f"invalid column name {name!r}{first}", line=1, field=name)
    seen = set()
    for name in names:
        if name in seen:
            raise SequenceFormatError(path, f"duplicate column '{name}'", line=1, field=name)
        seen.add(name)
    for name in REQUIRED_COLUMNS:
        if name not in seen:
            similar = [n for n in names if n.lower().startswith(name + "_") or n.lower() == name]
            hint = ""
            if similar:
                hint = (f" (found {similar[0]!r}: the column must be named '{name}' and hold SI units/radians;"
                        " degrees or other units are not accepted)")
            raise SequenceFormatError(path, f"missing column '{name}'{hint}; header must contain "
                                      + ",".join(REQUIRED_COLUMNS), line=1, field=name)
    return names


def _line_problem(path, names: list[str], line: str, number: int) -> SequenceFormatError | None:
    """The problem of one data line (field count, a field that is not a number), or None."""
    fields = line.split(",")
    n = len(names)
    if len(fields) != n:
        missing = names[len(fields)] if len(fields) < n else None
        return SequenceFormatError(path, f"expected {n} comma-separated fields ({','.join(names)}), "
                                   f"got {len(fields)}", line=number, field=missing)
    for name, text in zip(names, fields):
        value = text.strip()
        try:
            if "_" in value or not value or not value.isascii():
                raise ValueError
            if name == "scan" and not -(2**63) <= int(value) < 2**63:
                return SequenceFormatError(path, f"integer {value} out of range", line=number, field=name)
            float(value)
        except ValueError:
            want = "an integer" if name == "scan" else "a number"
            return SequenceFormatError(path, f"expected {want}, got {text!r}", line=number, field=name)
    return None


def _locate_bad_line(path, names: list[str], lines: list[str], exc: Exception) -> SequenceFormatError:
    """Name the first line numpy could not parse: the row its message names if that line is bad (it counts
    from the first data row and we allow no blank lines), else a walk over all lines."""
    match = re.search(r"row (\d+)", str(exc))  # 0-based for values, 1-based for a column-count change
    for row in (int(match.group(1)) - 1, int(match.group(1))) if match else ():
        if 0 <= row < len(lines):
            problem = _line_problem(path, names, lines[row], row + 2)
            if problem is not None and all(_line_problem(path, names, ln, 0) is None
                                           for ln in lines[max(row - 2, 0):row]):
                return problem
    for i, line in enumerate(lines):
        problem = _line_problem(path, names, line, i + 2)
        if problem is not None:
            return problem
    return SequenceFormatError(path, f"cannot parse the rows ({exc})")


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _check_values(path, cols: dict[str, np.ndarray]) -> None:
    """Vectorised value rules; raises for the earliest offending row (ties: the order below)."""
    problems = []  # (row, field, reason)

    def add(mask, name, reason):
        row = _first(mask)
        if row is not None:
            problems.append((row, name, reason(row)))

    for name in REQUIRED_COLUMNS[1:]:
        col = cols[name]
        add(~np.isfinite(col), name, lambda r, c=col: f"value {c[r].item()!r} is not finite")
    scan, t = cols["scan"], cols["t"]
    add(scan < 0, "scan", lambda r: f"scan index {scan[r]} must be >= 0")
    add(cols["range"] < 0, "range", lambda r: f"negative value {cols['range'][r].item()!r} (range must be >= 0)")
    for name, bound in ANGLE_BOUNDS.items():
        col = cols[name]

        def reason(r, c=col, b=bound, nm=name):
            v = c[r].item()
            return f"value {v!r} outside [-{b:.9g}, {b:.9g}]; {angle_hint(nm, v)}"

        add(np.abs(col) > bound, name, reason)
    if scan.size > 1:
        ds = np.diff(scan)
        add(np.r_[False, ds < 0], "scan",
            lambda r: f"scan index decreases ({scan[r - 1]} on the line before, {scan[r]} here)")
        add(np.r_[False, (ds == 0) & (t[1:] != t[:-1])], "t",
            lambda r: f"scan {scan[r]} has rows with different times ({t[r - 1].item()!r} and {t[r].item()!r}); "
                      "all rows of a scan share its time")
        add(np.r_[False, (ds > 0) & ~(t[1:] > t[:-1])], "t",
            lambda r: f"time does not increase from scan {scan[r - 1]} (t = {t[r - 1].item()!r}) to scan "
                      f"{scan[r]} (t = {t[r].item()!r}); scan times must strictly increase")
    if problems:
        row, name, reason = min(problems, key=lambda p: p[0])
        raise SequenceFormatError(path, reason, line=row + 2, field=name)


def parse_radar_csv(path, text: str) -> dict[str, np.ndarray]:
    """Parse and validate the text of a radar.csv (BOM/CRLF already handled by `decode_text`).

    Returns:
        {column name: (N,) contiguous array} in header order; 'scan' is int64, the rest float64.
    """
    header, _, body = text.partition("\n")
    names = _parse_header(path, header)
    body = body.rstrip()
    dtype = np.dtype([(name, np.int64 if name == "scan" else np.float64) for name in names])
    if not body:
        return {name: np.zeros(0, dtype[name]) for name in names}
    probe = "\n" + body + "\n"
    blank = re.search(r"\n[ \t]*\n", probe)
    if blank:
        line = probe[: blank.start() + 1].count("\n") + 1
        raise SequenceFormatError(path, "blank line inside the data", line=line)
    lines = body.split("\n")
    try:
        table = np.loadtxt(lines, delimiter=",", dtype=dtype, comments=None, ndmin=1)
    except Exception as exc:  # noqa: BLE001 - any parser failure becomes a located InputError
        raise _locate_bad_line(path, names, lines, exc) from None
    cols = {name: np.ascontiguousarray(table[name]) for name in names}
    del table
    _check_values(path, cols)
    return cols


def split_scans(cols: dict[str, np.ndarray]) -> list[RadarScan]:
    """Columns of a validated radar.csv -> one RadarScan per scan index (views into the columns)."""
    scan = cols["scan"]
    extras = [name for name in cols if name not in REQUIRED_COLUMNS]
    if scan.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(scan)) + 1
    starts, ends = np.r_[0, cuts], np.r_[cuts, scan.size]
    t, rng, az, el, vr = (cols[k] for k in REQUIRED_COLUMNS[1:])
    return [RadarScan(scan=int(scan[s]), t=float(t[s]), range=rng[s:e], azimuth=az[s:e], elevation=el[s:e],
                      radial_velocity=vr[s:e], extra={k: cols[k][s:e] for k in extras})
            for s, e in zip(starts.tolist(), ends.tolist())]


# ------------------------------------------------------------------------------------------------- cache


def _signature(size: int, mtime_ns: int, digest: str) -> str:
    return f"v{_CACHE_VERSION}:{size}:{mtime_ns}:{digest}"


def _file_signature(csv_path) -> str | None:
    """Size, mtime_ns and the SHA-256 of the whole content (hashing is ~100x faster than parsing)."""
    try:
        st = os.stat(csv_path)
        h = hashlib.sha256()
        with open(csv_path, "rb") as fh:
            for chunk in iter(lambda: fh.read(_HASH_CHUNK), b""):
                h.update(chunk)
    except OSError:
        return None
    return _signature(st.st_size, st.st_mtime_ns, h.hexdigest())


def _load_cache(csv_path) -> dict[str, np.ndarray] | None:
    cpath = cache_path(csv_path)
    if not cpath.is_file():
        return None
    signature = _file_signature(csv_path)
    try:
        with np.load(cpath, allow_pickle=False) as npz:
            if str(npz["signature"]) != signature:
                return None
            names = [str(n) for n in npz["names"]]
            cols = {name: npz[f"col{k}"] for k, name in enumerate(names)}
    except Exception:  # noqa: BLE001 - a corrupt or foreign cache is simply not used
        return None
    if any(name not in cols for name in REQUIRED_COLUMNS) or not _cache_columns_valid(csv_path, cols):
        return None
    return cols


def _cache_columns_valid(csv_path, cols: dict[str, np.ndarray]) -> bool:
    """A loaded cache obeys the reader's rules (dtypes, lengths, values): a cache that does not is not used
    (the CSV is parsed instead), so a damaged or forged cache never yields what the CSV could not."""
    n = len(cols["scan"])
    if any(c.ndim != 1 or len(c) != n for c in cols.values()) or cols["scan"].dtype != np.int64 or \
            any(c.dtype != np.float64 for k, c in cols.items() if k != "scan"):
        return False
    try:
        _check_values(csv_path, cols)
    except InputError:
        return False
    return True


def _store_cache(csv_path, signature: str, cols: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    arrays = {f"col{k}": col for k, col in enumerate(cols.values())}
    np.savez(buf, signature=np.array(signature), names=np.array(list(cols)), **arrays)
    try:
        atomic_write_bytes(cache_path(csv_path), buf.getvalue())
    except OSError:
        pass  # read-only location: the cache is an optimisation only


def read_radar_csv(path, *, use_cache: bool = True) -> list[RadarScan]:
    """Read and validate a radar.csv (see docs/sequence_format.md) into RadarScans, one per scan index.

    With `use_cache`, a valid `.radar.csv.npz` next to the file (same size, mtime_ns and SHA-256 of the whole
    file as when it was made, and values that pass the reader's checks) is loaded instead of parsing; otherwise the CSV is parsed and the cache
    (re)written atomically. Caching never changes the result.

    Raises:
        SequenceFormatError (InputError) naming file, line and column (see `parse_radar_csv` rules).

    Checked by: tests/sim/test_sequence.py::test_cache_is_used_and_invalidated
    """
    path = Path(path)
    if use_cache:
        cols = _load_cache(path)
        if cols is not None:
            return split_scans(cols)
    try:
        st = os.stat(path)
        data = path.read_bytes()
    except FileNotFoundError:
        raise SequenceFormatError(path, "file not found") from None
    except OSError as exc:
        raise SequenceFormatError(path, f"cannot read ({exc.strerror or exc})") from None
    cols = parse_radar_csv(path, decode_text(path, data))
    if use_cache and len(data) == st.st_size:
        _store_cache(path, _signature(st.st_size, st.st_mtime_ns, hashlib.sha256(data).hexdigest()), cols)
    return split_scans(cols)


# ------------------------------------------------------------------------------------------------ writing


def _check_scans(scans) -> list[str]:
    """Writer-side validation (so that nothing is written that the reader rejects); returns extra names."""
    if not isinstance(scans, (list, tuple)):
        raise InputError(f"seq.scans: expected a list of RadarScan, got {type(scans).__name__}")
    extras = None
    prev = None
    for i, sc in enumerate(scans):
        where = f"seq.scans[{i}]"
        if not isinstance(sc, RadarScan):
            raise InputError(f"{where}: expected a RadarScan, got {type(sc).__name__}")
        if sc.scan < 0:
            raise InputError(f"{where}.scan: scan index must be >= 0, got {sc.scan}")
        if prev is not None and not (sc.scan > prev.scan and sc.t > prev.t):
            raise InputError(f"{where}: scan index and time must strictly increase (scan {prev.scan} at "
                             f"t = {prev.t!r}, then scan {sc.scan} at t = {sc.t!r})")
        prev = sc
        if len(sc) == 0:
            continue
        for name in REQUIRED_COLUMNS[2:]:
            col = getattr(sc, name)
            if col.shape != (len(sc),):
                raise InputError(f"{where}.{name}: expected shape ({len(sc)},), got {col.shape}")
            if not np.all(np.isfinite(col)):
                raise InputError(f"{where}.{name}: contains NaN or infinity")
        if np.any(sc.range < 0):
            raise InputError(f"{where}.range: negative range")
        for name, bound in ANGLE_BOUNDS.items():
            if np.any(np.abs(getattr(sc, name)) > bound):
                raise InputError(f"{where}.{name}: values outside [-{bound:.9g}, {bound:.9g}] rad")
        names = list(sc.extra)
        if extras is None:
            for name in names:
                if not _NAME.match(name) or name in REQUIRED_COLUMNS:
                    raise InputError(f"{where}.extra: invalid or reserved column name {name!r}")
            extras = names
        elif names != extras:
            raise InputError(f"{where}.extra: columns {names} differ from the earlier scans' {extras}")
    return extras or []


def format_radar_csv(scans) -> bytes:
    """Bytes of a radar.csv for `scans` (empty scans write no rows); floats as repr, bit-exact on reading.

    Columns: scan,t,range,azimuth,elevation,radial_velocity then the extras in the scans' `extra` order.
    """
    extras = _check_scans(scans)
    full = [sc for sc in scans if len(sc)]
    header = ",".join(REQUIRED_COLUMNS + tuple(extras))
    if not full:
        return (header + "\n").encode("ascii")
    counts = [len(sc) for sc in full]
    text_cols = [
        [s for sc, n in zip(full, counts) for s in [str(sc.scan)] * n],
        [s for sc, n in zip(full, counts) for s in [repr(sc.t)] * n],
    ]
    for name in REQUIRED_COLUMNS[2:]:
        text_cols.append(list(map(repr, np.concatenate([getattr(sc, name) for sc in full]).tolist())))
    for name in extras:
        text_cols.append(list(map(repr, np.concatenate([sc.extra[name] for sc in full]).tolist())))
    body = "\n".join(map(",".join, zip(*text_cols)))
    return (header + "\n" + body + "\n").encode("ascii")


def write_radar_csv(path, scans) -> None:
    """Write a radar.csv atomically and drop a stale cache next to it."""
    data = format_radar_csv(scans)
    atomic_write_bytes(path, data)
    try:
        os.unlink(cache_path(path))
    except FileNotFoundError:
        pass
