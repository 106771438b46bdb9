"""Sensor faults injected into a simulated sequence: clutter rate, ghost detections, dropped scans, timestamp
jitter and outages (docs/simulator.md, "Faults"). All are off by default, and off they change nothing: the
clean simulation is bit-identical with or without this module.

- clutter: the radar's own false-alarm model (`RadarConfig.clutter_rate`, Poisson per scan, uniform in the
  field of view and range) with the given rate; it replaces the scenario's rate, so it draws from the radar's
  stream (the other scans' detections then differ from the clean run's).
- ghosts: multipath ghosts, Poisson(rate) per scan: a copy of a real (non-clutter) detection of the scan at a
  longer range (a second bounce: range + U(GHOST_OFFSET) m, same azimuth, elevation, radial velocity);
  label GHOST; dropped beyond max_range.
- dropped: each scan missing from radar.csv with probability p (ground truth keeps every vehicle state).
- jitter: the recorded scan time is t_k + e_k, e_k ~ N(0, sigma^2) truncated (clipped) to +-0.45 scan periods,
  so recorded times stay strictly increasing (consecutive gaps >= 0.1 period); the measurement geometry stays
  at the true t_k; sigma is at most 0.15 periods (3 sigma inside the clip).
- outage: intervals START:DURATION (s) during which scans are empty (no radar.csv rows).
- outages: RATE:DURATION, outages at RATE per minute (a Poisson process: the count over the sequence is
  Poisson(RATE / 60 * span), the starts uniform over it), each DURATION s long; empty like `outage`.
- doppler_common: SIGMA[:RHO], an error common to every radial velocity of a scan, as a wrong sensor velocity
  b_k would give (v_r += -u . b_k, u the detection's true direction): b_k a 3-vector in the sensor frame,
  AR(1) from scan to scan, b_k = RHO b_k-1 + sqrt(1 - RHO^2) SIGMA e_k (stationary: SIGMA per axis; RHO 0.9
  unless given). Real radars show it (RadarScenes: 0.03-0.08 m/s, lag-1 0.56-0.97, docs/realdata.md).

Randomness: ghosts, dropped scans, jitter and the outage starts draw from their own generators, spawned from a fault
SeedSequence that is independent of the trajectory, world and radar streams; turning one of them on leaves
the clean detections (and the other faults' draws) unchanged.

Checked by: tests/sim/test_faults.py, tests/scenarios/test_faults_scenarios.py
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from rodo.estimator.errors import InputError

from .objects import CLUTTER, GHOST
from .radar import Detections, RadarConfig

GHOST_OFFSET = (1.0, 10.0)  # m: extra range of a ghost over the detection it copies
JITTER_CLIP = 0.45  # scan periods: the recorded-time perturbation is clipped to +- this
JITTER_MAX = 0.15  # scan periods: the largest sigma accepted
MAX_RATE = 10_000.0  # per scan: clutter and ghost rates above this are refused (memory)
MAX_OUTAGE_RATE = 600.0  # outages per minute (10 per second): higher rates are refused
DOPPLER_RHO = 0.9  # default scan-to-scan correlation of the common Doppler error
NAMES = ("clutter", "ghosts", "dropped", "jitter", "outage", "outages", "doppler_common")


@dataclass(frozen=True)
class Faults:
    """Fault settings; the defaults are all off.

    Attributes:
        clutter: false alarms per scan (None: the scenario radar's own rate).
        ghosts: multipath ghosts per scan (Poisson mean).
        dropped: probability that a scan is missing.
        jitter: 1-sigma timestamp jitter, s.
        outage: ((start, duration), ...) in seconds: scans in [start, start + duration) are empty.
        outages: (rate per minute, duration s) of random outages, or None (`outage_intervals`).
        doppler_common: (sigma m/s, rho) of the scans' common Doppler error, or None (`common_doppler_errors`).
    """

    clutter: float | None = None
    ghosts: float = 0.0
    dropped: float = 0.0
    jitter: float = 0.0
    outage: tuple = ()
    outages: tuple | None = None
    doppler_common: tuple | None = None

    def __post_init__(self):
        if self.clutter is not None:
            _check("clutter", self.clutter, 0.0, MAX_RATE, "false alarms per scan")
        _check("ghosts", self.ghosts, 0.0, MAX_RATE, "ghosts per scan")
        _check("dropped", self.dropped, 0.0, 1.0, "probability", hi_open=True)
        _check("jitter", self.jitter, 0.0, 1.0, "sigma in seconds")
        try:
            outage = tuple((start, duration) for start, duration in self.outage)
        except (TypeError, ValueError):
            raise InputError(f"--fault outage: expected (start, duration) pairs in seconds, got {self.outage!r}") \
                from None
        object.__setattr__(self, "outage", outage)
        for start, duration in outage:
            _check("outage", start, 0.0, np.inf, "start in seconds", hi_open=True)
            _check("outage", duration, 0.0, np.inf, "duration in seconds", lo_open=True, hi_open=True)
        if self.outages is not None:
            rate, duration = _pair("outages", self.outages, "(rate per minute, duration in seconds)")
            _check("outages", rate, 0.0, MAX_OUTAGE_RATE, "rate per minute")
            _check("outages", duration, 0.0, np.inf, "duration in seconds", lo_open=True, hi_open=True)
            object.__setattr__(self, "outages", (float(rate), float(duration)))
        if self.doppler_common is not None:
            sigma, rho = _pair("doppler_common", self.doppler_common, "(sigma in m/s, rho)")
            _check("doppler_common", sigma, 0.0, 10.0, "sigma in m/s")
            _check("doppler_common", rho, 0.0, 1.0, "scan-to-scan correlation rho", hi_open=True)
            object.__setattr__(self, "doppler_common", (float(sigma), float(rho)))

    @property
    def active(self) -> bool:
        """True when anything differs from the clean simulation."""
        return self != Faults()

    @property
    def changes_scans(self) -> bool:
        """True when ghosts, dropped scans, jitter or outages are on (clutter lives in the radar config)."""
        return replace(self, clutter=None).active

    def radar(self, config: RadarConfig) -> RadarConfig:
        """The radar with the clutter rate applied (the same object when clutter is not set)."""
        return config if self.clutter is None else replace(config, clutter_rate=float(self.clutter))

    def check_duration(self, duration: float) -> None:
        """InputError naming --fault outage and the duration when an outage starts after the simulation ends
        (START > duration): it would empty no scan, a fault asked for and silently not applied."""
        for start, length in self.outage:
            if start > duration:
                raise InputError(f"--fault outage={start:g}:{length:g}: starts after the end of the simulated "
                                 f"{duration:g} s (--duration), so it would empty no scan; start it before "
                                 f"{duration:g} s or simulate longer")

    def check_rate(self, rate_hz: float) -> None:
        """The jitter bound depends on the scan period: sigma <= JITTER_MAX periods."""
        if self.jitter > JITTER_MAX / rate_hz:
            raise InputError(f"--fault jitter: sigma must be at most {JITTER_MAX} scan periods "
                             f"({JITTER_MAX / rate_hz:.4g} s at {rate_hz:g} Hz), got {self.jitter!r}")


def _pair(name: str, value, form: str) -> tuple:
    """The two elements of `--fault name`'s value, or an InputError saying the expected form."""
    try:
        first, second = value
    except (TypeError, ValueError):
        raise InputError(f"--fault {name}: expected {form}, got {value!r}") from None
    return first, second


def _check(name, value, lo, hi, what, lo_open=False, hi_open=False) -> None:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if ok:
        value = float(value)
        ok = (np.isfinite(value) and (value > lo if lo_open else value >= lo)
              and (value < hi if hi_open else value <= hi))
    if not ok:
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise InputError(f"--fault {name}: {what} must be a finite number in {interval}, got {value!r}")


def parse_fault(text: str, faults: Faults) -> Faults:
    """One `--fault NAME=VALUE` on top of `faults` (outage intervals accumulate): InputError naming it."""
    name, sep, value = str(text).partition("=")
    name = name.strip()
    if not sep or name not in NAMES:
        raise InputError(f"--fault: expected NAME=VALUE with NAME one of {', '.join(NAMES)}, got {text!r}")
    if name == "doppler_common":
        first, sep, rho = value.partition(":")
        try:
            pair = (float(first), float(rho) if sep else DOPPLER_RHO)
        except ValueError:
            raise InputError(f"--fault doppler_common: expected SIGMA or SIGMA:RHO (m/s, correlation in [0, 1)), "
                             f"got {value!r}") from None
        return replace(faults, doppler_common=pair)
    if name in ("outage", "outages"):
        first, sep, duration = value.partition(":")
        try:
            pair = (float(first), float(duration))
        except ValueError:
            sep = ""
        if not sep:
            form = "START:DURATION in seconds (e.g. 5.0:2.0)" if name == "outage" else \
                "RATE:DURATION, outages per minute and seconds each (e.g. 2:1.5)"
            raise InputError(f"--fault {name}: expected {form}, got {value!r}")
        if name == "outages":
            return replace(faults, outages=pair)
        return replace(faults, outage=faults.outage + (pair,))
    try:
        number = float(value)
    except ValueError:
        raise InputError(f"--fault {name}: expected a number, got {value!r}") from None
    return replace(faults, **{name: number})


def parse_faults(texts) -> Faults:
    """A list of `--fault NAME=VALUE` strings -> Faults (a later value of the same name wins)."""
    faults = Faults()
    for text in texts or ():
        faults = parse_fault(text, faults)
    return faults


@dataclass(frozen=True)
class Faulted:
    """The result of `apply`: per scan the detections, the recorded time and whether the scan was dropped."""

    dets: list
    t_recorded: np.ndarray
    dropped: np.ndarray


def apply(faults: Faults, dets: list, t: np.ndarray, config: RadarConfig,
          seed_seq: np.random.SeedSequence) -> Faulted:
    """Apply ghosts, outages, dropped scans and jitter to the clean per-scan detections (not mutated).

    Args:
        faults: the settings (clutter is already in the radar: `Faults.radar`).
        dets: (K,) list of `Detections`, one per scan at the true times t.
        t: (K,) true scan times.
        config: the radar (field of view, range and rate).
        seed_seq: the fault SeedSequence; spawns the ghost, dropped, jitter, outage and Doppler generators
            (spawn(5) gives the same first four as spawn(4): adding a generator changed no earlier draw).
    """
    rng_ghost, rng_drop, rng_jitter, rng_outage, rng_doppler = [np.random.default_rng(s) for s in seed_seq.spawn(5)]
    if len(t):
        faults.check_duration(float(t[-1]) + 1.0 / config.rate_hz)  # the CLI checks --duration itself, first
    intervals = faults.outage
    if faults.outages is not None and len(t):
        intervals = intervals + outage_intervals(*faults.outages, t[0], t[-1] + 1.0 / config.rate_hz, rng_outage)
    bias = None if faults.doppler_common is None else common_doppler_errors(len(dets), *faults.doppler_common,
                                                                              rng_doppler)
    out = []
    for k, det in enumerate(dets):
        if bias is not None:
            det = add_common_doppler_error(det, bias[k])
        if faults.ghosts > 0:
            det = add_ghosts(det, faults.ghosts, config, rng_ghost)
        if any(start <= t[k] < start + duration for start, duration in intervals):
            det = _subset(det, np.zeros(0, dtype=int))
        out.append(det)
    dropped = rng_drop.random(len(t)) < faults.dropped if faults.dropped > 0 else np.zeros(len(t), bool)
    return Faulted(out, jittered_times(t, faults.jitter, config.rate_hz, rng_jitter), dropped)


def outage_intervals(rate_per_min: float, duration: float, t0: float, t1: float,
                     rng: np.random.Generator) -> tuple[tuple[float, float], ...]:
    """Random outages over [t0, t1): a Poisson process of `rate_per_min` per minute, i.e. a count
    ~ Poisson(rate_per_min / 60 * (t1 - t0)) and starts uniform in [t0, t1), sorted; each `duration` s long.

    Checked by: tests/sim/test_faults.py::test_outages_at_a_rate_count_close_to_the_rate
    """
    n = rng.poisson(rate_per_min / 60.0 * max(t1 - t0, 0.0))
    starts = np.sort(rng.uniform(t0, t1, n))
    return tuple((float(s), float(duration)) for s in starts)


def jittered_times(t: np.ndarray, sigma: float, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """t + clip(N(0, sigma^2), +-JITTER_CLIP / rate_hz): strictly increasing for scans 1 / rate_hz apart."""
    if sigma <= 0:
        return np.array(t, dtype=float)
    clip = JITTER_CLIP / rate_hz
    return t + np.clip(sigma * rng.standard_normal(len(t)), -clip, clip)


def common_doppler_errors(n: int, sigma: float, rho: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) sensor-velocity errors of n scans, AR(1): b_0 ~ N(0, sigma^2 I), b_k = rho b_k-1 + sqrt(1 - rho^2)
    sigma e_k (stationary: sigma per axis, lag-1 correlation rho).

    Checked by: tests/sim/test_faults.py::test_common_doppler_error_is_one_sensor_velocity_error_per_scan
    """
    e = rng.standard_normal((n, 3)) * sigma
    b = np.empty((n, 3))
    for k in range(n):
        b[k] = e[k] if k == 0 else rho * b[k - 1] + np.sqrt(1.0 - rho * rho) * e[k]
    return b


def add_common_doppler_error(det: Detections, b: np.ndarray) -> Detections:
    """The scan's detections with v_r - u . b, u the unit direction of each detection's true azimuth and
    elevation (a sensor that believes its velocity is off by b measures every static target so)."""
    az, el = det.true_polar[:, 1], det.true_polar[:, 2]
    u_b = np.cos(el) * (np.cos(az) * b[0] + np.sin(az) * b[1]) + np.sin(el) * b[2]
    return replace(det, radial_velocity=det.radial_velocity - u_b)


def add_ghosts(det: Detections, rate: float, config: RadarConfig, rng: np.random.Generator) -> Detections:
    """Poisson(rate) ghosts: copies of random real detections at range + U(GHOST_OFFSET), inserted at random
    positions; ghosts beyond max_range are not reported. A scan without real detections gets none."""
    real = np.flatnonzero(det.label != CLUTTER)
    n = rng.poisson(rate)
    if n == 0 or real.size == 0:
        return det
    src = rng.choice(real, size=n)
    offset = rng.uniform(*GHOST_OFFSET, n)
    keep = det.range[src] + offset <= config.max_range
    src, offset = src[keep], offset[keep]
    m = len(src)
    true = det.true_polar[src].copy()
    true[:, 0] += offset
    optional = {f: None if getattr(det, f) is None else getattr(det, f)[src] for f in _OPTIONAL}
    ghost = Detections(det.range[src] + offset, det.azimuth[src], det.elevation[src], det.radial_velocity[src],
                       np.full(m, GHOST, dtype=det.label.dtype), np.full(m, -1), np.full(m, -1),
                       np.full((m, 3), np.nan), true, **optional)
    perm = rng.permutation(len(det) + m)
    return _subset(_concat(det, ghost), perm)


_FIELDS = ("range", "azimuth", "elevation", "radial_velocity", "label", "object_id", "landmark_id", "p_world",
           "true_polar")
_OPTIONAL = ("rcs", "snr")  # physical radars (sensor profiles): a ghost fault reports its source's values


def _concat(a: Detections, b: Detections) -> Detections:
    optional = {f: None if getattr(a, f) is None else np.concatenate([getattr(a, f), getattr(b, f)])
                for f in _OPTIONAL}
    return Detections(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in _FIELDS), **optional)


def _subset(det: Detections, idx: np.ndarray) -> Detections:
    optional = {f: None if getattr(det, f) is None else getattr(det, f)[idx] for f in _OPTIONAL}
    return Detections(*(getattr(det, f)[idx] for f in _FIELDS), **optional)


__all__ = ["GHOST", "Faulted", "Faults", "add_common_doppler_error", "add_ghosts", "apply", "common_doppler_errors",
           "jittered_times", "outage_intervals", "parse_fault", "parse_faults"]
