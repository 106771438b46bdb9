"""TUM trajectory files: rows `t tx ty tz qx qy qz qw` of T_world_vehicle (docs/sequence_format.md).

Reading validates every row (8 numbers, finite, unit quaternion within 1e-6, strictly increasing times) and
names the file, the 1-based line and the field of the first problem. Comment lines start with '#'; blank lines
are skipped. Writing uses '%.9f' (the TUM/evo convention): times and positions to 1 ns / 1 nm.

Checked by: tests/sim/test_tum.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.lie import so3

from ._seqio import UNIT_QUATERNION_TOL, SequenceFormatError, atomic_write_bytes, read_text
from .sequence_types import Trajectory

TUM_FIELDS = ("t", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


def _locate(path, lines: list[tuple[int, str]]) -> SequenceFormatError:
    for number, line in lines:
        fields = line.split()
        if len(fields) != 8:
            field = TUM_FIELDS[len(fields)] if len(fields) < 8 else None
            return SequenceFormatError(path, f"expected 8 whitespace-separated fields ({' '.join(TUM_FIELDS)}), "
                                       f"got {len(fields)}", line=number, field=field)
        for name, text in zip(TUM_FIELDS, fields):
            try:
                if "_" in text or not text.isascii():
                    raise ValueError
                float(text)
            except ValueError:
                return SequenceFormatError(path, f"expected a number, got {text!r}", line=number, field=name)
    return SequenceFormatError(path, "cannot parse the rows")


def parse_tum(path, text: str) -> Trajectory:
    """Parse the text of a TUM file (see `read_tum`); `path` is used in messages."""
    lines = [(k, line) for k, line in enumerate(text.split("\n"), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise SequenceFormatError(path, "no poses (only comments or blank lines)")
    try:
        data = np.loadtxt([line for _, line in lines], dtype=float, comments=None, ndmin=2)
        if data.shape[1] != 8:
            raise ValueError(f"{data.shape[1]} columns")
    except Exception:  # noqa: BLE001 - any parser failure becomes a located InputError
        raise _locate(path, lines) from None
    numbers = np.array([k for k, _ in lines])
    bad = ~np.isfinite(data)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise SequenceFormatError(path, f"value {data[row, col].item()!r} is not finite", line=int(numbers[row]),
                                  field=TUM_FIELDS[col])
    t = data[:, 0]
    if t.size > 1:
        dt = np.diff(t)
        if np.any(dt <= 0):
            k = int(np.flatnonzero(dt <= 0)[0]) + 1
            what = "duplicate time" if dt[k - 1] == 0 else "times not sorted: time decreases"
            raise SequenceFormatError(path, f"{what} ({t[k].item()!r} after {t[k - 1].item()!r} on line "
                                      f"{numbers[k - 1]}); times must strictly increase", line=int(numbers[k]),
                                      field="t")
    q = data[:, 4:8]
    big = np.abs(q).max(axis=1) > 2.0  # surely not unit; its norm could overflow (1e154: found by the fuzzer)
    norm = np.where(big, np.abs(q).max(axis=1), np.linalg.norm(np.where(big[:, None], 0.0, q), axis=1))
    off = big | (np.abs(norm - 1.0) > UNIT_QUATERNION_TOL)
    if off.any():
        k = int(np.flatnonzero(off)[0])
        size = f"|q| {'>=' if big[k] else '='} {norm[k].item()!r}"
        raise SequenceFormatError(path, f"not a unit quaternion ({size}, tolerance "
                                  f"{UNIT_QUATERNION_TOL:g}); order is qx qy qz qw", line=int(numbers[k]),
                                  field="qx qy qz qw")
    T = np.zeros((t.size, 4, 4))
    T[:, :3, :3] = so3.from_quaternion(q)
    T[:, :3, 3] = data[:, 1:4]
    T[:, 3, 3] = 1.0
    return Trajectory(t=t.copy(), T_world_vehicle=T)


def read_tum(path) -> Trajectory:
    """Read a TUM trajectory file `t tx ty tz qx qy qz qw` (T_world_vehicle, quaternion [qx, qy, qz, qw]).

    Raises:
        SequenceFormatError (InputError) naming file, line and field: missing/empty file, wrong field count,
        non-numbers, NaN/inf, duplicate or unsorted times, non-unit quaternion (never normalised silently).

    Checked by: tests/sim/test_tum.py
    """
    return parse_tum(path, read_text(path))


def format_tum(traj: Trajectory) -> str:
    """Text of a TUM file ('%.9f' per value, qw >= 0, '\\n' line endings, no comment)."""
    if not isinstance(traj, Trajectory):
        raise SequenceFormatError("trajectory", f"expected a Trajectory, got {type(traj).__name__}")
    if len(traj) == 0:
        raise SequenceFormatError("trajectory", "no poses: a TUM file needs at least one row")
    T = traj.T_world_vehicle
    rows = np.concatenate([traj.t[:, None], T[:, :3, 3], so3.to_quaternion(T[:, :3, :3]).reshape(-1, 4)], axis=1)
    rows = rows + 0.0  # no '-0.000000000' from negative zeros
    fmt = " ".join(["%.9f"] * 8)
    out = "\n".join(fmt % tuple(row) for row in rows.tolist())
    return out.replace("-0.000000000", "0.000000000") + ("\n" if out else "")


def write_tum(path, traj: Trajectory) -> None:
    """Write a TUM file atomically; same trajectory -> same bytes.

    Checked by: tests/sim/test_tum.py::test_tum_round_trip
    """
    atomic_write_bytes(path, format_tum(traj).encode("ascii"))
