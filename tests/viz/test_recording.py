"""Rerun recordings read back with rerun.chunk.RrdReader. The numbers they plot are computed in rodo.validation
(tested in tests/validation/); here they are recomputed independently from the truth and the run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.estimator.lie import se3
from rodo.estimator.scan import ScanDetail
from rodo.sim.sequence import Sequence
from rodo.validation.driver import run_sequence
from rodo.viz.recording import DETECTION_CLASSES, detection_classes, record_run

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------------------- recordings
@pytest.fixture(scope="module")
def run():
    from rodo import scenarios

    seq, truth = scenarios.get("hills").simulate(3, duration=1.2)
    result = run_sequence(seq, OdometryConfig.for_model("ca-polar"))
    return seq, truth, result


def _chunks(path):
    from rerun.chunk import RrdReader

    return RrdReader(path).stream().to_chunks()


def _column(chunks, entity, column, static=False):
    """Rows of `column` of an entity (temporal rows sorted by frame), as a list."""
    rows = []
    for ch in chunks:
        if ch.entity_path != entity or ch.is_static != static:
            continue
        rb = ch.to_record_batch()
        if column not in rb.schema.names:
            continue
        vals = rb.column(column).to_pylist()
        keys = rb.column("frame").to_pylist() if not static else range(len(vals))
        rows.extend(zip(keys, vals))
    return [v for _, v in sorted(rows, key=lambda kv: kv[0])]


def _synthetic_detail(seq, truth, result, rng):
    """ScanDetail per frame: static = truth label 0/1, every other static detection associated with a random
    map point."""
    out = []
    by_t = {s.t: s for s in seq.scans}
    for k, e in enumerate(result.estimates):
        scan = by_t[e.t]
        lab = truth["det_label"][truth["scan_offsets"][k]:truth["scan_offsets"][k + 1]]
        static = lab <= 1
        det = np.flatnonzero(static)[::2]
        mp = rng.normal(size=(max(len(det), 1) + 5, 3)) * 20
        out.append(ScanDetail(scan.polar, static, det, rng.permutation(len(mp))[:len(det)], mp))
    return out


@pytest.fixture(scope="module")
def recorded(run, tmp_path_factory):
    """A recording of the run with truth and synthetic detail, written in rerun's strict mode (raise on malformed
    data; restored afterwards): (path, chunks, detail)."""
    import rerun as rr

    seq, truth, result = run
    detail = _synthetic_detail(seq, truth, result, np.random.default_rng(np.random.SeedSequence(5)))
    before = rr.strict_mode()
    rr.set_strict_mode(True)
    try:
        path = record_run(tmp_path_factory.mktemp("a") / "run.rrd", seq, result, truth=truth, detail=detail)
    finally:
        rr.set_strict_mode(before)
    assert rr.get_global_data_recording() is None  # an explicit stream, never the global one
    return path, _chunks(path), detail


def test_recording_has_every_entity_and_a_blueprint(recorded):
    from rerun.chunk import RrdReader

    path, chunks, _ = recorded
    paths = {ch.entity_path for ch in chunks}
    for entity in ("/world", "/world/vehicle", "/world/vehicle/sensor", "/world/vehicle/sensor/scan", "/world/map",
                   "/world/associations", "/world/estimate/trajectory", "/world/truth/trajectory",
                   "/world/estimate/covariance", "/world/truth/vehicle", "/metrics/error/translation",
                   "/metrics/drift", "/metrics/nees/pose", "/metrics/nees/velocity", "/metrics/nees/pose_window",
                   "/metrics/nees/relative_scan", "/metrics/ellipsoid/fraction", "/metrics/nis", "/metrics/nis/doppler",
                   "/metrics/nis/pull", "/metrics/counts", "/metrics/timing", "/velocity/nu_x",
                   "/acceleration/omega_dot_z", "/events"):
        assert entity in paths, entity
    assert any(s.kind == "blueprint" for s in RrdReader(path).blueprints())


def test_recording_world_frame_trajectories_and_extrinsic(run, recorded):
    import rerun as rr

    seq, truth, result = run
    _, chunks, _ = recorded
    n = len(result.estimates)
    T_world_vehicle = np.stack([e.T_world_vehicle for e in result.estimates])
    xyz = _column(chunks, "/world", "ViewCoordinates:xyz", static=True)
    z_up = [d.value for d in rr.components.ViewCoordinates.RIGHT_HAND_Z_UP.coordinates]
    assert np.ravel(xyz).tolist() == z_up and z_up[2] == rr.components.ViewCoordinates.FLU.coordinates[2].value
    strip = np.array(_column(chunks, "/world/estimate/trajectory", "LineStrips3D:strips", static=True)[0][0])
    assert np.allclose(strip, result.trajectory().T_world_vehicle[:, :3, 3], atol=1e-4)
    gt = np.array(_column(chunks, "/world/truth/trajectory", "LineStrips3D:strips", static=True)[0][0])
    assert np.allclose(gt[0], strip[0], atol=1e-5)  # aligned at the first pose
    T_world_vehicle_truth = se3.inverse(truth["T_vehicle_world"])
    T_estimate_truth = T_world_vehicle[0] @ se3.inverse(T_world_vehicle_truth[0])  # world frames e <- g
    expected = T_estimate_truth @ T_world_vehicle_truth
    assert np.allclose(gt, expected[:, :3, 3], atol=1e-4)
    trans = np.array(_column(chunks, "/world/vehicle", "Transform3D:translation")).reshape(n, 3)
    assert np.allclose(trans, T_world_vehicle[:, :3, 3], atol=1e-4)
    # the extrinsic: static, logged exactly once
    ext = [ch for ch in chunks if ch.entity_path == "/world/vehicle/sensor"
           and "Transform3D:translation" in ch.to_record_batch().schema.names]
    assert len(ext) == 1 and ext[0].is_static and ext[0].num_rows == 1
    assert np.allclose(_column(chunks, "/world/vehicle/sensor", "Transform3D:translation", static=True)[0][0],
                       seq.sensor.T_vehicle_sensor[:3, 3], atol=1e-6)


def _by_frame(chunks, entity, column="Scalars:scalars"):
    """{frame: row} of a temporal column (frames whose row was left out as a gap are absent)."""
    out = {}
    for ch in chunks:
        if ch.entity_path == entity and not ch.is_static:
            rb = ch.to_record_batch()
            out.update(zip(rb.column("frame").to_pylist(), rb.column(column).to_pylist()))
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}


def _xi(truth, result, k):
    """Left pose error ln(T_true T_est^-1) at scan k, the truth aligned at the first pose (independently)."""
    T_estimate_truth = result.estimates[0].T_world_vehicle @ truth["T_vehicle_world"][0]
    e = result.estimates[k]
    return se3.log(truth["T_vehicle_world"][k] @ se3.inverse(T_estimate_truth) @ se3.inverse(e.T_vehicle_world))


def test_recording_nees_and_nis_match_an_independent_computation(run, recorded):
    """NEES: bounds are the chi-square quantiles; values recomputed independently from the truth dict: the pose
    against P_pose_absolute, pose_window against the window's marginal P[:6, :6]."""
    _, truth, result = run
    _, chunks, _ = recorded
    n = len(result.estimates)
    window = np.array(_column(chunks, "/metrics/nees/pose_window", "Scalars:scalars"))
    assert window.shape == (n, 3)
    assert np.allclose(window[:, 1], chi2.ppf(0.025, 6)) and np.allclose(window[:, 2], chi2.ppf(0.975, 6))
    pose = _by_frame(chunks, "/metrics/nees/pose")
    assert len(pose) >= n - 1
    for k in (1, n // 2, n - 1):
        e, xi = result.estimates[k], _xi(truth, result, k)
        assert window[k, 0] == pytest.approx(xi @ np.linalg.solve(e.P[:6, :6], xi), rel=1e-6, abs=1e-9)
        assert pose[k][0] == pytest.approx(xi @ np.linalg.solve(e.P_pose_absolute, xi), rel=1e-6, abs=1e-9)
        assert np.allclose(pose[k][1:], chi2.ppf([0.025, 0.975], 6))
    assert window[0, 0] == pytest.approx(0.0, abs=1e-9)
    nis = np.array(_column(chunks, "/metrics/nis", "Scalars:scalars"))
    assoc = [e.n_associated for e in result.estimates if np.isfinite(e.nis)]
    assert nis[-1, 2] == pytest.approx(chi2.ppf(0.975, 4 * assoc[-1]) / assoc[-1])
    doppler = np.array(_column(chunks, "/metrics/nis/doppler", "Scalars:scalars")).ravel()
    want = np.array([e.doppler_nis for e in result.estimates])
    assert np.isnan(want[0]) and len(doppler) == np.isfinite(want).sum() >= n - 1  # none at the first scan
    np.testing.assert_allclose(doppler, want[np.isfinite(want)])
    pull = np.array(_column(chunks, "/metrics/nis/pull", "Scalars:scalars")).ravel()
    want = np.array([e.pose_pull for e in result.estimates])
    assert np.isfinite(want).sum() >= n - 1 and np.all(want[np.isfinite(want)] >= 0.0)
    np.testing.assert_allclose(pull, want[np.isfinite(want)])


def test_recording_has_every_consistency_measure(run, recorded):
    """Every measure of odometry_nees under metrics/nees (equal to validation's per-scan values at the matched
    scans), and the truth-inside-the-ellipsoid series recomputed from the drawn ellipsoid."""
    from rodo.validation.odometry_consistency import MEASURES, odometry_nees
    from rodo.validation.run_consistency import run_states

    _, truth, result = run
    _, chunks, _ = recorded
    states = run_states(result)
    ref = odometry_nees(states, truth, span=1.0, tau=float(states["velocity_correlation_time"]))
    frame_of = {float(t): k for k, t in enumerate(result.t)}
    for name in MEASURES:
        got = _by_frame(chunks, f"/metrics/nees/{name}")
        assert got, name
        for t, v in zip(ref["t"], ref[name]):
            k = frame_of[float(t)]
            assert (np.isnan(v) and k not in got) or got[k][0] == pytest.approx(v, rel=1e-9, abs=1e-12), name
    n = len(result.estimates)
    half = np.array(_column(chunks, "/world/estimate/covariance", "Ellipsoids3D:half_sizes")).reshape(n, 3)
    inside = _by_frame(chunks, "/metrics/ellipsoid/inside")
    fraction = _by_frame(chunks, "/metrics/ellipsoid/fraction")
    T_estimate_truth = result.estimates[0].T_world_vehicle @ truth["T_vehicle_world"][0]
    flags = []
    for k in sorted(inside):
        e = result.estimates[k]
        C = e.T_vehicle_world[:3, :3]
        d = T_estimate_truth @ se3.inverse(truth["T_vehicle_world"][k])[:, 3] - e.T_world_vehicle[:, 3]
        Sigma_w = C.T @ e.P_pose_absolute[:3, :3] @ C
        assert inside[k][0] == float(d[:3] @ np.linalg.solve(Sigma_w, d[:3]) <= 9.0)
        assert np.allclose(np.sort(half[k]), 3 * np.sqrt(np.linalg.eigvalsh(Sigma_w)), rtol=1e-5)
        flags.append(inside[k][0])
        assert fraction[k][0] == pytest.approx(100 * np.mean(flags))
        assert fraction[k][1] == pytest.approx(100 * chi2.cdf(9.0, 3))
    assert len(inside) >= n - 1


def test_recording_covariance_ellipsoid_is_the_world_position_covariance(run, recorded):
    """3-sigma ellipsoid of the world position from the absolute pose covariance: C^T P_pose_absolute[:3, :3] C."""
    from scipy.spatial.transform import Rotation

    _, _, result = run
    _, chunks, _ = recorded
    n = len(result.estimates)
    half = np.array(_column(chunks, "/world/estimate/covariance", "Ellipsoids3D:half_sizes")).reshape(n, 3)
    e = result.estimates[-1]
    C = e.T_vehicle_world[:3, :3]
    Sigma_w = C.T @ e.P_pose_absolute[:3, :3] @ C
    assert np.allclose(np.sort(half[-1]), 3 * np.sqrt(np.linalg.eigvalsh(Sigma_w)), rtol=1e-5)
    assert not np.allclose(np.sort(half[-1]), 3 * np.sqrt(np.linalg.eigvalsh(C.T @ e.P[:3, :3] @ C)), rtol=1e-2)
    quat = np.array(_column(chunks, "/world/estimate/covariance", "Ellipsoids3D:quaternions")).reshape(n, 4)
    R = Rotation.from_quat(quat[-1]).as_matrix()   # the ellipsoid's axes rebuild C^T P_abs C
    assert np.allclose(R @ np.diag((half[-1] / 3) ** 2) @ R.T, Sigma_w, rtol=1e-4, atol=1e-6 * np.abs(Sigma_w).max())
    assert np.array_equal(_column(chunks, "/world/estimate/covariance", "Ellipsoids3D:centers")[-1][0],
                          np.float32(e.T_world_vehicle[:3, 3]))


def test_recording_timelines_scan_classes_and_associations(run, recorded):
    from rodo.estimator.measurements import polar_to_cartesian

    seq, truth, result = run
    _, chunks, detail = recorded
    # both timelines; time = scan time
    ts = [ch for ch in chunks if ch.entity_path == "/metrics/counts" and not ch.is_static][0].to_record_batch()
    assert {"frame", "time"} <= set(ts.schema.names)
    t_logged = np.array([x.total_seconds() if hasattr(x, "total_seconds") else x / 1e9
                         for x in ts.column("time").to_pylist()])
    assert np.allclose(t_logged, result.t, atol=1e-6)
    # scan classes and association lines
    cls = _column(chunks, "/world/vehicle/sensor/scan", "Points3D:class_ids")
    k = len(result.estimates) - 1
    lab = truth["det_label"][truth["scan_offsets"][k]:truth["scan_offsets"][k + 1]]
    assert np.array_equal(cls[k], detection_classes(detail[k], lab))
    assert set(np.unique(np.concatenate(cls))) <= set(DETECTION_CLASSES)
    lines = np.array(_column(chunks, "/world/associations", "LineStrips3D:strips")[k])
    d = detail[k]
    T_world_sensor = result.estimates[k].T_world_vehicle @ seq.sensor.T_vehicle_sensor
    p_world = se3.transform_points(T_world_sensor, polar_to_cartesian(d.polar[d.det_idx]))
    assert np.allclose(lines[:, 0], p_world, atol=1e-3)
    assert np.allclose(lines[:, 1], d.map_points[d.map_idx], atol=1e-4)


def test_recording_without_detail_or_truth(run, tmp_path):
    seq, truth, result = run
    plain = Sequence(seq.sensor, seq.scans, None)
    chunks = _chunks(record_run(tmp_path / "plain.rrd", plain, result))
    paths = {ch.entity_path for ch in chunks}
    assert "/world/truth/trajectory" not in paths and "/metrics/nees/pose" not in paths
    assert "/velocity/nu_x" in paths and "/world/vehicle/sensor/scan" in paths
    cls = _column(chunks, "/world/vehicle/sensor/scan", "Points3D:class_ids")
    assert set(np.unique(np.concatenate(cls))) == {4}   # no association detail, no labels
    # truth labels without detail: clutter and movers are marked
    chunks = _chunks(record_run(tmp_path / "labels.rrd", seq, result, truth=truth))
    cls = np.concatenate(_column(chunks, "/world/vehicle/sensor/scan", "Points3D:class_ids"))
    lab = truth["det_label"][:truth["scan_offsets"][len(result.estimates)]]
    assert np.array_equal(cls == 3, lab == 3) and np.array_equal(cls == 6, lab == 2)


def test_two_recordings_are_independent_files(run, tmp_path):
    from rerun.chunk import RrdReader

    seq, _, result = run
    a = record_run(tmp_path / "a.rrd", seq, result, recording_id="run-a")
    b = record_run(tmp_path / "b.rrd", seq, result, recording_id="run-b")
    assert [r.recording_id for r in RrdReader(a).recordings()] == ["run-a"]
    assert [r.recording_id for r in RrdReader(b).recordings()] == ["run-b"]


def test_record_run_rejects_bad_input(run, tmp_path):
    seq, truth, result = run
    with pytest.raises(InputError, match="detail"):
        record_run(tmp_path / "x.rrd", seq, result, detail=[None])
    with pytest.raises(InputError, match="truth"):
        record_run(tmp_path / "x.rrd", seq, result, truth={"t": truth["t"]})


def test_scan_detail_rejects_inconsistent_input():
    with pytest.raises(InputError, match="ScanDetail.static"):
        ScanDetail(np.ones((3, 4)), [True, False], [], [], np.zeros((0, 3)))
    with pytest.raises(InputError, match="ScanDetail.map_idx"):
        ScanDetail(np.ones((3, 4)), [True] * 3, [0], [2], np.zeros((1, 3)))
    with pytest.raises(InputError, match="ScanDetail.polar"):
        ScanDetail(np.full((3, 4), np.nan), [True] * 3, [], [], np.zeros((0, 3)))


def test_detection_classes():
    d = ScanDetail(np.ones((5, 4)), [True, True, False, True, False], [3], [0], np.zeros((1, 3)))
    assert detection_classes(d).tolist() == [1, 1, 2, 0, 2]
    assert detection_classes(d, np.array([0, 3, 2, 0, 3])).tolist() == [1, 3, 2, 0, 3]


def test_importing_viz_and_commands_loads_neither_rerun_nor_matplotlib():
    code = ("import sys, rodo.viz, rodo.viz.recording, rodo.viz.figures, rodo.viz.blueprint, rodo.validation, "
            "rodo.validation.experiments, rodo.commands.view, rodo.commands.figures, rodo.commands.demo, "
            "rodo.commands.run; "
            "bad = [m for m in ('rerun', 'matplotlib') if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


# ------------------------------------------------------------------------------------------- rodo view
def test_view_without_display_says_how(run, tmp_path, monkeypatch, capsys):
    from rodo import cli
    from rodo.commands import view

    seq, _, result = run
    path = record_run(tmp_path / "v.rrd", seq, result)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(view.sys, "platform", "linux")
    monkeypatch.setattr(view.subprocess, "call", lambda *a, **k: pytest.fail("must not start a viewer"))
    assert cli.main(["view", str(path)], commands=[view]) == 0
    out = capsys.readouterr().out
    assert f"rerun {path.resolve()}" in out
    assert cli.main(["view", str(tmp_path / "missing.rrd")], commands=[view]) == 2
    assert "missing.rrd" in capsys.readouterr().err


def test_view_with_display_starts_the_viewer(run, tmp_path, monkeypatch):
    from rodo import cli
    from rodo.commands import view

    seq, _, result = run
    path = record_run(tmp_path / "v.rrd", seq, result)
    calls = []
    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(view, "find_viewer", lambda: "/opt/bin/rerun")
    monkeypatch.setattr(view.subprocess, "call", lambda argv: calls.append(argv) or 0)
    assert cli.main(["view", str(path)], commands=[view]) == 0
    assert calls == [["/opt/bin/rerun", str(path)]]


def test_cv_recording_has_truth_only_acceleration(run, tmp_path):
    seq, truth, _ = run
    result = run_sequence(seq, OdometryConfig.for_model("cv-cartesian"))
    chunks = _chunks(record_run(tmp_path / "cv.rrd", seq, result, truth=truth))
    names = _column(chunks, "/acceleration/omega_dot_z", "SeriesLines:names", static=True)[0]
    assert names == ["truth omega_dot_z (rad/s^2)"]
    vel = np.array(_column(chunks, "/metrics/nees/velocity", "Scalars:scalars"))
    k = len(result.estimates) - 1
    eta = truth["varpi"][k] - result.estimates[k].varpi
    assert vel[k, 0] == pytest.approx(eta @ np.linalg.solve(result.estimates[k].P[6:12, 6:12], eta), rel=1e-6)


def test_rodo_run_writes_a_readable_recording(run, tmp_path, capsys):
    from rodo import cli
    from rodo.commands import run as run_command
    from rodo.sim.simulate import write_simulation

    seq, truth, _ = run
    write_simulation(tmp_path / "seq", seq, truth)
    rrd = tmp_path / "out" / "run.rrd"
    assert cli.main(["run", str(tmp_path / "seq"), "--out", str(tmp_path / "out"), "--rerun", str(rrd)],
                    commands=[run_command]) == 0
    paths = {ch.entity_path for ch in _chunks(rrd)}
    assert {"/world/estimate/trajectory", "/world/vehicle/sensor/scan", "/metrics/timing"} <= paths
