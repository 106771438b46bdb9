"""`rodo verdict`: the criteria on hand-made rows, and one tiny real verdict through the CLI (calibration drive,
both calibrations, the campaign, the table) that resumes without redoing a step and refuses other parameters."""

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo import scenarios
from rodo.cli import main
from rodo.commands.calibrate import parse_floor
from rodo.commands.verdict import _steps
from rodo.estimator.config import OdometryConfig
from rodo.estimator.errors import InputError
from rodo.validation.campaign_files import read_results
from rodo.validation.verdict import CELLS, OUTSIDE, SHARE_TARGET, SPAN_LIMIT, SPANS, judge, render_markdown
from tests.cli.helpers import fails

shares = st.one_of(st.none(), st.floats(0.0, 1.0))
means = st.one_of(st.none(), st.floats(0.0, 10.0))


def _row(scenario, values):
    """A verdict row whose models' measures have the given (share, mean) per measure, CA/P then CV/C."""
    it = iter(values)
    models = {}
    for name in ("CA/P", "CV/C"):
        c = {m: {"fraction_scans_within": next(it), "mean_per_dof": None} for m in CELLS}
        c.update({m: {"fraction_scans_within": None, "mean_per_dof": next(it)} for m in SPANS})
        models[name] = {"consistency": c}
    return {"scenario": scenario, "models": models}


@given(st.lists(st.tuples(shares, shares, means, means, shares, shares, means, means), min_size=1, max_size=4))
def test_judge_counts_a_cell_at_the_target_and_a_span_within_the_limit(spec):
    rows = [_row(f"s{i}", v) for i, v in enumerate(spec)]
    crit = judge(rows)
    cell_values = [v for vs in spec for v in (vs[0], vs[1], vs[4], vs[5])]
    span_values = [v for vs in spec for v in (vs[2], vs[3], vs[6], vs[7])]
    assert [c["share"] for c in crit["cells"]] == cell_values
    assert crit["cells_met"] == sum(v is not None and v >= SHARE_TARGET for v in cell_values)
    assert crit["spans_met"] == sum(v is not None and v <= SPAN_LIMIT for v in span_values)


def test_judge_at_the_boundaries():
    crit = judge([_row("a", [0.90, 0.8999, 2.0, 2.0001, None, 1.0, None, 0.0])])
    assert [c["met"] for c in crit["cells"]] == [True, False, False, True]
    assert [s["met"] for s in crit["spans"]] == [True, False, False, True]


def test_the_short_cells_say_where_they_miss():
    """A cell short of the target lists its scans below and above the bounds and those one run puts above; a cell
    that meets it, or one from a summary written before the counts, lists nothing."""
    row = _row("city", [0.85, 0.95, 1.0, 1.0, 0.80, 0.93, 1.0, 1.0])
    c = row["models"]["CA/P"]["consistency"]["velocity"]
    c.update(scans_below=3, scans_above=40, scans_above_one_run=31)
    row["models"]["CA/P"]["consistency"]["relative_scan"].update(scans_below=9, scans_above=9, scans_above_one_run=0)
    crit = judge([row])
    assert [k for k in OUTSIDE if k in crit["cells"][0]] == list(OUTSIDE) and "scans_above" not in crit["cells"][2]
    for m in row["models"].values():  # the rest of a row, for the report
        m.update(kitti_t_err_pct=dict.fromkeys(("mean", "lower", "upper")), ellipsoid_3sigma_pct=None, learned={})
    row["paired_kitti_t_err_pct"] = {"mean_difference": None, "lower": None, "upper": None, "a_lower": 0, "trials": 0}
    text = render_markdown({"rows": [row], "criteria": crit})
    assert "- city CA/P velocity: 3 below, 40 above (31 of them one run's)" in text
    assert "CA/P one scan:" not in text and "CV/C velocity:" not in text  # met; short but without counts
    assert "gross failure" not in text


def test_the_means_carry_their_interval_and_the_runs_with_a_gross_failure_are_named():
    """The span and absolute pose means show their interval over the runs where the summary has one (not the
    velocity's: judged scan by scan); a cell's runs with a gross failure are named under the table."""
    row = _row("city", [0.95] * 8)
    for name, m in row["models"].items():
        m.update(kitti_t_err_pct=dict.fromkeys(("mean", "lower", "upper")), ellipsoid_3sigma_pct=None, learned={})
        m["consistency"]["pose"] = {"mean_per_dof": 0.73, "mean_interval_per_dof": [0.52, 1.04]}
        m["consistency"]["velocity"]["mean_interval_per_dof"] = [0.8, 1.2]
    row["models"]["CV/C"]["gross_failure_runs"] = [3, 7]
    row["paired_kitti_t_err_pct"] = {"mean_difference": None, "lower": None, "upper": None, "a_lower": 0, "trials": 0}
    text = render_markdown({"rows": [row], "criteria": judge([row])})
    assert text.count("| 0.73 (0.52-1.04) |") == 2 and "(0.80-1.20)" not in text
    assert "Campaign runs with a gross failure" in text and "city CV/C (trials 3, 7)." in text
    assert "CA/P (trials" not in text


ARGS = ["--scenarios", "stop_and_go", "--runs", "2", "--duration", "3", "--calibration-duration", "5",
        "--seed", "3"]


@pytest.fixture(scope="module")
def verdict_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("verdict") / "v"
    assert main(["verdict", *ARGS, "--jobs", "2", "--out", str(out)]) == 0
    return out


@pytest.mark.slow
def test_a_verdict_reports_its_campaign_at_the_configs_it_learned(verdict_dir):
    verdict = json.loads((verdict_dir / "verdict.json").read_text())
    summary = json.loads((verdict_dir / "stop_and_go" / "summary.json").read_text())
    campaign = json.loads((verdict_dir / "stop_and_go" / "campaign.json").read_text())
    row = verdict["rows"][0]
    for name, label, file in (("CA/P", "ca-learned", "ca"), ("CV/C", "cv-learned", "cv")):
        config = verdict_dir / "calibration" / f"stop_and_go_{file}.toml"
        assert campaign["configs"][label] == config.read_text()  # the campaign ran the learned config
        for measure, c in row["models"][name]["consistency"].items():
            for key in ("fraction_scans_within", "mean_interval_per_dof", *OUTSIDE):
                assert c[key] == summary["models"][label]["consistency"][measure][key]
        assert row["models"][name]["ok"] == 2
        lag = OdometryConfig.from_toml(config).uncertainty.velocity_lag_per_yaw_acceleration[5]
        assert row["models"][name]["learned"]["yaw_rate_lag"] == lag  # learned for the CV model only
        assert (lag == 0.0) == (name == "CA/P")
        assert row["models"][name]["learned"]["stationary"] == []  # off unless asked (`--stationary-error`)
        report = json.loads(config.with_suffix(".json").read_text())["consistency"]  # the scans left out, as reported
        assert row["models"][name]["learned"]["gross_failures"] == [
            report["velocity_inflation"]["gross_failures"]["scans"], report["relative_inflation"]["gross_failures"]]
        growth = {r["label"]: r["ratio"] for r in summary["models"][label]["error_growth"]["table"]}
        assert row["models"][name]["error_growth"] == growth  # the campaign's, per axis
        assert len(growth["1 s"]) == 6 and growth["5 s"] is None  # 3 s drives: no 5 s span
        assert len(growth["velocity"]) == 6 and (growth["acceleration"] is None) == (label == "cv-learned")
    crit = verdict["criteria"]
    assert len(crit["cells"]) == 4 and crit["cells_met"] == sum(c["share"] >= 0.9 for c in crit["cells"])
    text = (verdict_dir / "verdict.md").read_text()
    assert "base.toml" not in text and not (verdict_dir / "base.toml").exists()  # no --config
    assert f"{crit['cells_met']} of 4 cells" in text and "| stop_and_go | CA/P |" in text
    vel, one_s = (" ".join(f"{x:.2f}" for x in row["models"]["CV/C"]["error_growth"][k]) for k in ("velocity", "1 s"))
    assert "## Per axis" in text and f"| stop_and_go | CV/C | {vel} | {one_s} | - | " in text
    for c in crit["cells"]:  # each short cell says where its scans miss
        line = f"{c['scans_below']} below, {c['scans_above']} above ({c['scans_above_one_run']} of them one run's)"
        assert (line in text) == (not c["met"])
    assert verdict["parameters"]["calibration_duration"] == 5.0


@pytest.mark.slow
def test_a_verdict_resumes_without_redoing_a_step_and_refuses_other_parameters(verdict_dir, capsys):
    config = verdict_dir / "calibration" / "stop_and_go_ca.toml"
    before = (config.stat().st_mtime_ns, (verdict_dir / "calibration" / "stop_and_go" / "truth.npz").stat().st_mtime_ns,
              read_results(verdict_dir / "stop_and_go" / "results.csv"))
    capsys.readouterr()
    assert main(["verdict", *ARGS, "--jobs", "1", "--out", str(verdict_dir), "--resume"]) == 0
    out = capsys.readouterr().out
    assert out.count("done before, kept") == 3 and "skipped 4 already done" in out
    after = (config.stat().st_mtime_ns, (verdict_dir / "calibration" / "stop_and_go" / "truth.npz").stat().st_mtime_ns,
             read_results(verdict_dir / "stop_and_go" / "results.csv"))
    assert after == before
    fails(capsys, ["verdict", *ARGS, "--out", verdict_dir], "campaign.json", "--resume")
    other = [a if a != "5" else "6" for a in ARGS]
    fails(capsys, ["verdict", *other, "--out", verdict_dir, "--resume"], "calibration_duration")


@pytest.mark.slow
def test_a_failed_step_is_named_with_its_log(tmp_path, capsys):
    out = tmp_path / "v"
    seq = out / "calibration" / "stop_and_go"
    scenarios.simulate_to("stop_and_go", 1, seq, duration=1.0)
    lines = (seq / "radar.csv").read_text().splitlines()
    lines[3] = "not,a,detection"
    (seq / "radar.csv").write_text("\n".join(lines) + "\n")
    err = fails(capsys, ["verdict", *ARGS, "--jobs", "1", "--out", out, "--resume"],
                "calibrate stop_and_go CA/P failed (exit 2)", "radar.csv", "log:")
    assert "radar.csv, line 4" in err


@pytest.mark.slow
def test_several_calibration_drives_are_simulated_at_their_seeds_and_pooled(tmp_path, capsys):
    """--calibration-drives 2: the second drive at the next seed (a simulation of its own, bit for bit), both
    calibrations pooling the two (their reports count the sequences and the scans of both), and the count a
    parameter of the verdict that a resume without it refuses."""
    out = tmp_path / "v"
    argv = ["verdict", *ARGS, "--calibration-seed", "40"]
    assert main([*argv, "--calibration-drives", "2", "--jobs", "2", "--out", str(out)]) == 0
    first, second = out / "calibration" / "stop_and_go", out / "calibration" / "stop_and_go-1"
    again = tmp_path / "again"
    scenarios.simulate_to("stop_and_go", 41, again, duration=5.0)
    assert (second / "radar.csv").read_bytes() == (again / "radar.csv").read_bytes()
    assert (first / "radar.csv").read_bytes() != (second / "radar.csv").read_bytes()
    scans = sum(len(np.load(d / "truth.npz")["t"]) for d in (first, second))
    for file in ("ca", "cv"):
        report = json.loads((out / "calibration" / f"stop_and_go_{file}.json").read_text())
        assert (report["sequences"], report["scans"]) == (2, scans)
    assert json.loads((out / "campaign.json").read_text())["calibration_drives"] == 2
    fails(capsys, [*argv, "--out", out, "--resume"], "calibration_drives")


@pytest.mark.parametrize("argv, needle", [
    (["--scenarios", "nowhere"], "--scenarios"),
    (["--calibration-drives", "0"], "--calibration-drives"),
    (["--calibration-drives", "21"], "--calibration-drives"),
    (["--runs", "1"], "--runs"),
    (["--duration", "nan"], "--duration"),
    (["--calibration-duration", "0"], "--calibration-duration"),
    (["--calibration-duration", "0.3"], "at least 1 s"),  # too short to calibrate: refused before simulating it
    (["--jobs", "0"], "--jobs"),
    (["--floor-ca", "nan"], "--floor"),
    (["--floor-cv", "1e9"], "--floor"),
    (["--floor-ca", "1e-4,1e-3"], "--floor"),
])
def test_bad_options_are_refused_before_any_work(tmp_path, capsys, argv, needle):
    fails(capsys, ["verdict", *argv, "--out", tmp_path / "v"], needle)
    assert not (tmp_path / "v").exists()


def test_an_output_that_is_a_file_is_refused(tmp_path, capsys):
    out = tmp_path / "a_file"
    out.write_text("not a directory\n")
    fails(capsys, ["verdict", "--out", out], "--out", "not a directory")
    assert out.read_text() == "not a directory\n"


def test_each_model_is_calibrated_at_its_own_floor(tmp_path):
    """--floor-ca and --floor-cv (one value or six) reach their model's calibration step as given: rodo calibrate
    reads back the same values."""
    given = {"ca-polar": "1e-4,1e-4,1e-4,1e-3,1e-3,1e-4", "cv-cartesian": "2e-4"}
    floors = {model: parse_floor(text) for model, text in given.items()}
    args = argparse.Namespace(out=str(tmp_path), calibration_drives=1, calibration_seed=100, calibration_duration=5.0,
                              floor_ca=given["ca-polar"], floor_cv=given["cv-cartesian"], runs=2, duration=3.0,
                              seed=3, jobs=1, heading_reversion=False, stationary_error=False, axis_correlation=True,
                              vehicle_rates=False, config=None)
    _, cals, _ = _steps(args, ["city"])
    assert sorted(argv[argv.index("--model") + 1] for _, argv, _ in cals) == sorted(floors)
    for _, argv, _ in cals:
        assert parse_floor(argv[argv.index("--floor") + 1]) == floors[argv[argv.index("--model") + 1]]
    assert floors["ca-polar"] == [1e-4, 1e-4, 1e-4, 1e-3, 1e-3, 1e-4] and floors["cv-cartesian"] == 2e-4


@pytest.mark.parametrize("flag", ["heading_reversion", "stationary_error", "no_axis_correlation", "vehicle_rates"])
def test_a_calibration_flag_reaches_both_calibrations(tmp_path, flag):
    """--heading-reversion, --stationary-error, --vehicle-rates, --no-axis-correlation: both models' calibration
    steps learn the yaw's reversion, the bounded error per axis or the vehicle's rate terms, or do not learn the
    registration's correlation per axis (rodo calibrate's flag of the same name); without it neither does (the
    last: both learn it)."""
    off = {"heading_reversion": False, "stationary_error": False, "no_axis_correlation": False,
           "vehicle_rates": False}
    args = argparse.Namespace(out=str(tmp_path), calibration_drives=1, calibration_seed=100, calibration_duration=5.0,
                              floor_ca="1e-4", floor_cv="1e-4", runs=2, duration=3.0, seed=3, jobs=1,
                              config=None, **dict(off, **{flag: True}))
    args.axis_correlation = not args.no_axis_correlation  # the parser's dest for --no-axis-correlation
    option = "--" + flag.replace("_", "-")
    _, cals, _ = _steps(args, ["city", "hills"])
    assert len(cals) == 4 and all(option in argv for _, argv, _ in cals)
    others = [o for o in ("--heading-reversion", "--stationary-error", "--no-axis-correlation", "--vehicle-rates")
              if o != option]
    assert not any(o in argv for _, argv, _ in cals for o in others)
    _, cals, _ = _steps(argparse.Namespace(**dict(vars(args), **off, axis_correlation=True)), ["city"])
    assert not any(option in argv for _, argv, _ in cals)


BASE = "[vehicle]\nsigma_vertical_velocity = 0.05\nsigma_lateral_velocity = 0.04\n\n[map]\ncapacity = 1200\n"


@pytest.mark.slow
def test_a_base_config_reaches_both_calibrations_and_is_a_parameter(tmp_path, capsys):
    """--config: both learned configs keep the base's settings that calibration does not learn (the non-holonomic
    terms, the map's capacity); the verdict keeps the copy it calibrated from and the base's hash, and a resume
    with another base, or without one, is refused."""
    base, out = tmp_path / "base.toml", tmp_path / "v"
    base.write_text(BASE)
    argv = ["verdict", *ARGS, "--jobs", "2", "--out", str(out)]
    assert main([*argv, "--config", str(base)]) == 0
    for file in ("ca", "cv"):
        config = OdometryConfig.from_toml(out / "calibration" / f"stop_and_go_{file}.toml")
        assert (config.vehicle.sigma_vertical_velocity, config.vehicle.sigma_lateral_velocity) == (0.05, 0.04)
        assert config.map.capacity == 1200
        assert config.model == {"ca": "ca-polar", "cv": "cv-cartesian"}[file]
    assert (out / "base.toml").read_bytes() == base.read_bytes()
    assert "started from base.toml" in (out / "verdict.md").read_text()
    meta = json.loads((out / "campaign.json").read_text())
    assert meta["config_sha256"] == hashlib.sha256(base.read_bytes()).hexdigest()
    fails(capsys, [*argv, "--resume"], "config_sha256")
    other = tmp_path / "other.toml"
    other.write_text(BASE.replace("1200", "1300"))
    fails(capsys, [*argv, "--resume", "--config", str(other)], "config_sha256")
    assert main([*argv, "--resume", "--config", str(base)]) == 0
    assert "calibrate stop_and_go CA/P: done before, kept" in capsys.readouterr().out


@pytest.mark.parametrize("text, needle", [
    (None, "config file not found"),
    ('model = "ca-polar"\n', "sets model"),
    ("[vehicle]\nsigma_vertical_velocity = -1.0\n", "sigma_vertical_velocity"),
    ("[vehicle\n", "invalid TOML"),
])
def test_a_bad_base_config_is_refused_before_any_work(tmp_path, capsys, text, needle):
    base = tmp_path / "base.toml"
    if text is not None:
        base.write_text(text)
    fails(capsys, ["verdict", "--config", base, "--out", tmp_path / "v"], needle, str(base))
    assert not (tmp_path / "v").exists()


def test_a_step_stopped_by_ctrl_c_is_the_verdict_interrupted(tmp_path, monkeypatch):
    """A calibration stopped by Ctrl-C returns 130 (rodo.cli): the verdict is interrupted (exit 130, "interrupted"),
    not a step that failed and must be fixed."""
    from rodo.commands import verdict

    monkeypatch.setattr(verdict, "run_step", lambda argv, log: verdict.INTERRUPTED)
    with pytest.raises(KeyboardInterrupt):
        verdict._run([("calibrate city CA/P", ["calibrate"], False)], tmp_path, 1)
    monkeypatch.setattr(verdict, "run_step", lambda argv, log: 2)
    (tmp_path / "calibrate_city_CAP.log").write_text("rodo calibrate: error: broken\n")  # the step's log
    with pytest.raises(verdict.StepFailed, match="failed \\(exit 2\\)"):
        verdict._run([("calibrate city CA/P", ["calibrate"], False)], tmp_path, 1)


@pytest.mark.parametrize("code, exit_code", [(1, 1), (2, 2), (137, 1)])
def test_a_failed_step_passes_its_exit_code_on(tmp_path, monkeypatch, capsys, code, exit_code):
    """A step that exits 1 (the machine's fault: a full disk, `rodo.cli.environment_message`) makes the verdict exit
    1, one that exits 2 (the input's) exit 2, anything else 1; the message names the step and its log's last line.
    Every failed step was an input error (exit 2) before (the review of session 56, finding 6)."""
    from rodo.commands import verdict

    def step(argv, where):
        Path(where).write_text("rodo simulate: error: No space left on device (/x/radar.csv): free some space\n")
        return code

    monkeypatch.setattr(verdict, "run_step", step)
    with pytest.raises(verdict.StepFailed) as failed:
        verdict._run([("simulate city", ["simulate"], False)], tmp_path, 1)
    assert failed.value.code == exit_code and f"simulate city failed (exit {code})" in str(failed.value)
    assert "No space left on device (/x/radar.csv)" in str(failed.value)

    def raising(args):
        raise failed.value

    monkeypatch.setattr(verdict, "_verdict", raising)
    assert verdict.main(None) == exit_code
    assert capsys.readouterr().err.startswith(f"rodo verdict: error: simulate city failed (exit {code})")
