"""Several radars on one vehicle: a rig directory of single-radar sequences tied together by rig.toml.

    RIG_DIR/rig.toml          sensors = ["radar1", "radar2", ...]   (sub-directories; the order is the sensor index)
    RIG_DIR/radar1/ ...       each a sequence directory of its own (radar.csv, sensor.toml with its extrinsics)
    RIG_DIR/groundtruth.txt   optional: the vehicle's poses (TUM), on the radars' clock

Backwards compatible by construction: every sensor stays a valid sequence (`rodo run RIG_DIR/radar2` runs that
radar alone) and a directory without rig.toml is read as before. The scans of all radars are merged by time
(`Rig.scans`); two radars with a scan at the same instant are refused (the odometry takes one scan per time).
Format and rules: docs/sequence_format.md ("Rigs").

Checked by: tests/sim/test_rig.py
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.tomlcompat import tomllib

from ._seqio import SequenceFormatError, atomic_write_bytes, read_text
from .sensor_geometry import DEG, mount
from .sequence import (GROUNDTRUTH_TXT, RADAR_CSV, RIG_TOML, check_one_layout, read_sequence, read_tum,
                       remove_stale, write_sequence)
from .sequence_types import RadarScan, Sequence, Trajectory
from .tum import format_tum


# simulated rigs: name -> [(radar sub-directory, T_vehicle_sensor)]; the first is the scenario's own front radar
# (`sim.sensor_geometry.default_mount`), the others corner radars at the front bumper's ends, looking 50 deg outwards
_CORNERS = [("front_left", mount(3.4, 0.85, 0.5, yaw=50.0 * DEG, pitch=0.5 * DEG)),
            ("front_right", mount(3.4, -0.85, 0.5, yaw=-50.0 * DEG, pitch=0.5 * DEG))]
LAYOUTS = {"front-corners": [("front", None)] + _CORNERS, "corners": _CORNERS}


@dataclass
class Rig:
    """Radars on one vehicle: names (sub-directories), their sequences, the vehicle's ground truth or None."""

    names: list[str]
    sequences: list[Sequence]
    groundtruth: Trajectory | None = None

    def scans(self, where: str = "rig") -> list[tuple[float, int, RadarScan]]:
        """(t, sensor index, scan) of every radar, by time; InputError naming both radars when two scan at once."""
        merged = sorted(((s.t, i, s) for i, seq in enumerate(self.sequences) for s in seq.scans),
                        key=lambda item: (item[0], item[1]))
        for (t0, i0, _), (t1, i1, _) in zip(merged, merged[1:]):
            if t1 == t0:
                raise InputError(f"{where}: radars {self.names[i0]!r} and {self.names[i1]!r} both have a scan at "
                                 f"t = {float(t0)!r} s: the odometry takes one scan per instant (offset one "
                                 "radar's clock)")
        return merged


def is_rig(path) -> bool:
    """Whether `path` is a rig directory (rig.toml); InputError if it is a single sequence too."""
    if (Path(path) / RIG_TOML).is_file():
        check_one_layout(Path(path))
        return True
    return False


def _names(path: Path, text: str) -> list[str]:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SequenceFormatError(path, f"not valid TOML ({exc})") from None
    unknown = sorted(set(data) - {"sensors", "description"})
    if unknown:
        raise SequenceFormatError(path, f"unknown key(s) {', '.join(unknown)} (expected sensors, description)")
    names = data.get("sensors")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise SequenceFormatError(path, "expected a non-empty list of sub-directory names", field="sensors")
    for n in names:
        if Path(n).is_absolute() or ".." in Path(n).parts or n != Path(n).as_posix().strip("/"):
            raise SequenceFormatError(path, f"{n!r} is not a sub-directory name of the rig", field="sensors")
    if len(set(names)) != len(names):
        raise SequenceFormatError(path, "a radar is listed twice", field="sensors")
    return names


def read_rig(path, *, use_cache: bool = True) -> Rig:
    """Read and validate a rig directory (see module docstring); errors name the file, line and field.

    Checked by: tests/sim/test_rig.py::test_round_trip_and_merge
    """
    path = Path(path)
    if not is_rig(path):
        raise SequenceFormatError(path, f"not a rig directory (expected {RIG_TOML} in it)")
    names = _names(path / RIG_TOML, read_text(path / RIG_TOML))
    sequences = [read_sequence(path / n, use_cache=use_cache) for n in names]
    check_one_clock(path, names, sequences)
    gt_path = path / GROUNDTRUTH_TXT
    return Rig(names, sequences, read_tum(gt_path) if gt_path.exists() else None)


def check_one_clock(path: Path, names: list[str], sequences: list[Sequence]) -> None:
    """InputError naming both radar.csv files and their time spans unless every two radars with scans scan over
    overlapping times: all radars of a rig share one clock, and a radar on another (or offset by far more than its
    turn) would send the one estimator jumping in time. Each span is widened by one scan period of its radar
    (1 / rate_hz): radars taking turns may start and stop up to a period apart.

    Checked by: tests/sim/test_input_defects_rig_clock.py
    """
    spans = [(n, s.scans[0].t, s.scans[-1].t, 1.0 / s.sensor.rate_hz)
             for n, s in zip(names, sequences) if s.scans]
    for i, (a, a0, a1, pa) in enumerate(spans):
        for b, b0, b1, pb in spans[i + 1:]:
            if a0 - pa > b1 + pb or b0 - pb > a1 + pa:
                raise InputError(f"{path / a / RADAR_CSV} (scans at {a0:.6g} to {a1:.6g} s) and "
                                 f"{path / b / RADAR_CSV} (scans at {b0:.6g} to {b1:.6g} s) do not overlap in time: "
                                 "all radars of a rig share one clock (different clocks or time offsets?); give "
                                 "them the same time base")


def write_rig(path, rig: Rig) -> None:
    """Write a rig directory: each sequence into its sub-directory (`write_sequence`), rig.toml, groundtruth.txt
    when given (a stale one is removed otherwise).

    Checked by: tests/sim/test_rig.py::test_round_trip_and_merge
    """
    path = Path(path)
    if not isinstance(rig, Rig) or len(rig.names) != len(rig.sequences) or not rig.names:
        raise InputError("rig: expected a Rig with one name per sequence")
    _names(path / RIG_TOML, _rig_text(rig.names))
    gt_bytes = None if rig.groundtruth is None else format_tum(rig.groundtruth).encode("ascii")
    for name, seq in zip(rig.names, rig.sequences):
        write_sequence(path / name, seq)
    write_rig_toml(path, rig.names)
    if gt_bytes is not None:
        atomic_write_bytes(path / GROUNDTRUTH_TXT, gt_bytes)
    else:
        remove_stale(path / GROUNDTRUTH_TXT)


def _rig_text(names: list[str]) -> str:
    return "# radars of one vehicle (docs/sequence_format.md, Rigs)\nsensors = [" \
        + ", ".join(f'"{n}"' for n in names) + "]\n"


def write_rig_toml(path, names: list[str]) -> None:
    """rig.toml naming the sequence sub-directories `names` (already written) of the rig at `path`."""
    path = Path(path)
    text = _rig_text(list(names))
    _names(path / RIG_TOML, text)
    atomic_write_bytes(path / RIG_TOML, text.encode())


def merged_groundtruth(rig: Rig) -> Trajectory | None:
    """The rig's ground truth, else the radars' own ground truths merged by time (equal times kept once)."""
    if rig.groundtruth is not None:
        return rig.groundtruth
    parts = [s.groundtruth for s in rig.sequences if s.groundtruth is not None]
    if not parts:
        return None
    t = np.concatenate([p.t for p in parts])
    T = np.concatenate([p.T_world_vehicle for p in parts])
    t, first = np.unique(t, return_index=True)
    return Trajectory(t, T[first])
