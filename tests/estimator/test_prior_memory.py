"""`uncertainty.prior_memory` end to end: CA/P at the true Qc of a prior-consistent drive (`prior_ca`, the motion
drawn from the CA prior's own SDE with its stiff default Qc), with and without a marginalised prior that
forgets. The window-level property (the Schur complement scaled by exp(-dt / memory)) is in test_window.py."""

import dataclasses

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.sim.sde_trajectory import DEFAULT_QC
from rodo.validation.driver import run_sequence


def _end_error(seq, truth, memory: float) -> np.ndarray:
    """[x, y, z, roll, pitch, yaw] error of the pose at the end relative to the start (vehicle frame)."""
    config = OdometryConfig.for_model("ca-polar")
    config = config.replace(noise=dataclasses.replace(config.noise, qc_ca=tuple(DEFAULT_QC["ca"])),
                            uncertainty=dataclasses.replace(config.uncertainty, prior_memory=memory))
    est = run_sequence(seq, config).estimates
    T = est[-1].T_vehicle_world @ se3.inverse(est[0].T_vehicle_world)
    T_true = truth["T_vehicle_world"][len(est) - 1] @ se3.inverse(truth["T_vehicle_world"][0])
    return se3.log(se3.inverse(T_true) @ T)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_forgetting_prior_keeps_ca_at_its_true_qc_on_course(seed):
    """10 s (100 m) of prior_ca with the estimator at the drive's own Qc. With the exact marginalisation the
    pitch and roll run away (measured, seeds 1 / 2: 4.3 / 6.7 m of z error, roll 0.14 / 0.07 rad, pitch 0.07 /
    0.10 rad): the prior, stiff about the angular acceleration, never forgets what the map (made from the same
    scans) counts twice. With prior_memory 0.5 s: 0.10 / 0.56 m and at most 0.02 rad. (With the older states
    re-linearised at every step, `solver.relinearize_older`, 0.31 / 0.09 m; over seeds 1-6 the forgetting runs
    end 0.10-0.69 m off, mean 0.34 m, against 0.08-0.38 m, mean 0.20 m: this drive sits on the edge of stability,
    docs/estimator.md, step 6.)"""
    seq, truth = scenarios.get("prior_ca").simulate(seed, duration=10.0)
    exact, forgetting = _end_error(seq, truth, 0.0), _end_error(seq, truth, 0.5)
    assert np.linalg.norm(forgetting[:3]) < 1.0 and np.abs(forgetting[3:]).max() < 0.05
    assert np.linalg.norm(exact[:3]) > 5 * np.linalg.norm(forgetting[:3])
