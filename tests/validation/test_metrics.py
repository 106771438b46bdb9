"""Trajectory metrics: Umeyama/ATE, RPE, per-axis drift, velocity errors, the combined report."""

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import minimize

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from rodo.sim.sequence import Trajectory
from tests.strategies import twists
from rodo.validation.metrics import (DRIFT_AXES, ate, drift, euler_zyx, evaluate, jsonable, pose_errors, rpe,
                                    umeyama_se3, velocity_errors)


def _rng(seed):
    return np.random.default_rng(np.random.SeedSequence(seed))


def _chain(xi):
    out = [np.eye(4)]
    for T in se3.exp(xi):
        out.append(out[-1] @ T)
    return np.stack(out)


def _drive(seed, n=200):
    rng = _rng(seed)
    xi = np.c_[rng.uniform(0.5, 1.5, n - 1), rng.normal(0, 0.05, (n - 1, 2)), rng.normal(0, 0.02, (n - 1, 3))]
    return _chain(xi)


# ---------------------------------------------------------------- Umeyama / ATE
@given(twists("any", 50.0), arrays(np.float64, (30, 3), elements=st.floats(-30, 30)).filter(
    lambda p: np.linalg.matrix_rank(p - p.mean(axis=0), tol=1e-3) == 3))
def test_umeyama_recovers_transform(xi, src):
    T = se3.exp(xi)
    np.testing.assert_allclose(umeyama_se3(src, se3.transform_points(T, src)), T, atol=1e-9)


def test_umeyama_never_returns_a_reflection():
    src = _rng(1).normal(0, 1, (20, 3))
    T = umeyama_se3(src, src * np.array([1.0, 1.0, -1.0]))  # a mirror image: best proper rotation only
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)


@given(st.integers(0, 2**32 - 1))
def test_ate_alignment_is_the_least_squares_optimum(seed):
    rng = _rng(seed)
    gt = _drive(seed, 40)
    est = se3.exp(rng.normal(0, [3, 3, 3, 0.3, 0.3, 0.3])) @ gt
    est[:, :3, 3] += rng.normal(0, 0.5, (40, 3))
    got = ate(gt, est)

    def cost(x):
        p = se3.transform_points(se3.exp(x), est[:, :3, 3])
        return np.mean(np.sum((p - gt[:, :3, 3]) ** 2, axis=1))

    x0 = se3.log(np.array(got["T_align"]))
    best = min(minimize(cost, x0 + d, method="BFGS").fun for d in (np.zeros(6), rng.normal(0, 0.1, 6)))
    assert got["ate_rmse_m"] ** 2 == pytest.approx(best, rel=1e-6)
    assert got["ate_rmse_m"] ** 2 <= best * (1 + 1e-9)
    assert got["ate_max_m"] >= got["ate_rmse_m"] >= got["ate_mean_m"] > 0


def test_ate_of_a_perfect_estimate_in_another_frame_is_zero():
    gt = _drive(2)
    est = se3.exp(np.array([10.0, -4, 2, 0.3, -0.1, 2.0])) @ gt
    assert ate(gt, est)["ate_rmse_m"] < 1e-9
    assert ate(gt, est, align=False)["ate_rmse_m"] > 1.0


@given(twists("vehicle", 2.0), st.integers(0, 199))
def test_pose_errors_of_a_known_perturbation(xi, k):
    """T_true = exp(xi^) T_est for state poses T = T_vehicle_world: pose_errors recovers xi, the rotation angle
    |phi| and the position difference; rows without truth (NaN) give NaN."""
    T_wv_true = _drive(1)
    T_vw_est = se3.exp(-xi) @ se3.inverse(T_wv_true)
    T_wv_est = se3.inverse(T_vw_est)
    T_wv_true = T_wv_true.copy()
    T_wv_true[k] = np.nan
    err = pose_errors(T_wv_est, T_wv_true)
    ok = np.arange(200) != k
    np.testing.assert_allclose(err.xi[ok], np.broadcast_to(xi, (199, 6)), atol=1e-8)
    np.testing.assert_allclose(err.rotation_deg[ok], np.degrees(np.linalg.norm(xi[3:])), atol=1e-7)
    np.testing.assert_allclose(err.drift[ok], T_wv_est[ok, :3, 3] - T_wv_true[ok, :3, 3])
    np.testing.assert_allclose(err.translation[ok], np.linalg.norm(err.drift[ok], axis=1))
    assert np.isnan(err.xi[k]).all() and np.isnan(err.translation[k]) and np.isnan(err.rotation_deg[k])
    with pytest.raises(InputError, match="est, true"):
        pose_errors(T_wv_est, T_wv_true[:5])


# ---------------------------------------------------------------- RPE
def test_rpe_per_frame_sees_one_bad_step():
    xi = np.tile([1.0, 0, 0, 0, 0, 0.01], (99, 1))
    steps = se3.exp(xi)
    gt = _chain(xi)
    steps[40] = steps[40] @ se3.exp(np.array([0.0, 0.3, 0.4, 0, 0, 0]))  # one step 0.5 m off
    est = [np.eye(4)]
    for S in steps:
        est.append(est[-1] @ S)
    est = np.stack(est)
    r = rpe(gt, est)
    assert r["rpe_trans_max_m"] == pytest.approx(0.5, rel=1e-9)
    assert r["rpe_trans_mean_m"] == pytest.approx(0.5 / 99, rel=1e-9)
    assert r["rpe_trans_rmse_m"] == pytest.approx(0.5 / np.sqrt(99), rel=1e-9)
    assert r["rpe_rot_max_deg"] < 1e-9


def test_rpe_per_metre_on_a_heading_error():
    # 1 m steps along x; estimate steps theta off: over the 11 frames spanning > 10 m the error is
    # 2 sin(theta/2) * 11 m, divided by the 11 m travelled
    theta, n = 0.02, 60
    k = np.arange(n)
    gt = se3.from_rotation_translation(np.broadcast_to(np.eye(3), (n, 3, 3)), np.c_[k, 0 * k, 0 * k])
    est = se3.from_rotation_translation(np.broadcast_to(np.eye(3), (n, 3, 3)),
                                        np.c_[k * np.cos(theta), k * np.sin(theta), 0 * k])
    r = rpe(gt, est, delta_m=10.0)
    assert r["rpe_trans_pct"] == pytest.approx(200 * np.sin(theta / 2), rel=1e-9)
    assert r["rpe_rot_deg_per_m"] == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(rpe(gt, est, delta_m=100.0)["rpe_trans_pct"])


# ---------------------------------------------------------------- drift
@given(twists("vehicle", 20.0))
def test_euler_zyx_inverts_the_composition(phi):
    roll, pitch, yaw = np.clip(phi[3:], -1.2, 1.2)
    C = so3.exp([0, 0, yaw]) @ so3.exp([0, pitch, 0]) @ so3.exp([roll, 0, 0])
    np.testing.assert_allclose(euler_zyx(C), [roll, pitch, yaw], atol=1e-12)


def test_planar_estimate_of_a_hill_shows_z_and_pitch_drift():
    n = 101
    s = np.linspace(0, 100, n)
    z = 5.0 * np.sin(np.pi * s / 200)  # climbs 5 m
    pitch = -np.arctan(5 * np.pi / 200 * np.cos(np.pi * s / 200))  # nose up is negative pitch about y (left)
    C = so3.exp(np.c_[0 * s, pitch, 0 * s])
    gt = se3.from_rotation_translation(C, np.c_[s, 0 * s, z])
    flat = se3.from_rotation_translation(np.broadcast_to(np.eye(3), (n, 3, 3)), np.c_[s, 0 * s, 0 * s])
    d = drift(gt, se3.exp(np.array([3.0, 1, 0, 0, 0, 0.5])) @ flat)  # another world frame: no effect
    R0 = C[0]
    rel_last = R0.T @ (gt[-1, :3, 3] - gt[0, :3, 3])
    assert d["final"]["z"] == pytest.approx(-rel_last[2], rel=1e-9)
    assert d["final"]["x"] == pytest.approx(100 - rel_last[0], rel=1e-9)
    assert d["final"]["pitch"] == pytest.approx(np.rad2deg(pitch[0] - pitch[-1]), rel=1e-9)
    assert d["final"]["roll"] == pytest.approx(0, abs=1e-9) and d["final"]["yaw"] == pytest.approx(0, abs=1e-9)
    rel = np.einsum("ji,nj->ni", R0, gt[:, :3, 3] - gt[0, :3, 3])
    assert d["max_abs"]["z"] == pytest.approx(np.max(np.abs(rel[:, 2])), rel=1e-9)
    assert d["max_abs"]["pitch"] == pytest.approx(np.rad2deg(np.max(np.abs(pitch - pitch[0]))), rel=1e-9)
    assert d["series"].shape == (n, 6) and tuple(d["final"]) == DRIFT_AXES


def test_drift_of_perfect_estimate_is_zero():
    gt = _drive(5)
    d = drift(gt, se3.exp(np.array([1.0, 2, 3, 0.1, 0.2, 0.3])) @ gt)
    assert max(abs(v) for v in d["final"].values()) < 1e-9


# ---------------------------------------------------------------- velocity
def test_velocity_errors_of_a_known_bias():
    t = np.arange(50) * 0.1
    rng = _rng(4)
    truth = rng.normal(0, 3, (50, 6))
    est = truth + np.array([0.1, 0.2, -0.2, 0.0, 0.0, np.deg2rad(2.0)])
    v = velocity_errors(t[1:] + 2e-4, est[1:], t, truth)
    assert v["matched"] == 49
    assert v["nu_rmse_mps"] == pytest.approx(0.3, rel=1e-9)
    np.testing.assert_allclose(v["nu_rmse_per_axis_mps"], [0.1, 0.2, 0.2], rtol=1e-9)
    assert v["omega_rmse_degps"] == pytest.approx(2.0, rel=1e-9)
    with pytest.raises(InputError, match="varpi"):
        velocity_errors(t, est[:, :3], t, truth)


# ---------------------------------------------------------------- combined report
def test_evaluate_report_has_the_documented_keys_and_zero_errors_for_truth():
    T = _drive(7, 300)
    t = np.arange(300) * 0.1
    gt = Trajectory(t, T)
    est = Trajectory(t + 1e-4, se3.exp(np.array([1.0, 0, 0, 0, 0, 1.0])) @ T)
    rep = evaluate(gt, est, lengths=(50.0, 100.0), step=5)
    for key in ("kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m", "segments", "drift", "rpe"):
        assert key in rep
    assert rep["kitti_t_err_pct"] < 1e-9 and rep["ate_rmse_m"] < 1e-9
    assert {s["length_m"] for s in rep["segments"]} == {50.0, 100.0}
    json.dumps(jsonable(rep), allow_nan=False)


def test_jsonable_replaces_nan():
    assert jsonable({"a": np.float64("nan"), "b": [np.int64(3), np.array([1.0, np.inf])]}) == \
        {"a": None, "b": [3, [1.0, None]]}
