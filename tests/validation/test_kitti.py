"""The KITTI metric: a case computed on paper, an independent brute-force port of the devkit's loops, and evo."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3, so3
from rodo.validation.kitti import LENGTHS, kitti_errors, trajectory_distances


def _straight(n: int) -> np.ndarray:
    """n poses along x, 1 m apart, identity orientation (T_world_vehicle)."""
    return se3.from_rotation_translation(np.broadcast_to(np.eye(3), (n, 3, 3)), np.c_[np.arange(n), np.zeros((n, 2))])


def _chain(steps: np.ndarray) -> np.ndarray:
    """Compose relative steps (n, 4, 4) starting at the identity."""
    out = [np.eye(4)]
    for s in steps:
        out.append(out[-1] @ s)
    return np.stack(out)


def test_heading_error_on_a_straight_line_matches_hand_computation():
    # ground truth: 201 poses along x, 1 m apart. Estimate: the same orientations, but every position step
    # points theta off the x axis. Devkit detail: the last frame is the first with dist > dist[first] + L
    # (strict), so a "100 m" segment spans 101 frames of 1 m and is still divided by 100:
    # t_err = |(101, 0) - 101 (cos th, sin th)| / 100 = 2 * 1.01 * sin(th / 2); r_err = 0.
    theta = np.deg2rad(2.0)
    gt = _straight(201)
    k = np.arange(201)
    est = se3.from_rotation_translation(np.broadcast_to(np.eye(3), (201, 3, 3)),
                                        np.c_[k * np.cos(theta), k * np.sin(theta), np.zeros(201)])
    res = kitti_errors(gt, est)
    # first frames 0, 10, ..., 90 fit a 100 m segment (f + 101 <= 200); no 200 m segment fits
    assert res.n_segments == 10
    assert set(res.segments[:, 1]) == {100.0}
    np.testing.assert_allclose(res.segments[:, 2], 2 * 1.01 * np.sin(theta / 2), rtol=1e-12)
    np.testing.assert_allclose(res.t_err_pct, 100 * 2 * 1.01 * np.sin(theta / 2), rtol=1e-12)
    assert res.r_err_deg_per_m == pytest.approx(0.0, abs=1e-9)
    assert res.per_length() == {100.0: (pytest.approx(res.t_err_pct), pytest.approx(0.0, abs=1e-9), 10)}


def test_constant_yaw_rate_error_gives_rotation_error_per_metre():
    # estimate turns delta per 1 m step while the truth goes straight: over a segment of 101 steps the error
    # rotation is 101 delta about z, so r_err = 101 delta / 100 rad/m.
    delta = 1e-3
    step = se3.from_rotation_translation(so3.exp(np.array([0.0, 0.0, delta])), np.array([1.0, 0.0, 0.0]))
    est = _chain(np.broadcast_to(step, (250, 4, 4)))
    gt = _straight(251)
    res = kitti_errors(gt, est, lengths=(100.0, 200.0))
    want = np.where(res.segments[:, 1] == 100, 101 * delta / 100, 201 * delta / 200)
    np.testing.assert_allclose(res.segments[:, 3], want, rtol=1e-9)
    assert res.per_length()[200.0][2] == 5  # firsts 0..40 (f + 201 <= 250)


def _devkit(gt, est, lengths, step):
    """A line-by-line port of the C++ devkit's calcSequenceErrors (evaluate_odometry.cpp)."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[i - 1] + float(np.sqrt(np.sum((gt[i - 1][:3, 3] - gt[i][:3, 3]) ** 2))))
    err = []
    for first_frame in range(0, len(gt), step):
        for length in lengths:
            last_frame = -1
            for i in range(first_frame, len(dist)):
                if dist[i] > dist[first_frame] + length:
                    last_frame = i
                    break
            if last_frame == -1:
                continue
            pose_delta_gt = np.linalg.inv(gt[first_frame]) @ gt[last_frame]
            pose_delta_result = np.linalg.inv(est[first_frame]) @ est[last_frame]
            pose_error = np.linalg.inv(pose_delta_result) @ pose_delta_gt
            a, b, c = pose_error[0, 0], pose_error[1, 1], pose_error[2, 2]
            d = 0.5 * (a + b + c - 1.0)
            r_err = np.arccos(max(min(d, 1.0), -1.0))
            t_err = np.sqrt(pose_error[0, 3] ** 2 + pose_error[1, 3] ** 2 + pose_error[2, 3] ** 2)
            err.append((first_frame, length, t_err / length, r_err / length))
    return np.array(err).reshape(-1, 4)


def _random_pair(seed: int, n: int = 300):
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    xi = np.c_[rng.uniform(0.5, 2.0, n - 1), rng.normal(0, 0.1, (n - 1, 2)), rng.normal(0, 0.02, (n - 1, 3))]
    gt = _chain(se3.exp(xi))
    noise = np.c_[rng.normal(0, 0.02, (n - 1, 3)), rng.normal(0, 0.002, (n - 1, 3))]
    est = _chain(se3.exp(xi + noise))
    return gt, est


@given(st.integers(0, 2**32 - 1), st.integers(1, 12))
def test_agrees_with_brute_force_devkit_port(seed, step):
    gt, est = _random_pair(seed)
    lengths = (20.0, 50.0, 100.0, 200.0)
    res = kitti_errors(gt, est, lengths, step)
    ref = _devkit(gt, est, lengths, step)
    assert res.segments.shape == ref.shape and len(ref) > 0
    np.testing.assert_allclose(res.segments, ref, rtol=1e-10, atol=1e-13)
    assert res.t_err_pct == pytest.approx(100 * ref[:, 2].mean(), rel=1e-12)
    assert res.r_err_deg_per_m == pytest.approx(np.rad2deg(ref[:, 3].mean()), rel=1e-12)


def test_distances_and_short_trajectory():
    gt = _straight(50)
    np.testing.assert_array_equal(trajectory_distances(gt), np.arange(50.0))
    res = kitti_errors(gt, gt, LENGTHS)
    assert res.n_segments == 0 and np.isnan(res.t_err_pct) and np.isnan(res.r_err_deg_per_m)


def test_perfect_estimate_in_another_world_frame_has_zero_error():
    gt, _ = _random_pair(3)
    A = se3.exp(np.array([5.0, -2.0, 1.0, 0.1, -0.2, 0.7]))
    res = kitti_errors(gt, A @ gt, (50.0, 100.0), 5)
    assert res.n_segments > 0
    assert res.t_err_pct < 1e-9 and res.r_err_deg_per_m < 1e-6


@pytest.mark.parametrize("bad, match", [
    (lambda g: (g, g[:-1]), "matching"),
    (lambda g: (g[..., :3], g[..., :3]), "matching"),
    (lambda g: (g, np.where(np.arange(len(g))[:, None, None] == 3, np.nan, g)), "NaN"),
])
def test_bad_input_is_named(bad, match):
    gt = _straight(20)
    with pytest.raises(InputError, match=match):
        kitti_errors(*bad(gt))
    with pytest.raises(InputError, match="step"):
        kitti_errors(gt, gt, step=0)


def test_agrees_with_evo_rpe_per_segment():
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.trajectory import PosePath3D

    gt, est = _random_pair(11, 250)
    res = kitti_errors(gt, est, (20.0, 50.0, 100.0), 3)
    ref = PosePath3D(poses_se3=list(gt))
    est_path = PosePath3D(poses_se3=list(est))
    dist = trajectory_distances(gt)
    cache = {}

    def evo_errors(gap, rel):  # all_pairs: pair k is (k, k + gap)
        if (gap, rel) not in cache:
            m = evo_metrics.RPE(rel, delta=gap, delta_unit=evo_metrics.Unit.frames, all_pairs=True)
            m.process_data((ref, est_path))
            cache[gap, rel] = m.error
        return cache[gap, rel]

    for f, L, t_err, r_err in res.segments:
        f = int(f)
        gap = int(np.searchsorted(dist, dist[f] + L, side="right")) - f
        t_evo = evo_errors(gap, evo_metrics.PoseRelation.translation_part)[f]
        r_evo = evo_errors(gap, evo_metrics.PoseRelation.rotation_angle_rad)[f]
        assert t_evo / L == pytest.approx(t_err, rel=1e-9, abs=1e-12)
        assert r_evo / L == pytest.approx(r_err, rel=1e-6, abs=1e-10)
    assert res.n_segments > 20
