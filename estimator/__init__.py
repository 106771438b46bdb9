"""The paper's estimator: SE(3) math, the CV and CA motion priors, the polar and Cartesian measurement models,
Doppler front end, association, local map, sliding-window MAP and the per-scan odometry.

A map of the package (each module's public names are re-exported here):

    lie/                SO(3) and SE(3) (`so3`, `se3`) and their compiled kernels
    priors/             the array-level priors: ConstantAccelerationPrior (Magnus mean, F_k, Q_k),
                        ConstantVelocityPrior, `exact` (ODE references)
    state.py            State: {T_vehicle_world, varpi, varpi_dot} and its left perturbation
    motion.py           MotionPrior (CA, CV): the priors as the estimator uses them
    radar_geometry.py   polar <-> Cartesian with Jacobians, propagated position covariance
    measurement_models.py  MeasurementModel (polar, Cartesian): space, noise, residual, association metric
    measurements.py     the NumPy reference of the measurement prediction and its Jacobians (used as
                        `rodo.estimator.measurements`, not re-exported: its names are the reference's)
    association.py      gating and one-to-one maximum-likelihood matching (eq. 86-88)
    scan_association.py the odometry's windowed, compiled association of the map with a scan
    ego_velocity.py     Doppler ego-velocity (RANSAC, least squares)
    consensus.py        which Doppler consensus is the world (the consensus switch, moving groups)
    doppler.py          the Doppler front end: static detections, velocity correction, standstill
    local_map.py        LocalMap: the bounded map of points
    surface.py          surface-shaped covariances of new map points (the optional surface model)
    ground.py           the road returns kept out of the pairs and the map (the optional ground band)
    window.py           SlidingWindow: Gauss-Newton over prior, motion and measurement terms, marginalisation
    window_sets.py      MeasurementSet: a scan's pairs in the window; SetPacks: the sets packed for its kernels
    spd.py              the window's dense SPD solves, the trailing block of an inverse (its covariances)
    uncertainty.py      the pose covariance that grows as drift does (relative, absolute, over a span)
    heading_reversion.py  the yaw error's reversion to an anchor in that drift (optional)
    attitude_jitter.py  a smooth roll and pitch error beside that drift (optional)
    stationary_error.py  a bounded pose error per axis beside that drift, with its lever arm (optional)
    reported_covariances.py  ReportedCovariances: those parts put together, scan by scan
    velocity_inflation.py  the reported velocity variance's factor (speed, Doppler innovation, body rates)
    velocity_lag.py     the velocity's lag behind a manoeuvre, a bias the reported velocity covariance adds
    pull.py             the scan's pull on its solved pose, and the one-scan relative pose's factor
    odometry.py         RadarOdometry: predict, Doppler front end, associate, solve, map update
    sensor.py           Sensor: one radar of the odometry (extrinsics, noise, association, Doppler front end)
    sensor_values.py    the value rules of a radar's description and detections (units), one set for the files
                        and the Python API
    scan.py             ScanEstimate, ScanDetail: what a scan returns
    config.py           OdometryConfig and its sections (TOML)
    config_rules.py     every config value's type, finiteness and range (one table, checked at load)
    errors.py           InputError, check_finite
    tomlcompat.py       tomllib on every supported Python (tomli on 3.10)
    registry.py         Registry: named definitions (the scenarios', the sensor profiles')

Configurations: `OdometryConfig.for_model("ca-polar")` (the paper's method), `"cv-cartesian"` (its baseline),
`"ca-cartesian"` and `"cv-polar"` (ablations): the product of a `MotionPrior` and a `MeasurementModel`.
Docs: docs/estimator.md, docs/priors.md, docs/measurements.md, docs/architecture.md.
"""

from importlib import import_module

# public name -> the module that defines it. Loaded on first use (PEP 562), so `import rodo.estimator.lie`
# (the simulator's only need) does not import numba and the compiled kernels.
_EXPORTS = {
    "association": ("Association", "associate", "gate_threshold", "innovation_covariance", "match"),
    "config": ("MODELS", "OdometryConfig", "UncertaintyConfig"),
    "config_rules": ("RULES", "Rule", "check_values"),
    "consensus": ("ConsensusSwitch", "moving_voxels"),
    "doppler": ("DopplerFrontEnd", "body_velocity", "sensor_velocity"),
    "ego_velocity": ("EgoVelocity", "estimate_ego_velocity", "least_squares_velocity"),
    "errors": ("InputError", "check_finite"),
    "tomlcompat": ("tomllib",),
    "registry": ("Registry",),
    "lie": ("se3", "so3"),
    "local_map": ("LocalMap",),
    "measurement_models": ("CartesianModel", "MeasurementModel", "PolarModel", "measurement_model"),
    "motion": ("ConstantAccelerationMotion", "ConstantVelocityMotion", "MotionPrior", "motion_prior",
               "motion_prior_for"),
    "odometry": ("RadarOdometry",),
    "priors": ("ConstantAccelerationPrior", "ConstantVelocityPrior"),
    "radar_geometry": ("cartesian_position_covariance", "polar_to_cartesian", "polar_to_cartesian_jacobian",
                       "wrap_angle"),
    "scan_association": ("MapAssociation", "ScanMeasurements"),
    "scan": ("ScanDetail", "ScanEstimate"),
    "spd": ("inv_spd", "solve_spd", "trailing_inverse"),
    "sensor": ("Sensor",),
    "sensor_values": ("check_polar_bounds", "check_sensor_values"),
    "state": ("State", "stacked"),
    "surface": ("surface_covariances",),
    "ground": ("off_road", "road_mask"),
    "heading_reversion": ("heading_reversion_matrix",),
    "attitude_jitter": ("absolute_excess", "span_excess", "span_variance"),
    "stationary_error": ("span_term", "taken_out"),
    "reported_covariances": ("ReportedCovariances",),
    "uncertainty": ("DriftCovariance", "predicted_relative_covariance", "relative_pose_covariance",
                    "revision_covariance", "scan_relative_covariances", "span_covariance"),
    "pull": ("pose_pull", "pull_term", "relative_factor"),
    "velocity_inflation": ("doppler_term", "velocity_factor", "velocity_inflated", "velocity_inflation_array",
                           "velocity_inflation_terms"),
    "velocity_lag": ("VelocityLag", "lag_accelerations", "lag_matrix", "with_lag"),
    "window": ("SlidingWindow",),
    "window_sets": ("MeasurementSet", "SetPacks"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
