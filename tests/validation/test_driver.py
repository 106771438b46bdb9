"""validation/driver.py: which times get an estimate (scan_times), empty scans known only from groundtruth.txt,
a sequence with nothing to estimate, write_run's files, relative_pose_errors."""

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.sim.sequence import (NoiseSigmas, RadarScan, SensorConfig, Sequence, Trajectory, read_sequence, read_tum,
                          write_sequence)
from rodo.validation.driver import relative_pose_errors, run_sequence, scan_times, write_run

RATE = 13.0
GAP = (5, 6, 7, 8)  # scans left without rows (about 0.3 s of total blockage)

SENSOR = SensorConfig(RATE, np.eye(4), NoiseSigmas(0.02, 0.002, 0.005, 0.01), (-1.0, 1.0), (-0.2, 0.2), 100.0)


def _scan(k: int, t: float) -> RadarScan:
    return RadarScan(k, t, [10.0], [0.1], [0.0], [-1.0])


def _still(t) -> Trajectory:
    return Trajectory(t, np.broadcast_to(np.eye(4), (len(t), 4, 4)))


@given(n=st.integers(1, 60), data=st.data())
def test_scan_times_adds_groundtruth_times_without_scans(n, data):
    t = np.arange(n) / RATE
    with_rows = sorted(data.draw(st.sets(st.integers(0, n - 1)), label="scans with rows"))
    seq = Sequence(SENSOR, [_scan(k, t[k]) for k in with_rows], _still(np.round(t, 9)))  # groundtruth: 9 decimals
    got = scan_times(seq)
    # one time per scan: a scan's exact time where it has rows, the groundtruth time otherwise
    want = np.array([t[k] if k in with_rows else np.round(t[k], 9) for k in range(n)])
    assert np.array_equal(got, want)
    # no groundtruth: only the scans with rows
    assert np.array_equal(scan_times(Sequence(SENSOR, seq.scans, None)), t[with_rows])


def test_scan_times_do_not_take_groundtruth_between_consecutive_scans():
    """Poses at half periods between scans whose indices do not skip are not scans of this radar (a ground truth at
    twice its rate): the scans with rows alone (tests/validation/test_input_defects_gt_times.py has the rule)."""
    t = np.arange(5) / RATE
    extra = t[:-1] + 0.5 / RATE  # groundtruth at half periods: no scan within 1 us
    gt = np.sort(np.r_[np.round(t, 9), np.round(extra, 9)])
    got = scan_times(Sequence(SENSOR, [_scan(k, t[k]) for k in range(5)], _still(gt)))
    assert np.array_equal(got, t)


def test_scan_times_take_groundtruth_where_the_scan_index_skips():
    t = np.arange(5) / RATE
    kept = [0, 1, 4]  # scans 2 and 3 without rows: their poses are empty scans
    got = scan_times(Sequence(SENSOR, [_scan(k, t[k]) for k in kept], _still(np.round(t, 9))))
    assert np.allclose(got, t, atol=1e-9) and len(got) == 5


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    d = tmp_path_factory.mktemp("city1")
    scenarios.simulate_to("city", 0, d, duration=1)  # 14 scans
    return read_sequence(d)


@pytest.fixture(scope="module")
def gap_run(city, tmp_path_factory):
    """The city sequence written with scans 5-8 empty (no rows; still in groundtruth.txt), read back and run."""
    d = tmp_path_factory.mktemp("gap")
    write_sequence(d, Sequence(city.sensor, [s for s in city.scans if s.scan not in GAP], city.groundtruth))
    seq = read_sequence(d)
    assert len(seq.scans) == len(city.scans) - len(GAP) and len(seq.groundtruth.t) == len(city.scans)

    class Counter:
        n = 0

        def update(self):
            Counter.n += 1

    result = run_sequence(seq, OdometryConfig.for_model("ca-polar"), progress=Counter())
    out = d / "out"
    write_run(out, result)
    return seq, result, out, Counter.n


def test_empty_scans_known_from_groundtruth_get_an_estimate(gap_run):
    seq, result, out, updates = gap_run
    n = len(seq.groundtruth.t)
    assert updates == n  # the progress bar sees every reported time
    est = read_tum(out / "estimate.txt")
    assert np.array_equal(est.t, seq.groundtruth.t) and len(result.estimates) == n
    with np.load(out / "states.npz") as z:
        s = {k: z[k] for k in z.files}
    gap = np.isin(np.arange(n), GAP)
    assert np.all(s["n_detections"][gap] == 0) and np.all(s["n_detections"][~gap] > 100)
    assert np.all(s["n_associated"][gap] == 0)
    for key in ("T_vehicle_world", "varpi", "varpi_dot", "P"):
        assert np.all(np.isfinite(s[key])), key
    assert json.loads((out / "summary.json").read_text())["scans"] == n


def test_uncertainty_grows_through_the_gap_and_the_prior_bridges_it(gap_run):
    seq, result, _, _ = gap_run
    pose_var = np.array([np.trace(e.P[:6, :6]) for e in result.estimates])
    first, last = GAP[0], GAP[-1]
    # no measurements: the prior alone propagates, so the pose covariance grows at every empty scan ...
    assert np.all(np.diff(pose_var[first - 1:last + 1]) > 0)
    # ... and the first scan with detections brings it back down
    assert pose_var[last + 1] < 0.2 * pose_var[last]
    # the constant-acceleration prediction stays on the ground truth over the 0.3 s gap (measured 2 cm)
    err = np.linalg.norm(result.trajectory().T_world_vehicle[:, :3, 3] - seq.groundtruth.T_world_vehicle[:, :3, 3],
                         axis=1)
    assert err[first:last + 1].max() < 0.05 and err.max() < 0.05


def test_groundtruth_only_sequence_gives_a_row_per_time(tmp_path):
    t = np.round(np.arange(6) / RATE, 9)
    result = run_sequence(Sequence(SENSOR, [], _still(t)), OdometryConfig())
    assert np.array_equal(result.t, t)
    write_run(tmp_path, result)
    assert np.array_equal(read_tum(tmp_path / "estimate.txt").t, t)
    assert all(np.all(np.isfinite(e.T_world_vehicle)) for e in result.estimates)


def test_no_scans_and_no_groundtruth_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="no scans"):
        run_sequence(Sequence(SENSOR, [], None), OdometryConfig())
    write_sequence(tmp_path, Sequence(SENSOR, [], None))  # radar.csv with its header only
    seq = read_sequence(tmp_path)
    assert seq.scans == [] and seq.groundtruth is None
    with pytest.raises(InputError, match="no scans"):
        run_sequence(seq, OdometryConfig.for_model("cv-cartesian"))


def test_relative_pose_errors_recover_a_known_perturbation():
    rng = np.random.default_rng(np.random.SeedSequence(7))
    steps = np.c_[rng.uniform(0.5, 1.5, (20, 1)), rng.normal(0, 0.05, (20, 5))]
    T = [np.eye(4)]
    for S in se3.exp(steps):
        T.append(T[-1] @ S)
    gt = Trajectory(np.arange(21) * 0.1, np.stack(T))
    dt, dr = relative_pose_errors(gt, gt)
    assert dt.shape == (20,) and np.allclose(dt, 0, atol=1e-12) and np.allclose(dr, 0, atol=1e-7)
    delta = rng.normal(0, 0.01, (20, 6))  # each estimated step = true step @ exp(delta)
    E = [np.eye(4)]
    for S, D in zip(se3.exp(steps), se3.exp(delta)):
        E.append(E[-1] @ S @ D)
    dt, dr = relative_pose_errors(gt, Trajectory(gt.t, np.stack(E)))
    np.testing.assert_allclose(dt, np.linalg.norm(se3.exp(-delta)[:, :3, 3], axis=1), rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(dr, np.linalg.norm(delta[:, 3:], axis=1), rtol=1e-6)
