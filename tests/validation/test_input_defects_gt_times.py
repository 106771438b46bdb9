"""groundtruth.txt's times add empty scans to a run only where they are the radar's own scan times
(validation.driver.scan_times / empty_scan_times, docs/sequence_format.md): ground truth at another phase or rate
leaves the run bit-identical to the run without it; the simulator's empty scans (dropped, outages, with jitter)
are still run."""

from __future__ import annotations

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.estimator.config import OdometryConfig
from rodo.sim.faults import parse_faults
from rodo.sim.sequence import Sequence, Trajectory, read_sequence, write_tum
from rodo.validation.driver import empty_scan_times, run_sequence, scan_times

RATE = 13.0


@pytest.fixture(scope="module")
def city(tmp_path_factory):
    """2 s of city (27 scans, every one with rows) and its run without groundtruth.txt."""
    d = tmp_path_factory.mktemp("city")
    scenarios.simulate_to("city", 1, d, duration=2.0)
    seq = read_sequence(d)
    bare = Sequence(seq.sensor, seq.scans, None)
    return d, seq, run_sequence(bare, OdometryConfig.for_model("ca-polar"), keep_estimates=False)


def _moved(gt: Trajectory, how: str) -> Trajectory:
    """The ground truth shifted by 30 ms, or at 4x the scan rate (the same poses repeated)."""
    if how == "shifted":
        return Trajectory(gt.t + 0.03, gt.T_world_vehicle)
    t = np.arange(4 * (len(gt.t) - 1) + 1) / (4 * RATE)
    return Trajectory(t, np.repeat(gt.T_world_vehicle, 4, axis=0)[:len(t)])


@pytest.mark.parametrize("how", ["shifted", "4x"])
def test_shifted_or_faster_groundtruth_changes_nothing(city, how):
    _, seq, bare = city
    with_gt = Sequence(seq.sensor, seq.scans, _moved(seq.groundtruth, how))
    rows = np.array([s.t for s in seq.scans])
    assert len(with_gt.groundtruth.t) > len(rows) or how == "shifted"
    assert np.array_equal(scan_times(with_gt), rows)  # 27 scans, not 54 (shifted) or 105 (4x)
    result = run_sequence(with_gt, OdometryConfig.for_model("ca-polar"), keep_estimates=False)
    assert np.array_equal(result.t, bare.t)
    assert np.array_equal(result.columns["T_world_vehicle"], bare.columns["T_world_vehicle"])
    assert np.array_equal(result.columns["P"], bare.columns["P"])


@pytest.mark.parametrize("how", ["shifted 0.5 ms", "4x"])
def test_groundtruth_file_off_the_scan_times_gives_the_same_estimate_file(city, tmp_path, capsys, how):
    """Through `rodo run`: groundtruth.txt 0.5 ms after every scan (close enough for the evaluation's 1 ms
    association) or at 4x the rate next to the same radar.csv gives estimate.txt byte for byte as without
    groundtruth.txt, and the run is still evaluated against it."""
    d, seq, _ = city
    gt = seq.groundtruth
    gt = Trajectory(gt.t + 5e-4, gt.T_world_vehicle) if how != "4x" else _moved(gt, how)
    for name, truth in (("with", gt), ("none", None)):
        s = tmp_path / name
        s.mkdir()
        for f in ("radar.csv", "sensor.toml"):
            (s / f).write_bytes((d / f).read_bytes())
        if truth is not None:
            write_tum(s / "groundtruth.txt", truth)
        assert main(["run", str(s), "--out", str(tmp_path / f"run_{name}")]) == 0
    out = capsys.readouterr().out
    assert out.count('"scans": 27') == 2 and "ATE" in out
    assert (tmp_path / "run_with" / "estimate.txt").read_bytes() == \
        (tmp_path / "run_none" / "estimate.txt").read_bytes()


@pytest.mark.parametrize("faults", [
    ["dropped=0.3", "outage=0:0.3", "outage=1.8:0.5"],  # empty scans inside, at the start and at the end
    ["jitter=0.008", "dropped=0.3", "outage=0:0.3", "outage=1.8:0.5"],  # the same off the regular grid
])
def test_simulated_empty_scans_are_still_run(tmp_path, faults):
    """Every simulated scan gets an estimate, those without rows at their groundtruth.txt time, with no
    detections; the run is the one of the sequence's scans (none dropped, none added)."""
    _, truth = scenarios.simulate_to("city", 2, tmp_path, duration=2.0, faults=parse_faults(faults))
    seq = read_sequence(tmp_path)
    recorded = truth["fault_t_recorded"]
    empty = np.diff(truth["scan_offsets"]) == 0
    assert empty[0] and empty[-1] and 3 < empty.sum() < len(empty) - 5  # the case is what it claims to be
    times = scan_times(seq)
    assert len(times) == len(recorded) and np.allclose(times, recorded, rtol=0, atol=1e-6)
    result = run_sequence(seq, OdometryConfig.for_model("ca-polar"), keep_estimates=False)
    assert np.array_equal(result.columns["n_detections"] == 0, empty)
    assert np.all(np.isfinite(result.columns["T_world_vehicle"]))


def _still(t) -> Trajectory:
    return Trajectory(np.asarray(t, float), np.broadcast_to(np.eye(4), (len(t), 4, 4)))


def test_empty_scan_rule_on_synthetic_times():
    t_all = np.arange(12) / RATE
    g = np.round(t_all, 9)  # groundtruth.txt keeps 9 decimals
    rows = np.array([2, 3, 6, 7, 9])  # empty: 0, 1 (before), 4, 5, 8 (between), 10, 11 (after)
    t, index = t_all[rows], rows
    got = empty_scan_times(t, index, g, RATE)
    assert np.array_equal(got, g[np.setdiff1d(np.arange(12), rows)])
    # the poses before the first scan with rows count only when they are as many as its index
    earlier = np.r_[np.round(-1 / RATE, 9), g]  # indices from 1: three poses before scan 3
    assert np.array_equal(empty_scan_times(t, index + 1, earlier, RATE)[:3], earlier[:3])
    assert not np.any(empty_scan_times(t, index + 1, g, RATE) < t[0])  # two poses before scan 3: not its scans
    assert np.array_equal(empty_scan_times(t, index + 1, g, RATE), g[[4, 5, 8, 10, 11]])
    # off the scan times: a pose missing at a scan with rows, a half-period phase, another count between scans
    assert len(empty_scan_times(t, index, np.delete(g, 6), RATE)) == 0
    assert len(empty_scan_times(t, index, g + 0.5 / RATE, RATE)) == 0
    assert len(empty_scan_times(t, index, np.sort(np.r_[g, g[4] + 0.3 / RATE]), RATE)) == 0
    # one scan with rows: the poses after it count when a whole number of periods after it, not at 4x the rate
    assert np.array_equal(empty_scan_times(t_all[:1], np.array([0]), g[:4], RATE), g[1:4])
    fast = np.round(np.arange(13) / (4 * RATE), 9)
    assert len(empty_scan_times(t_all[:1], np.array([0]), fast, RATE)) == 0
    # a radar.csv without rows: every pose is a scan (nothing else to go by)
    assert np.array_equal(scan_times(Sequence(_sensor(), [], _still(g))), g)


def _sensor():
    from rodo.sim.sequence import NoiseSigmas, SensorConfig

    return SensorConfig(RATE, np.eye(4), NoiseSigmas(0.02, 0.002, 0.005, 0.01), (-1.0, 1.0), (-0.2, 0.2), 100.0)
