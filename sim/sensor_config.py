"""sensor.toml of a sequence: read with full validation, write deterministically and atomically.

Format and rules: docs/sequence_format.md. Errors are `SequenceFormatError` (an InputError) naming the file,
the line of the offending key (1-based) and the key.

Checked by: tests/sim/test_sequence.py, tests/sim/test_sequence_fuzz.py
"""

from __future__ import annotations

import re

import numpy as np

from rodo.estimator.lie import so3
from rodo.estimator.tomlcompat import tomllib

from ._seqio import UNIT_QUATERNION_TOL, SequenceFormatError, atomic_write_bytes, float_text, read_text
from .sequence_types import SIGMA_NAMES, NoiseSigmas, SensorConfig, check_sensor_values

# section -> (required keys, optional keys); None is the top level
_SCHEMA = {
    None: (("rate_hz", "extrinsics", "noise", "fov"), ("name", "description")),
    "extrinsics": (("translation", "quaternion"), ()),
    "noise": (SIGMA_NAMES, ()),
    "fov": (("azimuth", "elevation", "max_range"), ("min_range",)),
}
_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]")


def _key_line(text: str, section: str | None, key: str | None) -> int | None:
    """1-based line where `key` is set in `[section]` (the section header if key is None); None if absent."""
    current = None
    for number, line in enumerate(text.split("\n"), start=1):
        head = _HEADER.match(line)
        if head:
            current = head.group(1).strip().strip('"')
            if current == (section if key is None else key if section is None else None):
                return number
            continue
        if current is None and section is not None:  # dotted key or inline table at the top level
            pattern = rf'"?{re.escape(section)}"?\s*' + (rf'\.\s*"?{re.escape(key)}"?\s*=' if key else r"[=.]")
        elif current == section and key is not None:
            pattern = rf'"?{re.escape(key)}"?\s*='
        else:
            continue
        if re.match(pattern, line.lstrip()):
            return number
    return None


class _Reader:
    def __init__(self, path, text: str):
        self.path, self.text = path, text

    def fail(self, dotted: str, reason: str):
        section, _, key = dotted.rpartition(".")
        section = section or None
        line = _key_line(self.text, section, key) if key else None
        if line is None and section is not None:
            line = _key_line(self.text, section, None)
        raise SequenceFormatError(self.path, reason, line=line, field=dotted)

    def table(self, data: dict, section: str | None) -> dict:
        required, optional = _SCHEMA[section]
        prefix = f"{section}." if section else ""
        for key in data:
            if key not in required and key not in optional:
                allowed = ", ".join(required + optional)
                self.fail(prefix + key, f"unknown key '{key}' (allowed here: {allowed})")
        for key in required:
            if key not in data:
                if key in _SCHEMA:
                    raise SequenceFormatError(self.path, f"missing section [{key}]", field=key)
                what = f"[{section}]" if section else "the top level"
                line = _key_line(self.text, section, None) if section else None
                raise SequenceFormatError(self.path, f"missing key '{key}' in {what}", line=line,
                                          field=prefix + key)
            if key in _SCHEMA and not isinstance(data[key], dict):
                self.fail(key, f"'{key}' must be a table [{key}], got {type(data[key]).__name__}")
        return data

    def number(self, value, dotted: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(dotted, f"expected a number, got {type(value).__name__} {value!r}")
        try:
            value = float(value)
        except OverflowError:
            self.fail(dotted, f"number too large: {str(value)[:20]}...")
        if not np.isfinite(value):
            self.fail(dotted, f"must be finite, got {value!r}")
        return value

    def vector(self, value, dotted: str, n: int) -> tuple[float, ...]:
        if not isinstance(value, list) or len(value) != n:
            self.fail(dotted, f"expected an array of {n} numbers, got {value!r}")
        return tuple(self.number(v, f"{dotted}") for v in value)


def parse_sensor_config(path, text: str) -> SensorConfig:
    """Parse the text of a sensor.toml (see `read_sensor_config`); `path` is used in messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"at line (\d+)", str(exc))
        line = int(match.group(1)) if match else None
        if line is None and "end of document" in str(exc):
            line = text.rstrip("\n").count("\n") + 1
        raise SequenceFormatError(path, f"TOML syntax error: {exc}", line=line) from None
    r = _Reader(path, text)
    r.table(data, None)
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            r.fail(key, f"expected a string, got {type(data[key]).__name__}")
    ext, noise, fov = (r.table(data[s], s) for s in ("extrinsics", "noise", "fov"))
    rate_hz = r.number(data["rate_hz"], "rate_hz")
    translation = r.vector(ext["translation"], "extrinsics.translation", 3)
    q = np.array(r.vector(ext["quaternion"], "extrinsics.quaternion", 4))
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_QUATERNION_TOL:
        r.fail("extrinsics.quaternion", f"not a unit quaternion (|q| = {norm!r}, tolerance "
               f"{UNIT_QUATERNION_TOL:g}); order is [qx, qy, qz, qw]")
    sigmas = tuple(r.number(noise[k], f"noise.{k}") for k in SIGMA_NAMES)
    az = r.vector(fov["azimuth"], "fov.azimuth", 2)
    el = r.vector(fov["elevation"], "fov.elevation", 2)
    max_range = r.number(fov["max_range"], "fov.max_range")
    min_range = r.number(fov.get("min_range", 0.0), "fov.min_range")
    check_sensor_values(rate_hz, sigmas, az, el, max_range, min_range, translation, r.fail)
    T = np.eye(4)
    T[:3, :3] = so3.from_quaternion(q)
    T[:3, 3] = translation
    return SensorConfig(rate_hz=rate_hz, T_vehicle_sensor=T, noise=NoiseSigmas(*sigmas), azimuth_fov=az,
                        elevation_fov=el, max_range=max_range, min_range=min_range)


def read_sensor_config(path) -> SensorConfig:
    """Read and validate a sensor.toml.

    Args:
        path: the TOML file.

    Returns:
        SensorConfig with T_vehicle_sensor built from [extrinsics] translation and quaternion [qx, qy, qz, qw].

    Raises:
        SequenceFormatError (InputError): missing file or section, TOML syntax, unknown key, wrong type,
        non-finite or non-positive rate/sigma, non-unit quaternion (|q| - 1 > 1e-6; never normalised
        silently), field of view outside [-pi, pi] / [-pi/2, pi/2] (hints at degrees).

    Checked by: tests/sim/test_sequence.py::test_sensor_config_round_trip,
    tests/sim/test_sequence_fuzz.py::test_malformed_sensor_toml_gives_input_error
    """
    return parse_sensor_config(path, read_text(path))


def format_sensor_config(cfg: SensorConfig) -> str:
    """TOML text of a SensorConfig; floats written with repr so that they read back bit-exactly."""
    if not isinstance(cfg, SensorConfig):
        raise SequenceFormatError("sensor config", f"expected a SensorConfig, got {type(cfg).__name__}")
    T = cfg.T_vehicle_sensor
    q = so3.to_quaternion(T[:3, :3])

    def arr(values):
        return "[" + ", ".join(float_text(v) for v in values) + "]"

    n = cfg.noise
    lines = [
        "# Radar sensor description (docs/sequence_format.md). SI units, angles in radians.",
        f"rate_hz = {float_text(cfg.rate_hz)}",
        "",
        "[extrinsics]  # T_vehicle_sensor: pose of the sensor in the vehicle frame",
        f"translation = {arr(T[:3, 3])}",
        f"quaternion = {arr(q)}  # [qx, qy, qz, qw]",
        "",
        "[noise]  # 1-sigma",
        f"range = {float_text(n.range)}",
        f"azimuth = {float_text(n.azimuth)}",
        f"elevation = {float_text(n.elevation)}",
        f"radial_velocity = {float_text(n.radial_velocity)}",
        "",
        "[fov]",
        f"azimuth = {arr(cfg.azimuth_fov)}",
        f"elevation = {arr(cfg.elevation_fov)}",
        f"max_range = {float_text(cfg.max_range)}",
        f"min_range = {float_text(cfg.min_range)}",
    ]
    return "\n".join(lines) + "\n"


def write_sensor_config(path, cfg: SensorConfig) -> None:
    """Write a sensor.toml atomically (same config -> same bytes).

    All floats round-trip bit-exactly except T_vehicle_sensor's rotation, which goes through a quaternion
    (error ~1e-16).

    Checked by: tests/sim/test_sequence.py::test_sensor_config_round_trip
    """
    atomic_write_bytes(path, format_sensor_config(cfg).encode("utf-8"))
