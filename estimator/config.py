"""Estimator configuration: small sections with vehicle defaults, loadable from TOML, saved with results.

`OdometryConfig.for_model("ca-polar")` gives the paper's method, `"cv-cartesian"` its baseline. The mixed
configurations `"ca-cartesian"` and `"cv-polar"` exist for ablations. A TOML file overrides any field:

    model = "ca-polar"
    window = 4
    [noise]
    qc_ca = [1.0, 0.1, 0.1, 0.01, 0.01, 0.05]

Unknown keys are errors (named), values are checked for type and range.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

from .config_rules import check_sections, check_values, section_from_dict
from .errors import InputError
from .tomlcompat import tomllib

MODELS = ("ca-polar", "cv-cartesian", "ca-cartesian", "cv-polar")


@dataclass(frozen=True)
class NoiseConfig:
    """Process and measurement noise. Qc diagonals are [linear x, y, z, angular x, y, z], body frame.

    qc_ca: power spectral density of the jerk (m^2/s^5, rad^2/s^5) for the CA prior.
    qc_cv: power spectral density of the acceleration (m^2/s^3, rad^2/s^3) for the CV prior.
    cartesian_sigma: the fixed Cartesian position sigma (m) of the baseline measurement model.
    map_sigma_polar, map_sigma_cartesian: isotropic uncertainty (m) added to every map point's own covariance
        (the detection noise it was created with), for the polar and the Cartesian models: surfaces are sampled
        at different places each scan. Tuned per model (as the paper tunes Q and R per approach): with the
        polar model, 0.3 m widened the gates enough to admit systematically offset pairs on resampled ground
        and guard rails, which pulled the pitch (highway, 1 km: 25 m of z drift at 0.3, 4.7 m at 0.1).
    sensor_sigma_scale: multiplies the sensor's 1-sigma noise from sensor.toml (tuning, as in the paper).
    sensor_sigma_scales: per channel [range, azimuth, elevation, radial velocity] factors on top of it (what
        `rodo calibrate` learns when the channels differ).
    sigma_floor: lower bounds of the 1-sigma [range m, azimuth rad, elevation rad, radial velocity m/s] the
        estimator uses (a noise-free sensor.toml must not make the information matrix singular).
    doppler_common_sigma: 1-sigma (m/s) of an error common to all radial velocities of one scan, per axis of
        the sensor velocity (a Doppler scale or bias, a time offset while accelerating, an extrinsic yaw error:
        what averaging a scan's detections does not remove). n independent detections claim the scan's
        sensor velocity to about sigma_vr / sqrt(n / dof); with this term each radial velocity's variance is
        raised by sigma_c^2 lambda_max(sum u u^T) in the solve (`doppler.common_doppler_error`) and sigma_c^2
        is added to the Doppler fit's covariance in the check of the prediction, so a scan claims the sensor
        velocity along no axis better than sigma_c. 0: off (the simulator's detections err independently).
        RadarScenes: 0.05, measured (docs/estimator.md, "Several radars").
    min_prior_dt: the motion prior between two states closer in time than this (s) gets the process noise of
        this interval (it then says less than it knows, never more). Several radars' scans can be almost
        simultaneous (RadarScenes: 0.06 ms apart), and as dt -> 0 the CA prior's Q_k shrinks as dt^5: its
        information (1e22 there) swamps the normal equations in double precision, and CA/C and CA/P diverged.
        States at least min_prior_dt apart (one radar at up to 1 / min_prior_dt Hz) are unaffected.
    """

    qc_ca: tuple[float, ...] = (2.0, 0.05, 0.05, 1e-4, 1e-3, 0.05)
    qc_cv: tuple[float, ...] = (1.0, 0.05, 0.05, 1e-3, 1e-3, 0.05)
    cartesian_sigma: float = 0.3
    map_sigma_polar: float = 0.1
    map_sigma_cartesian: float = 0.3
    sensor_sigma_scale: float = 1.0
    sensor_sigma_scales: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0)
    sigma_floor: tuple[float, ...] = (0.005, 5e-4, 5e-4, 0.005)
    doppler_common_sigma: float = 0.0  # m/s
    min_prior_dt: float = 0.01  # s


@dataclass(frozen=True)
class AssociationConfig:
    gate_probability: float = 0.95
    max_radius: float = 5.0
    doppler_sigma_floor: float = 0.05  # m/s, floor of the Doppler static/moving test
    reassociate: int = 1  # re-associate after the first solve this many times (each scores the first association's
    # candidates again at the solution: docs/estimator.md, step 5)
    ransac_above_sigma: float = 0.5  # m/s: a predicted sensor velocity this uncertain (a start) takes the widest
    # Doppler consensus inside its gate, or a free RANSAC fit when the gate holds under 20 % (or 8) of the scan
    doppler_jerk_margin: float = 0.5  # m/s: a confident prediction's Doppler fit may move this far beyond its
    # 3-sigma (hard braking, hand-held sensors: jerk the prior does not expect)
    consensus_switch_after: float = 0.5  # s: another Doppler consensus covering consensus_switch_ratio times
    # the space of ours (occupied consensus_voxel voxels) for this long is taken as the world (re-initialisation
    # on it); 0 disables it. Counting detections instead took a lead truck on `highway` (7.2 % instead of 0.25 %)
    consensus_switch_ratio: float = 3.0
    consensus_voxel: float = 2.0  # m
    moving_group_z: float = 4.0  # a voxel (consensus_voxel) of detections whose mean radial velocity is off the
    # world's by more than this many standard errors plus moving_group_margin moves, though each detection is inside
    # its gate (a queue of cars moving off, denser than the world); left out of the static set. 0 disables it
    moving_group_margin: float = 0.02  # m/s
    doppler_update_probability: float = 0.999  # chi-square level above which the scan's Doppler velocity
    # corrects the predicted velocity before association
    missing_elevation_zero: bool = False  # a detection whose elevation is exactly 0 has none (some 3D radars,
    # e.g. the LRR30-F of the RaFlow data: 13 % of its detections): such detections are not used. Off for a 2D
    # radar, whose every elevation is 0
    ground_band: float = 0.0  # m (estimator/ground.py)


@dataclass(frozen=True)
class MapConfig:
    """Local map (estimator/local_map.py). fuse: refine an associated map point with the detection placed
    by the solved estimate, information-weighted with the detection's noise plus map_sigma^2 (the surface is
    resampled every scan); off: map points never move. Off by default: on city/hills/stop_and_go seeds 1-3 it
    helped hills but not the other two on average (docs/estimator.md, "Map-point fusion"; measured before the
    [vehicle] terms). max_fused: fading memory of about this many observations per point (0: none)."""

    capacity: int = 1500
    max_age: int = 30
    voxel: float = 0.0
    fuse: bool = False
    max_fused: int = 20
    surface_normal_sigma: float = 0.0  # m, across a planar neighbourhood's surface; 0: off (the paper's isotropic
    # map sigma for every point). On: a new point whose neighbourhood is a plane gets surface_tangent_sigma along
    # it and this across it instead of the isotropic map sigma (estimator/surface.py, docs/consistency.md)
    surface_tangent_sigma: float = 0.1  # m, along a planar neighbourhood's surface (surface model on)
    surface_neighbours: int = 10  # most neighbours (the point included) of the plane fit
    surface_radius: float = 2.0  # m, farthest neighbour of the plane fit
    surface_planarity: float = 0.05  # a plane: smallest eigenvalue of the scatter below this times the middle one


@dataclass(frozen=True)
class OutageConfig:
    """After this long without associations (total blockage, a dropped sensor) the estimator
    re-initialises at the next scan with data: pose dead-reckoned through the outage, velocity from a Doppler
    fit, angular rates from the last scan with data, acceleration zero, a fresh window and map (the old map no
    longer fits the dead-reckoned pose). 0 disables it."""

    reinit_after: float = 1.0  # seconds


@dataclass(frozen=True)
class StandstillConfig:
    """Zero-velocity term: when the scan's Doppler says the sensor is at rest (the static detections' median
    |radial velocity| below max(speed / 2, sigma_vr), their least-squares velocity consistent with zero at 99
    %) the newest state gets varpi = 0 and varpi_dot = 0 (the linear acceleration only from the second scan at
    rest: a vehicle that has just stopped or is starting is at rest with an acceleration) with these 1-sigmas.
    Doppler alone cannot tell a standstill from a turn on the spot about an axis near the sensor; a wheeled
    vehicle at rest does not turn, which is what this assumes. speed = 0 disables it.

    A vehicle's linear acceleration jumps when it stops (braking, then nothing) and when it moves off, which
    white noise on jerk cannot describe: the interval into a scan whose standstill differs from the scan before
    gets the prior noise of such a jump of 1-sigma sigma_accel_jump at an unknown time within it (CA only; Q_k of
    the jerk PSD sigma_accel_jump^2 / dt on x, y, z: the acceleration's variance grows by sigma_accel_jump^2 over
    the interval; docs/estimator.md, step 4)."""

    speed: float = 0.05  # m/s
    sigma_velocity: float = 0.005  # m/s
    sigma_rate: float = 0.002  # rad/s
    sigma_accel: float = 0.01  # m/s^2
    sigma_angular_accel: float = 0.005  # rad/s^2
    sigma_accel_jump: float = 2.0  # m/s^2


@dataclass(frozen=True)
class VehicleConfig:
    """A road vehicle's roll and pitch rates are small and zero on average (its roll and pitch stay within a few
    degrees of the road's). The motion priors penalise changes of the rates (white-noise jerk, CA; white-noise
    acceleration, CV), not the rates: a small constant roll or pitch rate costs nothing, Doppler hardly sees it
    (it moves the sensor by the lever arm times the rate, ~1 mm/s), and elevations constrain it weakly, so it
    integrates into roll and pitch, and turns make that z drift. A zero-mean term on each moving state's roll
    and pitch rates with these 1-sigmas (rad/s) says what the vehicle does; 0 disables one (both 0 for a
    hand-held sensor or a drone). docs/estimator.md, "Roll and pitch rates", has the measurements.

    A wheel does not slip sideways: at the middle of the rear axle (the usual vehicle origin) a car's velocity
    points along its x axis, up to a few cm/s of slip. A single radar's Doppler measures two or three of the
    sensor's velocity components, not the vehicle's yaw rate and lateral velocity apart (its lever arm ties
    them), so without this a yaw-rate error passes as lateral velocity and integrates into heading.
    sigma_lateral_velocity and sigma_vertical_velocity put zero-mean terms (m/s) on the y and z velocity of
    each moving state at the vehicle origin (the non-holonomic constraint); 0 disables one. Only for a
    vehicle frame whose origin does not slip (the simulator's; RadarScenes' rear axle); docs/estimator.md,
    "Lateral and vertical velocity", has the measurements."""

    sigma_roll_rate: float = 0.01  # rad/s
    sigma_pitch_rate: float = 0.015  # rad/s
    sigma_lateral_velocity: float = 0.0  # m/s at the vehicle origin; 0: off
    sigma_vertical_velocity: float = 0.0  # m/s at the vehicle origin; 0: off


@dataclass(frozen=True)
class UncertaintyConfig:
    """How the reported pose covariance accounts for what the window's covariance leaves out
    (`rodo.estimator.uncertainty`, docs/consistency.md).

    velocity_correlation_time: tau (s) of the velocity error, which the motion prior keeps correlated from scan
        to scan so that it integrates into pose; 0 composes the per-scan relative covariances as independent.
    inflation: factor (> 0) on each scan's relative pose covariance, before it is composed over a span and into
        the absolute pose (reported covariances only); `rodo calibrate` fits it where kappa cannot make the
        one-scan relative pose consistent.
    inflation_per_rate: + these x |omega_x|, |omega_y|, |omega_z| (the scan's estimated body rates, rad/s) on that
        factor: as the velocity, the registration's relative pose is over-confident where the body rolls or
        pitches (docs/consistency.md, "The one-scan relative pose with the rates"). Reported covariances only.
    inflation_per_doppler: + this x ln(1 + the scan's Doppler innovation NIS per dof) on that factor, as the
        velocity's (docs/consistency.md, "The one-scan relative pose with the rates"). Reported covariances only.
    inflation_per_pull: + this x the scan's pull on its solved pose per dof (`estimator.pull`) on that factor:
        where the scan and its map disagree as a rigid body the registration's error is larger than its
        covariance says (docs/consistency.md, "The scan's pull"). Reported covariances only.
    measurement_inflation: factor (>= 1) on every associated pair's covariance in the solve (not the gates): a
        scan's pairs share map errors and carry less information than counted as independent; 1: the paper's.
    velocity_error_share: the share g (> 0) of the window's velocity covariance that the drift recursion takes as
        its velocity error's variance (one scan's relative pose gains g dt^2 P_varpi from it; the spans and the
        absolute pose compose it): the registration pins a scan's pose to the map whatever the window's velocity
        error, so less of that error reaches the relative pose than dead reckoning would carry (at rest on a fresh
        map most: docs/consistency.md, "The velocity error's share and the registration's correlation"). `rodo
        calibrate` learns it with the one-scan factor. Reported covariances only; 1: the whole velocity covariance.
    velocity_error_share_per_speed: + this x the speed |nu| (s/m, >= 0) on that share, g + g_v |nu|: at rest on a
        static scene the one scan's error is smaller than at speed, where the surfaces the registration sees are
        resampled (docs/consistency.md, "The velocity error's share with the speed"). `rodo calibrate` learns it
        with the share from a drive that stops. Reported covariances only; 0: a share independent of the speed.
    registration_correlation: the share alpha (0-1) of each scan's relative pose covariance that the drift
        recursion carries correlated over tau, with the velocity error (alpha Sigma_rel / dt^2 added to its
        variance), the rest composed as independent: the registration's errors are correlated over a few scans to
        a second (the same section). `rodo calibrate` chooses it with tau. Reported covariances only; 0:
        independent registrations.
    registration_axis_correlation: per axis [x, y, z, roll, pitch, yaw] (0-1 each) the share a_i of what alpha
        leaves independent that the recursion carries correlated as well, alpha_i = alpha + (1 - alpha) a_i: the
        registration's errors are correlated longer on some axes than on others (CV/C's forward position on city:
        docs/consistency.md, "The registration's correlation per axis"). `rodo calibrate` learns it
        by default. Reported covariances only; zeros: alpha on every axis.
    drift_rate_sigma: sigma of the registration's systematic error per metre driven, unknown but constant
        over a run ([x, y, z] m/m, [roll, pitch, yaw] rad/m, vehicle frame): the absolute pose's error grows
        with the distance, not its square root. Not in the solve.
    velocity_inflation, velocity_inflation_per_speed: the reported velocity variance is the window's times
        velocity_inflation + velocity_inflation_per_speed x speed (m/s): its error grows with the speed, the
        window's covariance hardly does (`velocity_inflation.velocity_inflated`). Not in the solve or the gates.
    velocity_inflation_per_doppler: + this x ln(1 + the scan's Doppler innovation NIS per dof) on that factor:
        where the motion leaves the prior's model (a turn's onset, a start) the scan's Doppler disagrees with
        the prediction, and the velocity's error is larger than the window's covariance (docs/consistency.md,
        "... and at a manoeuvre"). Not in the solve or the gates.
    velocity_inflation_per_rate: + these x |omega_x|, |omega_y|, |omega_z| (the scan's estimated body rates, rad/s)
        on that factor: the window's velocity is over-confident where the body rolls, pitches or turns
        (docs/consistency.md, "... and with the rates"). Not in the solve or the gates.
    velocity_axis_inflation: factors per axis [vx, vy, vz, wx, wy, wz] (body frame) on that reported variance, for
        the shape of the window's velocity covariance (docs/consistency.md, "... and per axis"); `rodo calibrate`
        learns them (`--no-velocity-axes` leaves them at 1). Not in the solve, the gates or the drift recursion.
    velocity_lag_per_acceleration, velocity_lag_per_yaw_acceleration: the velocity error [vx, vy, vz, wx, wy, wz]
        per unit of the estimated forward acceleration (s, rad s/m) and of the yaw acceleration (s m/rad, s): a prior
        that does not model the manoeuvre lags behind it by a bias b = L a, which the reported velocity covariance
        adds as b b^T (`estimator.velocity_lag`; docs/consistency.md, "The velocity's lag behind a manoeuvre");
        `rodo calibrate` learns them for the constant-velocity prior. Not in the solve, the gates or the drift
        recursion. Zeros: off.
    velocity_lag_time: the time constant (s, > 0) with which that acceleration, the change of the emitted
        forward velocity and yaw rate over dt, is smoothed (the raw change over dt would be unbounded for scans
        close in time, as a rig's radars are).
    heading_reversion_time: the time constant (s) with which the drift recursion's yaw error reverts to an anchor
        (`estimator.heading_reversion`; docs/consistency.md, "The heading reverts"); `rodo calibrate
        --heading-reversion` learns it. Reported covariances only. 0: off.
    heading_anchor_time: the time constant (s, > 0) with which that anchor follows the yaw error (with the
        reversion on; learned with it).
    attitude_jitter_variance: the variance V (rad^2, per axis) of a smooth, bounded roll and pitch error beside
        the drift recursion (`estimator.attitude_jitter`; docs/consistency.md, "Roll and pitch jitter"): a relative
        pose over L s gains, on its roll and pitch variances, the covariance between its one-scan changes that
        composing them leaves out (about 1.1 V over 1 s at T 1 s), the absolute pose the same since the run's
        first scan. `rodo calibrate` learns it. Reported covariances only. 0: off.
    attitude_jitter_time: that error's correlation time T (s, > 0).
    stationary_variance: per axis [x, y, z, roll, pitch, yaw] (m^2, rad^2) the variance V of a bounded pose
        error beside the drift recursion (`estimator.stationary_error`; docs/consistency.md, "A bounded error per
        axis"): its change over one scan is taken out of the scan's relative pose covariance before the recursion
        composes it, and a relative pose over a span (the absolute pose, from the run's first scan) adds the
        error's change over the span with its lever arm. `rodo calibrate --stationary-error` learns it. Reported
        covariances only; the one-scan relative pose covariance is unchanged. Zeros: off.
    stationary_time: per axis that error's correlation time T (s, > 0).
    prior_memory: time constant (s) of the marginalised prior's memory (its information times exp(-dt /
        prior_memory) at each marginalisation): the map, made from the same scans, brings their information back
        (docs/consistency.md, "A prior that forgets"). 0: off (the paper's marginalisation).
    """

    velocity_correlation_time: float = 0.25  # s
    inflation: float = 1.0
    inflation_per_rate: tuple[float, ...] = (0.0, 0.0, 0.0)  # s/rad
    inflation_per_doppler: float = 0.0
    inflation_per_pull: float = 0.0
    velocity_error_share: float = 1.0
    velocity_error_share_per_speed: float = 0.0  # s/m
    registration_correlation: float = 0.0
    registration_axis_correlation: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    measurement_inflation: float = 1.0
    drift_rate_sigma: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    prior_memory: float = 0.0  # s
    velocity_inflation: float = 1.0
    velocity_inflation_per_speed: float = 0.0
    velocity_inflation_per_doppler: float = 0.0
    velocity_inflation_per_rate: tuple[float, ...] = (0.0, 0.0, 0.0)  # s/rad
    velocity_axis_inflation: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    velocity_lag_per_acceleration: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # s; rad s/m
    velocity_lag_per_yaw_acceleration: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # s m/rad; s
    velocity_lag_time: float = 0.3  # s
    heading_reversion_time: float = 0.0  # s
    heading_anchor_time: float = 100.0  # s
    attitude_jitter_variance: float = 0.0
    attitude_jitter_time: float = 1.0  # s
    stationary_variance: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # m^2; rad^2
    stationary_time: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)  # s


@dataclass(frozen=True)
class SolverConfig:
    """Gauss-Newton settings and the initial state's uncertainty (vehicle frame, per axis x, y, z / roll,
    pitch, yaw): a vehicle barely rolls or pitches, and an unconstrained initial roll acceleration would be
    carried on by the constant-acceleration prior."""

    iterations: int = 5
    step_tolerance: float = 1e-4  # Gauss-Newton stops after a step whose largest element is below this (m, rad,
    # m/s, ...): convergence is quadratic, the next step would be ~1e-8 (measured on city: steps 1e-2, 1e-5, 1e-8)
    step_sigma_tolerance: float = 0.05  # or a full step shorter than this in posterior sigmas
    refine_iterations: int = 1  # Gauss-Newton steps after the re-association, the last applied without a cost
    # check or another linearisation (it starts at the solution of a problem a few pairs away; on city the step
    # after it is 3e-6 median, 1e-5 at the 90th percentile; with 3 checked steps the accuracy was the same)
    relinearize_older: bool = False  # re-linearise the older states' measurement terms at every step of a solve
    # (true) or once per solve, then from its quadratic model (false: ~0.9x the time per scan; docs/estimator.md)
    reweight_older: bool = True  # (if false above) re-weight and re-linearise them at each scan's first solve
    # (true), or keep their own scan's weights and the next scan's model (false: ~0.92x time, less accurate)
    robust_c: float = 3.0  # Cauchy scale in whitened units; 0 disables the robust loss
    init_velocity_sigma: float = 0.2  # m/s on the Doppler initialisation
    init_rate_sigma: tuple[float, ...] = (0.02, 0.02, 0.2)  # rad/s
    init_accel_sigma: tuple[float, ...] = (1.0, 0.2, 0.2)  # m/s^2
    init_angular_accel_sigma: tuple[float, ...] = (0.02, 0.02, 0.2)  # rad/s^2


@dataclass(frozen=True)
class OdometryConfig:
    model: str = "ca-polar"
    window: int = 4
    seed: int = 0
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    map: MapConfig = field(default_factory=MapConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    outage: OutageConfig = field(default_factory=OutageConfig)
    standstill: StandstillConfig = field(default_factory=StandstillConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)

    def __post_init__(self):
        check_values(self, ranges=False)  # every value's type first (estimator/config_rules.py), so that the
        check_sections(self, MODELS)  # checks across keys compare numbers
        check_values(self)  # every value finite and in its range (estimator/config_rules.py)

    @property
    def prior(self) -> str:
        return self.model.split("-")[0]

    @property
    def measurement(self) -> str:
        return self.model.split("-")[1]

    @classmethod
    def for_model(cls, model: str, **overrides) -> "OdometryConfig":
        return cls(model=model, **overrides)

    def to_dict(self) -> dict:
        """Plain dict (tuples as lists), e.g. for summary.json; `from_dict(to_dict())` round-trips."""
        def plain(v):
            return [plain(x) for x in v] if isinstance(v, (tuple, list)) else \
                {k: plain(x) for k, x in v.items()} if isinstance(v, dict) else v

        return plain(dataclasses.asdict(self))

    def replace(self, **changes) -> "OdometryConfig":
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "OdometryConfig":
        sections = {"noise": NoiseConfig, "association": AssociationConfig, "map": MapConfig, "solver": SolverConfig,
                    "outage": OutageConfig, "standstill": StandstillConfig,
                    "vehicle": VehicleConfig, "uncertainty": UncertaintyConfig}
        top = {f.name for f in dataclasses.fields(cls)}
        kwargs = {}
        for key, value in data.items():
            if key not in top:
                raise InputError(f"{source}: unknown key {key!r}; known: {', '.join(sorted(top))}")
            if key in sections:
                if not isinstance(value, dict):
                    raise InputError(f"{source}: [{key}] must be a table")
                kwargs[key] = section_from_dict(sections[key], value, f"{source}: [{key}]")
            else:
                kwargs[key] = value
        try:
            return cls(**kwargs)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    @classmethod
    def from_toml(cls, path: str | Path, model: str | None = None) -> "OdometryConfig":
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"{path}: config file not found") from None
        except IsADirectoryError:
            raise InputError(f"{path}: is a directory, expected a TOML config file") from None
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror})") from None
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{path}: invalid TOML: {exc}") from None
        if model is not None:
            data.setdefault("model", model)
        return cls.from_dict(data, source=str(path))

