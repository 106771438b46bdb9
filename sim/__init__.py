"""The simulator: trajectories, scenes, the radar sensor model, and the sequence format on disk.

The package, file by file (the names below are re-exported here; submodules stay importable as
`rodo.sim.<file>`):
    trajectory.py      exact CA-segment trajectories: `Segment`, `Profile`, `Motion`, `ProfileBuilder`, `Route`,
                       `route_of`, and the profile generators `city`, `highway`, `hills`, `stop_and_go`, `crawl`,
                       `yaw_accel`.
    objects.py         scene primitives: `Patches`, `Points`, `MovingBox`, `RigidStates`, `box`, `rectangle`,
                       `empty_patches`; detection labels `STATIC_SURFACE`, `STATIC_POINT`, `MOVING`, `CLUTTER`,
                       `GHOST`.
    world.py           scenes around a route: `World`, `SceneParams` (`CITY`, `CITY_ONCOMING`, `CITY_TWO_LANES`,
                       `HIGHWAY`, `RURAL`), `build_world`, `landmark_world` (persistent point scatterers only),
                       traffic (`lead_vehicle`, `oncoming_vehicle`, `overtaking_vehicle`; `World.with_traffic`).
    traffic.py         traffic clear of itself and of the parked cars: `footprints`, `overlap`, `collision_free`.
    sensor_geometry.py where a radar sits and what it sees of a point: `mount`, `default_mount`,
                       `sensor_velocity`, `polar`.
    radar.py           the sensor model: `Radar`, `RadarConfig`, `Detections`; built on culling.py (what a scan can see at all: per-scene patch geometry and the
                       pre-selection near the sensor) and occlusion.py (the angular cell grid, the gates, the
                       depth buffer, the nearest entry per cell; its loops compiled in radar_kernels.py).
                       Those are internal (not re-exported).
    radar_physics.py   the radar equation of a sensor profile (`RadarPhysics`, `RadarConfig.physics`): RCS per
                       scatterer class, SNR, Swerling-1 detection, noise from SNR, ambiguities, quantisation.
    multipath.py       multipath ghosts: mirror images of targets across large flat reflectors (`mirror`).
    profiles.py        named, versioned sensor profiles (`SensorProfile`; `get_profile`, `profile_names`,
                       `profile_radar_config` are its `get`, `names`, `radar_config`): generic (the default),
                       lrr30f, iwr6843aop, corner2d.
    simulate.py        profile + world + radar -> sequence and truth: `simulate_sequence` (the module's
                       `simulate`; the module itself keeps the name `rodo.sim.simulate`), `write_simulation`,
                       `load_truth`, `TRUTH_NPZ`.
    prior_sampling.py  Monte Carlo of the CA prior's SDE: `sample_prior`, `propagate_mean_cov`, `nees_bounds`,
                       `yaw_acceleration_case` (and `errors`, `nees`, `covariance_test` in the module).
    sde_trajectory.py  trajectories drawn from the CA or CV prior's own SDE (the prior_ca / prior_cv scenarios):
                       `draw_sde_trajectory` (the module's `draw`), `SdeTrajectory`.
    sequence.py        the sequence format (docs/sequence_format.md): `Sequence`, `SensorConfig`, `NoiseSigmas`,
                       `RadarScan`, `Trajectory`, `read_sequence`, `write_sequence`, ... (its `__all__`), built on
                       sequence_types.py, radar_csv.py, sensor_config.py, tum.py and _seqio.py.
    convert/           real recordings -> the sequence format (`rodo.sim.convert.radarscenes`, `.ti_mmwave`, `.vod`;
                       not imported here).

Only numpy, scipy and numba are imported (numba for radar_kernels.py, with numba's on-disk cache; no plotting).
"""

from .objects import CLUTTER, GHOST, MOVING, STATIC_POINT, STATIC_SURFACE, MovingBox, Patches, Points, RigidStates, box, \
    empty_patches, rectangle
from .prior_sampling import nees_bounds, propagate_mean_cov, sample_prior, yaw_acceleration_case
from .sde_trajectory import SdeTrajectory
from .sde_trajectory import draw as draw_sde_trajectory
from .radar import Detections, Radar, RadarConfig
from .sensor_geometry import default_mount, mount, polar, sensor_velocity
from .radar_physics import RadarPhysics
from .multipath import mirror
from .profiles import SensorProfile
from .profiles import get as get_profile
from .profiles import names as profile_names
from .profiles import radar_config as profile_radar_config
from .sequence import (GROUNDTRUTH_TXT, RADAR_CSV, SENSOR_TOML, NoiseSigmas, RadarScan, SensorConfig, Sequence,
                       SequenceFormatError, Trajectory, polar_to_cartesian, read_sequence, read_tum, write_sequence,
                       write_tum)
from .simulate import TRUTH_NPZ, load_truth, write_simulation
from .simulate import simulate as simulate_sequence
from .trajectory import Motion, Profile, ProfileBuilder, Route, Segment, city, crawl, highway, hills, route_of, \
    stop_and_go, yaw_accel
from .traffic import collision_free, footprints, overlap
from .world import CITY, CITY_ONCOMING, CITY_TWO_LANES, HIGHWAY, RURAL, SceneParams, World, build_world, \
    landmark_world, lead_vehicle, oncoming_vehicle, overtaking_vehicle

__all__ = [
    # trajectory.py
    "Motion", "Profile", "ProfileBuilder", "Route", "Segment", "city", "crawl", "highway", "hills", "route_of",
    "stop_and_go", "yaw_accel",
    # objects.py
    "CLUTTER", "GHOST", "MOVING", "STATIC_POINT", "STATIC_SURFACE", "MovingBox", "Patches", "Points", "RigidStates", "box",
    "empty_patches", "rectangle",
    # world.py
    "CITY", "CITY_ONCOMING", "CITY_TWO_LANES", "HIGHWAY", "RURAL", "SceneParams", "World", "build_world",
    "landmark_world", "lead_vehicle", "oncoming_vehicle", "overtaking_vehicle",
    # traffic.py
    "collision_free", "footprints", "overlap",
    # radar.py
    "Detections", "Radar", "RadarConfig",
    # sensor_geometry.py
    "default_mount", "mount", "polar", "sensor_velocity",
    # radar_physics.py, multipath.py, profiles.py
    "RadarPhysics", "mirror", "SensorProfile", "get_profile", "profile_names", "profile_radar_config",
    # simulate.py
    "TRUTH_NPZ", "load_truth", "simulate_sequence", "write_simulation",
    # prior_sampling.py
    "nees_bounds", "propagate_mean_cov", "sample_prior", "yaw_acceleration_case",
    # sde_trajectory.py
    "SdeTrajectory", "draw_sde_trajectory",
    # sequence.py
    "GROUNDTRUTH_TXT", "RADAR_CSV", "SENSOR_TOML", "NoiseSigmas", "RadarScan", "SensorConfig", "Sequence",
    "SequenceFormatError", "Trajectory", "polar_to_cartesian", "read_sequence", "read_tum", "write_sequence",
    "write_tum",
]
