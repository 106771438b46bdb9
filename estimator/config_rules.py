"""Every value of an `OdometryConfig` checked for type, finiteness and range, by one table of rules.

`check_values(config)` walks every section (a dataclass field of OdometryConfig) and every key in it: numbers
must be numbers (not booleans, integers where the default is one), finite (TOML accepts `nan` and `inf`, which
the estimator cannot), and inside the range that `RULES` gives for "section.key". A key without a rule (one
added since) still gets the type and finiteness checks. The error names the section and key as in the TOML
file, `[noise] map_sigma_polar = nan: must be a finite number >= 0`; `OdometryConfig.from_dict` prefixes the
file. The checks read the values and never change them (results stay bit-identical). `check_sections` holds
the checks no single key's rule expresses (the model, vector lengths, messages of their own). `section_from_dict`
reads one section from its TOML table first (unknown keys and types, named).

Checked by: tests/cli/test_bad_config.py
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class Rule:
    """A range: lo < x (lo <= x if lo_closed), x < hi (x <= hi if hi_closed); `size` elements for a list."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_closed: bool = True
    hi_closed: bool = True
    size: int | None = None
    also: tuple = ()  # values allowed outside the range (e.g. 0 = disabled)

    def holds(self, x: float) -> bool:
        if x in self.also:
            return True
        above = x >= self.lo if self.lo_closed else x > self.lo
        below = x <= self.hi if self.hi_closed else x < self.hi
        return above and below

    def text(self) -> str:
        parts = []
        if self.lo > -math.inf:
            parts.append(f"{'>=' if self.lo_closed else '>'} {_num(self.lo)}")
        if self.hi < math.inf:
            parts.append(f"{'<=' if self.hi_closed else '<'} {_num(self.hi)}")
        also = f" (or {', '.join(_num(a) for a in self.also)})" if self.also else ""
        return " and ".join(parts) + also


def _num(x) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 2**63 else f"{x:g}"


POSITIVE = Rule(0.0, lo_closed=False)
NONNEGATIVE = Rule(0.0)
PROBABILITY = Rule(0.0, 1.0, lo_closed=False, hi_closed=False)
# sigmas and variances are squared (or multiplied) on their way into covariances: 1e200 overflowed to inf there
# (OverflowError, NaN covariances). Bounds far beyond any meaning (a sigma of 1000 km, 1000 km/s, 1e6 rad) keep
# every square and product finite; a key whose meaning needs more would say so here
MAX_SIGMA = 1e6  # in the key's unit
MAX_VARIANCE = MAX_SIGMA**2
SIGMA = Rule(0.0, MAX_SIGMA)  # >= 0: 0 disables the term
POSITIVE_SIGMA = Rule(0.0, MAX_SIGMA, lo_closed=False)
# a detection's or map point's position sigma, m: the polar model adds it to the polar R (radians at the floor
# 5e-4), and at 1e6 m the sum was no longer positive definite in double precision; 1 km is beyond any map
MAX_POSITION_SIGMA = 1e3
# the other end: a term's information is 1 / sigma^2, and a time constant divides dt; at the smallest doubles both
# overflowed (5e-324: a divide-by-zero, then NaN). 1e-9 in a sigma's unit is beyond any sensor; 0 stays "off"
MIN_SIGMA = 1e-9
INFORMATION_SIGMA = Rule(MIN_SIGMA, MAX_SIGMA)
INFORMATION_SIGMA_OR_OFF = Rule(MIN_SIGMA, MAX_SIGMA, also=(0.0,))
POSITION_SIGMA = Rule(0.0, MAX_POSITION_SIGMA)
POSITIVE_POSITION_SIGMA = Rule(0.0, MAX_POSITION_SIGMA, lo_closed=False)

# "section.key" -> range; a list's rule applies to each element and fixes its length
RULES: dict[str, Rule] = {
    "window": Rule(2, 1000),
    "seed": Rule(0, 2**63 - 1),
    "noise.qc_ca": Rule(1e-20, 1e8, size=6),  # beyond: Q_k under- or overflows (calibrate fits inside)
    "noise.qc_cv": Rule(1e-20, 1e8, size=6),
    "noise.cartesian_sigma": POSITIVE_POSITION_SIGMA,
    "noise.map_sigma_polar": POSITION_SIGMA,
    "noise.map_sigma_cartesian": POSITION_SIGMA,
    "noise.sensor_sigma_scale": Rule(0.0, 1e6, lo_closed=False),  # ratios to sensor.toml's sigmas (may be tiny)
    "noise.sensor_sigma_scales": Rule(0.0, 1e6, lo_closed=False, size=4),
    "noise.sigma_floor": Rule(0.0, 1e3, lo_closed=False, size=4),
    "noise.doppler_common_sigma": SIGMA,
    "noise.min_prior_dt": Rule(0.0, 1.0),  # s: a floor on the scan interval, not a time in ms
    "association.gate_probability": PROBABILITY,
    "association.max_radius": POSITIVE,
    "association.doppler_sigma_floor": SIGMA,
    "association.reassociate": Rule(0, 100),
    "association.ransac_above_sigma": NONNEGATIVE,
    "association.doppler_jerk_margin": POSITIVE,
    "association.consensus_switch_after": NONNEGATIVE,
    "association.consensus_switch_ratio": Rule(1.0, lo_closed=False),
    "association.consensus_voxel": POSITIVE,
    "association.moving_group_z": NONNEGATIVE,
    "association.moving_group_margin": NONNEGATIVE,
    "association.doppler_update_probability": PROBABILITY,
    "association.ground_band": NONNEGATIVE,
    "map.capacity": Rule(10, 10_000_000),
    "map.max_age": Rule(0, 1_000_000),
    "map.voxel": Rule(1e-3, also=(0.0,)),  # m: 0 off; a voxel key floor(p / voxel) must stay an integer
    "map.max_fused": Rule(2, 1_000_000, also=(0,)),
    "map.surface_normal_sigma": POSITION_SIGMA,
    "map.surface_tangent_sigma": POSITIVE_POSITION_SIGMA,
    "map.surface_neighbours": Rule(5, 1000),
    "map.surface_radius": POSITIVE,
    "map.surface_planarity": Rule(0.0, 1.0, lo_closed=False),
    "outage.reinit_after": NONNEGATIVE,
    "standstill.speed": NONNEGATIVE,
    "standstill.sigma_velocity": INFORMATION_SIGMA,
    "standstill.sigma_rate": INFORMATION_SIGMA,
    "standstill.sigma_accel": INFORMATION_SIGMA,
    "standstill.sigma_angular_accel": INFORMATION_SIGMA,
    "standstill.sigma_accel_jump": SIGMA,
    "vehicle.sigma_roll_rate": INFORMATION_SIGMA_OR_OFF,
    "vehicle.sigma_pitch_rate": INFORMATION_SIGMA_OR_OFF,
    "vehicle.sigma_lateral_velocity": INFORMATION_SIGMA_OR_OFF,
    "vehicle.sigma_vertical_velocity": INFORMATION_SIGMA_OR_OFF,
    "uncertainty.velocity_correlation_time": NONNEGATIVE,
    "uncertainty.inflation": POSITIVE,
    "uncertainty.measurement_inflation": Rule(1.0),
    "uncertainty.drift_rate_sigma": Rule(0.0, MAX_SIGMA, size=6),
    "uncertainty.prior_memory": NONNEGATIVE,
    "uncertainty.velocity_inflation": Rule(0.0, lo_closed=False),
    "uncertainty.velocity_inflation_per_speed": NONNEGATIVE,
    "uncertainty.velocity_inflation_per_doppler": NONNEGATIVE,
    "uncertainty.velocity_inflation_per_rate": Rule(0.0, size=3),
    "uncertainty.inflation_per_rate": Rule(0.0, size=3),
    "uncertainty.inflation_per_doppler": NONNEGATIVE,
    "uncertainty.inflation_per_pull": NONNEGATIVE,
    "uncertainty.velocity_error_share": POSITIVE,
    "uncertainty.velocity_error_share_per_speed": NONNEGATIVE,
    "uncertainty.registration_correlation": Rule(0.0, 1.0),
    "uncertainty.registration_axis_correlation": Rule(0.0, 1.0, size=6),
    "uncertainty.velocity_axis_inflation": Rule(0.0, lo_closed=False, size=6),
    "uncertainty.velocity_lag_per_acceleration": Rule(-MAX_SIGMA, MAX_SIGMA, size=6),  # b = L a enters as b b^T
    "uncertainty.velocity_lag_per_yaw_acceleration": Rule(-MAX_SIGMA, MAX_SIGMA, size=6),
    "uncertainty.velocity_lag_time": POSITIVE,
    "uncertainty.heading_reversion_time": Rule(1e-3, also=(0.0,)),  # s: 0 off; it divides dt
    "uncertainty.heading_anchor_time": POSITIVE,
    "uncertainty.attitude_jitter_variance": Rule(0.0, MAX_VARIANCE),
    "uncertainty.attitude_jitter_time": POSITIVE,
    "uncertainty.stationary_variance": Rule(0.0, MAX_VARIANCE, size=6),
    "uncertainty.stationary_time": Rule(0.0, lo_closed=False, size=6),
    "solver.iterations": Rule(1, 1000),
    "solver.step_tolerance": POSITIVE,
    "solver.step_sigma_tolerance": NONNEGATIVE,
    "solver.refine_iterations": Rule(1, 1000),
    "solver.robust_c": NONNEGATIVE,
    "solver.init_velocity_sigma": POSITIVE_SIGMA,
    "solver.init_rate_sigma": Rule(0.0, MAX_SIGMA, lo_closed=False, size=3),
    "solver.init_accel_sigma": Rule(0.0, MAX_SIGMA, lo_closed=False, size=3),
    "solver.init_angular_accel_sigma": Rule(0.0, MAX_SIGMA, lo_closed=False, size=3),
}

_INTEGER = (int, np.integer)
_NUMBER = (int, float, np.integer, np.floating)


def check_values(config, ranges: bool = True) -> None:
    """InputError naming `[section] key = value` for the first value of wrong type, non-finite or out of range.

    ranges=False checks the types only (OdometryConfig runs it before its own checks, which compare numbers).

    Checked by: tests/cli/test_bad_config.py::test_every_rule_refuses_out_of_range_and_non_finite_values
    """
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            defaults = type(value)()
            for g in dataclasses.fields(value):
                check_value(f.name, g.name, getattr(value, g.name), getattr(defaults, g.name), ranges)
        elif f.name in RULES:
            check_value(None, f.name, value, 0, ranges)


def check_value(section: str | None, key: str, value, default, ranges: bool = True) -> None:
    """One value against its default's type and, if ranges, finiteness and its rule (`RULES`), if any."""
    name = f"[{section}] {key}" if section else key
    rule = RULES.get(f"{section}.{key}" if section else key)
    shown = f"{name} = {_toml(value)}"
    if isinstance(default, bool):
        if not isinstance(value, (bool, np.bool_)):
            raise InputError(f"{shown}: expected true or false")
        return
    if isinstance(default, str):
        return  # the model name, checked against MODELS by OdometryConfig
    if isinstance(default, tuple):
        if not isinstance(value, (tuple, list)):
            raise InputError(f"{shown}: expected a list of numbers")
        if ranges and rule is not None and rule.size is not None and len(value) != rule.size:
            raise InputError(f"{shown}: expected {rule.size} numbers, got {len(value)}")
        items = list(value)
    else:
        items = [value]
    want_int = isinstance(default, _INTEGER) and not isinstance(default, bool)
    for x in items:
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, _INTEGER if want_int else _NUMBER):
            raise InputError(f"{shown}: expected {'an integer' if want_int else 'a number'}"
                             f"{' in every element' if isinstance(default, tuple) else ''}")
    for x in items if ranges else ():
        each = "each element " if isinstance(default, tuple) else ""
        if not math.isfinite(x):
            raise InputError(f"{shown}: {each}must be a finite number{' ' + rule.text() if rule else ''}")
        if rule is not None and not rule.holds(x):
            raise InputError(f"{shown}: {each}must be {rule.text()}")


def _toml(value) -> str:
    """A value as it reads in TOML (nan, inf, true, [1.0, 2.0])."""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, (float, np.floating)) and not math.isfinite(value):
        return "nan" if math.isnan(value) else "inf" if value > 0 else "-inf"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return repr(value)


def section_from_dict(kind, values: dict, where: str):
    """One section (a dataclass `kind`) from its TOML table: unknown keys, lists that are not numbers, numbers
    that are not numbers (or booleans, or integers where the default is one) are errors that name `where` and
    the key; the values are converted to the default's type."""
    fields = {f.name: f for f in dataclasses.fields(kind)}
    defaults = kind()
    out = {}
    for key, value in values.items():
        if key not in fields:
            raise InputError(f"{where}: unknown key {key!r}; known: {', '.join(sorted(fields))}")
        default = getattr(defaults, key)
        if isinstance(default, tuple):
            if not isinstance(value, (list, tuple)) or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                raise InputError(f"{where} {key}: expected a list of numbers, got {value!r}")
            value = tuple(float(v) for v in value)
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise InputError(f"{where} {key}: expected true or false, got {value!r}")
        elif not isinstance(value, (int, float)) or isinstance(value, bool):
            raise InputError(f"{where} {key}: expected a number, got {value!r}")
        elif isinstance(default, int) and not isinstance(value, int):
            raise InputError(f"{where} {key}: expected an integer, got {value!r}")
        out[key] = type(default)(value) if not isinstance(default, tuple) else value
    return kind(**out)


def check_sections(config, models) -> None:
    """The checks that do not fit one key's rule (`RULES`): the model among `models`, lengths of the vector keys,
    ranges with a message of their own. Raises InputError naming the key."""
    _check_model_and_noise(config, models)
    _check_solver(config)
    _check_association_and_map(config)


def _check_model_and_noise(c, models) -> None:
    if c.model not in models:
        raise InputError(f"model: unknown {c.model!r}; known: {', '.join(models)}")
    if not (isinstance(c.window, int) and c.window >= 2):
        raise InputError(f"window: must be an integer >= 2, got {c.window!r}")
    for name, qc in (("noise.qc_ca", c.noise.qc_ca), ("noise.qc_cv", c.noise.qc_cv)):
        if len(qc) != 6 or not all(np.isfinite(qc)) or min(qc) <= 0:
            raise InputError(f"{name}: must be 6 positive numbers, got {list(qc)}")
    if not 0 < c.association.gate_probability < 1:
        raise InputError("association.gate_probability: must be in (0, 1)")
    if c.map.capacity < 10:
        raise InputError("map.capacity: must be >= 10")
    for name in ("cartesian_sigma", "sensor_sigma_scale"):
        if not getattr(c.noise, name) > 0:
            raise InputError(f"noise.{name}: must be > 0")
    if c.noise.map_sigma_polar < 0 or c.noise.map_sigma_cartesian < 0:
        raise InputError("noise.map_sigma_polar, noise.map_sigma_cartesian: must be >= 0")
    if isinstance(c.seed, bool) or not isinstance(c.seed, int) or c.seed < 0:
        raise InputError(f"seed: must be an integer >= 0, got {c.seed!r}")
    scales = c.noise.sensor_sigma_scales
    if len(scales) != 4 or not all(np.isfinite(scales)) or min(scales) <= 0:
        raise InputError(f"noise.sensor_sigma_scales: must be 4 positive numbers [range, azimuth, elevation, "
                         f"radial_velocity], got {list(scales)}")
    if len(c.noise.sigma_floor) != 4 or min(c.noise.sigma_floor) <= 0:
        raise InputError("noise.sigma_floor: must be 4 positive numbers [range, azimuth, elevation, "
                         f"radial_velocity], got {list(c.noise.sigma_floor)}")


def _check_solver(c) -> None:
    if not c.solver.step_tolerance > 0:
        raise InputError(f"solver.step_tolerance: must be > 0, got {c.solver.step_tolerance}")
    if c.solver.iterations < 1 or c.solver.refine_iterations < 1:
        raise InputError(f"solver.iterations, solver.refine_iterations: must be >= 1, got "
                         f"{c.solver.iterations}, {c.solver.refine_iterations}")
    if c.solver.robust_c < 0:
        raise InputError(f"solver.robust_c: must be >= 0 (0 disables the robust loss), got {c.solver.robust_c}")
    for name in ("init_rate_sigma", "init_accel_sigma", "init_angular_accel_sigma"):
        v = getattr(c.solver, name)
        if len(v) != 3 or min(v) <= 0:
            raise InputError(f"solver.{name}: must be 3 positive numbers, got {list(v)}")
    if not c.solver.init_velocity_sigma > 0:
        raise InputError("solver.init_velocity_sigma: must be > 0")


def _check_association_and_map(c) -> None:
    if not c.association.max_radius > 0:
        raise InputError(f"association.max_radius: must be > 0, got {c.association.max_radius}")
    if c.association.reassociate < 0 or c.association.doppler_sigma_floor < 0:
        raise InputError("association.reassociate, association.doppler_sigma_floor: must be >= 0")
    # [standstill]: speed >= 0 (0 disables it), the sigmas > 0: config_rules.RULES
    for name in ("sigma_roll_rate", "sigma_pitch_rate", "sigma_lateral_velocity", "sigma_vertical_velocity"):
        if not getattr(c.vehicle, name) >= 0:
            unit = "rad/s" if name.endswith("rate") else "m/s"
            raise InputError(f"vehicle.{name}: must be >= 0 {unit} (0 disables it), "
                             f"got {getattr(c.vehicle, name)}")
    for name, ok, rule in (("doppler_update_probability", lambda x: 0 < x < 1, "in (0, 1)"),
                           ("consensus_switch_ratio", lambda x: x > 1, "> 1"),
                           ("consensus_switch_after", lambda x: x >= 0, ">= 0 s"),
                           ("consensus_voxel", lambda x: x > 0, "> 0 m"),
                           ("doppler_jerk_margin", lambda x: x > 0, "> 0 m/s")):
        value = getattr(c.association, name)
        if not ok(value):
            raise InputError(f"association.{name}: must be {rule}, got {value}")
    # [uncertainty]: every key's range is in config_rules.RULES
    if not c.outage.reinit_after >= 0:
        raise InputError(f"outage.reinit_after: must be >= 0 seconds, got {c.outage.reinit_after}")
    if c.map.max_age < 0 or c.map.voxel < 0:
        raise InputError("map.max_age, map.voxel: must be >= 0")
    if not isinstance(c.map.fuse, bool):
        raise InputError(f"map.fuse: must be true or false, got {c.map.fuse!r}")
    if c.map.max_fused < 0 or c.map.max_fused == 1:
        raise InputError(f"map.max_fused: must be 0 (no fading) or >= 2, got {c.map.max_fused}")
