"""Synthetic drives for the tests of the uncertainty fits and measures (tests/validation/test_calibrate_heading.py,
test_calibrate_jitter.py, test_calibrate_stationary.py, test_error_growth.py): a vehicle driving straight on with
small yaw steps, and the states and truth arrays of a run whose pose errors the test draws and whose one-scan
relative covariance it states."""

import numpy as np

from rodo.estimator.lie import se3


def straight_drive(rng: np.random.Generator, n: int, step_range=(0.6, 1.0), yaw_sigma: float = 0.01) -> np.ndarray:
    """(n, 4, 4) T_vehicle_world of a drive from the identity: each step forward by U(step_range) m, yawing by
    N(0, yaw_sigma^2) rad."""
    T = [np.eye(4)]
    for _ in range(n - 1):
        step = np.array([-rng.uniform(*step_range), 0.0, 0.0, 0.0, 0.0, rng.normal(0, yaw_sigma)])
        T.append(se3.exp(step) @ T[-1])
    return np.stack(T)


def run_arrays(t: np.ndarray, T_est, T_true: np.ndarray, Sigma: np.ndarray) -> tuple[dict, dict]:
    """(states, truth) of a run at times t with the estimates T_est and the truth T_true (T_vehicle_world), its
    one-scan relative covariances Sigma (n, 6, 6; row 0 NaN, as a run writes it), the first pose known (P
    1e-12: the errors start at zero), zero velocities, no revisions or restarts."""
    n = len(t)
    states = {"t": t, "T_vehicle_world": np.stack(T_est), "varpi": np.zeros((n, 6)),
              "P": np.tile(np.eye(18) * 1e-12, (n, 1, 1)), "P_relative": Sigma, "P_revision": np.zeros((n, 6, 6)),
              "restarted": np.zeros(n, bool)}
    return states, {"t": t, "T_vehicle_world": T_true, "varpi": np.zeros((n, 6))}


def stated_run(dt: float, T_true: np.ndarray, errors, stated: np.ndarray) -> tuple[dict, dict]:
    """`run_arrays` of a run at scans dt apart whose estimates are exp(-e_k) T_true[k] (errors (n, 6), e_0 = 0:
    the truth is aligned at the first scan) and whose states state the one-scan relative covariance `stated`
    (6, 6) at every scan."""
    n = len(T_true)
    Sigma = np.tile(stated, (n, 1, 1))
    Sigma[0] = np.nan
    T_est = [se3.exp(-np.asarray(e, dtype=float)) @ T for e, T in zip(errors, T_true)]
    return run_arrays(dt * np.arange(n), T_est, T_true, Sigma)
