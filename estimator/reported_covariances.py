"""What the odometry reports beside the window's covariance, scan by scan (`ReportedCovariances`): the parts of
`uncertainty` (the module docstring there has the model) put together for one run.

Checked by: tests/estimator/test_uncertainty.py::test_the_restart_is_flagged_and_adds_the_dead_reckoned_step_alone,
    tests/estimator/test_stationary_error.py::test_a_replay_equals_the_run_with_the_stationary_error
"""

from __future__ import annotations

import numpy as np

from .attitude_jitter import AbsoluteJitter, attitude_jitter_of, with_roll_pitch_variance
from .heading_reversion import heading_of
from .pull import relative_factor
from .stationary_error import is_on, span_term, stationary_error_of
from .uncertainty import DriftCovariance, recursion_inputs, registration_shares
from .velocity_inflation import velocity_inflated
from .velocity_lag import VelocityLag


class ReportedCovariances:
    """What the odometry reports beside the window's covariance, scan by scan: each scan's relative pose
    covariance and its revision (times `[uncertainty] inflation` + `inflation_per_rate` . |omega| +
    `inflation_per_doppler` ln(1 + the Doppler NIS) + `inflation_per_pull` pull, omega the scan's estimated body
    rates, pull its pull on the solved pose, `pose_pull`), the absolute pose
    covariance through the drift recursion (`DriftCovariance`: from the run's first scan, across
    re-initialisations with their dead-reckoned step, unscaled) with the roll and pitch jitter's excess since that
    scan (`attitude_jitter`) and the stationary error's change since it (`stationary_error`, whose one-scan
    change the recursion's inputs leave out), the velocity's variance scaled (`velocity_inflated`), its lag
    added (`VelocityLag`).

    Attributes:
        config: the odometry's `UncertaintyConfig`.
        last: the last estimate annotated (None before the first).
        restart_relative: (6, 6) the dead-reckoned relative pose of a re-initialisation in progress (set by the
            odometry, `predicted_relative_covariance`), None otherwise.

    Checked by: tests/estimator/test_uncertainty.py::test_the_restart_is_flagged_and_adds_the_dead_reckoned_step_alone,
        ::test_the_drift_recursion_starts_without_the_first_scans_velocity_error,
        tests/estimator/test_uncertainty_inflation.py::test_velocity_inflation_changes_the_report_not_the_estimate
    """

    def __init__(self, config):
        self.config = config
        self.axes = np.asarray(config.velocity_axis_inflation, dtype=float)  # converted once, not per scan
        self.relative_terms = (any(config.inflation_per_rate) or config.inflation_per_doppler != 0.0
                               or config.inflation_per_pull != 0.0)
        self.jitter = AbsoluteJitter(attitude_jitter_of(config))
        stationary = stationary_error_of(config)
        self.stationary = stationary if is_on(stationary) else None  # None: off, nothing to do per scan
        self.origin = None  # (T_vehicle_world, t) of the run's first scan, for the stationary error's span
        self.lag = VelocityLag(config)
        self.correlation = registration_shares(config.registration_correlation, config.registration_axis_correlation)
        self.drift: DriftCovariance | None = None
        self.last = None
        self.restart_relative: np.ndarray | None = None

    def annotate(self, est, P_relative, reuse: float, doppler_nis: float, pull: float):
        """The estimate (`ScanEstimate`) with P_relative, P_revision, P_pose_absolute, map_reuse, doppler_nis,
        pose_pull and restarted set and its velocity variance scaled. P_relative: (relative, revision) of the
        window's two newest states (`scan_relative_covariances`), or the re-initialisation's (restart_relative,
        zeros), or None at the first scan."""
        cfg, last = self.config, self.last  # the drift composes smoothed, unrevised pairs
        if P_relative is None or self.drift is None:
            self.drift = DriftCovariance.at_first_scan(est.P[:6, :6], cfg.velocity_correlation_time,
                                                       cfg.drift_rate_sigma, heading_of(cfg))
            P_relative, P_revision, P_absolute = np.full((6, 6), np.nan), np.zeros((6, 6)), est.P[:6, :6].copy()
            self.jitter.start(est.t)
            self.origin = est.T_vehicle_world, est.t
            step = None  # the lag's acceleration starts again, as at a re-initialisation
        elif self.restart_relative is not None:  # dead-reckoned across a re-initialisation, not registered:
            P_relative, P_revision, step = *P_relative, None  # so not scaled by `inflation` either
            est.restarted = True
            P_absolute = self.drift.restart(last.T_vehicle_world, est.T_vehicle_world, P_relative)
        else:
            f = (relative_factor(est.varpi, cfg.inflation, cfg.inflation_per_rate, cfg.inflation_per_doppler,
                                 doppler_nis, cfg.inflation_per_pull, pull) if self.relative_terms else cfg.inflation)
            P_relative, P_revision = (f * P for P in P_relative)
            dt = est.t - last.t
            step = (last.varpi, dt)
            speed = float(np.linalg.norm(est.varpi[:3])) if cfg.velocity_error_share_per_speed else None
            P_absolute = self.drift.update(last.T_vehicle_world, est.T_vehicle_world, dt, *recursion_inputs(
                P_relative, est.P[6:12, 6:12], dt, self.correlation, cfg.velocity_error_share,
                cfg.velocity_error_share_per_speed, speed, self.stationary))
        P_absolute = with_roll_pitch_variance(P_absolute, self.jitter.at(est.t))
        if self.stationary is not None:
            P_absolute = P_absolute + span_term(est.T_vehicle_world, self.origin[0], est.t - self.origin[1],
                                                self.stationary)
        self.last, self.restart_relative = est, None
        est.P_relative, est.P_revision, est.P_pose_absolute, est.map_reuse = P_relative, P_revision, P_absolute, reuse
        est.doppler_nis, est.pose_pull = doppler_nis, pull
        est.P = velocity_inflated(est.P, est.varpi, cfg.velocity_inflation, cfg.velocity_inflation_per_speed,
                                  cfg.velocity_inflation_per_doppler, est.doppler_nis, self.axes,
                                  cfg.velocity_inflation_per_rate)
        return self.lag.annotate(est, step)
