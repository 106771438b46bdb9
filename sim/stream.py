"""A simulation streamed scan by scan: the scans of `sim.simulate.simulate`, generated one at a time, so that an
hour of driving (about 47,000 scans of ~900 detections) never sits in memory whole.

`simulate` builds every scan, then the per-detection truth (truth.npz: labels, world points, true polar
coordinates of every detection; about 80 bytes per detection, some 4 GB for an hour). A long run needs neither:
`stream` computes the same motion, mover states and radar scans in the same order from the same generator, and
yields each `RadarScan` as soon as it exists; only the per-scan truth (`t`, `T_vehicle_world`, `varpi`,
`varpi_dot`, as in truth.npz) is kept, a few hundred bytes per scan, and each mover's states only over the scans
where it is present.

Same inputs -> the same scans as `simulate`, bit for bit (the generator is consumed in the same order).
Faults that change the recorded scans (ghosts, dropped scans, jitter, outages) are drawn over the whole
sequence at once (`sim.faults.apply`) and are not streamed: apply them with `simulate`; clutter is the radar
config's (`Faults.radar`), so it streams.

Checked by: tests/validation/test_stream.py::test_streamed_scans_equal_the_simulated_ones
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from rodo.estimator.errors import InputError

from .radar import Radar, RadarConfig, empty_detections
from .sequence import RadarScan
from .sequence_types import SensorConfig
from .simulate import scan_times
from .trajectory import Profile
from .world import World


@dataclass
class StreamedSimulation:
    """A simulation whose scans are generated on demand.

    Attributes:
        sensor: the sensor of the recorded sequence (`RadarConfig.sensor_config()`).
        truth: per-scan truth arrays, as in truth.npz: t (K,), T_vehicle_world (K, 4, 4), varpi (K, 6),
            varpi_dot (K, 6), T_vehicle_sensor (4, 4); no per-detection arrays.
    """

    sensor: SensorConfig
    truth: dict
    _world: World
    _T_world_vehicle: np.ndarray
    _radar: Radar
    _rng: np.random.Generator
    _tracks: list
    _used: bool = False

    def __len__(self) -> int:
        return len(self.truth["t"])

    def scans(self) -> Iterator[RadarScan]:
        """The K scans in order, each built when asked for (empty ones too: a total blockage gives 0 rows).

        One pass only: the scans consume the radar's random generator, so a second pass would differ.
        """
        if self._used:
            raise InputError("stream: the scans of a streamed simulation can be iterated once (they consume "
                             "its random generator); stream the simulation again for a second pass")
        self._used = True
        t, varpi = self.truth["t"], self.truth["varpi"]
        for k, tk in enumerate(t):
            if self._world.blacked_out(tk):
                det = empty_detections(self._radar.config)
            else:
                movers = [(m, T[k - k0], v[k - k0], w[k - k0]) for m, k0, T, v, w in self._tracks
                          if k0 <= k < k0 + len(T)]
                det = self._radar.scan(self._world, self._T_world_vehicle[k], varpi[k], self._rng, movers)
            yield RadarScan(k, float(tk), det.range, det.azimuth, det.elevation, det.radial_velocity,
                            extra=det.extra())


def stream(world: World, profile: Profile, config: RadarConfig, rng: np.random.Generator,
           duration: float | None = None) -> StreamedSimulation:
    """The scans of `sim.simulate.simulate(world, profile, config, rng, duration)` (no faults), streamed.

    Args: as `simulate`: the scene, the ego trajectory, the radar, the generator of all measurement randomness
        (consumed scan by scan), seconds to simulate (default: the whole profile).

    Returns:
        StreamedSimulation: its `scans()` yields what `simulate` returns in `Sequence.scans`, one at a time.

    Checked by: tests/validation/test_stream.py::test_streamed_scans_equal_the_simulated_ones
    """
    duration = profile.duration if duration is None else float(duration)
    if not (0 < duration <= profile.duration + 1e-9):
        raise InputError(f"duration: must be in (0, {profile.duration:.3f}] s, got {duration}")
    t = scan_times(min(duration, profile.duration), config.rate_hz)
    motion = profile.sample(t)
    tracks = [_track(m, t) for m in world.movers]
    truth = {"t": motion.t, "T_vehicle_world": motion.T_vehicle_world, "varpi": motion.varpi,
             "varpi_dot": motion.varpi_dot, "T_vehicle_sensor": np.array(config.T_vehicle_sensor)}
    return StreamedSimulation(config.sensor_config(), truth, world, motion.T_world_vehicle, Radar(config), rng,
                              [tr for tr in tracks if tr is not None])


def _track(mover, t: np.ndarray):
    """(mover, k0, T_world_object, v_world, w_world) over the scans k0 .. k0 + n - 1 where the mover is present
    (an interval of scans: present means t_on <= t <= t_off), or None if it never is.

    Only the present rows are kept (`MovingBox.states` computes only those): a mover of an hour-long drive is
    present for about a minute, and keeping every row of the few hundred movers of such a drive would take
    gigabytes.
    """
    s = mover.states(t)
    k = np.flatnonzero(s.present)
    if not k.size:
        return None
    k0, k1 = int(k[0]), int(k[-1]) + 1
    if k.size != k1 - k0:
        raise InputError(f"stream: mover {mover.object_id} is present over several intervals; use simulate")
    return mover, k0, s.T_world_object[k0:k1].copy(), s.v_world[k0:k1].copy(), s.w_world[k0:k1].copy()
