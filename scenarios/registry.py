"""The explicit registry of named, versioned scenarios (no discovery by magic: `scenarios.definitions` calls
`register` for each one, then `seal`, which makes those built in: never replaced). A scenario of your own is
registered the same way, `register(Scenario(...))` (`replace=True` replaces one of yours of that name, e.g. when a
notebook cell runs again); the CLI sees it when its module is a plugin (`rodo --plugin MODULE`, RODO_PLUGINS:
docs/simulator.md, "Custom scenarios and sensor profiles").

A scenario is a small definition: name, version, one-line description, a builder of (trajectory profile,
world, radar config), estimator defaults (a plain dict), and its default extent: a path length (metres,
KITTI-style sequences) or a duration (short manoeuvres). A scenario may take keyword parameters (`params`,
e.g. `qc` of the prior-consistent scenarios), passed to its profile builder; `extra_truth` adds arrays about
the profile to the truth (e.g. the Qc used). Randomness: `SeedSequence(seed)` spawns three
independent streams (trajectory, world, radar), so the same seed gives the same bytes.

Checked by: tests/scenarios/test_registry.py, tests/scenarios/test_faults_scenarios.py (faults)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from rodo.estimator.errors import InputError
from rodo.estimator.registry import USER_ENTRIES, Registry
from rodo.sim import profiles
from rodo.sim.faults import Faults
from rodo.sim.radar import RadarConfig
from rodo.sim.simulate import simulate, write_simulation
from rodo.sim.trajectory import Profile
from rodo.sim.world import World

MARGIN = 5.0  # s of extra trajectory past the simulated duration (movers may look ahead)
MAX_DURATION = 3600.0  # s: a simulation's memory grows with its length (about 1 GB per hour of scans)


@dataclass(frozen=True)
class Parts:
    """What a scenario builds for one seed: ego profile, world, radar, and the duration to simulate."""

    profile: Profile
    world: World
    radar: RadarConfig
    duration: float


@dataclass(frozen=True)
class Scenario:
    """A named, versioned scenario.

    Attributes:
        name, version, description: identity (bump the version whenever the output for a seed changes).
        profile: (rng, duration) -> Profile, the ego trajectory covering at least `duration` seconds.
        world: (rng, profile, duration) -> World built around the route.
        radar: () -> RadarConfig.
        estimator_defaults: plain dict of estimator settings suited to the scenario.
        length: default path length in metres (the duration is chosen to drive it), or None.
        duration: default duration in seconds when `length` is None.
        params: names of the keyword parameters the profile builder accepts (e.g. ("qc",)); None = default.
        extra_truth: optional (profile) -> dict of arrays added to the truth (truth.npz).
        sensor_profile: the sensor profile (`sim.profiles`) the scenario uses by default; "generic" is its own
            `radar()`.
    """

    name: str
    version: int
    description: str
    profile: Callable
    world: Callable
    radar: Callable = RadarConfig
    estimator_defaults: dict = field(default_factory=dict)
    length: float | None = None
    duration: float | None = None
    params: tuple[str, ...] = ()
    extra_truth: Callable | None = None
    sensor_profile: str = profiles.DEFAULT

    def __post_init__(self):
        given = [x is not None for x in (self.length, self.duration)]
        if sum(given) != 1:
            raise InputError(f"scenario {self.name!r}: give one of length (m) or duration (s), got length "
                             f"{self.length!r}, duration {self.duration!r}")
        value = self.length if given[0] else self.duration
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value > 0):
            raise InputError(f"scenario {self.name!r}: {'length' if given[0] else 'duration'} must be a positive "
                             f"number, got {value!r}")

    def radar_config(self, sensor_profile: str | None = None) -> RadarConfig:
        """The radar of sensor profile `sensor_profile` (None: the scenario's own; "generic": `radar()`);
        InputError listing the known profiles for an unknown name."""
        name = self.sensor_profile if sensor_profile is None else sensor_profile
        return self.radar() if profiles.get(name).name == profiles.DEFAULT else profiles.radar_config(name)

    def _radar(self, parts: "Parts", sensor_profile: str | None) -> RadarConfig:
        """The radar of a simulation: the built parts' own unless a sensor profile other than the default is
        asked for (or is the scenario's)."""
        if sensor_profile is None and self.sensor_profile == profiles.DEFAULT:
            return parts.radar
        return self.radar_config(sensor_profile)

    def _rngs(self, seed: int):
        return [np.random.default_rng(s) for s in _streams(seed)[:3]]

    def _params(self, params: dict) -> dict:
        """The given parameters, checked against `params` (InputError naming an unknown one); None dropped."""
        for key in params:
            if key not in self.params:
                takes = ", ".join(self.params) if self.params else "none"
                raise InputError(f"{key}: scenario {self.name!r} takes no parameter {key!r} (it takes: {takes})")
        return {k: v for k, v in params.items() if v is not None}

    def default_duration(self, seed: int, **params) -> float:
        """The duration that drives `length` metres for this seed (or the fixed `duration`)."""
        if self.length is None:
            return float(self.duration)
        rng = self._rngs(seed)[0]
        guess = 60.0
        while True:  # profiles extend the same random draw, so a longer profile has the same prefix
            profile = self.profile(rng, guess, **self._params(params))
            if profile.path_length() >= self.length:
                break
            if guess >= MAX_DURATION:  # a profile that never gets there (one of fixed length, or standing still)
                raise InputError(f"scenario {self.name!r}: its trajectory covers {profile.path_length():.0f} m of its "
                                 f"{self.length:g} m length within {profile.duration:g} s; give a duration, or a "
                                 "profile(rng, duration) that covers the duration asked")
            guess *= 2
            rng = self._rngs(seed)[0]
        lo, hi = 0.0, profile.duration
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if profile.path_length(mid) < self.length else (lo, mid)
        return float(np.ceil(hi * 10) / 10)

    def build(self, seed: int, duration: float | None = None, **params) -> Parts:
        """Profile, world and radar for `seed` (same seed and parameters -> identical parts)."""
        params = self._params(params)
        number = isinstance(duration, (int, float, np.integer, np.floating)) and not isinstance(duration, bool)
        if duration is not None and not (number and np.isfinite(duration) and duration > 0):
            raise InputError(f"duration: must be a positive number of seconds, got {duration!r}")
        if duration is not None and duration > MAX_DURATION:  # bounded before anything is allocated
            raise InputError(f"duration: at most {MAX_DURATION:g} s (one hour) per simulation, got {duration:g} s; "
                             "simulate shorter sequences (or several seeds)")
        duration = self.default_duration(seed, **params) if duration is None else float(duration)
        rng_traj, rng_world, _ = self._rngs(seed)
        profile = self.profile(rng_traj, duration + MARGIN, **params)
        world = self.world(rng_world, profile, duration)
        return Parts(profile, world, self.radar(), duration)

    def simulate(self, seed: int, duration: float | None = None, progress=None, radar: RadarConfig | None = None,
                 faults: Faults | None = None, sensor_profile: str | None = None, **params):
        """Simulate the scenario: returns (Sequence, truth dict) (see sim.simulate.simulate).

        `radar` overrides the scenario's radar, e.g. `RadarConfig().noise_free()` for model checks;
        `sensor_profile` names a sensor profile (`sim.profiles`, e.g. "lrr30f") instead; `faults`
        (`sim.faults.Faults`, default off) injects clutter, ghosts, dropped scans, jitter and outages, drawn
        from a fourth stream `SeedSequence(seed).spawn(4)[3]` (the first three are the clean streams, so the
        clean output is unchanged); `params` are the scenario's own parameters (e.g. `qc=` for prior_ca)."""
        faults = _faults(faults)
        parts = self.build(seed, duration, **params)
        config = faults.radar(self._radar(parts, sensor_profile) if radar is None else radar)
        faults.check_rate(config.rate_hz)  # before the simulation
        rng_radar = self._rngs(seed)[2]
        seq, truth = simulate(parts.world, parts.profile, config, rng_radar, parts.duration, progress,
                              faults, _streams(seed)[3])
        if self.extra_truth is not None:
            truth.update(self.extra_truth(parts.profile))
        return seq, truth

    def simulate_rig(self, seed: int, layout: str, duration: float | None = None, progress=None,
                     sensor_profile: str | None = None, faults: Faults | None = None,
                     **params) -> list[tuple[str, object, dict]]:
        """Several radars on the vehicle (`sim.rig.LAYOUTS[layout]`) on one drive: [(name, Sequence, truth)].

        The same world and trajectory for every radar; radar i has its layout mount and its own random streams
        (the first radar the scenario's, so a layout's "front" radar is `simulate(seed)` bit for bit, faults
        included) and scans i / (n rate) s after the first, so the n radars take turns. `faults` apply to every
        radar, each drawing its own.
        """
        from rodo.sim.rig import LAYOUTS
        if layout not in LAYOUTS:
            raise InputError(f"rig: unknown layout {layout!r}; known layouts: {', '.join(LAYOUTS)}")
        faults = _faults(faults)
        parts = self.build(seed, duration, **params)
        base = faults.radar(self._radar(parts, sensor_profile))
        faults.check_rate(base.rate_hz)
        out = []
        for i, (name, mount) in enumerate(LAYOUTS[layout]):
            config = base if mount is None else dataclasses.replace(base, T_vehicle_sensor=mount)
            if i == 0:  # the scenario's own radar and fault streams
                radar_seed, fault_seed = _streams(seed)[2:4]
            else:
                radar_seed, fault_seed = (np.random.SeedSequence(int(seed), spawn_key=(key + i,)) for key in (100, 200))
            rng = np.random.default_rng(radar_seed)
            offset = i / (len(LAYOUTS[layout]) * config.rate_hz)
            seq, truth = simulate(parts.world, parts.profile, config, rng, parts.duration, progress,
                                  faults, fault_seed, t_offset=offset)
            if self.extra_truth is not None:
                truth.update(self.extra_truth(parts.profile))
            out.append((name, seq, truth))
        return out

    def summary(self) -> str:
        extent = f"{self.length:.0f} m" if self.length is not None else f"{self.duration:.0f} s"
        return f"{self.name:<16} v{self.version:<3} {extent:>7}  {self.description}"


def _faults(faults) -> Faults:
    """`faults` or no faults; InputError for anything but a Faults (the CLI's text form goes through parse_faults)."""
    if faults is None:
        return Faults()
    if not isinstance(faults, Faults):
        raise InputError(f"faults: expected a sim.faults.Faults (sim.faults.parse_faults turns the CLI's "
                         f"'NAME=VALUE' texts into one), got {type(faults).__name__} {faults!r}")
    return faults


def _streams(seed: int) -> list[np.random.SeedSequence]:
    """SeedSequence(seed).spawn(4): trajectory, world, radar, faults (spawn(3) gives the same first three)."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0, got {seed!r}")
    return np.random.SeedSequence(int(seed)).spawn(4)


_REGISTRY: Registry[Scenario] = Registry("scenario", hint=USER_ENTRIES)
register = _REGISTRY.register  # register(scenario, replace=False); a built-in one is never replaced
seal = _REGISTRY.seal  # once, by scenarios.definitions: the scenarios registered so far are the built-in ones
names = _REGISTRY.names  # in registration order
get = _REGISTRY.get  # InputError listing the known names for an unknown one


def simulate_rig_to(name: str, seed: int, out_dir, layout: str, duration: float | None = None, progress=None,
                    faults: Faults | None = None, **params):
    """Simulate scenario `name` with the radars of rig `layout` and write a rig directory (docs/sequence_format.md,
    "Rigs"): each radar's sequence and truth in its sub-directory, rig.toml. Returns [(name, Sequence, truth)]."""
    from rodo.sim.rig import write_rig_toml
    radars = get(name).simulate_rig(seed, layout, duration, progress, faults=faults, **params)
    for radar, seq, truth in radars:
        write_simulation(Path(out_dir) / radar, seq, truth)
    write_rig_toml(out_dir, [r[0] for r in radars])
    return radars


def simulate_to(name: str, seed: int, out_dir, duration: float | None = None, progress=None,
                faults: Faults | None = None, sensor_profile: str | None = None, **params):
    """Simulate scenario `name` with `seed` (its `params`, e.g. qc=, optional `faults` and sensor profile) and
    write the sequence directory (radar.csv, sensor.toml, groundtruth.txt, truth.npz) to out_dir. Returns
    (Sequence, truth)."""
    scenario = get(name)
    seq, truth = scenario.simulate(seed, duration, progress, faults=faults, sensor_profile=sensor_profile, **params)
    write_simulation(Path(out_dir), seq, truth)
    return seq, truth
