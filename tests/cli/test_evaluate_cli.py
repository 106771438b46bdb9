"""`rodo evaluate`: JSON report equal to the library's, foreign TUM files, NEES/velocity from npz, clear errors."""

import json

import numpy as np
import pytest

from rodo.estimator.lie import se3
from rodo.cli import main
from rodo.commands import evaluate as evaluate_cmd
from rodo.sim.sequence import Trajectory, read_tum, write_tum
from rodo.validation.metrics import evaluate


def _run(argv):
    return main(["evaluate", *map(str, argv)], commands=[evaluate_cmd])


def _drive(n=400, seed=0):
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    xi = np.c_[rng.uniform(0.8, 1.2, n - 1), rng.normal(0, 0.02, (n - 1, 2)), rng.normal(0, 0.01, (n - 1, 3))]
    out = [np.eye(4)]
    for T in se3.exp(xi):
        out.append(out[-1] @ T)
    return np.stack(out), xi


@pytest.fixture
def files(tmp_path):
    T, xi = _drive()
    t = 100.0 + np.arange(len(T)) * 0.1
    noisy = xi + np.random.default_rng(np.random.SeedSequence(1)).normal(0, [0.01, 0.01, 0.01, 1e-3, 1e-3, 1e-3],
                                                                           xi.shape)
    E = [np.eye(4)]
    for S in se3.exp(noisy):
        E.append(E[-1] @ S)
    gt, est = Trajectory(t, T), Trajectory(t.copy(), np.stack(E))
    write_tum(tmp_path / "gt.txt", gt)
    write_tum(tmp_path / "est.txt", est)
    return tmp_path, gt, est


def test_json_report_matches_library_and_table_is_printed(files, capsys):
    d, gt, est = files
    out = d / "report.json"
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--json", out, "--lengths", "50,100,200",
                 "--step", "5"]) == 0
    text = capsys.readouterr().out
    assert "KITTI t_err" in text and "ATE rmse" in text and "final drift" in text
    rep = json.loads(out.read_text())
    for key in ("kitti_t_err_pct", "kitti_r_err_deg_per_m", "ate_rmse_m", "segments", "drift", "rpe"):
        assert key in rep
    assert set(rep["drift"]["final"]) == {"x", "y", "z", "roll", "pitch", "yaw"}
    direct = evaluate(read_tum(d / "gt.txt"), read_tum(d / "est.txt"), (50.0, 100.0, 200.0), 5)
    assert rep["kitti_t_err_pct"] == pytest.approx(direct["kitti_t_err_pct"], rel=1e-12)
    assert rep["ate_rmse_m"] == pytest.approx(direct["ate_rmse_m"], rel=1e-12)
    assert 0 < rep["kitti_t_err_pct"] < 10 and [s["length_m"] for s in rep["segments"]] == [50.0, 100.0, 200.0]
    assert "nees" not in rep and "velocity" not in rep


def test_accepts_tum_from_other_tools(files, capsys):
    d, gt, _ = files
    # a header comment, tabs, scientific notation, negative qw (the same rotation), fewer digits
    T = gt.T_world_vehicle
    from rodo.estimator.lie import so3

    q = -so3.to_quaternion(T[:, :3, :3])
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    lines += [f"{t:.6e}\t{p[0]:.7g} {p[1]:.7g}  {p[2]:.7g}\t" + " ".join(f"{v:.12f}" for v in qq)
              for t, p, qq in zip(gt.t, T[:, :3, 3], q)]
    (d / "other.txt").write_text("\n".join(lines) + "\n")
    assert _run(["--gt", d / "gt.txt", "--est", d / "other.txt", "--json", d / "r.json"]) == 0
    rep = json.loads((d / "r.json").read_text())
    assert rep["matched"] == len(gt.t) and rep["ate_rmse_m"] < 1e-4 and rep["kitti_t_err_pct"] < 1e-3  # 7 digits


def test_states_and_truth_add_nees_nis_and_velocity(files, capsys):
    d, gt, est = files
    n = len(gt.t)
    rng = np.random.default_rng(np.random.SeedSequence(5))
    T_vw_true = np.linalg.inv(gt.T_world_vehicle)
    varpi = rng.normal(0, 1, (n, 6))
    np.savez(d / "truth.npz", t=gt.t, T_vehicle_world=T_vw_true, varpi=varpi, varpi_dot=np.zeros((n, 6)))
    rel = T_vw_true @ np.linalg.inv(T_vw_true[0])
    P = np.broadcast_to(np.eye(12) * 1e-4, (n, 12, 12))
    e = rng.normal(0, 1e-2, (n, 12))
    np.savez(d / "states.npz", t=gt.t, T_vehicle_world=se3.exp(-e[:, :6]) @ rel, varpi=varpi - e[:, 6:],
             varpi_dot=np.zeros((n, 6)), P=P, nis=np.full(n, 4.0), n_associated=np.full(n, 50),
             ms_per_scan=np.full(n, 12.0))
    T_states = se3.exp(-e[:, :6]) @ rel
    write_tum(d / "est_states.txt", Trajectory(gt.t, np.linalg.inv(T_states)))  # the estimate the states belong to
    assert _run(["--gt", d / "gt.txt", "--est", d / "est_states.txt", "--states", d / "states.npz", "--truth",
                 d / "truth.npz", "--json", d / "r.json"]) == 0
    rep = json.loads((d / "r.json").read_text())
    assert rep["nees"]["dim"] == 12 and rep["nees"]["scans"] == n
    assert rep["nees"]["mean"] == pytest.approx(np.mean(np.sum(e ** 2, axis=1) / 1e-4), rel=1e-6)
    assert rep["velocity"]["nu_rmse_mps"] == pytest.approx(np.sqrt(np.mean(np.sum(e[:, 6:9] ** 2, axis=1))))
    assert rep["nis"]["mean"] == pytest.approx(4.0) and rep["ms_per_scan"]["median"] == 12.0
    assert "NEES (d=12)" in capsys.readouterr().out
    # the run's states alone (real data has no truth.npz): its NIS and time per scan, no NEES
    assert _run(["--gt", d / "gt.txt", "--est", d / "est_states.txt", "--states", d / "states.npz"]) == 0
    out = capsys.readouterr().out
    assert "NIS" in out and "NEES" not in out


def test_errors_exit_2_with_a_clear_message(files, capsys):
    d, gt, est = files
    (d / "bad.txt").write_text("0.0 1 2 3 0 0 0 1\n0.1 1 2 3 0 0 1\n")
    assert _run(["--gt", d / "gt.txt", "--est", d / "bad.txt"]) == 2
    err = capsys.readouterr().err
    assert "bad.txt" in err and "line 2" in err
    write_tum(d / "shifted.txt", Trajectory(est.t + 0.05, est.T_world_vehicle))  # another clock
    assert _run(["--gt", d / "gt.txt", "--est", d / "shifted.txt"]) == 2
    err = capsys.readouterr().err
    assert "gt.txt" in err and "shifted.txt" in err and "same sequence" in err
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--states", d / "nope.npz"]) == 2
    assert "--states" in capsys.readouterr().err
    (d / "junk.npz").write_text("not a zip")
    for option, expected in (("--truth", "truth.npz"), ("--states", "states.npz")):  # e.g. a TUM file given
        assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", option, d / "junk.npz"]) == 2
        err = capsys.readouterr().err
        assert f"{option} {d / 'junk.npz'}: not a readable .npz archive (expected the {expected}" in err, err
        assert "pickle" not in err and "unsafe" not in err
    np.savez(d / "partial.npz", t=gt.t)
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--states", d / "partial.npz"]) == 2
    assert "missing array(s) T_vehicle_world" in capsys.readouterr().err
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--lengths", "100,abc"]) == 2
    assert "--lengths" in capsys.readouterr().err
    assert _run(["--gt", d / "missing.txt", "--est", d / "est.txt"]) == 2
    assert "missing.txt" in capsys.readouterr().err
    n = len(gt.t)
    np.savez(d / "run_states.npz", t=gt.t, T_vehicle_world=np.linalg.inv(gt.T_world_vehicle), varpi=np.zeros((n, 6)),
             P=np.broadcast_to(np.eye(12), (n, 12, 12)))
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--truth", d / "run_states.npz"]) == 2  # alone
    assert "--truth: give it with --states" in capsys.readouterr().err
    assert _run(["--gt", d / "gt.txt", "--est", d / "est.txt", "--states", d / "run_states.npz", "--truth",
                 d / "run_states.npz"]) == 2  # a run's states given as the truth
    assert "--truth" in (err := capsys.readouterr().err) and "covariance P" in err
