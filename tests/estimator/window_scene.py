"""A sliding window over the hand-built scene (`tests.estimator.scene`) for the window's tests: n states on the
true CA trajectory (the newest of each push the motion prior's prediction, the first the truth), each with the
polar measurements of the landmarks in front of the sensor, noisy or exact, and an identity prior."""

from __future__ import annotations

import numpy as np

from rodo.estimator import measurements
from rodo.estimator.lie import se3
from rodo.estimator.measurement_models import PolarModel
from rodo.estimator.motion import motion_prior
from rodo.estimator.state import State
from rodo.estimator.window import MeasurementSet, SlidingWindow
from tests.estimator import scene


def window_with_scene(kind="ca", n=4, noisy=True, robust_c=3.0):
    rng = np.random.default_rng(5)
    t, T, varpi, vd = scene.trajectory(n)
    L = scene.landmarks(rng, n=300)
    motion = motion_prior(kind, (2.0, 0.05, 0.05, 1e-3, 1e-3, 0.05) if kind == "ca" else (1, .05, .05, .01, .01, .05))
    win = SlidingWindow(motion, n, PolarModel(), scene.T_VEHICLE_SENSOR, robust_c=robust_c)
    x0 = State(t[0], T[0], varpi[0], vd[0] if kind == "ca" else None)
    win.initialize(x0, np.eye(motion.dim) * 1.0)
    R = np.diag(scene.SIGMAS**2)
    for k in range(n):
        if k:
            prev = win.newest
            _, Q = motion.transition_and_noise(prev, t[k] - prev.t)
            win.push(motion.predict(prev, t[k]), Q)
        # measurements of the true landmarks from the true state
        T_sw = se3.inverse(scene.T_VEHICLE_SENSOR) @ T[k]
        ps = se3.transform_points(T_sw, L)
        vis = (ps[:, 0] > 1) & (np.linalg.norm(ps, axis=1) < 100)
        pred = measurements.predict("polar", T[k], varpi[k], L[vis], scene.T_VEHICLE_SENSOR)
        z = pred.z + (rng.normal(size=pred.z.shape) * scene.SIGMAS if noisy else 0)
        win.set_measurements(k, MeasurementSet(L[vis], z, np.broadcast_to(np.linalg.inv(R), (vis.sum(), 4, 4)).copy()))
    return win, (t, T, varpi, vd)
