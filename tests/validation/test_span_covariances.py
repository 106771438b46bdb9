"""validation/span_covariances.py: every span covariance of a run at once (or those of chosen starts), equal bit
for bit to the recursion of estimator.uncertainty.span_covariance span by span."""

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.uncertainty import span_covariance
from rodo.validation import span_covariances as sc
from rodo.validation.driver import run_sequence


@pytest.fixture(scope="module")
def states():
    seq, _ = scenarios.get("city").simulate(2, 2.0)  # 27 scans
    return run_sequence(seq, OdometryConfig.for_model("ca-polar"), keep_estimates=False).state_arrays()


@pytest.mark.parametrize("n, tau, drift", [(1, 0.25, None), (5, 0.25, [1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4]),
                                           (13, 0.0, None), (26, 0.5, None)])
def test_equals_span_covariance_bit_for_bit(states, n, tau, drift, monkeypatch):
    T, t = states["T_vehicle_world"], states["t"]
    Sigma_rel = states["P_relative"].copy()
    Sigma_rel[3] = np.nan  # a scan without a relative covariance counts as 0
    P_varpi = states["P"][:, 6:12, 6:12]
    want = np.stack([span_covariance(T, t, Sigma_rel, P_varpi, k - n, k, tau, drift) for k in range(n, len(t))])
    got = sc.span_covariances(T, t, Sigma_rel, P_varpi, n, tau, drift)
    assert got.shape == want.shape and got.tobytes() == want.tobytes()
    monkeypatch.setattr(sc, "BLOCK", 4)  # spans advanced in several blocks give the same
    assert sc.span_covariances(T, t, Sigma_rel, P_varpi, n, tau, drift).tobytes() == want.tobytes()
    starts = np.arange(0, len(t) - n, 3)  # some spans alone: their rows, whatever the blocks
    assert sc.span_covariances(T, t, Sigma_rel, P_varpi, n, tau, drift, starts=starts).tobytes() == \
        want[starts].tobytes()
    steps = sc.step_matrices(T, t, Sigma_rel, P_varpi, tau, np.arange(1, len(t)))  # built once, for every span
    assert sc.span_covariances(T, t, Sigma_rel, P_varpi, n, tau, drift, steps=steps).tobytes() == want.tobytes()
    assert sc.span_covariances(T, t, Sigma_rel, P_varpi, n, tau, drift, starts=starts, steps=steps).tobytes() == \
        want[starts].tobytes()


@pytest.mark.parametrize("n", [1, 4])
def test_equals_span_covariance_bit_for_bit_across_restarts(states, n, monkeypatch):
    """Scans flagged as re-initialisations (states.npz `restarted`) take the restart's step in both, and a span
    that starts at one starts its velocity error at zero in both."""
    T, t = states["T_vehicle_world"], states["t"]
    Sigma_rel, P_varpi = states["P_relative"], states["P"][:, 6:12, 6:12]
    restarts = np.zeros(len(t), bool)
    restarts[[6, 9, 20]] = True
    want = np.stack([span_covariance(T, t, Sigma_rel, P_varpi, k - n, k, 0.3, None, restarts)
                     for k in range(n, len(t))])
    got = sc.span_covariances(T, t, Sigma_rel, P_varpi, n, 0.3, None, restarts)
    assert got.tobytes() == want.tobytes()
    monkeypatch.setattr(sc, "BLOCK", 4)
    assert sc.span_covariances(T, t, Sigma_rel, P_varpi, n, 0.3, None, restarts).tobytes() == want.tobytes()
    plain = sc.span_covariances(T, t, Sigma_rel, P_varpi, n, 0.3)
    assert not np.allclose(got[6 - n], plain[6 - n], rtol=1e-6)  # the restart's step is another
    np.testing.assert_array_equal(got[:6 - n], plain[:6 - n])  # spans before it are the same


def test_no_span_fits(states):
    t = states["t"][:3]
    assert sc.span_covariances(states["T_vehicle_world"][:3], t, states["P_relative"][:3],
                               states["P"][:3, 6:12, 6:12], 3, 0.25).shape == (0, 6, 6)
