"""`rodo calibrate --no-truth`: EM over the estimator's posteriors writes a config `rodo run --config` accepts, its
check against the estimated velocity's growth (the report, the header's CHECK line, the figure), and the
measurement noise learned without truth (`--sensor-noise`)."""

import json

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.estimator.config import OdometryConfig
from tests.cli.helpers import fails


@pytest.mark.slow
def test_calibrate_without_truth_runs_em(cal_seq, tmp_path, capsys):
    base = tmp_path / "base.toml"
    base.write_text("window = 3\n[noise]\nqc_ca = [1.0, 0.1, 0.1, 0.001, 0.001, 0.01]\n")
    out = tmp_path / "em.toml"
    assert main(["calibrate", str(cal_seq), "--no-truth", "--config", str(base), "--iterations", "2",
                 "--duration", "1.0", "--learn", "x,y,z,yaw", "--out", str(out)]) == 0
    assert "EM iteration" in capsys.readouterr().out
    config = OdometryConfig.from_toml(out)
    report = json.loads(out.with_suffix(".json").read_text())
    its = report["iterations"]
    assert 1 <= len(its) <= 2 and its[0]["qc_in"] == [1.0, 0.1, 0.1, 0.001, 0.001, 0.01]
    assert config.window == 3 and config.noise.qc_ca == tuple(its[-1]["qc_out"])
    assert config.noise.qc_cv == OdometryConfig().noise.qc_cv  # the other prior is left alone
    assert config.noise.qc_ca[3:5] == (0.001, 0.001) and report["learned_components"] == ["x", "y", "z", "yaw"]
    assert "(x, y, z, yaw)" in out.read_text().splitlines()[1]
    assert np.all(np.isfinite(its[-1]["qc_out"])) and its[-1]["intervals"] >= 10
    assert report["velocity_growth"].startswith("not checked: velocity growth: the track spans")  # 1 s of drive
    assert report["velocity_growth"] in out.with_suffix(".md").read_text()
    assert main(["run", str(cal_seq), "--config", str(out), "--out", str(tmp_path / "run")]) == 0


@pytest.mark.slow
def test_calibrate_without_truth_draws_ems_check(tmp_path, capsys):
    """On a drive long enough for the check (8 s): the .json rows carry what the figure draws, the .md its table,
    and CONFIG_growth.png is written beside the config and named in the output."""
    d = tmp_path / "drive"
    scenarios.simulate_to("prior_ca_points", 3, d, duration=8.0)
    out = tmp_path / "em.toml"
    assert main(["calibrate", str(d), "--no-truth", "--iterations", "1", "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())["velocity_growth"]
    assert [r["component"] for r in rows] == ["x", "y", "z", "roll", "pitch", "yaw"]
    assert all(len(r["D"]) == len(r["lags"]) >= 3 and r["c"] >= 0 for r in rows if r["growth"] is not None)
    assert "| component | EM | from the velocity's growth | interval | EM outside |" in out.with_suffix(".md").read_text()
    png = tmp_path / "em_growth.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and str(png) in capsys.readouterr().out
    info = json.loads(out.with_suffix(".json").read_text())["information"]
    assert info["duration_s"] == pytest.approx(8.0, abs=0.1)
    assert [r["component"] for r in info["rows"]] == ["x", "y", "z", "roll", "pitch", "yaw"]
    # 8 s hold too little for 25 % anywhere: even the forward jerk's bound is about 0.12 x sqrt(30 / 8) s
    # (docs/calibration.md, "What a drive can tell")
    assert all(r["sd_log"] is None or r["sd_log"] > 0.125 for r in info["rows"])
    assert "BOUND: this drive cannot determine x, y, z, roll, pitch, yaw within 25 %" in out.read_text()
    assert "| component | Qc | bound on SD(log q) | within 25 % | drive length it needs (s) |" in \
        out.with_suffix(".md").read_text()


def test_the_em_report_names_the_components_outside_the_velocitys_growth():
    """The config's header says CHECK for the learned components outside their interval (not for one left at the
    base config's), and the markdown table marks them."""
    from rodo.commands.calibrate_report import header as _header, markdown as _markdown

    rows = [{"component": c, "em": 1.0, "growth": g, "interval": None if g is None else [0.5, 2.0],
             "outside": None if g is None else not 0.5 <= 1.0 / g <= 2.0}
            for c, g in zip(("x", "y", "z", "roll", "pitch", "yaw"), (1.0, 0.1, None, 0.1, 0.1, 1.2))]
    for r in rows:
        if r["growth"] is not None:
            r["interval"] = [0.5 * r["growth"], 2.0 * r["growth"]]
    report = {"mode": "EM without ground truth", "field": "qc_ca", "learned_components": ["x", "y", "z", "yaw",
                                                                                           "pitch"],
              "converged": True, "tolerance": 0.05, "velocity_growth": rows,
              "iterations": [{"qc_in": [1.0] * 6, "qc_out": [1.0] * 6, "change": 0.01, "remaining": 0.01,
                              "loglik": 1.0, "intervals": 10}]}
    check = [line for line in _header(report, "SEQ", "ca-polar") if line.startswith("CHECK")]
    assert len(check) == 1 and "EM's y, pitch lie outside" in check[0]  # roll is outside but not learned
    md = _markdown(report)
    assert "| y | 1 | 0.1 | 0.05 - 0.2 | **yes** |" in md and "| x | 1 | 1 | 0.5 - 2 | no |" in md
    assert "| z | 1 | - (no motion) | - | - |" in md and "for y, pitch:" in md
    assert "| roll | 1 (not learned) | 0.1 | 0.05 - 0.2 | - |" in md  # the base config's value: no verdict


def test_the_em_report_gives_the_drives_bound():
    """The config's header says BOUND for the learned components whose bound is wider than 25 % needs, the
    markdown table gives each one's bound and the drive length it needs (the bound shrinking as 1 / sqrt(T))."""
    from rodo.commands.calibrate_report import header as _header, markdown as _markdown

    rows = [{"component": c, "qc": 1.0, "learned": c != "roll", "sd_log": None if c == "roll" else sd,
             "within_95": sd <= 0.125 and c != "roll"}
            for c, sd in zip(("x", "y", "z", "roll", "pitch", "yaw"), (0.1, 0.25, 0.5, 1.0, 2.0, 0.125))]
    rows[4]["sd_log"] = None  # pitch: no information
    report = {"mode": "EM without ground truth", "field": "qc_ca",
              "learned_components": ["x", "y", "z", "pitch", "yaw"], "converged": True, "tolerance": 0.05,
              "velocity_growth": "not checked: short", "information": {"duration_s": 30.0, "samples": 2000,
                                                                       "rows": rows},
              "iterations": [{"qc_in": [1.0] * 6, "qc_out": [1.0] * 6, "change": 0.01, "remaining": 0.01,
                              "loglik": 1.0, "intervals": 10}]}
    bound = [line for line in _header(report, "SEQ", "ca-polar") if line.startswith("BOUND")]
    assert len(bound) == 1 and "cannot determine y, z, pitch within 25 %" in bound[0]
    md = _markdown(report)
    assert "| x | 1 | 0.1 | yes | 19 |" in md and "| y | 1 | 0.25 | **no** | 120 |" in md
    assert "| yaw | 1 | 0.125 | yes | 30 |" in md and "| roll | 1 | - (not learned) | - | - |" in md
    assert "| pitch | 1 | no information | **no** | - |" in md


@pytest.mark.slow
def test_calibrate_without_truth_learns_the_sensor_noise_when_asked(cal_seq, tmp_path, capsys):
    """--no-truth --sensor-noise: the config carries the learned per-channel factors and Cartesian sigma, the
    header and the markdown report say so; `rodo run` accepts it. Without --no-truth the flag is refused."""
    out = tmp_path / "em_r.toml"
    assert main(["calibrate", str(cal_seq), "--no-truth", "--sensor-noise", "--iterations", "1",
                 "--out", str(out)]) == 0
    config = OdometryConfig.from_toml(out)
    m = json.loads(out.with_suffix(".json").read_text())["measurement"]
    assert list(config.noise.sensor_sigma_scales) == m["sensor_sigma_scales"]
    assert config.noise.cartesian_sigma == m["cartesian_sigma"] and config.noise.sensor_sigma_scale == 1.0
    assert m["learned"] == [True] * 4 and m["pairs"] > 0
    assert "learned first from the static detections" in out.read_text()
    assert "## Measurement noise without ground truth" in out.with_suffix(".md").read_text()
    assert main(["run", str(cal_seq), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    fails(capsys, ["calibrate", str(cal_seq), "--sensor-noise", "--out", tmp_path / "x.toml"], "--sensor-noise",
          "--no-truth")


@pytest.mark.slow
def test_a_runaway_component_keeps_the_base_value(tmp_path):
    """blockage seed 3 (20 s; a blackout and a re-initialisation): EM's forward component has no fixed point on
    this drive (it reaches the fit's upper bound in the first run's stand-in). The command ends normally, not
    converged, names it RUNAWAY in the config's header, and writes the base config's value for it; the others are
    learned. (Before the review of session 57 this drive ended in a LinAlgError traceback.)"""
    d = tmp_path / "drive"
    scenarios.simulate_to("blockage", 3, d, duration=20.0)
    out = tmp_path / "em.toml"
    assert main(["calibrate", str(d), "--no-truth", "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["runaway"] == ["x"] and not report["converged"]
    assert "RUNAWAY: EM's x reached the fit's upper bound" in out.read_text()
    learned = OdometryConfig.from_toml(out).noise.qc_ca
    assert learned[0] == OdometryConfig.for_model("ca-polar").noise.qc_ca[0]
    assert all(np.isfinite(learned)) and max(learned[1:]) < 1e3
    json.loads(out.with_suffix(".json").read_text(), parse_constant=lambda c: pytest.fail(f"JSON has {c}"))
