"""`rodo table1`: the table builder on hand-made runs (pooling, length sets, bolding, overall row) and one tiny
real run through the CLI (two short scenarios, resumable)."""

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rodo.estimator.errors import InputError
from rodo import cli
from rodo.commands import table1 as table1_cmd
from rodo.validation.campaign import npz_path, read_results
from rodo.validation.table1 import (LENGTHS, SHORT_LENGTHS, build_table, load_runs, render_markdown,
                               segment_arrays)


def _seg(t_err, r_err, length=100.0):
    """Segment rows [first, length, t_err (fraction), r_err (rad/m)]."""
    t_err, r_err = np.atleast_1d(t_err), np.atleast_1d(r_err)
    return np.c_[np.arange(len(t_err)) * 10.0, np.full(len(t_err), length), t_err, r_err]


def _run(scenario, model, t_err, r_err, ms, path=1000.0, short=None):
    seg = _seg(t_err, r_err) if t_err is not None else np.zeros((0, 4))
    return {"scenario": scenario, "model": model, "path_length_m": path, "kitti_segments": seg,
            "kitti_segments_short": seg if short is None else short, "ms_per_scan": np.asarray(ms, float)}


def _row(table, name):
    return next(r for r in table["rows"] if r["scenario"] == name)


def test_build_table_pools_segments_over_runs_not_run_means():
    # run 1: one segment at 1 %, run 2: three at 3 % -> pooled 2.5 % (the mean of run means would be 2 %)
    runs = [_run("a", "ca-polar", 0.01, 1e-4, [10, 12], path=900.0),
            _run("a", "ca-polar", [0.03] * 3, [3e-4] * 3, [14], path=1100.0),
            _run("a", "cv-cartesian", 0.02, 2e-4, [20, 21, 22], path=900.0),
            _run("a", "cv-cartesian", 0.02, 2e-4, [23], path=1100.0)]
    row = _row(build_table(runs), "a")
    assert row["CA/P"]["t_err_pct"] == pytest.approx(2.5)
    assert row["CA/P"]["r_err_deg_per_m"] == pytest.approx(np.rad2deg(2.5e-4))
    assert row["CA/P"]["segments"] == 4
    assert row["CA/P"]["ms_per_scan"] == pytest.approx(12.0)  # median of the scans of all runs
    assert row["CV/C"]["ms_per_scan"] == pytest.approx(21.5)
    assert row["distance_km"] == pytest.approx(1.0) and row["runs"] == 2 and row["lengths"] == "standard"
    assert row["best"] == {"t_err_pct": ["CV/C"], "r_err_deg_per_m": ["CV/C"], "ms_per_scan": ["CA/P"]}


@given(st.lists(st.tuples(st.integers(1, 6), st.floats(0.0, 0.1), st.floats(0.0, 1e-3)), min_size=1, max_size=5))
def test_build_table_pooled_error_is_segment_weighted_mean(spec):
    runs = []
    for n, t, r in spec:
        for m in ("ca-polar", "cv-cartesian"):
            runs.append(_run("s", m, [t] * n, [r] * n, [1.0]))
    counts = np.array([n for n, _, _ in spec], float)
    expect_t = 100 * np.sum(counts * [t for _, t, _ in spec]) / counts.sum()
    expect_r = np.rad2deg(np.sum(counts * [r for _, _, r in spec]) / counts.sum())
    table = build_table(runs)
    for row in (_row(table, "s"), _row(table, "overall")):
        assert row["CA/P"]["t_err_pct"] == pytest.approx(expect_t, rel=1e-12, abs=1e-15)
        assert row["CV/C"]["r_err_deg_per_m"] == pytest.approx(expect_r, rel=1e-12, abs=1e-15)
        assert row["CA/P"]["segments"] == counts.sum()


def test_overall_row_pools_standard_scenarios_and_marks_short_ones():
    short = _seg([0.5], [0.05], length=10.0)
    runs = [_run("long", "ca-polar", [0.01, 0.01], [1e-4, 1e-4], [10.0, 11.0], path=800.0),
            _run("long", "cv-cartesian", [0.02], [2e-4], [20.0], path=800.0),
            _run("other", "ca-polar", [0.04, 0.04], [4e-4, 4e-4], [12.0], path=400.0),
            _run("other", "cv-cartesian", [0.01], [1e-4], [30.0, 31.0], path=400.0),
            _run("tiny", "ca-polar", None, None, [1.0], path=40.0, short=short),
            _run("tiny", "cv-cartesian", None, None, [2.0], path=40.0, short=short),
            _run("nothing", "ca-polar", None, None, [5.0], path=4.0, short=np.zeros((0, 4))),
            _run("nothing", "cv-cartesian", None, None, [5.0], path=4.0, short=np.zeros((0, 4)))]
    table = build_table(runs, ["long", "other", "tiny", "nothing"])
    assert [r["scenario"] for r in table["rows"]] == ["long", "other", "tiny", "nothing", "overall"]
    tiny, nothing, overall = _row(table, "tiny"), _row(table, "nothing"), _row(table, "overall")
    assert tiny["lengths"] == "short" and tiny["CA/P"]["t_err_pct"] == pytest.approx(50.0)
    assert tiny["best"]["t_err_pct"] == ["CV/C", "CA/P"]  # equal: both bold
    assert nothing["lengths"] == "n/a" and np.isnan(nothing["CA/P"]["t_err_pct"]) and nothing["best"]["t_err_pct"] == []
    # overall: segments of "long" and "other" only (4 CA/P: 1,1,4,4 % -> 2.5 %; 2 CV/C: 2,1 % -> 1.5 %)
    assert overall["pooled_scenarios"] == ["long", "other"] and overall["lengths"] == "standard"
    assert overall["CA/P"]["t_err_pct"] == pytest.approx(2.5) and overall["CV/C"]["t_err_pct"] == pytest.approx(1.5)
    assert overall["CA/P"]["segments"] == 4
    # runtime: median over every scan of every row, including the short and n/a rows
    assert overall["CA/P"]["ms_per_scan"] == pytest.approx(np.median([10, 11, 12, 1, 5]))
    assert overall["CV/C"]["ms_per_scan"] == pytest.approx(np.median([20, 30, 31, 2, 5]))
    assert overall["distance_km"] == pytest.approx(0.8 + 0.4 + 0.04 + 0.004)
    assert overall["best"] == {"t_err_pct": ["CV/C"], "r_err_deg_per_m": ["CV/C"], "ms_per_scan": ["CA/P"]}
    text = render_markdown(table)
    lines = {ln.split(" | ")[0].strip("| *"): ln for ln in text.splitlines() if ln.startswith("| ")}
    assert "**2.50**" not in lines["overall"] and "**1.50**" in lines["overall"] and "**10.5**" in text
    assert "tiny †" in lines and "nothing ‡" in lines
    assert "| n/a | n/a |" in lines["nothing ‡"]


def test_overall_falls_back_to_short_lengths_when_no_row_reaches_100_m():
    short_a = _seg([0.02], [1e-3], length=10.0)
    runs = [_run(s, m, None, None, [1.0], path=50.0, short=short_a) for s in ("x", "y")
            for m in ("ca-polar", "cv-cartesian")]
    overall = _row(build_table(runs), "overall")
    assert overall["lengths"] == "short" and overall["pooled_scenarios"] == ["x", "y"]
    assert overall["CA/P"]["t_err_pct"] == pytest.approx(2.0) and overall["CA/P"]["segments"] == 2


def test_build_table_rejects_bad_records():
    good = _run("a", "ca-polar", 0.01, 1e-4, [1.0])
    with pytest.raises(InputError, match=r"runs\[1\]: missing field\(s\) ms_per_scan"):
        build_table([good, {k: v for k, v in good.items() if k != "ms_per_scan"}])
    with pytest.raises(InputError, match=r"runs\[0\]\.model"):
        build_table([{**good, "model": "icp"}])
    with pytest.raises(InputError, match=r"runs\[0\]\.kitti_segments"):
        build_table([{**good, "kitti_segments": np.zeros((2, 3))}])


def test_a_model_missing_in_a_scenario_gives_na_errors_not_a_one_sided_bold():
    table = build_table([_run("a", "ca-polar", 0.01, 1e-4, [1.0])])
    row = _row(table, "a")
    assert row["lengths"] == "n/a" and row["best"]["t_err_pct"] == [] and row["CV/C"]["runs"] == 0


def test_short_lengths_are_the_devkit_lengths_over_ten():
    assert SHORT_LENGTHS == tuple(L / 10 for L in LENGTHS) and LENGTHS[0] == 100.0


def test_cli_rejects_unknown_scenario(tmp_path, capsys):
    rc = cli.main(["table1", "--scenarios", "city,nowhere", "--out", str(tmp_path / "o")], commands=[table1_cmd])
    assert rc == 2 and "--scenarios: unknown scenario(s) nowhere" in capsys.readouterr().err
    rc = cli.main(["table1", "--runs", "0", "--out", str(tmp_path / "o")], commands=[table1_cmd])
    assert rc == 2 and "--runs" in capsys.readouterr().err


@pytest.mark.slow
def test_tiny_real_run_writes_table_and_resumes(tmp_path, capsys):
    """1 run of two scenarios cut to 3 s (30 m and 90 m, so both on the 10-80 m lengths): the table's pooled
    overall errors must equal the devkit means recomputed from the saved segments, the errors must be those of
    a working odometry (< 5 %), and a resumed call must run nothing and write the same table."""
    out = tmp_path / "t1"
    argv = ["table1", "--runs", "1", "--scenarios", "yaw_accel,highway", "--duration", "3", "--jobs", "1",
            "--out", str(out)]
    assert cli.main(argv, commands=[table1_cmd]) == 0
    printed = capsys.readouterr().out
    assert "| yaw_accel † |" in printed and "ran 4 (trial, model) runs" in printed
    table = json.loads((out / "table1.json").read_text())
    md = (out / "table1.md").read_text()
    assert md.startswith("# Table I") and "**overall †**" in md
    overall = table["rows"][-1]
    assert overall["scenario"] == "overall" and overall["lengths"] == "short"
    for sc in ("yaw_accel", "highway"):
        rows = read_results(out / sc / "results.csv")
        assert sorted(r["model"] for r in rows) == ["ca-polar", "cv-cartesian"]
        assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]
    for label, model in (("CA/P", "ca-polar"), ("CV/C", "cv-cartesian")):
        seg = np.concatenate([np.load(npz_path(out / sc, 0, model))["kitti_segments_short"]
                              for sc in ("yaw_accel", "highway")])
        assert overall[label]["t_err_pct"] == pytest.approx(100 * seg[:, 2].mean(), rel=1e-12)
        assert overall[label]["r_err_deg_per_m"] == pytest.approx(np.rad2deg(seg[:, 3].mean()), rel=1e-12)
        assert 0 < overall[label]["t_err_pct"] < 5.0 and overall[label]["ms_per_scan"] > 0
    assert overall["distance_km"] == pytest.approx(sum(r["distance_km"] for r in table["rows"][:-1]))
    assert 0.02 < table["rows"][0]["distance_km"] < 0.04  # yaw_accel: 10 m/s for 3 s
    # again without --resume: refused before any work; with --resume: nothing to run, the same table
    assert cli.main(argv, commands=[table1_cmd]) == 2
    assert "pass --resume" in capsys.readouterr().err
    assert cli.main(argv + ["--resume"], commands=[table1_cmd]) == 0
    assert "ran 0 (trial, model) runs, skipped 4" in capsys.readouterr().out
    assert json.loads((out / "table1.json").read_text())["rows"] == table["rows"]
    assert len(load_runs(out, ["yaw_accel", "highway"])) == 4


def test_segment_arrays_match_kitti_on_a_known_drift():
    """A straight 150 m drive whose estimate is scaled by 1.02: every segment's translational error is 2 %."""
    from rodo.sim.sequence import Trajectory

    t = np.arange(0, 15.0, 0.1)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, 0, 3] = 10.0 * t
    E = T.copy()
    E[:, 0, 3] *= 1.02
    a = segment_arrays(Trajectory(t, T), Trajectory(t, E), step=10)
    assert a["path_length_m"] == pytest.approx(149.0)
    for key, lengths in (("kitti_segments", {100.0}), ("kitti_segments_short", set(SHORT_LENGTHS))):
        seg = a[key]
        assert set(seg[:, 1]) == lengths
        # the devkit's last frame is the first one more than L past the first: 0.1 s = 1 m steps, so the
        # segment is L + 1 m long and its error 2 % of that, divided by L
        assert np.allclose(seg[:, 2], 0.02 * (seg[:, 1] + 1.0) / seg[:, 1], rtol=1e-9)
        assert np.allclose(seg[:, 3], 0.0, atol=1e-12)


def test_a_scenario_whose_runs_all_failed_is_a_row_of_na():
    runs = [_run("ok", m, 0.01, 1e-4, [1.0]) for m in ("ca-polar", "cv-cartesian")]
    table = build_table(runs, ["ok", "failed"])
    failed = _row(table, "failed")
    assert failed["runs"] == 0 and failed["lengths"] == "n/a" and np.isnan(failed["distance_km"])
    line = next(ln for ln in render_markdown(table).splitlines() if ln.startswith("| failed"))
    assert line == "| failed ‡ | n/a | 0 | " + " | ".join(["n/a"] * 6) + " |"
    assert _row(table, "overall")["distance_km"] == pytest.approx(1.0)


@pytest.mark.slow
@pytest.mark.parametrize("option, value, key, saved", [
    ("--fault", "clutter=200", "faults", ["clutter=200"]),
    ("--profile", "lrr30f", "profile", "lrr30f"),
])
def test_table1_option_is_simulated_recorded_and_required_on_resume(tmp_path, capsys, option, value, key, saved):
    """`rodo table1 --fault` and `--profile`: every trial simulated with it (its rows differ from a plain run's:
    clutter, or the profile's sparser scans), saved in each scenario's campaign.json and in table1.json (a plain
    run saves nothing, so older campaigns still resume); resuming without it is refused naming campaign.json,
    resuming with it skips the finished rows."""
    base = ["table1", "--runs", "1", "--scenarios", "yaw_accel", "--duration", "1", "--jobs", "1"]
    rows = {}
    for name, extra in (("plain", []), ("with", [option, value])):
        assert cli.main(base + ["--out", str(tmp_path / name)] + extra, commands=[table1_cmd]) == 0
        rows[name] = {r["model"]: r for r in read_results(tmp_path / name / "yaw_accel" / "results.csv")}
        assert all(r["status"] == "ok" for r in rows[name].values())
    assert json.loads((tmp_path / "with" / "yaw_accel" / "campaign.json").read_text())[key] == saved
    assert json.loads((tmp_path / "with" / "table1.json").read_text())["parameters"][key] == saved
    assert key not in json.loads((tmp_path / "plain" / "yaw_accel" / "campaign.json").read_text())
    assert rows["plain"]["ca-polar"]["nis_mean"] != rows["with"]["ca-polar"]["nis_mean"]
    capsys.readouterr()
    assert cli.main(base + ["--out", str(tmp_path / "with"), "--resume"], commands=[table1_cmd]) == 2
    assert "campaign.json" in (err := capsys.readouterr().err) and key in err
    assert cli.main(base + ["--out", str(tmp_path / "with"), "--resume", option, value], commands=[table1_cmd]) == 0
    assert "ran 0 (trial, model) runs, skipped 2" in capsys.readouterr().out


@pytest.mark.parametrize("option, value, message", [
    ("--fault", "jitter=0.001", "--fault jitter: not supported by table1"),  # as by montecarlo
    ("--profile", "nope", "--profile: unknown sensor profile 'nope'"),
])
def test_table1_refuses_a_bad_option_before_any_work(tmp_path, capsys, option, value, message):
    base = ["table1", "--runs", "1", "--scenarios", "yaw_accel", "--duration", "1", "--jobs", "1"]
    assert cli.main(base + ["--out", str(tmp_path / "x"), option, value], commands=[table1_cmd]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "x").exists()
