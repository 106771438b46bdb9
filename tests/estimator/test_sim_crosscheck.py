"""The simulator and the estimator's measurement models are independent implementations of the same
geometry: at the true state, the estimator's prediction of each static scatterer must equal the simulator's
noise-free measurement of it. A disagreement means one of them is wrong."""

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator import measurements
from rodo.estimator.lie import se3


@pytest.mark.parametrize("name", ["city", "hills"])
def test_estimator_models_reproduce_the_simulator(name):
    seq, truth = scenarios.get(name).simulate(seed=3, duration=3.0)
    T_vs = truth["T_vehicle_sensor"]
    static = np.isin(truth["det_label"], [0, 1])
    checked = 0
    for k in range(0, len(truth["t"]), 7):
        rows = np.arange(truth["scan_offsets"][k], truth["scan_offsets"][k + 1])
        rows = rows[static[rows]]
        if len(rows) == 0:
            continue
        T, varpi = truth["T_vehicle_world"][k], truth["varpi"][k]
        pred = measurements.predict("polar", T, varpi, truth["det_p_world"][rows], T_vs)
        z_true = truth["det_true_polar"][rows]
        np.testing.assert_allclose(pred.z[:, 0], z_true[:, 0], atol=1e-9)
        np.testing.assert_allclose(measurements.residual("polar", z_true, pred.z)[:, 1:3], 0, atol=1e-9)
        np.testing.assert_allclose(pred.z[:, 3], z_true[:, 3], atol=1e-9)  # radial velocity, sign included
        cart = measurements.predict("cartesian", T, varpi, truth["det_p_world"][rows], T_vs)
        np.testing.assert_allclose(cart.z[:, :3], measurements.polar_to_cartesian(z_true), atol=1e-8)
        checked += len(rows)
    assert checked > 500
    # the sequence's ground truth is the inverse of the truth poses
    np.testing.assert_allclose(seq.groundtruth.T_world_vehicle, se3.inverse(truth["T_vehicle_world"]), atol=1e-9)
