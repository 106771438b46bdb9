"""The odometry's per-scan solve: which pairs the newest state is solved with after the re-association, and which
states' measurement terms each scan linearises afresh (`solver.reweight_older`). The end-to-end accuracy and the
robustness of the odometry are in test_odometry.py, the window's own math in test_window.py."""

import numpy as np
import pytest

from rodo.estimator.config import OdometryConfig
from rodo.estimator.lie import se3
from rodo.estimator.odometry import RadarOdometry
from tests.estimator import scene


@pytest.mark.parametrize("times", [0, 1, 2])
def test_the_newest_state_is_solved_with_the_reassociated_pairs(monkeypatch, times):
    """After the first solve the odometry re-associates `association.reassociate` times
    (`MapAssociation.reassociate`) on every scan with pairs, and the newest state's measurements are then the
    last re-association's pairs: their map points, detections and information."""
    from rodo.estimator import scan_association

    calls = []
    reassociate = scan_association.MapAssociation.reassociate

    def spy(self, x, local_map, scan, pairs):
        W, got = reassociate(self, x, local_map, scan, pairs)
        calls.append((W, local_map.points[got.map_idx], scan.z[got.det_idx]))
        return W, got

    monkeypatch.setattr(scan_association.MapAssociation, "reassociate", spy)
    rng = np.random.default_rng(2)
    t, T, varpi, vd = scene.trajectory(6)
    L = scene.landmarks(rng)
    config = OdometryConfig.from_dict({"model": "ca-polar", "association": {"reassociate": times}})
    odo = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    for k in range(6):
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
        assert len(calls) == times * k  # the first scan has no map to associate with
        if times and k:
            W, p, z = calls[-1]
            mset = odo.window.meas[-1]
            assert len(mset) == est.n_associated > 100
            np.testing.assert_array_equal(mset.W, W)
            np.testing.assert_array_equal(mset.p_world, p)
            np.testing.assert_array_equal(mset.z, z)


@pytest.mark.parametrize("reweight", [True, False])
def test_older_states_keep_their_terms_across_scans_unless_reweighted(monkeypatch, reweight):
    """`solver.reweight_older`: true (the default) re-weights and re-linearises every state's pairs at each scan's
    first solve; false keeps a set's robust weights from its own scan for good and linearises it afresh in its own
    scan and the next only, taking it from that linearisation's quadratic model after: each scan's first
    linearisation is then fresh for the two newest states alone, and every older set keeps its weights, the same
    array with the same values (with true, a new array from the new scan's residuals). Both follow the truth on a
    noisy scene."""
    from rodo.estimator import window_kernels

    calls = []

    def spy(kernel):  # the first linearisation of a solve (`gauss_newton`) or the marginalisation's
        def call(*args):
            n, ks, slot = len(args[6]), args[15], args[16]
            calls.append((n, sorted(int(n - 1 - k) for k in ks[slot >= 0])))  # ages of the fresh states (0: newest)
            return kernel(*args)
        return call

    for name in ("normal_equations", "gauss_newton"):
        monkeypatch.setattr(window_kernels, name, spy(getattr(window_kernels, name)))
    rng = np.random.default_rng(3)
    t, T, varpi, vd = scene.trajectory(16)
    L = scene.landmarks(rng)
    config = OdometryConfig.from_dict({"model": "ca-polar", "solver": {"reweight_older": reweight}})
    odo = RadarOdometry(config, scene.T_VEHICLE_SENSOR, scene.SIGMAS, 120.0)
    seen = {}  # id(set) -> (set, its weights array, a copy of their values) when it was last an older state's
    for k in range(len(t)):
        calls.clear()
        est = odo.process(t[k], scene.measure(T[k], varpi[k], vd[k], L, rng))
        n, fresh = calls[0]
        if k >= 6:  # a full window: every state has pairs
            assert n == odo.config.window + 1
            assert fresh == (list(range(n)) if reweight else [0, 1]), (k, fresh)
            for m in odo.window.meas[:-1]:  # every older set, the one newest at the scan before included
                assert id(m) in seen
                same = m.weights is seen[id(m)][1] and np.array_equal(m.weights, seen[id(m)][2])
                assert same != reweight, k
        seen = {id(m): (m, m.weights, m.weights.copy()) for m in odo.window.meas if m is not None}
    Tgt = T[-1] @ se3.inverse(T[0])
    err = se3.log(est.T_vehicle_world @ se3.inverse(Tgt))
    assert np.linalg.norm(err[:3]) < 0.05 and np.linalg.norm(err[3:]) < 5e-3, err
