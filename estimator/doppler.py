"""The odometry's Doppler front end: which detections are static, the scan's own sensor velocity, a
correction of the predicted velocity when the two disagree, and the standstill test.

Radial velocities see the sensor's velocity directly, v_r = -u . v_s for a static point, with

    v_s = -C_vs^T (nu + omega x r_vs)        (`sensor_velocity`, the one formula; its Jacobian d v_s / d varpi)

(T_vehicle_sensor = [C_vs, r_vs], varpi = [nu; omega]). Per scan (docs/estimator.md, steps 2-4):
- `DopplerFrontEnd.static_mask`: the largest Doppler consensus near the predicted sensor velocity (a
  prediction-gated RANSAC), or a free fit when the prediction is uncertain; objects that move slowly as a
  group are left out of it, and the consensus switch takes the world back from a co-moving object
  (`rodo.estimator.consensus`);
- `fit`: least-squares sensor velocity of the static detections;
- `correct`: a Kalman update of the predicted mean when the fit contradicts it (an unmodelled jerk);
- `standstill_information`: a zero-velocity term when the Doppler says the sensor is at rest.

Checked by: tests/estimator/test_odometry.py::test_hard_braking_is_followed,
    tests/estimator/test_ego_velocity.py, tests/estimator/test_moving_groups.py
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import association, doppler_kernels
from .association_kernels import lambda_max_sym3
from .config import OdometryConfig
from .consensus import MIN_STATIC, ConsensusSwitch, Voxels, moving_voxels
from .ego_velocity import RANSAC_ITERATIONS, EgoVelocity, is_planar, least_squares_velocity, ransac_velocity
from .lie import so3
from .motion import MotionPrior
from .radar_geometry import polar_to_cartesian
from .state import State


def sensor_velocity(varpi: np.ndarray, T_vehicle_sensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sensor's velocity in its own frame, v_s = -C_vs^T (nu + omega x r_vs), and J_v_varpi (3, 6).

    (The sign: a static point's radial velocity is v_r = -u . v_s with this v_s.)

    Checked by: tests/estimator/test_odometry.py::test_sensor_velocity_jacobian_matches_finite_differences
    """
    C, r = T_vehicle_sensor[:3, :3], T_vehicle_sensor[:3, 3]
    w0, w1, w2 = float(varpi[3]), float(varpi[4]), float(varpi[5])
    r0, r1, r2 = float(r[0]), float(r[1]), float(r[2])
    v = -C.T @ (varpi[:3] + np.array([w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0]))  # omega x r
    J = np.empty((3, 6))
    J[:, :3] = -C.T
    J[:, 3:] = C.T @ so3.hat(r)
    return v, J


def body_velocity(v_sensor: np.ndarray, omega: np.ndarray, T_vehicle_sensor: np.ndarray) -> np.ndarray:
    """nu such that `sensor_velocity([nu; omega])` is v_sensor: nu = -C_vs v_s - omega x r_vs.

    Checked by: tests/estimator/test_odometry.py::test_sensor_velocity_jacobian_matches_finite_differences
    """
    return -T_vehicle_sensor[:3, :3] @ v_sensor - np.cross(omega, T_vehicle_sensor[:3, 3])


@dataclass
class DopplerFit:
    """Least-squares sensor velocity of a scan's static detections.

    Attributes:
        v: (dof,) sensor velocity (dof 3, or 2 = [vx, vy] for a planar sensor).
        cov: (dof, dof) its covariance.
        radial_velocity: (n,) the static detections' radial velocities.
    """

    v: np.ndarray
    cov: np.ndarray
    radial_velocity: np.ndarray

    @property
    def dof(self) -> int:
        return len(self.v)


class DopplerFrontEnd:
    """The Doppler steps of one odometry run: its sensor, noise, random streams and consensus switch.

    Args:
        config: the odometry's configuration (association and standstill sections).
        T_vehicle_sensor: (4, 4) extrinsics.
        sigmas: (4,) the estimator's 1-sigma [range, azimuth, elevation, radial velocity].
        rng: random stream of the RANSAC fits.
        consensus_rng: the consensus switch's own stream (its checks change no other draw).
    """

    def __init__(self, config: OdometryConfig, T_vehicle_sensor: np.ndarray, sigmas: np.ndarray,
                 rng: np.random.Generator, consensus_rng: np.random.Generator):
        self.config = config
        self.T_vehicle_sensor = T_vehicle_sensor
        self.sigmas = sigmas
        self.rng = rng
        self.consensus = ConsensusSwitch(config.association, sigmas[3], consensus_rng)
        self.update_gate = {d: association.gate_threshold(config.association.doppler_update_probability, d)
                            for d in (2, 3)}
        self.pair_gate = {d: association.gate_threshold(config.association.gate_probability, d) for d in (2, 3)}
        self.still_gate = {d: association.gate_threshold(0.99, d) for d in (2, 3)}

    def _thresholds(self, polar: np.ndarray, v: np.ndarray, Sv: np.ndarray):
        """Per detection (compiled, `doppler_kernels.thresholds`): unit direction u (`polar_to_cartesian` at
        range 1, bit for bit), position pts, the fit's variance var_fit (radial velocity noise and the direction
        noise seen through the velocity v . du/daz, v . du/del), the prediction's gate mask (var_fit plus the
        predicted velocity's own uncertainty u^T Sv u, at 3 sigma + `association.doppler_sigma_floor`) and the
        fit's threshold 3 sqrt(var_fit) + the floor."""
        n = len(polar)
        az, el = polar[:, 1], polar[:, 2]
        u, pts, var_fit = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
        mask, fit_threshold = np.empty(n, bool), np.empty(n)
        doppler_kernels.thresholds(np.ascontiguousarray(polar, dtype=float), np.cos(az), np.sin(az), np.cos(el),
                                   np.sin(el), v, np.ascontiguousarray(Sv), self.sigmas,
                                   float(self.config.association.doppler_sigma_floor), u, pts, var_fit, mask,
                                   fit_threshold)
        return u, pts, var_fit, mask, fit_threshold

    def static_mask(self, polar: np.ndarray, x: State, P: np.ndarray, scan_dt: float):
        """Static detections by Doppler: (mask (n,), event note or None).

        A confident prediction (the usual case) seeds a prediction-gated RANSAC: only velocities within the
        prediction's 3-sigma plus `association.doppler_jerk_margin` compete, so an unmodelled jerk (hard
        braking, a hand-held sensor) does not split the static world into "moving" detections, and a larger
        moving consensus (a truck filling the view) is not taken for the world while the world offers
        MIN_STATIC detections near the prediction. Voxels whose detections move slowly as a group (a queue of
        cars moving off, each detection still inside its gate) are left out first (`consensus.moving_voxels`,
        `association.moving_group_z`). When fewer than MIN_STATIC are near a confident prediction, those few are
        the static set (event "doppler-few-static"): a free fit would take whatever fills the view. An uncertain
        prediction (after initialisation or an outage) takes the widest consensus inside its gate
        (`_widest_in_gate`); only one that explains too little of the scan leaves the decision to an
        unconstrained RANSAC fit, whose consensus is taken where it is wider than the gate. Otherwise it is again
        the gate's own consensus of MIN_STATIC, or no static set: a few detections that do not agree are no
        velocity (tests/estimator/test_doppler_front_end.py).
        """
        acfg = self.config.association
        az, el, vr = polar[:, 1], polar[:, 2], polar[:, 3]
        v, J = sensor_velocity(x.varpi, self.T_vehicle_sensor)
        Sv = J @ P[6:12, 6:12] @ J.T
        u, pts, var_fit, mask, fit_threshold = self._thresholds(polar, v, Sv)
        confident = np.sqrt(np.trace(Sv)) < acfg.ransac_above_sigma
        if confident:
            radius = 3.0 * np.sqrt(max(lambda_max_sym3(Sv), 0.0)) + acfg.doppler_jerk_margin
            # found once for both checks of the space a consensus covers (each finds them itself if it alone runs)
            both = acfg.moving_group_z > 0 and acfg.consensus_switch_after > 0
            voxels = Voxels.of(pts, acfg.consensus_voxel) if both else None
            moving = self._moving_groups(pts, u, vr, var_fit, mask, radius, voxels)
            mask &= ~moving
            ego = self._gated_ransac(polar, u, fit_threshold, v, radius, ~moving)
            ours = ego.inliers if ego.ok and ego.inliers.sum() >= max(MIN_STATIC, mask.sum()) else mask
            switch = self.consensus.outvoted(az, el, vr, fit_threshold, ours, pts, scan_dt, voxels)
            if switch is not None:
                return switch, "doppler-consensus-switch"
            # fewer than MIN_STATIC near a confident prediction: what fills the view is not the world (an
            # oncoming car passing close); a free fit would take it, the prior carries the scan instead
            return ours, None if ours.sum() >= MIN_STATIC else "doppler-few-static"
        elif mask.sum() >= MIN_STATIC and mask.sum() >= 0.2 * len(polar):
            return self._widest_in_gate(polar, fit_threshold, mask), None
        ego = self.widest_consensus(polar, fit_threshold)
        if ego.ok and ego.inliers.sum() > mask.sum():
            return ego.inliers, "doppler-ransac-fallback"
        # a few detections in the gate beside many far outside it: again only a consensus of them
        return self._widest_in_gate(polar, fit_threshold, mask), None

    def _widest_in_gate(self, polar: np.ndarray, threshold: np.ndarray, gated: np.ndarray) -> np.ndarray:
        """The static set under an uncertain prediction: the widest consensus (`ConsensusSwitch.widest`) among the
        detections inside its gate, or none when no consensus there has MIN_STATIC inliers (detections that do
        not agree are no velocity: ten stray detections of a start-up scan, taken whole, set the velocity metres
        per second off at the fit's confidence; docs/estimator.md, step 9). The gate of a start is
        wide (the initial yaw-rate sigma through the lever arm: 0.7 m/s at a sensor 3.5 m ahead), and a car
        moving slowly beside the vehicle falls inside it; taken as static, it bent the scan's Doppler fit, which
        then moved the prediction and the solve (tests/estimator/test_odometry_starts.py::
        test_movers_inside_the_starts_wide_gate_are_not_taken_for_the_world)."""
        idx = np.flatnonzero(gated)
        if len(idx) < MIN_STATIC:  # no consensus can have MIN_STATIC inliers (and no draws are spent)
            return np.zeros(len(polar), bool)
        # drawn from the consensus switch's stream: the RANSAC fits' stream stays as it was without this step
        ego = self.consensus.widest(polar[idx], self.consensus.rng, threshold[idx])
        if not ego.ok or ego.inliers.sum() < MIN_STATIC:
            return np.zeros(len(polar), bool)
        static = np.zeros(len(polar), bool)
        static[idx[ego.inliers]] = True
        return static

    def _moving_groups(self, pts: np.ndarray, u: np.ndarray, vr: np.ndarray, var_fit: np.ndarray,
                       gated: np.ndarray, radius: float, voxels: Voxels | None) -> np.ndarray:
        """Detections in voxels that move slowly as a group (`consensus.moving_voxels`, within `radius` of the
        world's Doppler fit); none when `association.moving_group_z` is 0."""
        acfg = self.config.association
        if acfg.moving_group_z <= 0:
            return np.zeros(len(vr), bool)
        return moving_voxels(pts, u, vr, var_fit, gated, acfg.consensus_voxel, acfg.moving_group_z,
                             acfg.moving_group_margin, radius, voxels=voxels)

    def _gated_ransac(self, polar: np.ndarray, u: np.ndarray, threshold: np.ndarray, v: np.ndarray,
                      radius: float, keep: np.ndarray) -> EgoVelocity:
        """The prediction-gated RANSAC (hypotheses within `radius` of v) over the detections in `keep` (u: all
        detections' directions); its inliers a mask over all of them. With every detection kept, the draws of a
        run without the test."""
        idx = np.flatnonzero(keep)
        ego = ransac_velocity(u[idx], polar[idx, 3], self.rng, float(self.sigmas[3]), threshold[idx],
                              RANSAC_ITERATIONS, is_planar(polar[idx, 2]), (v, float(radius)))
        inliers = np.zeros(len(polar), bool)
        inliers[idx[ego.inliers]] = True
        return replace(ego, inliers=inliers)

    def widest_consensus(self, polar: np.ndarray, threshold=None) -> EgoVelocity:
        """The Doppler fit to start from (`ConsensusSwitch.widest`, drawing first from the main stream)."""
        return self.consensus.widest(polar, self.rng, threshold)

    def fit(self, static: np.ndarray) -> DopplerFit | None:
        """Least-squares sensor velocity of the static detections (n, 4), or None (fewer than dof + 3
        detections, degenerate geometry). Planar (dof 2: vx, vy) when the elevations carry no information."""
        if len(static) < MIN_STATIC:
            return None
        fit = least_squares_velocity(static[:, 1], static[:, 2], static[:, 3], variance_floor=self.sigmas[3] ** 2,
                                     max_cond=1e8)
        if fit is None or len(static) < len(fit[0]) + 3:
            return None
        sigma_c = self.config.noise.doppler_common_sigma  # a common error no number of detections averages away
        cov = fit[1] + sigma_c**2 * np.eye(len(fit[0])) if sigma_c > 0 else fit[1]
        return DopplerFit(fit[0], cov, static[:, 3])

    def correct(self, x: State, P: np.ndarray, fit: DopplerFit | None,
                pairs_level: bool = False) -> tuple[State, float]:
        """The predicted state, corrected by the scan's Doppler ego-velocity when the two disagree, and the
        innovation's NIS per dof, nu^T S^-1 nu / dof (NaN without a fit): how far the scan's Doppler is from the
        prediction, which `uncertainty.velocity_inflation_per_doppler` turns into the reported velocity's
        variance (the prior's mistakes at a manoeuvre show here first).

        Association gates the radial velocity at the sensor's few cm/s, so a velocity prediction off by a
        tenth of a m/s (an unmodelled jerk: hard braking, a hand-held sensor) would reject most true pairs. The
        fit is compared with the predicted v_s (chi-square at `association.doppler_update_probability`); only
        when it contradicts it does a Kalman update move the mean. The result is only the linearisation point
        and the centre of the association gates: P stays the predicted covariance and the solve uses the
        detections through its own factors, so nothing is counted twice. (Updating P too, or updating at every
        scan, made the gates follow the least-squares fit's own errors: more pitch drift on the simulated city.)
        `pairs_level`: test at the pairs' gate level (`association.gate_probability`) instead (the odometry's
        re-centring when the pairs' gates rejected the scan, `RadarOdometry._recentre`).
        """
        if fit is None:
            return x, float("nan")
        _, J = sensor_velocity(x.varpi, self.T_vehicle_sensor)
        J = J[:fit.dof]
        H = np.zeros((fit.dof, len(P)))
        H[:, 6:12] = J
        S = H @ P @ H.T + fit.cov
        innovation = fit.v - J @ x.varpi
        gate = (self.pair_gate if pairs_level else self.update_gate)[fit.dof]
        nis = float(innovation @ np.linalg.solve(S, innovation))
        if nis <= gate:
            return x, nis / fit.dof  # the prediction agrees with the scan's Doppler: nothing to correct
        K = np.linalg.solve(S, H @ P).T
        return x.oplus(K @ innovation), nis / fit.dof

    def standstill_information(self, fit: DopplerFit | None, motion: MotionPrior,
                               settled: bool = True) -> np.ndarray | None:
        """Information of the zero-velocity term when the Doppler says the sensor is at rest, else None.

        `settled`: the scan before was at rest too. At the first scan of a standstill the linear acceleration is
        left free: a vehicle that has just stopped, or is starting (as every simulated drive from rest does at
        its first scan, at up to 3.6 m/s^2), is at rest with an acceleration, so that term waits for the second
        scan at rest (a zero acceleration there made the first scan's acceleration NEES/dof 1e4 on city). The
        angular acceleration stays held: a wheeled vehicle at rest does not start to turn, roll or pitch (freeing
        it too doubled city's z drift through an early pitch error).
        """
        cfg = self.config.standstill
        if fit is None or cfg.speed <= 0:
            return None
        # at rest every static detection's Doppler is noise: a fit consistent with zero, and a small median (the
        # fit's test first: moving, it fails and the median, a partial sort, is not needed)
        if not (fit.v @ np.linalg.solve(fit.cov, fit.v) <= self.still_gate[fit.dof]
                and np.median(np.abs(fit.radial_velocity)) <= max(0.5 * cfg.speed, self.sigmas[3])):
            return None
        sig = motion.tail_sigmas([cfg.sigma_velocity] * 3, [cfg.sigma_rate] * 3, [cfg.sigma_accel] * 3,
                                 [cfg.sigma_angular_accel] * 3)
        information = np.diag(1.0 / np.square(sig))
        if not settled:
            information[6:9, 6:9] = 0.0  # the CA prior's linear acceleration: free (the CV prior has none)
        return information


def common_doppler_error(W: np.ndarray, azimuth: np.ndarray, elevation: np.ndarray, sigma_c: float) -> np.ndarray:
    """The information matrices (m, 4, 4) of one scan's m pairs with the scan's common Doppler error
    (`noise.doppler_common_sigma`) spread over their radial velocities (index 3): each one's variance raised by
    c = sigma_c^2 lambda_max(sum_i u_i u_i^T), u_i the detections' directions, so that together they claim the
    sensor velocity along no axis better than sigma_c (along the best observed axis their information is
    lambda_max / (sigma_vr^2 + c) < 1 / sigma_c^2; a 2D radar's directions span the plane, lambda_max ~ m / 2).
    (W^-1 + c e3 e3^T)^-1 = W - c W e3 e3^T W / (1 + c W_33) (Sherman-Morrison), without inverting W.

    Checked by: tests/estimator/test_multi_radar.py::test_common_doppler_error_inflates_the_radial_velocity,
        ::test_common_doppler_error_bounds_what_a_scan_says_about_the_velocity
    """
    u = polar_to_cartesian(np.c_[np.ones_like(azimuth), azimuth, elevation])
    c = sigma_c**2 * float(np.linalg.eigvalsh(u.T @ u)[-1])
    w3 = W[:, :, 3]
    return W - (c / (1.0 + c * W[:, 3, 3]))[:, None, None] * w3[:, :, None] * w3[:, None, :]


def vehicle_information(config: OdometryConfig, dim: int) -> np.ndarray | None:
    """Information of the zero-mean roll and pitch rate and lateral and vertical velocity terms of a moving road
    vehicle (`VehicleConfig`) on the state's Euclidean part; None when all are off."""
    rate_info = np.zeros(dim - 6)
    v = config.vehicle
    for axis, sigma in ((1, v.sigma_lateral_velocity), (2, v.sigma_vertical_velocity),
                        (3, v.sigma_roll_rate), (4, v.sigma_pitch_rate)):
        rate_info[axis] = sigma**-2 if sigma > 0 else 0.0
    return np.diag(rate_info) if rate_info.any() else None
