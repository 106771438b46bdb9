"""Shared plumbing of the real-data converters: CSV reading with located errors, the drop report, scan building,
and the plausibility rules every converter applies (a scan rate from the times, the share of rows a rule may
drop before the input is refused, at least one detection).

Docs: docs/realdata.md. Checked by: tests/sim/test_convert.py, tests/sim/test_convert_review55.py
"""

from __future__ import annotations

import gzip
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError, out_of_space
from rodo.estimator.sensor_values import RATE_RANGE
from rodo.sim.sequence import RadarScan, Sequence, atomic_write_bytes, remove_stale, write_sequence
from rodo.sim.simulate import TRUTH_NPZ

CONVERSION_JSON = "conversion.json"
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
# Hz: a median step between scans outside it comes from times in another unit; SensorConfig's own bound, checked
# here first to name the input file and field
SCAN_RATE_HZ = RATE_RANGE
TIME_UNITS = (("seconds", 1.0), ("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9))
# a rule that drops rows (an angle out of range, a point too far) drops at most this share of them; more is
# a systematic error (a unit, a convention) and refused: the rest would be as wrong
MAX_DROP_SHARE = 0.01


@dataclass
class ConversionReport:
    """What a converter kept, dropped (and why) and assumed; written as conversion.json next to the sequence."""

    format: str
    source: str
    kept_detections: int = 0
    kept_scans: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)

    def drop(self, reason: str, bad: np.ndarray) -> np.ndarray:
        """Count the True entries of `bad` under `reason`; return the keep mask ~bad."""
        bad = np.asarray(bad, dtype=bool)
        n = int(bad.sum())
        if n:
            self.dropped[reason] = self.dropped.get(reason, 0) + n
        return ~bad

    def to_dict(self) -> dict:
        return {"format": self.format, "source": self.source, "kept_detections": self.kept_detections,
                "kept_scans": self.kept_scans, "dropped": dict(self.dropped), "notes": list(self.notes),
                "info": self.info}

    def summary(self) -> str:
        """Human-readable lines for the CLI."""
        lines = [f"{self.format}: kept {self.kept_detections} detections in {self.kept_scans} scans"]
        if self.dropped:
            lines += [f"  dropped {n} {reason}" for reason, n in sorted(self.dropped.items())]
        else:
            lines.append("  dropped nothing")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


@dataclass
class Conversion:
    """One converted sequence: the sequence, its report, and extra files (name -> text) written beside it."""

    name: str
    sequence: Sequence
    report: ConversionReport
    extra_files: dict[str, str] = field(default_factory=dict)


def open_text(path: Path):
    """Open a (possibly .gz) text file; InputError naming the file when it is missing or unreadable."""
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a file")
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        if path.suffix == ".gz":
            return gzip.open(path, "rt", encoding="utf-8", newline="")
        return open(path, encoding="utf-8", newline="")
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None


def _locate(path: Path, names: list[str], lines) -> InputError:
    """Walk the data lines (slow path, only after a parse failure) to name the first bad line and field."""
    for number, line in enumerate(lines, start=2):
        line = line.rstrip("\r\n")
        if not line.strip():
            return InputError(f"{path}, line {number}: blank line")
        parts = line.split(",")
        if len(parts) != len(names):
            return InputError(f"{path}, line {number}: expected {len(names)} fields ({','.join(names)}), "
                              f"got {len(parts)}")
        for name, value in zip(names, parts):
            try:
                float(value)
            except ValueError:
                return InputError(f"{path}, line {number}, field '{name}': not a number: {value.strip()!r}")
    return InputError(f"{path}: cannot parse the data rows")


def read_csv(path, required: tuple[str, ...], int_columns: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Read a numeric CSV with a header line; return the required columns (float64, int64 for `int_columns`).

    NaN values are returned as they are (the converters drop and count them). Raises InputError naming the
    file, line and field for a missing file, a missing column, a wrong field count or a non-number.
    """
    path = Path(path)
    with open_text(path) as f:
        try:
            header = f.readline()
            body = f.read()
        except (OSError, UnicodeDecodeError, EOFError, gzip.BadGzipFile) as exc:
            raise InputError(f"{path}: cannot read ({exc})") from None
    names = [n.strip() for n in header.strip().lstrip("\ufeff").split(",")]
    if not header.strip():
        raise InputError(f"{path}: empty file (expected a header line with {','.join(required)})")
    missing = [c for c in required if c not in names]
    if missing:
        raise InputError(f"{path}, line 1: missing column(s) {', '.join(missing)} "
                         f"(found {','.join(names)}; required {','.join(required)})")
    lines = body.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        return {c: np.zeros(0, dtype=np.int64 if c in int_columns else float) for c in required}
    if any(not line.strip() for line in lines):  # loadtxt skips them: row k would not be line k + 2 (fuzzer)
        raise _locate(path, names, lines)
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=float, ndmin=2, comments=None)
    except ValueError:
        raise _locate(path, names, lines) from None
    if data.shape[1] != len(names):
        raise _locate(path, names, lines)
    out = {c: data[:, names.index(c)] for c in required}
    for c in int_columns:
        col = out[c]
        whole = np.isfinite(col) & (col == np.round(col))
        if not whole.all():
            k = int(np.flatnonzero(~whole)[0])
            value = lines[k].split(",")[names.index(c)].strip()
            raise InputError(f"{path}, line {k + 2}, field '{c}': must be an integer, got {value!r}")
        if np.any(np.abs(col) > 2**52):  # float64 lost digits (e.g. ns timestamps): parse again as int64
            try:
                col = np.loadtxt(lines, delimiter=",", dtype=np.int64, usecols=[names.index(c)], ndmin=1,
                                 comments=None)
            except (ValueError, OverflowError):
                raise InputError(f"{path}, field '{c}': integers expected (int64 range)") from None
        out[c] = col.astype(np.int64)
    return out


YAML_SPECIAL_FLOATS = {".inf": "inf", "-.inf": "-inf", ".nan": "nan"}


def read_flat_yaml(path) -> dict[str, tuple[float, int]]:
    """Parse a flat `key: number` YAML file (comments allowed) -> {key: (value, line)}; strings are skipped."""
    path = Path(path)
    with open_text(path) as f:
        text = f.read()
    out = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line or ":" not in line:
            continue
        key, value = (s.strip() for s in line.split(":", 1))
        value = YAML_SPECIAL_FLOATS.get(value.lower().lstrip("+"), value)  # .inf, -.inf, .nan are numbers
        try:
            out[key] = (float(value), number)
        except ValueError:
            continue
    return out


def scans_from_rows(report: ConversionReport, scan: np.ndarray, t_scan: np.ndarray, rng, az, el, vr,
                    extra: dict[str, np.ndarray]) -> list[RadarScan]:
    """Group detection rows into RadarScans (vectorised split; rows need not be sorted).

    Args:
        scan: (n,) int scan index of each row; `t_scan[scan]` is its time (t_scan strictly increasing).
        rng, az, el, vr: (n,) polar detections (range is `rng`).
        extra: name -> (n,) extra columns.
    """
    for name in extra:
        if not _NAME.match(name):
            raise InputError(f"extra column name {name!r} is not an identifier")
    order = np.argsort(scan, kind="stable")
    cols = [a[order] for a in (rng, az, el, vr)]
    ext = {k: np.asarray(v, dtype=float)[order] for k, v in extra.items()}
    s = scan[order]
    starts = np.flatnonzero(np.r_[True, s[1:] != s[:-1]]) if len(s) else np.zeros(0, dtype=int)
    bounds = np.r_[starts, len(s)]
    scans = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        k = int(s[a])
        scans.append(RadarScan(k, float(t_scan[k]), *(c[a:b] for c in cols), {n: v[a:b] for n, v in ext.items()}))
    report.kept_detections = int(len(s))
    report.kept_scans = len(scans)
    return scans


def check_scan_step(times, unit_s: float, unit: str, where: str) -> None:
    """InputError naming `where` (file and field) unless the median step between consecutive scan `times` (in
    the input's unit, `unit_s` seconds each, abbreviated `unit`) is a scan rate within SCAN_RATE_HZ; the hint
    names the units in which the times would be one. Fewer than two times: nothing to check.

    Checked by: tests/sim/test_convert_review55.py::test_ti_trigger_times_in_milliseconds_name_file_and_field
    """
    times = np.asarray(times)
    if len(times) < 2:
        return
    step = float(np.median(np.diff(times)))
    lo, hi = SCAN_RATE_HZ
    if step > 0 and lo <= 1.0 / (step * unit_s) <= hi:
        return
    fits = [name for name, s in TIME_UNITS if s != unit_s and step > 0 and lo <= 1.0 / (step * s) <= hi]
    rate = f"{1.0 / (step * unit_s):.3g} Hz" if step > 0 else "no scan rate"
    raise InputError(f"{where}: median step {step:.6g} {unit} between scans, {rate}, is no radar's scan rate "
                     f"(expected {lo:g}-{hi:g} Hz): {' or '.join(fits) + '?' if fits else 'times in another unit?'}")


def drop_few(report: ConversionReport, keep: np.ndarray, bad: np.ndarray, reason: str, explain) -> np.ndarray:
    """Drop the `bad` rows among the kept ones under `reason` ("detections ..."), when they are at most
    MAX_DROP_SHARE of them; more is an InputError `explain(k)` (where and why, k the first bad row) with the
    counts: nothing is written. Returns the new keep mask.

    Checked by: tests/sim/test_convert_review55.py::test_radarscenes_azimuths_in_degrees_or_0_2pi_are_refused,
        ::test_radarscenes_a_few_azimuths_out_of_range_are_still_dropped
    """
    bad = keep & np.asarray(bad, dtype=bool)
    n_bad, n = int(bad.sum()), int(keep.sum())
    if n_bad > MAX_DROP_SHARE * n:
        raise InputError(f"{explain(int(np.flatnonzero(bad)[0]))} ({n_bad} of {n} {reason}, "
                         f"{100 * n_bad / n:.3g} %; up to {100 * MAX_DROP_SHARE:g} % are dropped and counted)")
    return keep & report.drop(reason, bad)


def require_detections(report: ConversionReport, where) -> None:
    """InputError naming `where` (the detections' file) when no detection was kept: an empty sequence is no
    conversion. Names what was dropped, if anything."""
    if report.kept_detections:
        return
    dropped = "; ".join(f"dropped {n} {reason}" for reason, n in sorted(report.dropped.items()))
    raise InputError(f"{where}: no detections" + (f" left ({dropped})" if dropped else ""))


def planar_poses(x, y, yaw) -> np.ndarray:
    """(M,) planar poses -> (M, 4, 4) T_world_vehicle (z = 0, rotation about z by yaw)."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.zeros((len(x), 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 2, 2] = T[:, 3, 3] = 1.0
    T[:, 0, 3], T[:, 1, 3] = x, y
    return T


def polar_from_xyz(p: np.ndarray):
    """(n, 3) sensor-frame points -> range, azimuth, elevation (paper eq. 80); range 0 gives elevation 0."""
    r = np.linalg.norm(p, axis=1)
    az = np.arctan2(p[:, 1], p[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.where(r > 0, np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)), 0.0)
    return r, az, el


def field_of_view(angles: np.ndarray, default: float, limit: float) -> tuple[float, float]:
    """The field of view the detections span, at least 1e-6 rad wide and inside [-limit, limit] (a single
    detection straight behind, azimuth pi, or straight up, elevation pi/2, must not push it past the limit);
    (-default, default) without detections."""
    if not len(angles):
        return -default, default
    lo, hi = float(angles.min()), float(angles.max())
    if hi - lo < 1e-6:
        lo, hi = (lo, lo + 1e-6) if lo + 1e-6 <= limit else (hi - 1e-6, hi)
    return lo, hi


def write_conversion(out_dir, conv: Conversion) -> Path:
    """Write the sequence, conversion.json and the extra files into `out_dir`; return the directory. Files of an
    earlier writer are removed: the simulator's truth.npz here, a converter's files by `write_sequence`.

    Checked by: tests/sim/test_input_defects_stale_files.py
    """
    out = Path(out_dir)
    write_sequence(out, conv.sequence)
    remove_stale(out / TRUTH_NPZ)  # a recording has no simulator truth: another drive's would be read as its own
    try:
        atomic_write_bytes(out / CONVERSION_JSON,
                           (json.dumps(conv.report.to_dict(), indent=2, sort_keys=True) + "\n").encode("utf-8"))
        for name, text in conv.extra_files.items():
            atomic_write_bytes(out / name, text.encode("utf-8"))
    except OSError as exc:
        if out_of_space(exc):  # the machine's: the CLI's one line and exit 1 (atomic_write_bytes named the file)
            raise
        raise InputError(f"{out}: cannot write ({exc.strerror or exc})") from None
    return out
