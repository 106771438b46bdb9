"""Radar odometry, one scan at a time: predict, classify static/moving by Doppler, associate, solve, map.

This is the algorithm layer (no file I/O, no printing): `RadarOdometry.process(t, polar)` takes one scan's
detections [range, azimuth, elevation, radial_velocity] (sensor frame) and returns the newest estimate.

Per scan k (paper sec. III-VI; docs/estimator.md gives the reasons and the measurements behind each step):
1. predict x_k = f(x_{k-1}) and P_k = F P F^T + Q with the configured prior (CV or CA);
2. static detections: the largest Doppler consensus near the predicted sensor velocity (a prediction-gated
   RANSAC), or a free RANSAC fit when the prediction is uncertain (moving objects and clutter are rejected
   either way, as in reve);
3. when the scan's Doppler velocity contradicts the prediction (an unmodelled jerk), move the predicted mean
   to it: it is the linearisation point and the centre of the association gates;
4. a zero-velocity term when the Doppler says the sensor is at rest;
5. associate map points with detections by maximum likelihood with S = G P G^T + R (+ map-point term), gated
   at the chi-square quantile (eq. 86-88), both windowed to the field of view;
6. add x_k to the sliding window, Gauss-Newton over prior, motion and measurement terms, re-associate with the
   refined estimate, solve again, marginalise the oldest state when the window is full;
7. update the local map: refresh associated points, add the unassociated static detections. The map ages
   with scans that have static detections, so a blockage does not expire the map needed after it.
"""

from __future__ import annotations

import time
import numpy as np
from scipy.spatial import cKDTree

from . import association_kernels as _akernel
from . import association, measurements
from .config import OdometryConfig
from .consensus import MIN_STATIC, ConsensusSwitch  # MIN_STATIC: fewest static detections to use
from .ego_velocity import estimate_ego_velocity, least_squares_velocity
from .errors import InputError, check_finite
from .lie import se3, so3
from .local_map import LocalMap
from .scan import ScanDetail, ScanEstimate
from .state import MotionModel, State
from .window import MeasurementSet, SlidingWindow



class RadarOdometry:
    """Sliding-window radar odometry (CV/C, CA/P, or the mixed ablations) for one sensor.

    Args:
        config: OdometryConfig (model, window, noise, association, map, solver).
        T_vehicle_sensor: (4, 4) extrinsics.
        sensor_sigmas: (4,) 1-sigma noise [range, azimuth, elevation, radial_velocity] (from sensor.toml).
        max_range: the sensor's maximum range (m), for pruning the map.
        record_detail: keep per-scan association detail in `ScanEstimate.detail` (for visual debugging).
        fov: ((az_min, az_max), (el_min, el_max)) radians, the sensor's field of view (sensor.toml): association
            is windowed inside it (`_window_masks`); None: no window.
    """

    def __init__(self, config: OdometryConfig, T_vehicle_sensor, sensor_sigmas, max_range: float = 200.0,
                 record_detail: bool = False, fov=None):
        self.config = config
        self.T_vs = check_finite("T_vehicle_sensor", T_vehicle_sensor, (4, 4))
        sig = check_finite("sensor_sigmas", sensor_sigmas, (4,))
        if np.any(sig <= 0):
            raise InputError(f"sensor_sigmas: must be > 0, got {sig}")
        self.sigmas = np.maximum(sig * config.noise.sensor_sigma_scale, config.noise.sigma_floor)
        self.max_range = float(max_range)
        self.fov = None
        if fov is not None:
            fov = check_finite("fov", fov, (2, 2))
            if fov.shape != (2, 2) or np.any(fov[:, 0] >= fov[:, 1]):
                raise InputError(f"fov: expected ((az_min, az_max), (el_min, el_max)) with min < max, got {fov}")
            self.fov = fov
        self.record_detail = record_detail
        # R does not depend on the detection in either model (diagonal polar sigmas, or the fixed Cartesian one)
        self._R = measurements.noise_covariance(config.measurement, np.array([[1.0, 0.0, 0.0, 0.0]]), self.sigmas,
                                                config.noise.cartesian_sigma)[0]
        qc = config.noise.qc_ca if config.prior == "ca" else config.noise.qc_cv
        self.motion = MotionModel(config.prior, qc)
        self.window = SlidingWindow(self.motion, config.window, config.measurement, self.T_vs,
                                    config.solver.robust_c)
        seeds = np.random.SeedSequence(config.seed).spawn(3)
        self.rng = np.random.default_rng(seeds[0])
        # its own random stream: the consensus checks change no other draw
        self._consensus = ConsensusSwitch(config.association, self.sigmas[3], np.random.default_rng(seeds[2]))
        self.map = LocalMap(config.map.capacity, config.map.max_age, config.map.voxel,
                            rng=np.random.default_rng(seeds[1]))
        self.gate = association.gate_threshold(config.association.gate_probability, 4)
        self._doppler_gate = {d: association.gate_threshold(config.association.doppler_update_probability, d)
                              for d in (2, 3)}
        self._still_gate = {d: association.gate_threshold(0.99, d) for d in (2, 3)}
        # a moving road vehicle's roll and pitch rates are near zero (VehicleConfig); None when both terms are off
        rate_info = np.zeros(self.motion.dim - 6)
        for axis, sigma in ((3, config.vehicle.sigma_roll_rate), (4, config.vehicle.sigma_pitch_rate)):
            rate_info[axis] = sigma**-2 if sigma > 0 else 0.0
        self._vehicle_info = np.diag(rate_info) if rate_info.any() else None
        self.P: np.ndarray | None = None
        self.scan_index = 0
        self._last_data: State | None = None  # newest state at the last scan with associations
        self.map_clock = 0  # counts scans with static detections: the map ages with observations, not time
        self._last_t: float | None = None
        self._scan_dt = 0.1  # s, the latest time between scans (counts the consensus-switch scans)

    # --- helpers ------------------------------------------------------------------------------------------
    def _sensor_velocity(self, varpi: np.ndarray, P_varpi: np.ndarray):
        """Sensor velocity in the sensor frame and its covariance: v_s = -C_vs^T (nu + omega x r_vs)."""
        C, r = self.T_vs[:3, :3], self.T_vs[:3, 3]
        v = -C.T @ (varpi[:3] + np.cross(varpi[3:], r))
        J = -C.T @ np.c_[np.eye(3), -so3.hat(r)]
        return v, J @ P_varpi @ J.T

    def _static_mask(self, polar: np.ndarray, x: State, P: np.ndarray) -> tuple[np.ndarray, str | None]:
        """Static detections by Doppler: the largest consensus near the predicted sensor velocity.

        A confident prediction (the usual case) seeds a prediction-gated RANSAC: only velocities within the
        prediction's 3-sigma plus `association.doppler_jerk_margin` compete, so an unmodelled jerk (hard
        braking, a hand-held sensor) does not split the static world into "moving" detections, and a larger
        moving consensus (a truck filling the view) is not taken for the world while the world offers
        MIN_STATIC detections near the prediction. Otherwise, and when an uncertain prediction (after
        initialisation or an outage) explains too little of the scan, an unconstrained RANSAC fit decides.
        """
        acfg = self.config.association
        az, el, vr = polar[:, 1], polar[:, 2], polar[:, 3]
        u = measurements.polar_to_cartesian(np.stack([np.ones(len(polar)), az, el], axis=1))
        v, Sv = self._sensor_velocity(x.varpi, P[6:12, 6:12])
        # per detection: radial velocity noise, the direction noise seen through the velocity (v . du/daz,
        # v . du/del), and the predicted velocity's own uncertainty
        ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
        d_az = np.stack([-ce * sa, ce * ca, np.zeros_like(az)], axis=1) @ v
        d_el = np.stack([-se * ca, -se * sa, ce], axis=1) @ v
        var_fit = self.sigmas[3] ** 2 + (self.sigmas[1] * d_az) ** 2 + (self.sigmas[2] * d_el) ** 2
        sigma = np.sqrt(var_fit + np.einsum("ni,ij,nj->n", u, Sv, u))
        mask = np.abs(vr + u @ v) <= 3.0 * sigma + acfg.doppler_sigma_floor
        confident = np.sqrt(np.trace(Sv)) < acfg.ransac_above_sigma
        fit_threshold = 3.0 * np.sqrt(var_fit) + acfg.doppler_sigma_floor
        if confident:
            radius = 3.0 * np.sqrt(np.linalg.eigvalsh(Sv)[-1]) + acfg.doppler_jerk_margin
            ego = estimate_ego_velocity(az, el, vr, self.rng, sigma_vr=self.sigmas[3], threshold=fit_threshold,
                                        near=(v, radius))
            ours = ego.inliers if ego.ok and ego.inliers.sum() >= max(MIN_STATIC, mask.sum()) else mask
            switch = self._consensus.outvoted(az, el, vr, fit_threshold, ours, u * polar[:, :1], self._scan_dt)
            if switch is not None:
                return switch, "doppler-consensus-switch"
            if ours.sum() >= MIN_STATIC:
                return ours, None
        elif mask.sum() >= MIN_STATIC and mask.sum() >= 0.2 * len(polar):
            return mask, None
        ego = self._widest_consensus(polar, fit_threshold)
        if ego.ok and ego.inliers.sum() > mask.sum():
            return ego.inliers, "doppler-ransac-fallback"
        return mask, None

    def _widest_consensus(self, polar: np.ndarray, threshold=None):
        """The Doppler fit to start from (`ConsensusSwitch.widest`, drawing first from the main stream)."""
        return self._consensus.widest(polar, self.rng, threshold)

    def _doppler_fit(self, static: np.ndarray):
        """Least-squares sensor velocity of the static detections: (v (dof,), covariance, dof, their radial
        velocities), or None (fewer than dof + 3 detections, degenerate geometry). Planar (dof 2: vx, vy) when
        the elevations carry no information (2D sensors)."""
        fit = least_squares_velocity(static[:, 1], static[:, 2], static[:, 3], variance_floor=self.sigmas[3] ** 2,
                                     max_cond=1e8)
        if fit is None or len(static) < len(fit[0]) + 3:
            return None
        return fit[0], fit[1], len(fit[0]), static[:, 3]

    def _doppler_update(self, x: State, P: np.ndarray, fit) -> State:
        """The predicted state, corrected by the scan's Doppler ego-velocity when the two disagree.

        Association gates the radial velocity at the sensor's few cm/s, so a velocity prediction off by a
        tenth of a m/s (an unmodelled jerk: hard braking, a hand-held sensor) would reject most true pairs. The
        least-squares sensor velocity of the static detections, v_s = -C_vs^T (nu + omega x r_vs), is compared
        with the prediction (chi-square at `association.doppler_update_probability`); only when it contradicts
        it does a Kalman update move the mean. The result is only the linearisation point and the centre of
        the association gates: P stays the predicted covariance and the solve uses the detections through its
        own factors, so nothing is counted twice. (Updating P too, or updating at every scan, made the gates
        follow the least-squares fit's own errors: more pitch drift on the simulated city.)
        """
        if fit is None:
            return x
        v, cov, dof, _ = fit
        C, r = self.T_vs[:3, :3], self.T_vs[:3, 3]
        J = (-C.T @ np.c_[np.eye(3), -so3.hat(r)])[:dof]
        H = np.zeros((dof, len(P)))
        H[:, 6:12] = J
        S = H @ P @ H.T + cov
        innovation = v - J @ x.varpi
        if innovation @ np.linalg.solve(S, innovation) <= self._doppler_gate[dof]:
            return x  # the prediction agrees with the scan's Doppler: nothing to correct
        K = np.linalg.solve(S, H @ P).T
        return x.oplus(K @ innovation)

    def _standstill_info(self, fit) -> np.ndarray | None:
        """Information of the zero-velocity term when the Doppler says the sensor is at rest, else None."""
        cfg = self.config.standstill
        if fit is None or cfg.speed <= 0:
            return None
        v, cov, dof, vr = fit
        # at rest every static detection's Doppler is noise: a small median, and a fit consistent with zero
        quiet = np.median(np.abs(vr)) <= max(0.5 * cfg.speed, self.sigmas[3])
        if not (quiet and v @ np.linalg.solve(cov, v) <= self._still_gate[dof]):
            return None
        sig = [cfg.sigma_velocity] * 3 + [cfg.sigma_rate] * 3
        if self.motion.dim == 18:
            sig += [cfg.sigma_accel] * 3 + [cfg.sigma_angular_accel] * 3
        return np.diag(1.0 / np.square(sig))

    def _associate(self, x: State, P: np.ndarray, z: np.ndarray, pts: np.ndarray, polar: np.ndarray, scan: dict):
        """Map points and detections paired inside the association window (`_window_masks`).

        Per map point, `association_kernels.prepare` evaluates the prediction, S = G P G^T + R + map term
        (`association.innovation_covariance` plus `_map_term`), its inverse and the search radius in one
        compiled pass over the map points inside the window; `association.match` does the rest. `scan` caches the
        KD-tree of this scan's detections and its candidates for the re-association. Returns (W_map,
        Association): W_map (m, 4, 4) the information of each map point's pair in the solve, (R + map term)^-1
        (NaN outside the window); None when nothing could be associated.
        """
        if len(self.map) == 0 or len(z) == 0:
            return None, association.Association(np.zeros(0, int), np.zeros(0, int), np.zeros(0), 0)
        # the window first (positions only), then the compiled pass over the map points inside it
        T_sw = se3.inverse(self.T_vs) @ x.T
        m_in, d_in = self._window_masks(self.map.points @ T_sw[:3, :3].T + T_sw[:3, 3], polar)
        mi = np.flatnonzero(m_in)
        m = len(mi)
        zp, p_s = np.empty((m, 4)), np.empty((m, 3))
        S, S_inv, W_in = np.empty((m, 4, 4)), np.empty((m, 4, 4)), np.empty((m, 4, 4))
        radius = np.empty(m)
        bad = _akernel.prepare(self.config.measurement == "polar", x.T, x.varpi, self.map.points[mi],
                               self.map.covariances[mi], self.config.map_sigma**2, np.ascontiguousarray(P[:12, :12]),
                               self._R, self.T_vs, self.gate, zp, p_s, S, S_inv, W_in, radius)
        if bad >= 0:  # a map point at the sensor, or an innovation covariance that is not positive definite
            raise FloatingPointError(f"association: map point {mi[bad % m]} has "
                                     + ("range 0" if bad < m else "a non positive definite S"))
        W_map = np.full((len(self.map), 4, 4), np.nan)  # outside the window: never paired, never read
        W_map[mi] = W_in
        if "tree" not in scan:
            scan["di"] = np.flatnonzero(d_in)
            scan["tree"] = cKDTree(pts[scan["di"]])
        di = scan["di"]
        a, scan["search"] = association.match(self.config.measurement, z[di], scan["tree"], zp, p_s, S_inv,
                                              np.minimum(radius, self.config.association.max_radius), self.gate,
                                              keys=mi, previous=scan.get("search"))
        return W_map, association.Association(mi[a.map_idx], di[a.det_idx], a.d2, a.n_candidates)

    def _window_masks(self, p_sensor: np.ndarray, polar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map points (predicted) and detections (measured) inside the field of view shrunk by 3 sigma of the
        angle noise. Detections exist only inside the field of view but map points are not cut there: a map
        point that has left it (ground passing below the lower edge) would be paired with the detections at
        the edge, all on one side of it, a bias the solve turns into pitch. The same window on both sides
        keeps the pairs symmetric. An angle whose field of view is narrower than the margin (a 2D radar's
        elevation) is not windowed."""
        m_in = np.ones(len(p_sensor), bool)
        d_in = np.ones(len(polar), bool)
        if self.fov is None:
            return m_in, d_in
        r = np.maximum(np.linalg.norm(p_sensor, axis=1), 1e-12)
        angles = ((np.arctan2(p_sensor[:, 1], p_sensor[:, 0]), polar[:, 1], self.fov[0], self.sigmas[1]),
                  (np.arcsin(np.clip(p_sensor[:, 2] / r, -1, 1)), polar[:, 2], self.fov[1], self.sigmas[2]))
        for pred_angle, meas_angle, (lo, hi), sigma in angles:
            if (hi - lo) - 6 * sigma < 0.1 * (hi - lo):  # the margin would eat the field of view
                continue
            lo, hi = lo + 3 * sigma, hi - 3 * sigma
            m_in &= (pred_angle >= lo) & (pred_angle <= hi)
            d_in &= (meas_angle >= lo) & (meas_angle <= hi)
        return m_in, d_in

    def _point_covariances(self, polar: np.ndarray, C_world_sensor: np.ndarray) -> np.ndarray:
        """World-frame covariance of new map points under the model's own noise assumption: the polar noise
        propagated (polar models) or the fixed Cartesian sigma (Cartesian models, the CV/C baseline)."""
        if self.config.measurement == "polar":
            cov_s = measurements.cartesian_position_covariance(polar, self.sigmas)
        else:
            cov_s = np.broadcast_to(self.config.noise.cartesian_sigma**2 * np.eye(3), (len(polar), 3, 3))
        return C_world_sensor @ cov_s @ C_world_sensor.T

    def _measurement_set(self, W_map, assoc, z) -> MeasurementSet | None:
        if W_map is None or len(assoc.map_idx) == 0:
            return None
        return MeasurementSet(self.map.points[assoc.map_idx], z[assoc.det_idx], W_map[assoc.map_idx])

    def _reinitialise(self, t: float, polar: np.ndarray, reason: str | None = None) -> tuple[State, np.ndarray, list]:
        """After an outage: dead-reckoned pose, Doppler velocity, last rates, zero acceleration, empty map."""
        T = self.motion.predict(self.window.newest, t).T
        x, P, _ = self._initial_state(t, polar, T=T, rates=self._last_data.varpi[3:])
        self.map = LocalMap(self.config.map.capacity, self.config.map.max_age, self.config.map.voxel,
                            rng=self.map._rng)
        if reason is None:
            reason = f"re-initialised after {t - self._last_data.t:.2f} s without associations"
        return x, P, [reason]

    def _initial_state(self, t: float, polar: np.ndarray, T=None, rates=None) -> tuple[State, np.ndarray, list]:
        cfg = self.config.solver
        events = ["initialised"]
        varpi = np.zeros(6)
        if rates is not None:
            varpi[3:] = rates
        vel_sigma = 5.0
        if len(polar) >= 3:
            ego = self._widest_consensus(polar)
            if ego.ok:
                # v_s = -C_vs^T (nu + omega x r_vs), with omega as known (zero at the start)
                varpi[:3] = -self.T_vs[:3, :3] @ ego.v_sensor - np.cross(varpi[3:], self.T_vs[:3, 3])
                vel_sigma = cfg.init_velocity_sigma
        x0 = self.motion.initial_state(t, np.eye(4) if T is None else T, varpi)
        sig = [1e-4] * 6 + [vel_sigma] * 3 + list(cfg.init_rate_sigma)
        if self.motion.dim == 18:
            sig += list(cfg.init_accel_sigma) + list(cfg.init_angular_accel_sigma)
        return x0, np.diag(np.square(sig)), events

    # --- the per-scan step ------------------------------------------------------------------------------
    def process(self, t: float, polar) -> ScanEstimate:
        """Process one scan at time t (s) with detections polar (n, 4); n may be 0."""
        polar = check_finite("polar", polar, (4,)).reshape(-1, 4)
        t = float(t)
        if self._last_t is not None and not t > self._last_t:
            raise InputError(f"t: scan times must increase strictly (got {t} after {self._last_t})")
        timings = {}
        tic = time.perf_counter()
        cfg = self.config
        model = cfg.measurement
        in_range = (polar[:, 0] > 0) & (polar[:, 0] <= self.max_range)
        polar = polar[in_range]
        events: list = []
        predicted = False  # True: x, P, Q predicted from the window (not a fresh initialisation)
        outage = self.config.outage.reinit_after
        if self._last_t is None:
            x, P, events = self._initial_state(t, polar)
            self.window.initialize(x, P)
            self._last_data = x.copy()
        elif (outage > 0 and len(polar) >= MIN_STATIC and self._last_data is not None
              and t - self._last_data.t > outage):
            x, P, events = self._reinitialise(t, polar)
            self.window.initialize(x, P)
            self._last_data = x.copy()  # the outage clock restarts: the fresh map needs a scan to fill
        else:
            prev = self.window.newest
            x = self.motion.predict(prev, t)
            F, Q = self.motion.transition_and_noise(prev, t - prev.t)
            P = F @ self.P @ F.T + Q
            predicted = True
        timings["predict"] = time.perf_counter() - tic

        tic = time.perf_counter()
        if self._last_t is not None:
            self._scan_dt = t - self._last_t
        static, note = self._static_mask(polar, x, P) if len(polar) else (np.zeros(0, bool), None)
        if note:
            events.append(note)
        if note == "doppler-consensus-switch" and predicted:
            x, P, more = self._reinitialise(t, polar[static], "re-initialised on the wider Doppler consensus")
            events += more
            self.window.initialize(x, P)
            self._last_data = x.copy()
            predicted = False
        fit = self._doppler_fit(polar[static]) if static.sum() >= MIN_STATIC else None
        if predicted:
            x = self._doppler_update(x, P, fit)
            self.window.push(x, Q)
        still = self._standstill_info(fit)  # at rest: every rate is zero; moving: roll and pitch rates near zero
        self.window.set_rate_prior(len(self.window.states) - 1, self._vehicle_info if still is None else still)
        z = measurements.to_model_space(model, polar[static]) if static.any() else np.zeros((0, 4))
        pts = measurements.polar_to_cartesian(polar[static]) if static.any() else np.zeros((0, 3))
        scan_cache: dict = {}
        W_map, assoc = self._associate(x, P, z, pts, polar[static], scan_cache)
        self.window.set_measurements(len(self.window.states) - 1, self._measurement_set(W_map, assoc, z))
        timings["associate"] = time.perf_counter() - tic

        tic = time.perf_counter()
        self.window.optimize(cfg.solver.iterations, cfg.solver.step_tolerance)
        for _ in range(cfg.association.reassociate):
            if W_map is None:
                break
            t_assoc = time.perf_counter()
            W_map, assoc = self._associate(self.window.newest, P, z, pts, polar[static], scan_cache)
            self.window.set_measurements(len(self.window.states) - 1, self._measurement_set(W_map, assoc, z))
            timings["associate"] += time.perf_counter() - t_assoc
            # from the last solution: the problem changed by a few pairs, and the step after the first is ~1e-5
            self.window.optimize(cfg.solver.refine_iterations, cfg.solver.step_tolerance, check_last=False)
        self.P = self.window.newest_covariance()  # at the solution; marginalising does not change it
        while len(self.window.states) > cfg.window:
            self.window.marginalize_oldest()
        timings["solve"] = time.perf_counter() - tic

        detail = None
        if self.record_detail:
            detail = ScanDetail(polar, static, np.flatnonzero(static)[assoc.det_idx], assoc.map_idx.copy(),
                                self.map.points.copy(), np.flatnonzero(in_range))
        tic = time.perf_counter()
        xk = self.window.newest
        if len(pts):
            self.map_clock += 1  # an empty scan (blockage) must not expire the map it will need afterwards
        if len(assoc.map_idx):
            self._last_data = xk.copy()
        T_world_sensor = se3.inverse(xk.T) @ self.T_vs
        if len(assoc.map_idx) and cfg.map.fuse:
            # the detection is a new sample of the surface near the point: its own noise plus the sampling spread
            det = assoc.det_idx
            R_w = self._point_covariances(polar[static][det], T_world_sensor[:3, :3]) + cfg.map_sigma**2 * np.eye(3)
            self.map.fuse(assoc.map_idx, se3.transform_points(T_world_sensor, pts[det]), R_w, self.map_clock,
                          cfg.map.max_fused)
        elif len(assoc.map_idx):
            self.map.refresh(assoc.map_idx, self.map_clock)
        if len(pts):
            new = np.ones(len(pts), bool)
            new[assoc.det_idx] = False
            self.map.add(se3.transform_points(T_world_sensor, pts[new]), self.map_clock,
                         covariances=self._point_covariances(polar[static][new], T_world_sensor[:3, :3]))
        self.map.prune(self.map_clock, xk.T, self.T_vs, self.max_range)
        timings["map"] = time.perf_counter() - tic

        nis = float(np.mean(assoc.d2)) if len(assoc.d2) else float("nan")
        if not (np.all(np.isfinite(xk.T)) and np.all(np.isfinite(self.P))):
            raise FloatingPointError("estimator state became non-finite")  # a bug, never silently written
        self._last_t = t
        self.scan_index += 1
        return ScanEstimate(t, xk.T.copy(), xk.varpi.copy(), None if xk.vd is None else xk.vd.copy(),
                            self.P.copy(), len(polar), int(static.sum()), len(assoc.map_idx), nis, timings, events,
                            detail, still is not None)
