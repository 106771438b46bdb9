"""`rodo demo`'s KITTI figure is `rodo evaluate`'s on the same files (the devkit's lengths, "-" under 100 m), and
`rodo evaluate` refuses a states.npz of another run and a truth.npz of another sequence before printing anything.

Sizing: two demo runs without figures (5 s of highway, 1 s of city) and three short city sequences; about 20 s.
"""

import json

import numpy as np
import pytest

from rodo import scenarios
from rodo.cli import main
from rodo.commands import demo as demo_cmd
from rodo.commands import evaluate as evaluate_cmd
from rodo.commands import run as run_cmd


def fails(capsys, argv, *needles) -> str:
    """`rodo argv` exits 2 with one line on stderr containing every needle, and prints nothing on stdout."""
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert rc == 2 and cap.out == "", (rc, cap.out)
    assert cap.err.startswith(f"rodo {argv[0]}: error: ") and cap.err.count("\n") == 1, cap.err
    assert "Traceback" not in cap.err and all(str(n) in cap.err for n in needles), (needles, cap.err)
    return cap.err


def _evaluate_json(tmp_path, gt, est, states, truth) -> dict:
    out = tmp_path / f"eval_{est.parent.name}.json"
    assert main(["evaluate", "--gt", str(gt), "--est", str(est), "--states", str(states), "--truth", str(truth),
                 "--json", str(out)], commands=[evaluate_cmd]) == 0
    return json.loads(out.read_text())


def _demo_and_evaluate(tmp_path, capsys, scenario: str, duration: str):
    """Run the demo, then `rodo evaluate` on each model's files: (the demo's printed text, and per model (its
    evaluation.json, evaluate's report, demo.json's entry, its row of the printed table))."""
    out = tmp_path / f"demo_{scenario}"
    assert main(["demo", "--out", str(out), "--scenario", scenario, "--duration", duration, "--no-figures"],
                commands=[demo_cmd]) == 0
    text = capsys.readouterr().out
    seq = out / f"{scenario}_seed0"
    report = json.loads((out / "demo.json").read_text())
    per_model = {}
    for model in demo_cmd.MODELS:
        ours = json.loads((out / model / "evaluation.json").read_text())
        theirs = _evaluate_json(tmp_path, seq / "groundtruth.txt", out / model / "estimate.txt",
                                out / model / "states.npz", seq / "truth.npz")
        row = next(line for line in text.splitlines() if line.startswith(f"| {model} |"))
        per_model[model] = (ours, theirs, report["runs"][model], row)
    return text, per_model


@pytest.mark.slow
def test_the_demos_kitti_figure_is_rodo_evaluates(tmp_path, capsys):
    """On 5 s of highway (about 150 m: KITTI defined) the demo's evaluation.json, demo.json and table hold exactly
    what `rodo evaluate` reports for the files the demo wrote."""
    _, per_model = _demo_and_evaluate(tmp_path, capsys, "highway", "5")
    for ours, theirs, reported, row in per_model.values():
        assert ours == theirs
        assert theirs["path_length_m"] > 100 and theirs["kitti_segments"] > 0
        assert [s["length_m"] for s in theirs["segments"]][0] == 100.0  # the devkit's lengths, not 50 m
        assert reported["kitti_t_err_pct"] == theirs["kitti_t_err_pct"] > 0
        assert row.split("|")[2].strip() == f"{theirs['kitti_t_err_pct']:.3f}"


@pytest.mark.slow
def test_the_demo_has_no_kitti_figure_below_100_m(tmp_path, capsys):
    """On 1 s of city (about 3 m) `rodo evaluate` has no KITTI figure, and neither has the demo: '-' in its table,
    null in its JSON, and a line saying why."""
    text, per_model = _demo_and_evaluate(tmp_path, capsys, "city", "1")
    for ours, theirs, reported, row in per_model.values():
        assert ours == theirs and theirs["kitti_t_err_pct"] is None and theirs["kitti_segments"] == 0
        assert reported["kitti_t_err_pct"] is None
        assert [c.strip() for c in row.split("|")[2:4]] == ["-", "-"]
    assert "KITTI -: the path" in text and "shorter than the KITTI devkit's shortest segment (100 m)" in text


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """City seed 0 (2 s, run with ca-polar), city seed 1 (2 s, the same clock) and city seed 0 (1 s, run)."""
    root = tmp_path_factory.mktemp("drives")
    for name, seed, duration in (("a", 0, 2.0), ("b", 1, 2.0), ("c", 0, 1.0)):
        scenarios.simulate_to("city", seed, root / name, duration=duration)
    for name in ("a", "c"):
        assert main(["run", str(root / name), "--out", str(root / f"run_{name}")], commands=[run_cmd]) == 0
    assert main(["run", str(root / "a"), "--model", "cv-cartesian", "--out", str(root / "run_a_cv")],
                commands=[run_cmd]) == 0
    return root


def _args(root, states="run_a", truth=None):
    argv = ["evaluate", "--gt", root / "a" / "groundtruth.txt", "--est", root / "run_a" / "estimate.txt",
            "--states", root / states / "states.npz"]
    return argv + (["--truth", truth] if truth is not None else [])


def test_states_of_another_run_are_refused_before_printing(drives, capsys):
    capsys.readouterr()
    err = fails(capsys, _args(drives, states="run_c"), "--states", "run_c/states.npz", "--est",
                "run_a/estimate.txt", "not the estimate's")
    assert "14 states" in err and "27 poses" in err
    # the run's own states pass
    assert main([str(a) for a in _args(drives)], commands=[evaluate_cmd]) == 0
    assert "NIS per pair" in capsys.readouterr().out


def test_states_of_another_run_on_the_same_times_are_refused(drives, capsys):
    """The other model's run of the same sequence: every time matches, the poses do not (its NIS, timing and NEES
    would be reported as this estimate's)."""
    capsys.readouterr()
    err = fails(capsys, _args(drives, states="run_a_cv"), "--states", "run_a_cv/states.npz", "--est",
                "run_a/estimate.txt", "poses are not the estimate's")
    assert "of 27 differ" in err


def test_states_off_by_more_than_the_tolerance_are_refused(drives, tmp_path, capsys):
    with np.load(drives / "run_a" / "states.npz") as z:
        states = dict(z)
    for shift, ok in ((0.0005, True), (0.002, False)):  # the default tolerance is 1 ms
        d = tmp_path / f"shift{shift}"
        d.mkdir()
        np.savez(d / "states.npz", **(states | {"t": states["t"] + shift}))
        argv = _args(drives, states=d)
        if ok:
            assert main([str(a) for a in argv], commands=[evaluate_cmd]) == 0
        else:
            fails(capsys, argv, f"--states {d / 'states.npz'} and --est", "within 0.001 s", "first at pose 0")
    capsys.readouterr()


def test_a_truth_of_another_sequence_is_refused_before_printing(drives, tmp_path, capsys):
    """City seed 1 has the same clock as seed 0 (every time matches) but another drive: refused, with both files
    named and nothing printed; seed 0's own truth gives the NEES."""
    capsys.readouterr()
    fails(capsys, _args(drives, truth=drives / "b" / "truth.npz"), "--truth", "b/truth.npz", "--gt",
          "a/groundtruth.txt", "not the ground truth's")
    assert main([str(a) for a in _args(drives, truth=drives / "a" / "truth.npz")], commands=[evaluate_cmd]) == 0
    assert "NEES (d=18)" in capsys.readouterr().out


def test_the_truth_pose_tolerance_is_a_millimetre(drives, tmp_path, capsys):
    """The sequence's own truth moved by 0.1 mm passes (rounding), by 1 cm is refused."""
    with np.load(drives / "a" / "truth.npz") as z:
        truth = dict(z)
    for dx, ok in ((1e-4, True), (1e-2, False)):
        T = truth["T_vehicle_world"].copy()
        T[:, 0, 3] -= dx  # T_vehicle_world's translation: the vehicle's position moves by dx
        path = tmp_path / f"truth_{dx}.npz"
        np.savez(path, **(truth | {"T_vehicle_world": T}))
        argv = _args(drives, truth=path)
        if ok:
            assert main([str(a) for a in argv], commands=[evaluate_cmd]) == 0
        else:
            fails(capsys, argv, f"--truth {path} and --gt", "0.001 m")
    capsys.readouterr()
