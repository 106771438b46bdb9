"""The prior-consistent scenarios prior_ca / prior_cv (and prior_ca_points / prior_cv_points, the same motion among
persistent point scatterers): the qc parameter, what truth.npz records, determinism,
bad input (Python and `rodo simulate --qc`), and the estimator end to end."""

import numpy as np
import pytest

from rodo import cli, scenarios
from rodo.commands import simulate as simulate_cmd
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.sim import sde_trajectory as sde
from rodo.sim.objects import CLUTTER, STATIC_POINT
from rodo.sim.simulate import load_truth, path_length
from rodo.validation.driver import run_sequence

QC = [0.5, 0.05, 0.05, 1e-4, 1e-4, 0.01]


def test_registered_with_the_qc_parameter():
    for name, kind, model in (("prior_ca", "ca", "ca-polar"), ("prior_cv", "cv", "cv-polar")):
        sc = scenarios.get(name)
        assert sc.params == ("qc",) and sc.estimator_defaults["model"] == model and sc.version >= 1
        parts = sc.build(0, duration=2.0)
        assert isinstance(parts.profile, sde.SdeTrajectory) and parts.profile.kind == kind
        np.testing.assert_array_equal(parts.profile.qc, sde.DEFAULT_QC[kind])
        assert parts.profile.duration >= 2.0 + scenarios.MARGIN - 1e-9
    assert scenarios.get("prior_ca").default_duration(0) == 60.0


def test_truth_records_the_prior_and_matches_the_drawn_motion(tmp_path):
    seq, truth = scenarios.simulate_to("prior_ca", 2, tmp_path / "s", duration=1.5, qc=QC)
    disk = load_truth(tmp_path / "s")
    assert str(disk["prior_kind"][0]) == "ca" and disk["prior_substep"].shape == (1,)
    np.testing.assert_array_equal(disk["prior_qc"], QC)
    parts = scenarios.get("prior_ca").build(2, duration=1.5, qc=QC)
    m = parts.profile.sample(truth["t"])
    assert np.array_equal(truth["T_vehicle_world"], m.T_vehicle_world)
    assert np.array_equal(truth["varpi_dot"], m.varpi_dot)
    _, cv = scenarios.get("prior_cv").simulate(2, duration=0.5)
    assert str(cv["prior_kind"][0]) == "cv" and np.all(cv["varpi_dot"] == 0)
    np.testing.assert_array_equal(cv["prior_qc"], sde.DEFAULT_QC["cv"])


def test_same_seed_same_bytes(tmp_path):
    for d in ("a", "b"):
        scenarios.simulate_to("prior_ca", 3, tmp_path / d, duration=1.0, qc=QC)
    scenarios.simulate_to("prior_ca", 4, tmp_path / "c", duration=1.0, qc=QC)
    scenarios.simulate_to("prior_ca", 3, tmp_path / "q", duration=1.0, qc=[2 * q for q in QC])
    for name in ("radar.csv", "sensor.toml", "groundtruth.txt", "truth.npz"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    for other in ("c", "q"):
        assert (tmp_path / "a" / "groundtruth.txt").read_bytes() != (tmp_path / other / "groundtruth.txt").read_bytes()


@pytest.mark.parametrize("qc", [[1, 2, 3], [1, 1, 1, 1, 1, 0], [1, 1, 1, 1, -1, 1], [1, 1, 1, np.inf, 1, 1], "x"])
def test_bad_qc_is_an_input_error_naming_qc(qc):
    with pytest.raises(InputError, match="qc"):
        scenarios.get("prior_cv").simulate(0, duration=0.5, qc=qc)


def test_parameters_are_checked_against_the_scenario():
    with pytest.raises(InputError, match="qc.*'city'"):
        scenarios.get("city").build(0, duration=1.0, qc=QC)
    with pytest.raises(InputError, match="speed"):
        scenarios.get("prior_ca").build(0, duration=1.0, speed=3.0)


def test_cli_qc_flag(tmp_path, capsys):
    out = tmp_path / "s"
    argv = ["simulate", "prior_ca", "--seed", "1", "--qc", ",".join(map(str, QC)), "--duration", "1", "--out", str(out)]
    assert cli.main(argv, commands=[simulate_cmd]) == 0
    np.testing.assert_array_equal(load_truth(out)["prior_qc"], QC)
    assert "CA prior SDE" in capsys.readouterr().out
    for bad in ("1,2,3", "1,1,1,1,1,-1", "1,1,1,1,1,nan", "a,b,c,d,e,f", "1,1,1,1,1,inf", "1,2,3,4,5,1e300"):
        argv = ["simulate", "prior_cv", "--qc", bad, "--duration", "1", "--out", str(tmp_path / "x")]
        assert cli.main(argv, commands=[simulate_cmd]) == 2
        assert "--qc" in capsys.readouterr().err
    assert cli.main(["simulate", "city", "--qc", "1,1,1,1,1,1", "--duration", "1", "--out", str(tmp_path / "y")],
                    commands=[simulate_cmd]) == 2
    assert "--qc" in capsys.readouterr().err and not (tmp_path / "y").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name, model", [("prior_ca", "ca-polar"), ("prior_cv", "cv-polar"),
                                         ("prior_ca_points", "ca-polar"), ("prior_cv_points", "cv-polar")])
def test_estimator_runs_on_the_prior_scenario(name, model):
    """10 s of the default draw: the estimator tracks it (final position error < 2 % of the path length)."""
    seq, truth = scenarios.get(name).simulate(0, duration=10.0)
    result = run_sequence(seq, OdometryConfig.for_model(model))
    assert len(result.estimates) == len(truth["t"])
    T_est = result.estimates[-1].T_world_vehicle
    T_true = seq.groundtruth.T_world_vehicle[-1]
    length = path_length(seq.groundtruth.T_world_vehicle)
    assert length > 80.0
    assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 0.02 * length


@pytest.mark.parametrize("name, base", [("prior_ca_points", "prior_ca"), ("prior_cv_points", "prior_cv")])
def test_points_scenario_drives_the_prior_through_persistent_points(name, base):
    """prior_*_points: the motion of prior_* for the same seed, bit for bit; every detection but clutter is a
    fixed landmark seen again scan after scan at the same true position."""
    sc = scenarios.get(name)
    assert sc.params == ("qc",) and sc.estimator_defaults == scenarios.get(base).estimator_defaults
    _, truth = sc.simulate(3, duration=2.0)
    _, base_truth = scenarios.get(base).simulate(3, duration=2.0)
    assert np.array_equal(truth["T_vehicle_world"], base_truth["T_vehicle_world"])
    np.testing.assert_array_equal(truth["prior_qc"], base_truth["prior_qc"])
    labels = truth["det_label"]
    assert set(np.unique(labels)) <= {STATIC_POINT, CLUTTER} and np.mean(labels == STATIC_POINT) > 0.8
    points = labels == STATIC_POINT
    ids, first, seen = np.unique(truth["det_landmark_id"][points], return_index=True, return_counts=True)
    assert ids.min() >= 0 and np.median(seen) >= 10  # 26 scans: most landmarks are seen again and again
    p = truth["det_p_world"][points]
    same = np.repeat(np.arange(len(ids)), seen)
    order = np.argsort(truth["det_landmark_id"][points], kind="stable")
    np.testing.assert_array_equal(p[order], p[first][same])
