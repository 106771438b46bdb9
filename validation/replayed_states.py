"""The states a run would have written at other uncertainty settings, from the states it wrote: the reported
covariances those settings scale or compose change, the estimate does not (none of them is in the solve), so no
run is needed. `rodo calibrate`'s uncertainty fits (`calibrate_consistency`) compare settings this way.

- `relative_inflated_states`: the relative pose covariances times a factor (`[uncertainty] inflation`);
- `velocity_inflated_states`: the velocity covariance at other velocity factors;
- `absolute_covariances`, `replayed`: the absolute pose covariances at another tau, drift rate, heading
  reversion, roll and pitch jitter and stationary error.

Checked by: tests/validation/test_calibrate_consistency.py
"""

from __future__ import annotations

import numpy as np

from rodo.estimator.attitude_jitter import absolute_excess, attitude_jitter_array, with_roll_pitch_variance
from rodo.estimator.heading_reversion import heading_reversion_array
from rodo.estimator.stationary_error import is_on, span_term, stationary_error_array
from rodo.estimator.uncertainty import drift_rate_sigma_array, fresh_starts
from rodo.estimator.velocity_inflation import velocity_inflated, velocity_inflation_array
from rodo.estimator.velocity_lag import lag_accelerations, with_lag

from .odometry_consistency import drift_velocity_covariances, recursion_inputs_of_run
from .span_covariances import drift_replay


def relative_inflated_states(states: dict, factor: float) -> dict:
    """The states a run would have written with its relative pose covariances (and their revision terms) times
    `factor` (the estimate does not depend on them), but at its re-initialisations (states' `restarted`), whose
    dead-reckoned step the factor does not scale; the absolute covariances are replayed from these
    (`_replayed`).

    Checked by: tests/validation/test_calibrate_consistency.py::test_relative_factor_states_are_a_run_at_that_factor
    """
    f = np.where(np.asarray(states.get("restarted", False), dtype=bool), 1.0, factor)
    f = f[:, None, None] if f.ndim else f
    out = dict(states, P_relative=f * np.asarray(states["P_relative"], dtype=float))
    if "P_revision" in states:
        out["P_revision"] = f * np.asarray(states["P_revision"], dtype=float)
    return out


def velocity_inflated_states(states: dict, inflation: float, per_speed: float, per_doppler: float = 0.0,
                             per_axis=None, per_rate=None, lag=None, lag_time: float = 0.3) -> dict:
    """The states a run at these velocity factors and this lag (L (6, 2), `estimator.velocity_lag`, smoothed over
    `lag_time`; None: none) would have written (from a run without them: the estimate does not depend on them):
    the reported velocity covariance scaled and the lag's b b^T added, the factors and each scan's b recorded.

    Checked by: tests/estimator/test_velocity_lag.py::test_the_run_adds_the_lag_the_states_replay
    """
    axes = np.ones(6) if per_axis is None else np.asarray(per_axis, dtype=float)
    rates = np.zeros(3) if per_rate is None else np.asarray(per_rate, dtype=float)
    P = velocity_inflated(np.asarray(states["P"], dtype=float), states["varpi"], inflation, per_speed, per_doppler,
                          states.get("doppler_nis"), axes, rates)
    out = dict(states, P=P, velocity_inflation=velocity_inflation_array(inflation, per_speed, per_doppler, rates),
               velocity_axis_inflation=axes)
    if lag is not None and np.any(lag):
        fresh = fresh_starts(states.get("restarted"), len(P))
        out["velocity_lag"] = lag_accelerations(states["varpi"], states["t"], fresh, lag_time) @ np.asarray(lag).T
        out["P"] = with_lag(P, out["velocity_lag"])
    return out


def replayed(states: dict, tau: float, drift_rate_sigma, heading=None, jitter=None, stationary=None) -> dict:
    """The states with the absolute covariances the run would have reported at this tau, drift rate (None: none),
    heading reversion ([T_r, T_a]; None: off), roll and pitch jitter ([V, T]; None: off) and stationary error
    ([V; T] (2, 6); None: off), all five recorded as the run records them (the span measures and `error_growth`
    read them); the estimate itself does not depend on them."""
    heading, jitter = heading_reversion_array(heading), attitude_jitter_array(jitter)
    stationary = stationary_error_array(stationary)
    P_absolute = absolute_covariances(states, tau, drift_rate_sigma, heading, jitter, stationary)
    return dict(states, P_pose_absolute=P_absolute,
                velocity_correlation_time=float(tau), drift_rate_sigma=drift_rate_sigma_array(drift_rate_sigma),
                heading_reversion=heading, attitude_jitter=jitter, stationary_error=stationary)


def absolute_covariances(states: dict, tau: float, drift_rate_sigma=None, heading=None, jitter=None,
                         stationary=None) -> np.ndarray:
    """(N, 6, 6) the absolute pose covariances a run would have reported with this tau, drift rate, heading
    reversion ([T_r, T_a]; None: off), roll and pitch jitter ([V, T]; None: off) and stationary error ([V; T];
    None: off): its recursion replayed over its stored relative and velocity covariances
    (`recursion_inputs_of_run`, the stationary error's one-scan change taken out), across its re-initialisations
    where states.npz flags them, `restarted` (`span_covariances.drift_replay`), the jitter's excess and the
    stationary error's change since its first scan added (`attitude_jitter.absolute_excess`,
    `stationary_error.span_term`); row 0: the first pose's.

    Checked by: tests/validation/test_calibrate_consistency.py::test_absolute_covariances_replay_the_run,
        ::test_absolute_covariances_replay_a_run_across_its_restart,
        tests/estimator/test_stationary_error.py::test_a_replay_equals_the_run_with_the_stationary_error
    """
    P = np.asarray(states["P"], dtype=float)
    P_window = drift_velocity_covariances(P, states["varpi"], states.get("velocity_inflation"),
                                          states.get("doppler_nis"), states.get("velocity_axis_inflation"),
                                          states.get("velocity_lag"))
    Sigma_rel, P_varpi = recursion_inputs_of_run(states, np.asarray(states["P_relative"], dtype=float), P_window,
                                                 stationary=stationary)
    T, t = np.asarray(states["T_vehicle_world"], dtype=float), np.asarray(states["t"], dtype=float)
    steps = drift_replay(T, t, Sigma_rel, P_varpi, P[0, :6, :6], tau, drift_rate_sigma, states.get("restarted"),
                         heading)
    P_absolute = np.stack([P[0, :6, :6]] + [drift.C[:6, :6] for drift in steps])
    P_absolute = with_roll_pitch_variance(P_absolute, absolute_excess(t, attitude_jitter_array(jitter)))
    if is_on(stationary):
        P_absolute = P_absolute + span_term(T, T[:1], t - t[0], stationary)
    return P_absolute
