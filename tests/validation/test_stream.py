"""Long drives in bounded memory: the streamed simulation (sim/stream.py, validation/streamed.py) gives the scans of
Scenario.simulate, and a run that keeps only per-scan arrays (driver.ScanColumns) gives the poses and states of a
run that keeps every ScanEstimate, bit for bit. No timing assertions: bench/scale.py measures speed and memory."""

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.sim.faults import parse_faults
from rodo.validation.driver import RunResult, ScanColumns, run_sequence
from rodo.validation.streamed import run_streamed, stream_scenario


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()  # NaNs in place too


@pytest.mark.parametrize("name, duration", [("highway", 2.0), ("city", 30.0)])
def test_streamed_scans_equal_the_simulated_ones(name, duration):
    # highway: a mover present from the first scan; city 30 s: movers that enter and leave mid-sequence
    seq, truth = scenarios.get(name).simulate(0, duration)
    sim = stream_scenario(name, 0, duration)
    assert sim._tracks, "the case should have a mover in view"
    assert sim.sensor == seq.sensor and len(sim) == len(seq.scans)
    for key in ("t", "T_vehicle_world", "varpi", "varpi_dot", "T_vehicle_sensor"):
        assert _same(sim.truth[key], truth[key]), key
    n = 0
    for got, want in zip(sim.scans(), seq.scans, strict=True):
        assert got.scan == want.scan and got.t == want.t
        assert _same(got.polar, want.polar)
        n += len(got)
    assert n == len(truth["det_label"])
    with pytest.raises(InputError, match="iterated once"):
        next(sim.scans())


def test_streaming_refuses_faults_that_change_the_scans():
    with pytest.raises(InputError, match="cannot be streamed"):
        stream_scenario("city", 0, 1.0, faults=parse_faults(["dropped=0.1"]))


@pytest.mark.parametrize("model", ["ca-polar", "cv-cartesian"])
def test_streamed_compact_run_gives_the_same_poses(model):
    seq, _ = scenarios.get("city").simulate(3, 2.0)
    config = OdometryConfig.for_model(model)
    full = run_sequence(seq, config)
    compact = run_streamed(stream_scenario("city", 3, 2.0), config)
    assert len(full.estimates) == len(seq.scans) and compact.estimates == []
    a, b = full.state_arrays(), compact.state_arrays()
    assert a.keys() == b.keys()
    for key in a:
        if key != "ms_per_scan":  # wall time
            assert _same(a[key], b[key]), key
    assert _same(full.trajectory().T_world_vehicle, compact.trajectory().T_world_vehicle)
    assert full.events == compact.events
    s_full, s_compact = full.summary(), compact.summary()
    for key in ("scans", "median_associations", "median_detections", "events", "config"):
        assert s_full[key] == s_compact[key]


def test_compact_run_keeps_the_same_arrays_as_a_full_run():
    """The columns equal the arrays stacked from the ScanEstimate objects (the driver's former state_arrays),
    and they are all a compact run keeps per scan: a few kB, whatever the run's length."""
    seq, _ = scenarios.get("city").simulate(4, 1.5)
    config = OdometryConfig.for_model("ca-polar")
    full = run_sequence(seq, config)
    est = full.estimates
    nan6 = np.full((6, 6), np.nan)
    want = {"t": np.array([e.t for e in est]), "T_vehicle_world": np.stack([e.T_vehicle_world for e in est]),
            "T_world_vehicle": np.stack([e.T_world_vehicle for e in est]),
            "varpi": np.stack([e.varpi for e in est]), "varpi_dot": np.stack([e.varpi_dot for e in est]),
            "P": np.stack([e.P for e in est]), "n_detections": np.array([e.n_detections for e in est]),
            "n_static": np.array([e.n_static for e in est]),
            "n_associated": np.array([e.n_associated for e in est]),
            "nis": np.array([e.nis for e in est], dtype=float),
            "P_relative": np.stack([nan6 if e.P_relative is None else e.P_relative for e in est]),
            "P_pose_absolute": np.stack([nan6 if e.P_pose_absolute is None else e.P_pose_absolute for e in est]),
            "map_reuse": np.array([e.map_reuse for e in est])}
    for key, value in want.items():
        assert _same(full.columns[key], value), key
    # rebuilt from the estimates (RunResult without columns), one row at a time through a growing buffer
    again = RunResult(config, est, full.wall_ms, full.events)
    for key in full.columns:
        assert _same(again.columns[key], full.columns[key]), key
    cols = ScanColumns(capacity=1)
    for e in est:
        cols.append(e)
    assert all(_same(cols.arrays()[k], full.columns[k]) for k in full.columns)
    # per scan: numbers only (no objects, dicts or lists), about 3.5 kB for an 18-state CA run
    assert all(a.dtype.kind in "fi" for a in full.columns.values())
    per_scan = sum(a[0].nbytes for a in full.columns.values())
    assert per_scan < 4096
