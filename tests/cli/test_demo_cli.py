"""`rodo demo`: the main job end to end on a 1 s sequence without figures (about 10 s on two cores)."""

import json

import numpy as np
import pytest

from rodo.cli import main
from rodo.commands import demo as demo_cmd
from rodo.commands.run import rodo_command
from rodo.sim.sequence import read_sequence, read_tum


@pytest.mark.slow
def test_demo_runs_end_to_end_and_writes_its_report(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--duration", "1", "--seed", "0", "--no-figures"],
                commands=[demo_cmd]) == 0
    text = capsys.readouterr().out
    assert "| ca-polar |" in text and "| cv-cartesian |" in text
    assert demo_cmd.ONE_DRIVE in text  # one drive is not the verdict: where the verdict is
    assert f"{rodo_command()} view {out / 'ca-polar.rrd'}" in text  # a command that works from the user's shell

    report = json.loads((out / "demo.json").read_text())
    mc = report["prior_montecarlo"]
    assert mc["samples"] == 2000 and mc["dof"] == 18 and isinstance(mc["pass"], bool)
    lo, hi = mc["nees_bounds_95"]
    assert lo < 18 < hi and 0.9 * lo < mc["mean_nees"] < 1.1 * hi  # the prior's NEES is near its dimension
    assert set(report["runs"]) == {"ca-polar", "cv-cartesian"}

    seq = read_sequence(out / "city_seed0")
    assert len(seq.scans) == 14 and (out / "city_seed0" / "truth.npz").is_file()
    for model, d in (("ca-polar", 18), ("cv-cartesian", 12)):
        run = report["runs"][model]
        # a 1 s drive (about 3 m) has no KITTI segment of 100 m: undefined, as `rodo evaluate` says
        assert run["kitti_t_err_pct"] is None and run["ate_rmse_m"] < 0.05, (model, run)
        est = read_tum(out / model / "estimate.txt")
        assert np.array_equal(est.t, seq.groundtruth.t)
        with np.load(out / model / "states.npz") as z:
            assert z["P"].shape == (14, d, d)
        summary = json.loads((out / model / "summary.json").read_text())
        assert summary["model"] == model and summary["scans"] == 14
        evaluation = json.loads((out / model / "evaluation.json").read_text())
        assert evaluation["ate_rmse_m"] == pytest.approx(run["ate_rmse_m"])
    rrd = out / "ca-polar.rrd"
    assert rrd.is_file() and rrd.read_bytes()[:4] == b"RRF2"
    assert not (out / "figures").exists()  # --no-figures
