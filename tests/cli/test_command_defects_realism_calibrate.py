"""`rodo realism` on a simulation too short to move: the Doppler statistics are marked not computable (n/a in the
table, null in strict JSON, a note), with no numpy warning; `rodo calibrate` on a sequence without static
detections: one error naming the sequence directory, no warning (warnings are errors in this test suite), no
output. Sizing: a 2 s city simulation with 99 % of its scans dropped, synthetic scans, and (with the real data)
a 2 s realism run; about 10 s."""

import json

import numpy as np
import pytest

from rodo.cli import main
from rodo.commands import realism as realism_cmd
from rodo.sim.sequence import RadarScan
from rodo.validation import calibrate_sensor as cs
from rodo.validation import realism
from tests.cli.helpers import fails

DOPPLER_ROWS = ("static Doppler residual spread (m/s)", "non-static fraction")


def _strict(text: str):
    """json.loads refusing NaN and Infinity (which Python's json writes by default and other parsers refuse)."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def _scans(speed: float, n_scans: int = 12, seed: int = 0) -> list:
    """Scans of static points seen by a sensor moving at `speed` m/s along x (rcs column)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_scans):
        n = 60
        az, el = rng.uniform(-1, 1, n), rng.uniform(-0.2, 0.2, n)
        u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        vr = -u @ np.array([speed, 0.0, 0.0]) + rng.normal(0, 0.05, n)
        out.append(RadarScan(k, 0.1 * k, rng.uniform(1, 50, n), az, el, vr, extra={"rcs": rng.normal(0, 5, n)}))
    return out


def test_a_side_without_moving_scans_has_no_doppler_statistics():
    still, moving = realism.pooled(_scans(0.0), "rcs", None), realism.pooled(_scans(5.0), "rcs", None)
    assert still.moving_scans == 0 and np.isnan(still.nonstatic) and still.residual.size == 0
    assert moving.moving_scans == 12 and 0 <= moving.nonstatic < 0.1
    rows = {r.name: r for r in realism.compare(still, moving, "rcs", planar=False)}
    for name in DOPPLER_ROWS:
        assert np.isnan(rows[name].sim) and rows[name].distance is None and rows[name].ok is None
        assert np.isfinite(rows[name].real)
    assert rows["range (m)"].distance is not None and rows["range (m)"].ok is not None  # the others compared
    notes = realism.not_computable(still, moving)
    assert len(notes) == 1 and "not computable for the simulation" in notes[0]
    report = realism.Report("generic", list(rows.values()), still, moving, notes)
    data = _strict(realism_cmd.report_json("generic", report))
    by_name = {r["statistic"]: r for r in data["rows"]}
    for name in DOPPLER_ROWS:
        assert by_name[name]["sim"] is None and by_name[name]["distance"] is None and by_name[name]["ok"] is None
    table = realism.format_table(report)
    assert "| static Doppler residual spread (m/s) | n/a |" in table and "nan" not in table


@pytest.mark.slow
def test_realism_of_a_short_walk_writes_strict_json(realdata_dir, tmp_path, capsys):
    """iwr6843aop's walk starts at 13.7 s: 2 s simulated never move. Exit 0, the Doppler rows null, a note."""
    out = tmp_path / "real"
    assert main(["realism", "iwr6843aop", "--realdata", str(realdata_dir), "--seeds", "0", "--duration", "2",
                 "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert cap.err == "", cap.err
    assert "not computable for the simulation" in cap.out and "nan" not in cap.out.lower().replace("n/a", "")
    data = _strict((out / "realism_iwr6843aop.json").read_text())
    rows = {r["statistic"]: r for r in data["rows"]}
    for name in DOPPLER_ROWS:
        assert rows[name]["sim"] is None and rows[name]["distance"] is None and rows[name]["ok"] is None
        assert rows[name]["real"] > 0
    assert rows["points per scan (mean)"]["distance"] is not None
    assert any("not computable" in n for n in data["notes"])


@pytest.fixture(scope="module")
def dropped(tmp_path_factory):
    d = tmp_path_factory.mktemp("dropped") / "dropped"
    assert main(["simulate", "city", "--seed", "1", "--duration", "2", "--fault", "dropped=0.99", "--out",
                 str(d)]) == 0
    return d


def test_calibrate_without_static_detections_names_the_sequence(dropped, tmp_path, capsys):
    out = tmp_path / "d.toml"
    fails(capsys, ["calibrate", dropped, "--out", out], f"error: {dropped}: measurement noise: need >= 12 "
          "static detections with truth", "got 0")
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_the_noise_fits_refuse_empty_residuals_before_any_mean():
    empty = np.zeros((0, 4))
    with pytest.raises(cs.InputError, match="need >= 12 static detections with truth"):
        cs.sigma_scale(empty, [0.1, 0.01, 0.01, 0.1])
    with pytest.raises(cs.InputError, match="need >= 12 static detections with truth.*got 11"):
        cs.channel_noise(np.ones((11, 4)), np.ones(11))
    with pytest.raises(cs.InputError, match="need >= 1 static detection, got 0"):
        cs.cartesian_sigma(empty, np.zeros(0))
    assert cs.cartesian_sigma(np.ones((1, 4)), np.ones(1)) == pytest.approx(1.0)  # one is enough there
