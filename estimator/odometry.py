"""Radar odometry, one scan at a time: predict, classify static/moving by Doppler, associate, solve, map.

The algorithm layer (no file I/O, no printing): `RadarOdometry.process(t, polar)` takes one scan's detections
[range, azimuth, elevation, radial_velocity] (sensor frame) and returns the newest estimate (`ScanEstimate`),
in named stages as kiss-icp's `register_frame`: predict, Doppler front end (`doppler`), associate
(`scan_association`), solve (`window`), map update (`local_map`). The model choice lives in a `MotionPrior`
(CA or CV) and a `MeasurementModel` (polar or Cartesian); nothing here branches on it.

Per scan k (paper sec. III-VI; docs/estimator.md gives the reasons and the measurements behind each step):
1. predict x_k = f(x_{k-1}) and P_k = F P F^T + Q with the configured prior (CV or CA);
2. static detections: the largest Doppler consensus near the predicted sensor velocity (prediction-gated
   RANSAC), or a free RANSAC fit when the prediction is uncertain (either rejects moving objects, as reve);
3. when the scan's Doppler velocity contradicts the prediction (an unmodelled jerk; at the pairs' gate level
   when the gates lost the scan, `_recentre`), move the predicted mean to it: linearisation point, gate centre;
4. a zero-velocity term when the Doppler says the sensor is at rest (a stop or start: an acceleration jump);
5. associate map points with the static detections off the road (`association.ground_band`) by maximum
   likelihood, S = G P G^T + R (+ map-point term), gated at the chi-square quantile (eq. 86-88), in the FOV;
6. Gauss-Newton over the window's prior, motion and measurement terms, re-associate, solve again, marginalise;
7. update the local map: refresh associated points, add the unassociated static detections (aged by scans
   with static detections: a blockage does not expire the map needed after it).
"""

from __future__ import annotations

import time

import numpy as np

from . import association
from .config import OdometryConfig
from .consensus import MIN_STATIC  # fewest static detections to use
from .doppler import DopplerFrontEnd, body_velocity, common_doppler_error, vehicle_information
from .errors import InputError, check_rows, check_time
from .ground import off_road
from .lie import se3
from .local_map import LocalMap
from .measurement_models import measurement_model
from .motion import motion_prior_for
from .pull import pose_pull
from .scan import ScanDetail, ScanEstimate
from .scan_association import MapAssociation, ScanMeasurements
from .sensor import Sensor
from .sensor_values import check_polar_bounds, check_sensor_arguments
from .state import State
from .surface import surface_covariances
from .reported_covariances import ReportedCovariances
from .uncertainty import predicted_relative_covariance, scan_relative_covariances
from .window import MeasurementSet, SlidingWindow

LOST_PAIRS = 0.1  # share of the static detections paired below which the gates lost the scan (_recentre)
RECOVERED_PAIRS = 0.25  # share of all the scan's detections a re-centred prediction must pair (_recentre)


class RadarOdometry:
    """Sliding-window radar odometry (CV/C, CA/P, or the mixed ablations) for one radar, or several
    (`add_sensor`: each scan with its own radar's extrinsics, noise, field of view and Doppler front end, at its
    own time; one window, one map).

    Args:
        config: OdometryConfig (model, window, noise, association, map, solver).
        T_vehicle_sensor: (4, 4) extrinsics.
        sensor_sigmas: (4,) 1-sigma noise [range, azimuth, elevation, radial_velocity] (from sensor.toml).
        max_range: the sensor's maximum range (m), for pruning the map.
        record_detail: keep per-scan association detail in `ScanEstimate.detail` (for visual debugging).
        fov: ((az_min, az_max), (el_min, el_max)) radians, the sensor's field of view (sensor.toml): association
            is windowed inside it (`MapAssociation.window_masks`); None: no window.
    """

    def __init__(self, config: OdometryConfig, T_vehicle_sensor, sensor_sigmas, max_range: float = 200.0,
                 record_detail: bool = False, fov=None):
        if not isinstance(config, OdometryConfig):
            raise InputError(f"config: expected an OdometryConfig (OdometryConfig.for_model(...)), got {config!r}")
        self.config, self.record_detail = config, record_detail
        self.motion = motion_prior_for(config)
        self.measurement = measurement_model(config.measurement)
        self.map_sigma = self.measurement.map_sigma(config.noise)
        self.surface_model = config.map.surface_normal_sigma > 0  # new points carry their resampling covariance
        seeds = np.random.SeedSequence(config.seed).spawn(3)
        self.sensors: list[Sensor] = []
        self.sensor = self._sensor(T_vehicle_sensor, sensor_sigmas, max_range, fov, (seeds[0], seeds[2]))
        self.window = SlidingWindow(self.motion, config.window, self.measurement, self.T_vehicle_sensor,
                                    config.solver.robust_c, config.solver.relinearize_older)
        self.map = LocalMap(config.map.capacity, config.map.max_age, config.map.voxel,
                            rng=np.random.default_rng(seeds[1]))
        self.vehicle_information = vehicle_information(config, self.motion.dim)
        self.P: np.ndarray | None = None  # the newest state's covariance as last emitted
        self.scan_index = 0
        self.last_with_data: State | None = None  # newest state at the last scan with associations
        self.map_clock = 0  # counts scans with static detections: the map ages with observations, not time
        self.last_t: float | None = None
        self.scan_dt = 0.1  # s, the latest time between scans (counts the consensus-switch scans)
        self.report = ReportedCovariances(config.uncertainty)  # relative, absolute and velocity (`uncertainty`)
        self.at_rest = False  # the last scan's Doppler said the sensor was at rest (the standstill term)
        self.doppler_nis = float("nan")  # this scan's Doppler innovation NIS per dof (`DopplerFrontEnd.correct`)

    def add_sensor(self, T_vehicle_sensor, sensor_sigmas, max_range: float = 200.0, fov=None) -> int:
        """Another radar on the same vehicle (multi-radar odometry): returns its index for `process`. Its scans
        join the same window and map at their own times, with its own extrinsics, noise, field of view and
        Doppler front end (random streams spawned from the config seed, apart from sensor 0's)."""
        i = len(self.sensors)
        seeds = np.random.SeedSequence(self.config.seed, spawn_key=(2 + i,)).spawn(2)
        self._sensor(T_vehicle_sensor, sensor_sigmas, max_range, fov, seeds)
        # every radar's scan ages the map: N radars keep N times the points for N times the scans, so the map
        # spans the time it does with one (city, a simulated front + corner rig: KITTI 0.38 -> 0.23 % for CA/P)
        self.map.capacity = self.config.map.capacity * len(self.sensors)
        self.map.max_age = self.config.map.max_age * len(self.sensors)
        return i

    def _sensor(self, T_vehicle_sensor, sensor_sigmas, max_range, fov, seeds) -> Sensor:
        config = self.config
        T, sig, max_range, fov = check_sensor_arguments(T_vehicle_sensor, sensor_sigmas, max_range, fov)
        sigmas = np.maximum(sig * config.noise.sensor_sigma_scale * np.asarray(config.noise.sensor_sigma_scales),
                            config.noise.sigma_floor)
        associator = MapAssociation(
            self.measurement, self.measurement.noise_covariance(sigmas, config.noise.cartesian_sigma), T,
            association.gate_threshold(config.association.gate_probability, 4), config.association.max_radius,
            0.0 if self.surface_model else self.map_sigma, fov, sigmas[1:3])
        doppler = DopplerFrontEnd(config, T, sigmas, np.random.default_rng(seeds[0]), np.random.default_rng(seeds[1]))
        self.sensors.append(Sensor(T, sigmas, max_range, associator, doppler))
        return self.sensors[-1]

    @property
    def _reach(self) -> float:
        """The farthest from the vehicle origin any sensor sees (m)."""
        return max(s.max_range + float(np.linalg.norm(s.T_vehicle_sensor[:3, 3])) for s in self.sensors)

    # the sensor of the scan in process (sensor 0 between scans)
    T_vehicle_sensor = property(lambda self: self.sensor.T_vehicle_sensor)
    sigmas = property(lambda self: self.sensor.sigmas)
    max_range = property(lambda self: self.sensor.max_range)
    associator = property(lambda self: self.sensor.associator)
    doppler = property(lambda self: self.sensor.doppler)

    # --- the per-scan step ------------------------------------------------------------------------------
    def process(self, t: float, polar, sensor: int = 0) -> ScanEstimate:
        """Process one scan at time t (s) with detections polar (n, 4) of radar `sensor` (`add_sensor`); n may
        be 0. Scan times increase strictly over all sensors."""
        if isinstance(sensor, (bool, np.bool_)) or not isinstance(sensor, (int, np.integer)) \
                or not 0 <= sensor < len(self.sensors):
            raise InputError(f"sensor: expected an index in [0, {len(self.sensors)}), got {sensor!r}")
        self.sensor = self.sensors[sensor]
        try:
            return self._process(t, polar)
        finally:
            self.sensor = self.sensors[0]

    def _process(self, t: float, polar) -> ScanEstimate:
        t, polar, in_range = self._accept(t, polar)
        timings, tic = {}, time.perf_counter()
        x, P, Q, events = self._predict(t, polar)
        timings["predict"] = time.perf_counter() - tic

        tic = time.perf_counter()
        x, P, static, still, fit = self._doppler_front_end(t, polar, x, P, Q, events)
        used = off_road(polar, static, self.T_vehicle_sensor, self.config.association.ground_band)
        scan = ScanMeasurements.of(polar[used], self.measurement)
        W_pairs, pairs = self._associate(x, P, scan)
        if len(pairs.map_idx) < LOST_PAIRS * len(scan.points) and len(self.map):  # empty after a (re-)start
            W_pairs, pairs = self._recentre(x, P, fit, scan, len(polar), W_pairs, pairs, events)
        timings["associate"] = time.perf_counter() - tic

        tic = time.perf_counter()
        reuse = float(np.mean(self.map.hits[pairs.map_idx])) if len(pairs.map_idx) else float("nan")
        W_pairs, pairs, P_relative = self._solve(scan, W_pairs, pairs, timings)
        T_world_sensor = se3.inverse(self.window.newest.T_vehicle_world) @ self.T_vehicle_sensor
        pull = self._pull(scan, pairs, T_world_sensor)
        timings["solve"] = time.perf_counter() - tic - timings.pop("reassociate", 0.0)
        detail = ScanDetail(polar, static, np.flatnonzero(used)[pairs.det_idx], pairs.map_idx.copy(),
                            self.map.points.copy(), np.flatnonzero(in_range)) if self.record_detail else None
        tic = time.perf_counter()
        self._update_map(scan, pairs, T_world_sensor)
        timings["map"] = time.perf_counter() - tic
        est = self._estimate(t, polar, static, pairs, timings, events, detail, still is not None)
        return self.report.annotate(est, P_relative, reuse, self.doppler_nis, pull)

    # --- stages -----------------------------------------------------------------------------------------
    def _accept(self, t, polar) -> tuple[float, np.ndarray, np.ndarray]:
        """Checked scan (finite; ranges >= 0 and angles in bounds, `check_polar_bounds`): time, the detections
        within (0, max_range] and the mask of those rows."""
        polar, t = check_rows("polar", polar, 4), check_time("t", t)
        check_polar_bounds("polar", polar)
        if self.last_t is not None and not t > self.last_t:
            raise InputError(f"t: scan times must increase strictly (got {t} after {self.last_t})")
        in_range = (polar[:, 0] > 0) & (polar[:, 0] <= self.max_range)
        if self.config.association.missing_elevation_zero:
            in_range &= polar[:, 2] != 0.0  # no elevation estimate: not a measurement of 0
        return t, polar[in_range], in_range

    def _predict(self, t: float, polar: np.ndarray):
        """x_k, P_k and Q_k: the prior's prediction, or a (re-)initialisation (Q None) at the first scan and
        after an outage (`outage.reinit_after` without associations)."""
        outage = self.config.outage.reinit_after
        if self.last_t is None:
            return self._restart(*self._initial_state(t, polar), None)
        if (outage > 0 and len(polar) >= MIN_STATIC and self.last_with_data is not None
                and t - self.last_with_data.t > outage):
            return self._restart(*self._reinitialise(t, polar), None)
        prev = self.window.newest
        x = self.motion.predict(prev, t)
        F, Q = self.motion.transition_and_noise(prev, t - prev.t)
        if t - prev.t < self.config.noise.min_prior_dt:  # another radar's scan just after: Q as of min_prior_dt
            Q = self.motion.transition_and_noise(prev, self.config.noise.min_prior_dt)[1]
        return x, F @ self.P @ F.T + Q, Q, []

    def _restart(self, x: State, P: np.ndarray, events: list, Q: None):
        """A fresh window at x; the outage clock restarts (the fresh map needs a scan to fill)."""
        self.window.initialize(x, P)
        self.last_with_data = x.copy()
        return x, P, Q, events

    def _doppler_front_end(self, t, polar, x, P, Q, events):
        """Static detections, the consensus switch, the Doppler correction of the predicted mean (which then
        joins the window) and the zero-velocity or vehicle rate term. Returns x, P, static mask, standstill and
        the static detections' Doppler fit."""
        if self.last_t is not None:
            self.scan_dt = t - self.last_t
        static, note = self.doppler.static_mask(polar, x, P, self.scan_dt) if len(polar) else (np.zeros(0, bool), None)
        if note:
            events.append(note)
        if note == "doppler-consensus-switch" and Q is not None:
            x, P, more = self._reinitialise(t, polar[static], "re-initialised on the wider Doppler consensus")
            events += more
            x, P, Q, _ = self._restart(x, P, [], None)
        fit = self.doppler.fit(polar[static])
        still = self.doppler.standstill_information(fit, self.motion, settled=self.at_rest)
        self.doppler_nis = float("nan")  # the scan's Doppler against the prediction: none at a (re-)start
        if Q is not None:
            if (still is not None) != self.at_rest:  # stopped or moved off: the acceleration jumps
                Q, P = self.motion.with_jump(Q, P, self.window.newest, t, self.config.standstill.sigma_accel_jump)
            x, self.doppler_nis = self.doppler.correct(x, P, fit)
            self.window.push(x, Q)
        self.at_rest = still is not None
        self.window.set_rate_prior(len(self.window.states) - 1, self.vehicle_information if still is None else still)
        return x, P, static, still, fit

    def _recentre(self, x: State, P: np.ndarray, fit, scan: ScanMeasurements, n: int, W_pairs, pairs, events):
        """The gates lost the scan (under LOST_PAIRS of the static detections paired): if the Doppler contradicts
        the prediction at the pairs' gate level and the mean moved to it pairs RECOVERED_PAIRS of the scan's n
        detections, it moves there (event "doppler-recentred"; docs/estimator.md, step 3)."""
        y, _ = self.doppler.correct(x, P, fit, pairs_level=True)
        if y is x:
            return W_pairs, pairs
        W_new, new = self.associator.associate(y, P, self.map, scan)
        if len(new.map_idx) < RECOVERED_PAIRS * n:
            return W_pairs, pairs
        self.window.replace_newest(y)
        self._set_newest_pairs(W_new, new, scan)
        events.append("doppler-recentred")
        return W_new, new

    def _associate(self, x: State, P: np.ndarray, scan: ScanMeasurements):
        W_pairs, pairs = self.associator.associate(x, P, self.map, scan)
        self._set_newest_pairs(W_pairs, pairs, scan)
        return W_pairs, pairs

    def _solve(self, scan: ScanMeasurements, W_pairs, pairs, timings: dict):
        """Gauss-Newton, re-association at the solution (`MapAssociation.reassociate`) and one refining step, the
        newest covariance, then marginalisation of the states beyond the window. The re-association's time counts
        as association."""
        cfg, solver = self.config, self.config.solver
        self.window.optimize(solver.iterations, solver.step_tolerance, solver.step_sigma_tolerance,
                             reweight=solver.reweight_older)
        for _ in range(cfg.association.reassociate):
            if W_pairs is None:
                break
            tic = time.perf_counter()
            W_pairs, pairs = self.associator.reassociate(self.window.newest, self.map, scan, pairs)
            self._set_newest_pairs(W_pairs, pairs, scan)
            elapsed = time.perf_counter() - tic
            timings["associate"] += elapsed
            timings["reassociate"] = timings.get("reassociate", 0.0) + elapsed
            # from the last solution: the problem changed by a few pairs, and the step after the first is ~1e-5
            self.window.optimize(solver.refine_iterations, solver.step_tolerance, check_last=False, reweight=False,
                                 marginal=len(self.window.states) > cfg.window)  # its Schur complement, for below
        P_emitted, (self.P, P_pair) = self.P, self.window.newest_covariances()  # marginalising does not change them
        P_relative = self._relative_covariance(P_pair, P_emitted)
        while len(self.window.states) > cfg.window:
            self.window.marginalize_oldest(cfg.uncertainty.prior_memory)
        return W_pairs, pairs, P_relative

    def _relative_covariance(self, P_pair: np.ndarray | None, P_emitted: np.ndarray | None):
        """(the window's two newest states' relative pose covariance, this scan's revision of the previous pose if
        that was emitted as solved); across a (re-)initialisation the dead-reckoned one; None at the first scan."""
        if P_pair is None:
            restart = self.report.restart_relative
            return None if restart is None else (restart, np.zeros((6, 6)))
        prev, new = self.window.states[-2].T_vehicle_world, self.window.states[-1].T_vehicle_world
        solved = getattr(self.report.last, "t", None) == self.window.states[-2].t  # emitted as solved
        return scan_relative_covariances(P_pair, P_emitted, prev, new, self.motion.dim, solved)

    def _pull(self, scan: ScanMeasurements, pairs, T_world_sensor: np.ndarray) -> float:
        """The scan's pull on its solved pose (`pose_pull`), before the map moves its points."""
        det, idx = pairs.det_idx, pairs.map_idx
        C = self._point_covariances(scan.polar[det], T_world_sensor[:3, :3]) + self.map.covariances[idx]
        return pose_pull(T_world_sensor, scan.points[det], self.map.points[idx], C,
                         0.0 if self.surface_model else self.map_sigma**2)

    def _update_map(self, scan: ScanMeasurements, pairs, T_world_sensor: np.ndarray) -> None:
        """Refresh (or fuse) the associated map points, add the unassociated static detections, prune (the scan
        placed with T_world_sensor, the newest state's). The map ages with scans that have static detections, so
        a blockage does not expire the map it needs after."""
        cfg = self.config
        xk = self.window.newest
        if len(scan.points):
            self.map_clock += 1
        if len(pairs.map_idx):
            self.last_with_data = xk.copy()
        if len(pairs.map_idx) and cfg.map.fuse:
            # the detection is a new sample of the surface near the point: its own noise plus the sampling spread
            det = pairs.det_idx
            R_world = self._point_covariances(scan.polar[det], T_world_sensor[:3, :3]) \
                + self.map_sigma**2 * np.eye(3)
            self.map.fuse(pairs.map_idx, se3.transform_points(T_world_sensor, scan.points[det]), R_world,
                          self.map_clock, cfg.map.max_fused)
        elif len(pairs.map_idx):
            self.map.refresh(pairs.map_idx, self.map_clock)
        if len(scan.points):
            new = np.ones(len(scan.points), bool)
            new[pairs.det_idx] = False
            p_new = se3.transform_points(T_world_sensor, scan.points[new])
            covariances = self._point_covariances(scan.polar[new], T_world_sensor[:3, :3])
            if self.surface_model:
                m = cfg.map
                covariances += surface_covariances(p_new, self.map.points, m.surface_normal_sigma,
                                                   m.surface_tangent_sigma, self.map_sigma, m.surface_neighbours,
                                                   m.surface_radius, m.surface_planarity)[0]
            self.map.add(p_new, self.map_clock, covariances=covariances)
        if len(self.sensors) == 1:
            self.map.prune(self.map_clock, xk.T_vehicle_world, self.T_vehicle_sensor, self.max_range)
        else:  # a point behind this radar may be ahead of another: prune by age and distance from the vehicle
            self.map.prune(self.map_clock, xk.T_vehicle_world, np.eye(4), self._reach, behind=False)

    def _estimate(self, t, polar, static, pairs, timings, events, detail, standstill) -> ScanEstimate:
        xk = self.window.newest
        nis = float(np.mean(pairs.d2)) if len(pairs.d2) else float("nan")
        if not (np.isfinite(xk.T_vehicle_world).all() and np.isfinite(self.P).all()):
            raise FloatingPointError("estimator state became non-finite")  # a bug, never silently written
        self.last_t = t
        self.scan_index += 1
        return ScanEstimate(t, xk.T_vehicle_world.copy(), xk.varpi.copy(),
                            None if xk.varpi_dot is None else xk.varpi_dot.copy(), self.P.copy(), len(polar),
                            int(static.sum()), len(pairs.map_idx), nis, timings, events, detail, standstill)

    # --- helpers ------------------------------------------------------------------------------------------
    def _point_covariances(self, z: np.ndarray, C: np.ndarray) -> np.ndarray:
        """World-frame covariance of new map points from detections z (C: world from sensor), model's noise."""
        return self.measurement.world_position_covariance(z, self.sigmas, self.config.noise.cartesian_sigma, C)

    def _set_newest_pairs(self, W_pairs, pairs, scan: ScanMeasurements) -> None:
        """The pairs (their information W_pairs) the newest state is solved with."""
        self.window.set_measurements(len(self.window.states) - 1, self._measurement_set(W_pairs, pairs, scan))

    def _measurement_set(self, W_pairs, pairs, scan: ScanMeasurements) -> MeasurementSet | None:
        if W_pairs is None or len(pairs.map_idx) == 0:
            return None
        kappa = self.config.uncertainty.measurement_inflation
        W = W_pairs if kappa == 1.0 else W_pairs / kappa
        if self.config.noise.doppler_common_sigma > 0:
            polar = scan.polar[pairs.det_idx]
            W = common_doppler_error(W, polar[:, 1], polar[:, 2], self.config.noise.doppler_common_sigma)
        return MeasurementSet(self.map.points[pairs.map_idx], scan.z[pairs.det_idx], W, self.T_vehicle_sensor)

    def _reinitialise(self, t: float, polar: np.ndarray, reason: str | None = None) -> tuple[State, np.ndarray, list]:
        """After an outage: dead-reckoned pose, Doppler velocity (dead-reckoned without a consensus of MIN_STATIC:
        docs/estimator.md, step 9), last rates, zero acceleration, empty map. The dead-reckoned pose's uncertainty
        relative to the last estimate carries the absolute covariance across."""
        last = self.window.newest
        predicted = self.motion.predict(last, t)
        F, Q = self.motion.transition_and_noise(last, t - last.t)
        T = predicted.T_vehicle_world
        self.report.restart_relative = predicted_relative_covariance(self.P, F, Q, last.T_vehicle_world, T)
        x, P, _ = self._initial_state(t, polar, T, self.last_with_data.varpi[3:],
                                      (predicted.varpi[:3], (F @ self.P @ F.T + Q)[6:9, 6:9]))
        self.map = self.map.cleared()
        if reason is None:
            reason = f"re-initialised after {t - self.last_with_data.t:.2f} s without associations"
        return x, P, [reason]

    def _initial_state(self, t: float, polar: np.ndarray, T=None, rates=None,
                       dead_reckoned=None) -> tuple[State, np.ndarray, list]:
        """The state at t: pose T (identity), the Doppler velocity of the scan's widest consensus (omega as known:
        `rates`) at `solver.init_velocity_sigma` where it has MIN_STATIC detections, else `dead_reckoned`
        (velocity (3,), covariance (3, 3)) or zero at 5 m/s (docs/estimator.md, step 9)."""
        cfg = self.config.solver
        v0 = np.zeros(3) if dead_reckoned is None else dead_reckoned[0]
        varpi, vel_sigma = np.concatenate((v0, np.zeros(3) if rates is None else rates)), 5.0
        if len(polar) >= 3:
            ego = self.doppler.widest_consensus(polar)
            if ego.ok and ego.inliers.sum() >= MIN_STATIC:
                varpi[:3] = body_velocity(ego.v_sensor, varpi[3:], self.T_vehicle_sensor)
                vel_sigma, dead_reckoned = cfg.init_velocity_sigma, None
        x0 = self.motion.initial_state(t, np.eye(4) if T is None else T, varpi)
        sig = [1e-4] * 6 + self.motion.tail_sigmas([vel_sigma] * 3, cfg.init_rate_sigma, cfg.init_accel_sigma,
                                                   cfg.init_angular_accel_sigma)
        P = np.diag(np.square(sig))
        if dead_reckoned is not None:
            P[6:9, 6:9] = dead_reckoned[1]
        return x0, P, ["initialised"]

