"""Named, versioned sensor profiles: a radar's field of view, rates, resolutions, accuracies and radar-equation
parameters (`sim.radar_physics.RadarPhysics`) as a `RadarConfig`, with the source of every number.

`generic` is the simulator's own imaging radar (`RadarConfig()`, no radar equation): every scenario uses it
unless told otherwise, and its output is bit-identical to the simulator before profiles existed. The others
are shaped like real sensors whose recordings are in ../shared/realdata (docs/realism.md compares them):

| profile | sensor | real data |
| --- | --- | --- |
| `lrr30f` | Hasco LRR30-F 77 GHz 4D imaging radar | RaFlow demo data (Shanghai, GNSS/INS) |
| `iwr6843aop` | TI IWR6843AOP 60 GHz single-chip radar (3 Tx, 4 Rx, antenna on package) | rio demo (handheld) |
| `corner2d` | a 77 GHz series corner radar, 2D (range, azimuth, Doppler, RCS) | RadarScenes sequence 105 (radar 3) |

Numbers are marked in the definitions: *datasheet* (a public data sheet or the dataset's paper), *data* (read off
the recording itself, e.g. a quantisation step), *calibrated* (tuned so that `rodo realism` matches the real
data; docs/realism.md gives the statistics), *assumed* (not published; a plausible value). Bump a profile's
version whenever its output for a seed changes. A profile of your own: `register(SensorProfile(...))` under a name of
its own (the built-in ones are sealed, never replaced; docs/simulator.md, "Custom scenarios and sensor profiles").

Checked by: tests/sim/test_profiles.py
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from rodo.estimator.registry import USER_ENTRIES, Registry

from .radar import RadarConfig
from .sensor_geometry import DEG, mount
from .radar_physics import RadarPhysics

DEFAULT = "generic"


@dataclass(frozen=True)
class SensorProfile:
    """A named, versioned radar.

    Attributes:
        name, version, description: identity (bump the version whenever the output for a seed changes).
        sources: where the numbers come from (data sheets, papers, the recordings).
        config: () -> RadarConfig, the sensor (a fresh object each call).
        points_per_scan: (low, high) detections per scan of the real sensor (data sheet or recording), or None.
    """

    name: str
    version: int
    description: str
    sources: str
    config: Callable[[], RadarConfig]
    points_per_scan: tuple | None = None

    def summary(self) -> str:
        return f"{self.name:<12} v{self.version:<3} {self.description}"


_REGISTRY: Registry[SensorProfile] = Registry("sensor profile", "profiles", USER_ENTRIES)
register = _REGISTRY.register  # register(profile, replace=False); a built-in profile is never replaced
names = _REGISTRY.names  # in registration order (the default first)
get = _REGISTRY.get  # rodo.estimator.errors.InputError listing the known profiles for an unknown name


def radar_config(name: str | None) -> RadarConfig:
    """The RadarConfig of profile `name` (None: the default)."""
    return get(DEFAULT if name is None else name).config()


def _lrr30f() -> RadarConfig:
    """Hasco LRR30-F. Datasheet (as quoted by RaFlow, Ding et al., RA-L 2022, and the data's README): 76-77 GHz,
    azimuth +-60 deg, elevation +-10 deg, radial velocity resolution 0.13 m/s. Data: ~12 Hz raw rate (README),
    RCS reported in 0.5 dB steps, |v_r| up to 26 m/s without wrap-around (no ambiguity modelled), ranges up to
    78 m in the demo data, 13 % of the detections without elevation (reported 0), heights in the radar frame
    falling with range (a frame pitched up ~3.5 deg). Assumed: range resolution 0.2 m, beam widths 2 x 4 deg
    (noise), accuracy floors. Calibrated (`rodo realism lrr30f`, docs/realism.md): snr_1m_db, the RCS classes,
    the beam pattern (60 x 6.25 deg, centred 3.3 deg below the reported boresight), the mount's pitch, the cell
    grid, surface fill and its saturation range, clutter rate, ghost rate."""
    physics = RadarPhysics(
        snr_1m_db=94.3, pfa=1e-4,
        rcs_dbsm={"ground": (-35.0, 5.0), "facade": (-6.0, 6.0), "metal": (-5.0, 6.0), "point": (2.0, 5.0),
                  "vehicle": (5.6, 6.0)},
        range_resolution=0.2, velocity_resolution=0.13, beamwidth=(2.0 * DEG, 4.0 * DEG), rcs_step_db=0.5,
        ghost_prob=0.4, ghost_loss_db=6.0, ghost_min_area=1.0, pattern=(60.0 * DEG, 6.25 * DEG),
        pattern_tilt=-3.3 * DEG, elevation_missing=0.13)
    return RadarConfig(rate_hz=12.0, T_vehicle_sensor=mount(3.7, 0.0, 0.5, pitch=3.75 * DEG),
                       sigmas=(0.1, 0.3 * DEG, 0.6 * DEG, 0.02),
                       azimuth_fov=(-60 * DEG, 60 * DEG), elevation_fov=(-10 * DEG, 10 * DEG), min_range=0.5,
                       max_range=250.0, cell_azimuth=0.5 * DEG, cell_elevation=1.0 * DEG, surface_fill=0.8,
                       min_density_range=40.0, clutter_rate=40.0, clutter_speed=20.0, physics=physics)


def _iwr6843aop() -> RadarConfig:
    """TI IWR6843AOP (IWR6843AOP data sheet SWRS240, and the AOP EVM user guide SWRU546): 60-64 GHz (4 GHz:
    range resolution c / 2B = 3.75 cm at full bandwidth), 3 Tx x 4 Rx antenna on package, field of view about
    +-60 deg in azimuth and elevation, angular resolution about 29 deg (4 virtual elements per axis: 2 / N rad).
    Data (rio demo): ~10.2 Hz, Doppler quantised in 0.125 m/s steps, SNR ('intensity') in 0.1 dB steps from
    ~6 dB (the CFAR threshold), ranges 0.47-19 m (the demo's 20 m configuration). Assumed: 64 Doppler bins
    (unambiguous +-4 m/s), accuracy floors, ghost rate. Data: the direction of motion in the sensor frame (from the
    recording's own Doppler fits: azimuth -63 deg, -87 to -30; elevation +7 deg), which sets the mount's yaw and
    pitch roughly. Calibrated (`rodo realism iwr6843aop`, docs/realism.md): snr_1m_db, the RCS classes, the beam
    pattern (76 x 35 deg, centred 7 deg above the reported boresight), the Doppler and angle precision terms
    (velocity_resolution 0.06 m/s: the peak's bin, not an interpolated estimate; beam width 6 deg for the noise,
    finer than the 29 deg resolution), the mount (yawed 60 deg left, pitched 11.2 deg down), the cell grid,
    surface fill and clutter rate."""
    physics = RadarPhysics(
        snr_1m_db=54.0, pfa=float(np.exp(-4.0)),
        rcs_dbsm={"ground": (-18.2, 6.0), "facade": (-17.2, 6.0), "metal": (-2.0, 6.0), "point": (-4.5, 5.0),
                  "vehicle": (2.0, 6.0)},
        range_resolution=0.044, velocity_resolution=0.06, beamwidth=(6.0 * DEG, 6.0 * DEG),
        doppler_max=4.0, doppler_step=0.125, snr_step_db=0.1, ghost_prob=0.01, ghost_loss_db=6.0,
        ghost_min_area=1.0, pattern=(75.7 * DEG, 35.0 * DEG), pattern_tilt=7.0 * DEG)
    return RadarConfig(rate_hz=10.24, T_vehicle_sensor=mount(0.3, 0.0, 0.6, yaw=60.0 * DEG, pitch=-11.2 * DEG),
                       sigmas=(0.03, 1.0 * DEG, 2.0 * DEG, 0.0),
                       azimuth_fov=(-70 * DEG, 70 * DEG), elevation_fov=(-45 * DEG, 45 * DEG), min_range=0.3,
                       max_range=20.0, cell_azimuth=2.5 * DEG, cell_elevation=2.0 * DEG, surface_fill=1.2,
                       clutter_rate=1.75, clutter_speed=4.0, physics=physics)


def _corner2d() -> RadarConfig:
    """A RadarScenes-like 77 GHz series corner radar (Schumann et al., FUSION 2021: four radars at the car's
    front corners, 2D: range, azimuth, Doppler, RCS). Data (sequence 105 export, radar3): ~13 Hz, mount 3.86 m
    forward, 0.70 m left, yawed 0.436 rad; static-point Doppler residual MAD 0.06-0.09 m/s; 140-365 detections
    per scan (5-95 %). Assumed (series radars of this class): azimuth +-75 deg, range 100 m, range resolution
    0.15 m, beam width 4 deg, vertical beam +-8 deg (elevation not reported). Calibrated (`rodo realism corner2d`,
    docs/realism.md): snr_1m_db, the RCS classes, the beam pattern (77 x 5.6 deg, centred 1.8 deg up), the mount's
    pitch (2.1 deg up), detection cells of 0.5 deg x 0.5 m (`range_cell`: several detections per object along
    the range), surface fill and its saturation range, clutter and ghost rates."""
    physics = RadarPhysics(
        snr_1m_db=93.6, pfa=1e-4,
        rcs_dbsm={"ground": (-30.0, 5.0), "facade": (-8.5, 6.0), "metal": (-5.0, 6.0), "point": (-5.8, 5.0),
                  "vehicle": (3.6, 6.0)},
        range_resolution=0.15, velocity_resolution=0.1, beamwidth=(4.0 * DEG, 16.0 * DEG),
        report_elevation=False, ghost_prob=0.008, pattern=(77.4 * DEG, 5.64 * DEG), pattern_tilt=1.8 * DEG,
        range_cell=0.5)
    return RadarConfig(rate_hz=13.0, T_vehicle_sensor=mount(3.86, 0.70, 0.5, yaw=0.436, pitch=2.1 * DEG),
                       sigmas=(0.1, 0.3 * DEG, 10.0 * DEG, 0.03), azimuth_fov=(-75 * DEG, 75 * DEG),
                       elevation_fov=(-8 * DEG, 8 * DEG), min_range=0.5, max_range=100.0, cell_azimuth=0.5 * DEG,
                       cell_elevation=16.0 * DEG, surface_fill=7.9, min_density_range=28.6, clutter_rate=5.3,
                       physics=physics)


GENERIC = register(SensorProfile(
    DEFAULT, 1, "the simulator's generic 4D imaging radar (RadarConfig(); no radar equation)",
    "docs/simulator.md (Radar)", RadarConfig))
LRR30F = register(SensorProfile(
    "lrr30f", 1, "Hasco LRR30-F-like 77 GHz 4D imaging radar, radar equation, calibrated on the RaFlow demo data",
    _lrr30f.__doc__, _lrr30f, points_per_scan=(260, 477)))
IWR6843AOP = register(SensorProfile(
    "iwr6843aop", 1, "TI IWR6843AOP-like 60 GHz single-chip radar, 20 m, calibrated on the rio demo",
    _iwr6843aop.__doc__, _iwr6843aop, points_per_scan=(19, 87)))
CORNER2D = register(SensorProfile(
    "corner2d", 1, "RadarScenes-like 2D 77 GHz corner radar (front left, yawed 25 deg), calibrated on RadarScenes",
    _corner2d.__doc__, _corner2d, points_per_scan=(140, 365)))

_REGISTRY.seal()  # the profiles above are built in: versioned, never replaced (a profile of your own: another name)


__all__ = ["CORNER2D", "DEFAULT", "GENERIC", "IWR6843AOP", "LRR30F", "SensorProfile", "get", "names", "radar_config",
           "register"]
