"""The sequence format: a directory with radar.csv, sensor.toml and optionally groundtruth.txt.

Specification, examples and validation rules: docs/sequence_format.md. This module is the public face of the
format; the work is split along the files: `sim.radar_csv` (detections, cache), `sim.sensor_config`
(sensor.toml), `sim.tum` (groundtruth.txt), `sim.sequence_types` (the dataclasses).

Every malformed input raises `SequenceFormatError`, an `estimator.errors.InputError`, whose message names the
file, the 1-based line and the field. Writers are deterministic (same sequence -> same bytes) and atomic.

Checked by: tests/sim/test_sequence.py, tests/sim/test_sequence_fuzz.py, tests/sim/test_tum.py
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rodo.estimator.errors import InputError, out_of_space

from ._seqio import SequenceFormatError, atomic_write_bytes, replace_synced, temporary_beside
from .radar_csv import cache_path, format_radar_csv, read_radar_csv
from .sensor_config import format_sensor_config, read_sensor_config, write_sensor_config
from .sequence_types import (
    NoiseSigmas,
    RadarScan,
    SensorConfig,
    Sequence,
    Trajectory,
    polar_to_cartesian,
)
from .tum import format_tum, read_tum, write_tum

RADAR_CSV = "radar.csv"
SENSOR_TOML = "sensor.toml"
GROUNDTRUTH_TXT = "groundtruth.txt"
RIG_TOML = "rig.toml"  # a rig directory (sim/rig.py) instead of one sequence
# what a converter puts beside a sequence: its report (sim.convert CONVERSION_JSON) and RadarScenes' odometry;
# they describe a recording, not what is written next: `write_sequence` removes them (a converter then adds its own)
CONVERTER_FILES = ("conversion.json", "odom.csv")

__all__ = [
    "GROUNDTRUTH_TXT", "RADAR_CSV", "RIG_TOML", "SENSOR_TOML", "CONVERTER_FILES", "NoiseSigmas", "RadarScan",
    "SensorConfig", "Sequence", "SequenceFormatError", "atomic_write_bytes", "Trajectory", "cache_path",
    "check_one_layout", "check_scan_rate", "polar_to_cartesian", "read_radar_csv", "read_sensor_config",
    "read_sequence", "read_tum", "remove_stale", "replace_synced", "temporary_beside", "write_sensor_config",
    "write_sequence", "write_tum",
]


def read_sequence(path, *, use_cache: bool = True) -> Sequence:
    """Read and validate a sequence directory.

    Args:
        path: the directory holding radar.csv, sensor.toml and optionally groundtruth.txt.
        use_cache: load/store the parsed radar.csv in `.radar.csv.npz` next to it (invalidated when the CSV's
            size, mtime_ns or content hash change; a cache whose values fail the checks is not used).

    Returns:
        Sequence with one RadarScan per scan index that has rows, in order; groundtruth None when
        groundtruth.txt is absent.

    Raises:
        SequenceFormatError (InputError): missing directory or required file, a rig directory (rig.toml: give
        one of its radars), or any malformed content (message names file, line and field).
        InputError: the scans and the ground truth do not overlap in time (names both files).

    Checked by: tests/sim/test_sequence.py::test_round_trip_is_bit_exact_and_deterministic
    """
    path = Path(path)
    if not path.is_dir():
        raise SequenceFormatError(path, "not a sequence directory (expected radar.csv and sensor.toml in it)")
    check_one_layout(path)
    if (path / RIG_TOML).is_file():
        radars = sorted(d.name for d in path.iterdir() if (d / RADAR_CSV).is_file())
        example = f"e.g. {path / radars[0]} (radars: {', '.join(radars)})" if radars else "a radar's sub-directory"
        raise SequenceFormatError(path, f"holds a rig ({RIG_TOML}: several radars), not a single sequence; give "
                                  f"one radar's directory, {example}; `rodo run` reads a whole rig")
    sensor = read_sensor_config(path / SENSOR_TOML)
    scans = read_radar_csv(path / RADAR_CSV, use_cache=use_cache)
    check_scan_rate(scans, sensor.rate_hz, path)
    gt_path = path / GROUNDTRUTH_TXT
    groundtruth = read_tum(gt_path) if gt_path.exists() else None
    if groundtruth is not None and scans and len(groundtruth.t):
        _check_time_bases(path, scans[0].t, scans[-1].t, float(groundtruth.t[0]), float(groundtruth.t[-1]))
    return Sequence(sensor=sensor, scans=scans, groundtruth=groundtruth)


def check_one_layout(path: Path) -> None:
    """InputError unless the directory is one sequence (radar.csv) or one rig (rig.toml), not both: which one a
    command reads would otherwise depend on the command."""
    if (path / RIG_TOML).is_file() and (path / RADAR_CSV).is_file():
        raise InputError(f"{path}: holds both a rig ({RIG_TOML}) and a single sequence ({RADAR_CSV}); keep one per "
                         "directory")


RATE_MISMATCH = 10.0  # the scans' period over 1 / rate_hz beyond which the two disagree (milliseconds: 1000)


def check_scan_rate(scans, rate_hz: float, path) -> None:
    """InputError unless the scans' period agrees with sensor.toml's rate_hz within a factor RATE_MISMATCH: times
    in milliseconds, microseconds or nanoseconds (or a rate in the wrong unit) would otherwise run as a drive 1000x
    slower, silently wrong. The period is the median time step between consecutive scans. Scans without detections
    write no rows, which lengthens the steps; so a period too long is refused only when the median step per scan
    index is too long as well (for indices that count the radar's scans it is the period itself; an index that
    counts something else cannot make a sequence refused). One pair of scans is enough.

    Checked by: tests/sim/test_sequence_rate.py
    """
    if len(scans) < 2:
        return
    step = np.diff(np.array([s.scan for s in scans], dtype=np.int64))
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):  # finite times may step by inf
        dt = np.diff(np.array([s.t for s in scans], dtype=float))
        period = float(np.median(dt))
        per_index = float(np.median(dt[step > 0] / step[step > 0])) if np.any(step > 0) else period
        ratio = period * rate_hz
        slow = min(ratio, per_index * rate_hz)
    if 1.0 / RATE_MISMATCH <= ratio and not slow > RATE_MISMATCH:
        return
    units = {3: "milliseconds", 6: "microseconds", 9: "nanoseconds"}
    decade = int(round(np.log10(ratio))) if np.isfinite(ratio) and ratio > 0 else None
    hint = f"radar.csv's t is in seconds, {SENSOR_TOML}'s rate_hz in Hz"
    hint = f"times in {units[decade]}? {hint}" if decade in units else f"{hint}: is one of them in another unit?"
    raise SequenceFormatError(Path(path) / RADAR_CSV, f"the scans are {period:.6g} apart (median), but "
                              f"{SENSOR_TOML}'s rate_hz = {rate_hz:g} means {1.0 / rate_hz:.6g} s: {hint}",
                              field="t")


TIME_BASE_TOLERANCE = 1e-3  # s, as validation.association.DEFAULT_TOLERANCE


def _check_time_bases(path: Path, t0: float, t1: float, g0: float, g1: float) -> None:
    """Scans in [t0, t1] and ground truth in [g0, g1] must share some time: files on different clocks
    would make every evaluation (and an initialisation from the truth) silently wrong. A gap below
    TIME_BASE_TOLERANCE is no other clock (groundtruth.txt keeps 9 decimals, radar.csv every digit)."""
    if t1 < g0 - TIME_BASE_TOLERANCE or t0 > g1 + TIME_BASE_TOLERANCE:
        raise InputError(f"{path / RADAR_CSV} (scans at {t0:.6g} to {t1:.6g} s) and {path / GROUNDTRUTH_TXT} "
                         f"(poses at {g0:.6g} to {g1:.6g} s) do not overlap in time: different clocks or time "
                         "offsets? Give both files the same time base")


def write_sequence(path, seq: Sequence) -> None:
    """Write a sequence directory (created if needed; its three files are replaced atomically).

    Empty scans write no rows. A stale radar cache is removed, and so is a stale groundtruth.txt when
    `seq.groundtruth` is None, and a converter's files (CONVERTER_FILES: conversion.json, odom.csv), which describe
    the recording converted before, not this sequence (a converter writes its own after this call). The
    simulator's truth.npz is left alone (a simulated sequence rewritten with scans removed keeps its truth; a
    converter removes it: `sim.convert.write_conversion`).

    Raises:
        InputError: `seq` does not satisfy the format's rules (names the offending scan and field).

    Checked by: tests/sim/test_sequence.py::test_round_trip_is_bit_exact_and_deterministic,
        tests/sim/test_input_defects_stale_files.py
    """
    if not isinstance(seq, Sequence):
        raise InputError(f"seq: expected a Sequence, got {type(seq).__name__}")
    if not isinstance(seq.sensor, SensorConfig):
        raise InputError(f"seq.sensor: expected a SensorConfig, got {type(seq.sensor).__name__}")
    if seq.groundtruth is not None and not isinstance(seq.groundtruth, Trajectory):
        raise InputError(f"seq.groundtruth: expected a Trajectory or None, got {type(seq.groundtruth).__name__}")
    # format everything first: nothing is written when any part is invalid
    radar_bytes = format_radar_csv(seq.scans)
    check_scan_rate(seq.scans, seq.sensor.rate_hz, path)
    sensor_bytes = format_sensor_config(seq.sensor).encode("utf-8")
    gt_bytes = None if seq.groundtruth is None else format_tum(seq.groundtruth).encode("ascii")
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if out_of_space(exc):  # the machine's (mkdir's error names its directory)
            raise
        raise InputError(f"{path}: cannot create the sequence directory ({exc.strerror or exc})") from None
    atomic_write_bytes(path / RADAR_CSV, radar_bytes)
    remove_stale(cache_path(path / RADAR_CSV))
    atomic_write_bytes(path / SENSOR_TOML, sensor_bytes)
    gt_path = path / GROUNDTRUTH_TXT
    if gt_bytes is not None:
        atomic_write_bytes(gt_path, gt_bytes)
    else:
        remove_stale(gt_path)
    for name in CONVERTER_FILES:
        remove_stale(path / name)


def remove_stale(path: Path) -> None:
    """Remove a file left by an earlier writer (none is fine); InputError naming it when it cannot be removed."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as exc:
        raise InputError(f"{path}: cannot remove this stale file ({exc.strerror or exc}); remove it by hand or "
                         "write to another directory") from None
