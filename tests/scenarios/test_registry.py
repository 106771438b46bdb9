"""The scenario registry and the `rodo scenarios` / `rodo simulate` commands."""

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo import cli
from rodo.commands import simulate as simulate_cmd
from rodo.sim.sequence import read_sequence

REQUIRED = ["city", "highway", "hills", "stop_and_go", "blockage", "yaw_accel"]


def test_registry_lists_the_required_scenarios():
    assert set(REQUIRED) <= set(scenarios.names())
    for name in scenarios.names():
        sc = scenarios.get(name)
        assert sc.name == name and sc.version >= 1 and sc.description
        assert isinstance(sc.estimator_defaults, dict) and "model" in sc.estimator_defaults


def test_unknown_name_raises_input_error_listing_names():
    with pytest.raises(InputError) as exc:
        scenarios.get("citty")
    for name in REQUIRED:
        assert name in str(exc.value)


@pytest.mark.parametrize("name", ["city", "highway", "hills", "stop_and_go"])
def test_long_scenarios_cover_kitti_lengths(name):
    sc = scenarios.get(name)
    for seed in (0, 1):
        parts = sc.build(seed)
        assert parts.profile.path_length(parts.duration) > 900.0
        assert parts.profile.speed_range()[0] >= -1e-12


def test_hills_and_stop_and_go_do_what_they_say():
    parts = scenarios.get("hills").build(0, duration=60.0)
    from rodo.sim.trajectory import route_of

    assert np.ptp(route_of(parts.profile).p_world[:, 2]) > 5.0
    parts = scenarios.get("stop_and_go").build(0, duration=40.0)
    speed = -parts.profile.twist(np.arange(0, 40.0, 1 / 13))[0][:, 0]
    assert np.sum(speed == 0.0) > 13


def test_blockage_has_near_total_and_total_blockage():
    from rodo.scenarios.definitions import BLOCKAGE_BLACKOUT, BLOCKAGE_SLOW

    seq, truth = scenarios.get("blockage").simulate(0, duration=BLOCKAGE_SLOW[1])
    counts = np.diff(truth["scan_offsets"])
    t = truth["t"]
    dark = (t >= BLOCKAGE_BLACKOUT[0]) & (t <= BLOCKAGE_BLACKOUT[1])
    assert np.all(counts[dark] == 0) and dark.sum() >= 26  # total blockage: empty scans, still in the truth
    assert np.all(counts[~dark] > 100)
    assert len(t) == len(seq.groundtruth.t) == len(counts)
    # near-total: while crawling at 1.6 m/s the truck hides all but a few per cent of the static world
    scan = truth["det_scan"]
    static = np.bincount(scan[truth["det_label"] < 2], minlength=len(t))
    slow = (t > BLOCKAGE_SLOW[0] + 1.0) & (t < BLOCKAGE_SLOW[1] - 1.0)
    free = ~dark & (t < 9.0)
    assert np.median(static[slow]) < 0.1 * np.median(static[free])
    assert np.abs(-truth["varpi"][slow, 0] - 1.6).max() < 1e-9


def test_same_seed_same_bytes_on_disk(tmp_path):
    for d in ("a", "b"):
        scenarios.simulate_to("yaw_accel", 3, tmp_path / d, duration=1.0)
    for name in ("radar.csv", "sensor.toml", "groundtruth.txt", "truth.npz"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    scenarios.simulate_to("yaw_accel", 4, tmp_path / "c", duration=1.0)
    assert (tmp_path / "a" / "radar.csv").read_bytes() != (tmp_path / "c" / "radar.csv").read_bytes()


def test_bad_seed_and_duration_are_input_errors():
    sc = scenarios.get("yaw_accel")
    with pytest.raises(InputError, match="seed"):
        sc.simulate(-1, duration=1.0)
    with pytest.raises(InputError, match="duration"):
        sc.simulate(0, duration=-1.0)


def test_cli_scenarios_lists_one_line_each(capsys):
    assert cli.main(["scenarios"], commands=[simulate_cmd]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(scenarios.names())
    for line, name in zip(lines, scenarios.names()):
        assert line.split()[0] == name and " v" in line


def test_cli_simulate_writes_and_summarises(tmp_path, capsys):
    out = tmp_path / "seq"
    assert cli.main(["simulate", "city", "--seed", "2", "--out", str(out), "--duration", "1.0"],
                    commands=[simulate_cmd]) == 0
    text = capsys.readouterr().out
    assert "scans 14" in text and "median" in text and "path length" in text
    seq = read_sequence(out, use_cache=False)
    assert len(seq.scans) == 14 and (out / "truth.npz").is_file()


def test_cli_unknown_scenario_exits_2_with_names(tmp_path, capsys):
    code = cli.main(["simulate", "nowhere", "--out", str(tmp_path / "x")], commands=[simulate_cmd])
    assert code == 2
    err = capsys.readouterr().err
    assert "nowhere" in err and all(name in err for name in REQUIRED)


def test_noise_free_override_reproduces_geometry():
    from rodo.estimator.lie import se3
    from rodo.sim.radar import RadarConfig
    from rodo.sim.sequence import polar_to_cartesian

    cfg = RadarConfig().noise_free()
    seq, truth = scenarios.get("highway").simulate(0, duration=0.5, radar=cfg)
    off = truth["scan_offsets"]
    for k, sc in enumerate(seq.scans):
        p = se3.transform_points(seq.groundtruth.T_world_vehicle[k] @ cfg.T_vehicle_sensor,
                                 polar_to_cartesian(sc.range, sc.azimuth, sc.elevation))
        np.testing.assert_allclose(p, truth["det_p_world"][off[k]:off[k + 1]], atol=1e-9)
    assert not (truth["det_label"] == 3).any()
