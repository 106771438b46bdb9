"""`rodo calibrate` with ground truth: the config it writes is accepted by `rodo run --config` and round-trips
through OdometryConfig.from_toml; the reports beside it; bad input exits 2 naming the file, option or field. Without
ground truth (EM): tests/cli/test_calibrate_no_truth_cli.py."""

import json
import shutil

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.estimator.config import OdometryConfig
from rodo.sim.simulate import load_truth
from rodo.validation.error_growth import AXES, error_growth, growth_table
from tests.cli.helpers import fails


@pytest.mark.slow
def test_calibrate_with_truth_writes_a_config_rodo_run_accepts(cal_seq, tmp_path, capsys):
    out = tmp_path / "learned.toml"
    assert main(["calibrate", str(cal_seq), "--model", "cv-polar", "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("# rodo calibrate") and "ground truth" in text.splitlines()[0]
    config = OdometryConfig.from_toml(out)
    report = json.loads(out.with_suffix(".json").read_text())
    assert config.model == "cv-polar"
    assert config.noise.qc_ca == tuple(report["qc_ca"]["qc"]) and config.noise.qc_cv == tuple(report["qc_cv"]["qc"])
    assert config.noise.sensor_sigma_scale == pytest.approx(1.0, rel=0.10)
    np.testing.assert_allclose(config.noise.sensor_sigma_scales, 1.0, rtol=0.10)  # sensor.toml is the truth
    assert report["measurement"]["channels"]["range"]["sigma"] == pytest.approx(0.02, rel=0.10)
    assert "| range |" in out.with_suffix(".md").read_text()
    velocity = report["consistency"]["velocity_inflation"]  # the lag, by default for a constant-velocity model
    assert list(config.uncertainty.velocity_lag_per_acceleration) == velocity["lag_per_acceleration"]
    assert list(config.uncertainty.velocity_lag_per_yaw_acceleration) == velocity["lag_per_yaw_acceleration"]
    assert any(velocity["lag_per_yaw_acceleration"])  # least squares: never exactly 0 on a real drive
    assert "lag behind a manoeuvre" in out.with_suffix(".md").read_text()
    capsys.readouterr()
    assert main(["run", str(cal_seq), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    assert np.abs(np.load(tmp_path / "run" / "states.npz")["velocity_lag"]).max() > 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["model"] == "cv-polar" and summary["config"] == config.to_dict()
    assert np.prod(config.uncertainty.velocity_axis_inflation) == pytest.approx(1.0, rel=1e-9)  # per axis by default
    assert config.uncertainty.heading_reversion_time == 0.0  # and the heading's reversion
    assert report["consistency"]["heading_reversion"]["fitted"] is False
    assert report["consistency"]["attitude_jitter"]["fitted"] is True  # the attitude jitter by default
    assert config.uncertainty.attitude_jitter_variance == report["consistency"]["attitude_jitter"]["variance"]


@pytest.mark.slow
def test_calibrate_learns_the_velocity_per_axis_by_default(cal_seq, tmp_path, capsys):
    """With truth the config carries the fitted per-axis velocity factors (product 1; --velocity-axes is the
    default; the velocity's lag is not learned for this constant-acceleration model by default), the report and
    its markdown name them, and `rodo run` accepts the config. --no-velocity-axes and --no-velocity-lag (below,
    with --no-attitude-jitter, for a constant-velocity model) leave them at 1 and 0."""
    out = tmp_path / "axes.toml"
    assert main(["calibrate", str(cal_seq), "--out", str(out)]) == 0
    g = OdometryConfig.from_toml(out).uncertainty.velocity_axis_inflation
    report = json.loads(out.with_suffix(".json").read_text())
    assert list(g) == report["consistency"]["velocity_inflation"]["per_axis"]
    assert np.prod(g) == pytest.approx(1.0, rel=1e-9) and max(g) / min(g) > 1.1
    assert "per axis vx, vy, vz, wx, wy, wz" in out.with_suffix(".md").read_text()
    unc = OdometryConfig.from_toml(out).uncertainty  # not learned for the constant-acceleration prior by default
    assert unc.velocity_lag_per_acceleration == unc.velocity_lag_per_yaw_acceleration == (0.0,) * 6
    assert "lag behind a manoeuvre" not in out.with_suffix(".md").read_text()
    assert main(["run", str(cal_seq), "--config", str(out), "--out", str(tmp_path / "run")]) == 0


@pytest.mark.slow
def test_calibrate_learns_the_heading_reversion_when_asked(cal_seq, tmp_path, capsys):
    """--heading-reversion on a 12 s drive: the report holds the grid's points with T_r up to a tenth of the
    drive (off and 1 s), each with the yaw's error growth and its cost, the config the point of least cost (at the
    tau before it) and tau chosen again with it,
    the markdown the grid and the choice, and `rodo run` accepts the config. On the 2 s drive only off is tried."""
    from rodo.validation import calibrate_consistency as cc

    longer = tmp_path / "city12"
    scenarios.simulate_to("city", 2, longer, duration=12.0)
    out = tmp_path / "heading.toml"
    assert main(["calibrate", str(longer), "--heading-reversion", "--out", str(out)]) == 0
    unc = OdometryConfig.from_toml(out).uncertainty
    c = json.loads(out.with_suffix(".json").read_text())["consistency"]
    h = c["heading_reversion"]
    assert h["fitted"] is True and set(h["grid"]) == {"0/0", "1/20", "1/50", "1/100", "1/200"}
    cost = {k: r["cost"] for k, r in h["grid"].items()}  # of the yaw's error growth over 1, 2, 5 and 10 s, the drive
    assert all(len(r["yaw"]) == 5 and r["cost"] == cc.tau_cost(r["yaw"]) for r in h["grid"].values())
    assert cost[f"{h['time']:g}/{h['anchor_time']:g}"] == min(cost.values())
    assert unc.heading_reversion_time == h["time"]
    assert unc.heading_anchor_time == (h["anchor_time"] if h["time"] > 0 else 100.0)
    taus = {float(k): cc.tau_cost((r["relative_span"], r["pose"])) for k, r in c["tau_grid"].items()}
    assert taus[unc.velocity_correlation_time] == min(taus.values())  # at the chosen reversion
    assert "heading reversion grid" in out.with_suffix(".md").read_text()
    assert main(["run", str(longer), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    # the report's error growth per axis (its replay of the fitted terms) is the run's at the written config
    with np.load(tmp_path / "run" / "states.npz") as z:
        states = dict(z)
    ran = growth_table(error_growth(states, load_truth(longer)))
    reported = c["error_growth"]["table"]
    assert [r["count"] for r in ran] == [r["count"] for r in reported] and reported[0]["count"] > 0
    for a, b in zip(ran, reported):
        assert a["ratio"] == b["ratio"] or a["ratio"] == pytest.approx(b["ratio"], rel=1e-9)
    assert "Error growth per axis" in out.with_suffix(".md").read_text()

    assert main(["calibrate", str(cal_seq), "--heading-reversion", "--out", str(tmp_path / "short.toml")]) == 0
    h = json.loads((tmp_path / "short.json").read_text())["consistency"]["heading_reversion"]
    assert set(h["grid"]) == {"0/0"} and h["time"] == 0.0


@pytest.mark.slow
def test_calibrate_learns_the_stationary_error_when_asked(tmp_path, capsys):
    """--stationary-error on a 15 s hills drive: per axis the report's choice (a share and time of the grid, or off)
    with its cost below the one without by MIN_GAIN at least, the config its variances and times, the markdown
    the line; `rodo run` at the written config reports the absolute pose the calibration replayed (its error
    growth is the report's), the stationary error on at least one axis (the yaw's cost falls by about 10 there;
    on city's first 12 s, which this test drove until session 50, the fall is near MIN_GAIN or below it, as the
    CPU's BLAS kernels round: learned on an Intel machine, not on an AMD EPYC)."""
    from rodo.validation import calibrate_stationary as cst

    longer = tmp_path / "hills15"
    scenarios.simulate_to("hills", 2, longer, duration=15.0)
    out = tmp_path / "stationary.toml"
    assert main(["calibrate", str(longer), "--stationary-error", "--out", str(out)]) == 0
    unc = OdometryConfig.from_toml(out).uncertainty
    s = json.loads(out.with_suffix(".json").read_text())["consistency"]["stationary_error"]
    assert s["fitted"] is True and list(s["axes"]) == [AXES[a] for a in cst.AXIS_ORDER]
    for i, name in enumerate(AXES):
        a = s["axes"][name]
        assert unc.stationary_variance[i] == a["variance"] and unc.stationary_time[i] == a["time"]
        if a["share"]:
            assert a["share"] in cst.SHARES and a["time"] in cst.TIMES
            assert a["cost"] <= a["cost_without"] - cst.MIN_GAIN
        else:
            assert a["variance"] == 0.0
    assert any(unc.stationary_variance)
    assert "stationary error per axis" in out.with_suffix(".md").read_text()
    assert main(["run", str(longer), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    with np.load(tmp_path / "run" / "states.npz") as z:
        states = dict(z)
    ran = growth_table(error_growth(states, load_truth(longer)))
    reported = json.loads(out.with_suffix(".json").read_text())["consistency"]["error_growth"]["table"]
    for a, b in zip(ran, reported):
        assert a["ratio"] == b["ratio"] or a["ratio"] == pytest.approx(b["ratio"], rel=1e-9)


@pytest.mark.slow
def test_calibrate_learns_the_registrations_correlation_per_axis_when_asked(tmp_path, capsys):
    """--axis-correlation on a 12 s CV/C drive: per axis the report's choice (a share of the grid with its cost
    below the one without by MIN_GAIN at least, or 0), the config those shares, the markdown the line, the
    config's header the shares taken (none here: a drive this short learns none; the fit's choice is tested on
    drives with a known share, tests/validation/test_calibrate_axis_correlation.py); `rodo run` at the written
    config records them and reports the absolute pose the calibration replayed (its error growth is the
    report's)."""
    from rodo.validation import calibrate_axis_correlation as cac
    from rodo.validation.calibrate_stationary import AXIS_ORDER, MIN_GAIN

    longer = tmp_path / "city12"
    scenarios.simulate_to("city", 2, longer, duration=12.0)
    out = tmp_path / "axes.toml"
    assert main(["calibrate", str(longer), "--model", "cv-cartesian", "--axis-correlation", "--out", str(out)]) == 0
    unc = OdometryConfig.from_toml(out).uncertainty
    a = json.loads(out.with_suffix(".json").read_text())["consistency"]["registration_axis_correlation"]
    assert a["fitted"] is True and list(a["axes"]) == [AXES[i] for i in AXIS_ORDER]
    for i, name in enumerate(AXES):
        x = a["axes"][name]
        assert unc.registration_axis_correlation[i] == x["share"] == a["shares"][i]
        assert x["share"] == 0.0 or (x["share"] in cac.SHARES and x["cost"] <= x["cost_without"] - MIN_GAIN)
    assert "registration's correlation per axis" in out.with_suffix(".md").read_text()
    header = "".join(line for line in out.read_text().splitlines() if line[:1] == "#")
    assert ("registration_axis_correlation (" in header) == any(a["shares"])  # named where a share was taken
    assert main(["run", str(longer), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    with np.load(tmp_path / "run" / "states.npz") as z:
        states = dict(z)
    np.testing.assert_array_equal(states["registration_axis_correlation"], unc.registration_axis_correlation)
    ran = growth_table(error_growth(states, load_truth(longer)))
    reported = json.loads(out.with_suffix(".json").read_text())["consistency"]["error_growth"]["table"]
    assert [r["count"] for r in ran] == [r["count"] for r in reported]
    for r, b in zip(ran, reported):
        assert r["ratio"] == b["ratio"] or r["ratio"] == pytest.approx(b["ratio"], rel=1e-9)


def test_the_header_names_the_per_axis_shares_taken():
    """The config header's uncertainty line names the axes whose registration's correlation the fit took, with their
    shares, and says nothing of the term where it took none or was not asked."""
    from rodo.commands.calibrate_report import _axis_words

    def report(shares):
        return {"registration_axis_correlation": {"fitted": True, "axes": {k: {"share": x} for k, x in shares.items()}}}

    named = _axis_words(report({"yaw": 0.0, "x": 0.25, "pitch": 1.0}))
    assert named == ", registration_axis_correlation (x 0.25, pitch 1)"
    assert _axis_words(report({"yaw": 0.0, "x": 0.0})) == ""
    assert _axis_words({"registration_axis_correlation": {"fitted": False}}) == _axis_words({}) == ""


@pytest.mark.slow
def test_calibrate_learns_the_attitude_jitter_unless_told_not_to(cal_seq, tmp_path, capsys):
    """By default (and with --attitude-jitter) the report holds the fit (the 1 s span's mean NEES/dof without
    and with the jitter; V positive only where it was over 1, and then bringing it to 1), the config its V at the
    base config's T, the markdown and the header name it, and `rodo run` reports it in its states;
    --no-attitude-jitter keeps the base config's (here V 3e-6 rad^2 at T 0.5 s) and fits nothing."""
    out = tmp_path / "jitter.toml"
    assert main(["calibrate", str(cal_seq), "--attitude-jitter", "--out", str(out)]) == 0
    unc = OdometryConfig.from_toml(out).uncertainty
    j = json.loads(out.with_suffix(".json").read_text())["consistency"]["attitude_jitter"]
    assert j["fitted"] is True and j["time"] == unc.attitude_jitter_time == 1.0
    assert unc.attitude_jitter_variance == j["variance"]
    if j["mean_without"] > 1.0:
        assert j["variance"] > 0 and j["mean_with"] == pytest.approx(1.0, abs=1e-6)
    else:
        assert j["variance"] == 0.0
    assert "attitude jitter variance" in out.with_suffix(".md").read_text()
    assert "attitude_jitter_variance" in "".join(line for line in out.read_text().splitlines() if line[:1] == "#")
    assert main(["run", str(cal_seq), "--config", str(out), "--out", str(tmp_path / "run")]) == 0
    states = np.load(tmp_path / "run" / "states.npz")
    np.testing.assert_array_equal(states["attitude_jitter"], [j["variance"], 1.0])

    base = tmp_path / "base.toml"
    base.write_text("[uncertainty]\nattitude_jitter_variance = 3e-6\nattitude_jitter_time = 0.5\n")
    kept = tmp_path / "kept.toml"
    assert main(["calibrate", str(cal_seq), "--config", str(base), "--model", "cv-polar", "--no-attitude-jitter",
                 "--no-velocity-axes", "--no-velocity-lag", "--out", str(kept)]) == 0
    unc = OdometryConfig.from_toml(kept).uncertainty
    assert unc.velocity_axis_inflation == (1.0,) * 6
    assert unc.velocity_lag_per_acceleration == unc.velocity_lag_per_yaw_acceleration == (0.0,) * 6
    assert (unc.attitude_jitter_variance, unc.attitude_jitter_time) == (3e-6, 0.5)
    j = json.loads(kept.with_suffix(".json").read_text())["consistency"]["attitude_jitter"]
    assert j == {"variance": 3e-6, "time": 0.5, "fitted": False}
    assert "attitude_jitter_variance" not in "".join(line for line in kept.read_text().splitlines() if line[:1] == "#")


def test_the_vehicle_rates_need_the_truth(cal_seq, tmp_path, capsys):
    """--vehicle-rates with --no-truth exits 2 naming both; with --no-consistency it is learned all the same (it is
    not in the uncertainty section); without it (the default) the base config's terms are kept."""
    fails(capsys, ["calibrate", str(cal_seq), "--vehicle-rates", "--no-truth", "--out", tmp_path / "x.toml"],
          "--vehicle-rates", "--no-truth")
    out, kept = tmp_path / "v.toml", tmp_path / "k.toml"
    assert main(["calibrate", str(cal_seq), "--vehicle-rates", "--no-consistency", "--out", str(out)]) == 0
    v = json.loads(out.with_suffix(".json").read_text())["vehicle"]
    unc = OdometryConfig.from_toml(out).vehicle
    assert v["fitted"] and [unc.sigma_roll_rate, unc.sigma_pitch_rate] == v["sigma"] != v["before"]
    assert "vehicle.sigma_roll_rate" in out.with_suffix(".md").read_text()
    assert main(["calibrate", str(cal_seq), "--no-consistency", "--out", str(kept)]) == 0
    assert OdometryConfig.from_toml(kept).vehicle == OdometryConfig.for_model("ca-polar").vehicle
    assert "vehicle" not in json.loads(kept.with_suffix(".json").read_text())


@pytest.mark.parametrize("flag", ["--velocity-axes", "--velocity-lag", "--heading-reversion", "--attitude-jitter",
                                  "--stationary-error", "--axis-correlation"])
@pytest.mark.parametrize("other", ["--no-truth", "--no-consistency"])
def test_an_uncertainty_flag_without_the_uncertainty_section_is_refused(cal_seq, tmp_path, capsys, flag, other):
    """Asking to learn a term of the uncertainty section while leaving that section out exits 2 naming both."""
    fails(capsys, ["calibrate", str(cal_seq), flag, other, "--out", tmp_path / "x.toml"], flag, other)


@pytest.mark.slow
def test_calibrate_pools_several_sequences(cal_seq, tmp_path, capsys):
    """Two sequences with truth: one config from both, Qc the maximum likelihood over both drives' intervals
    (not either one's), the sensor noise over both drives' detections; the header names both."""
    from rodo.sim.simulate import load_truth
    from rodo.validation import calibrate as cal
    from rodo.validation.calibrate_config import truth_track

    second = tmp_path / "city3"
    scenarios.simulate_to("city", 3, second, duration=2.0)
    out = tmp_path / "both.toml"
    assert main(["calibrate", str(cal_seq), str(second), "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    tracks = [truth_track(load_truth(d)) for d in (cal_seq, second)]
    assert report["sequences"] == 2 and report["scans"] == sum(len(k.t) for k in tracks)
    for kind in ("ca", "cv"):
        pooled, first = cal.fit_qc_to_truth(kind, tracks), cal.fit_qc_to_truth(kind, tracks[0])
        np.testing.assert_allclose(report[f"qc_{kind}"]["qc"], pooled.qc, rtol=1e-9)
        assert report[f"qc_{kind}"]["loglik"] == pytest.approx(pooled.loglik, rel=1e-12)
        assert abs(pooled.loglik - first.loglik) > 0.3 * abs(first.loglik)  # both drives' intervals count
    assert report["qc_ca"]["intervals"] == sum(len(k.t) - 1 for k in tracks)
    assert f"{cal_seq} {second}" in out.read_text().splitlines()[0]
    assert "consistency" in report and OdometryConfig.from_toml(out).model == "ca-polar"


def test_calibrate_bad_input(cal_seq, tmp_path, capsys):
    out = tmp_path / "c.toml"
    fails(capsys, ["calibrate", tmp_path / "nope", "--out", out], "nope", "not a sequence directory")
    no_truth = tmp_path / "no_truth"
    shutil.copytree(cal_seq, no_truth)
    (no_truth / "truth.npz").unlink()
    fails(capsys, ["calibrate", no_truth, "--out", out], "truth.npz", "--no-truth")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--iterations", "0"], "--iterations")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--duration", "-1"], "--duration")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--floor", "0"], "--floor")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--floor", "1e8"], "--floor", "upper bound")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--floor", "1e-25"], "--floor", "lower bound")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--floor", "1e-4,1e-3"], "--floor", "one number or six")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--floor", "1e-4,1e-4,1e-4,x,1e-3,1e-4"], "--floor", "'1e-4,")
    empty = tmp_path / "empty"
    empty.mkdir()
    for name in ("sensor.toml", "groundtruth.txt"):
        (empty / name).write_bytes((cal_seq / name).read_bytes())
    (empty / "radar.csv").write_text((cal_seq / "radar.csv").read_text().splitlines()[0] + "\n")  # the header only
    fails(capsys, ["calibrate", empty, "--out", out, "--no-truth"], "radar.csv", "no detections")
    fails(capsys, ["calibrate", cal_seq, "--out", out, "--no-truth", "--learn", "x,jaw"], "--learn", "jaw")
    fails(capsys, ["calibrate", cal_seq, "--out", tmp_path], "--out", "is a directory")
    fails(capsys, ["calibrate", cal_seq, "--out", tmp_path / "missing" / "c.toml"], "--out", "does not exist")
    fails(capsys, ["calibrate", cal_seq, "--out", tmp_path / "c.json"], "--out", "overwritten")
    bad = tmp_path / "bad.toml"
    bad.write_text("[noise]\nqc_ca = [1, 2]\n")
    fails(capsys, ["calibrate", cal_seq, "--config", bad, "--out", out], "bad.toml", "noise.qc_ca")
    other = tmp_path / "other"
    shutil.copytree(cal_seq, other)
    lines = (other / "radar.csv").read_text().splitlines()
    (other / "radar.csv").write_text("\n".join(lines[:-5]) + "\n")  # truth.npz no longer matches radar.csv
    fails(capsys, ["calibrate", other, "--out", out], "truth.npz", "radar.csv")
    fails(capsys, ["calibrate", cal_seq, cal_seq, "--no-truth", "--out", out], "--no-truth", "one sequence, got 2")
    fails(capsys, ["calibrate", cal_seq, no_truth, "--out", out], "no_truth", "truth.npz")
    moved = tmp_path / "moved"
    shutil.copytree(cal_seq, moved)
    toml = (moved / "sensor.toml").read_text()
    (moved / "sensor.toml").write_text(toml.replace("max_range", "max_range = 60.0\n# was max_range", 1))
    fails(capsys, ["calibrate", cal_seq, moved, "--out", out], "moved", "sensor.toml", "another sensor")
    assert not out.exists()


def test_the_report_names_the_gross_failures_it_left_out():
    """CONFIG.md's words for the scans the factor fits left out (validation.gross_failures): none, a count (the
    one-scan fit), or each scan by run and time (the velocity fit), the first MAX_NAMED of them."""
    from rodo.commands.calibrate_report import MAX_NAMED, _failure_words

    assert _failure_words(0) == "" and _failure_words({"scans": 0, "runs": [], "t": []}) == ""
    assert _failure_words(3) == ("; 3 scans left out as gross failures (NEES above 100 per dof at the median scan's "
                                 "level)")
    assert _failure_words(1).startswith("; 1 scan left out")
    n = MAX_NAMED + 2
    words = _failure_words({"scans": n, "runs": [4] * n, "t": [25.5 + 0.25 * i for i in range(n)]})
    assert words.startswith(f"; {n} scans left out as gross failures (NEES above 100 per dof at the median scan's "
                            "level): run 4 at 25.50 s, run 4 at 25.75 s, ")
    assert words.count("run 4 at") == MAX_NAMED and words.endswith(" and 2 more (runs: the SEQ_DIRs from 0)")
