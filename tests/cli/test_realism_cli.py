"""`rodo realism PROFILE` and `rodo profiles`: the report runs on the real data (skipped with a message when
../shared/realdata is absent), writes its table, numbers and figure, and bad input exits 2 naming the problem.
The statistics' own pieces (KS distance, relative difference, pooling) are checked on synthetic data."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rodo.cli import main
from rodo.sim.sequence import RadarScan
from rodo.validation import realism
from tests.cli.helpers import fails


def test_profiles_lists_every_profile(capsys):
    from rodo.sim import profiles

    assert main(["profiles"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in profiles.names())


@pytest.mark.slow
def test_realism_runs_on_the_raflow_data(realdata_dir, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["realism", "lrr30f", "--realdata", str(realdata_dir), "--seeds", "0", "--duration", "3",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for name in ("points per scan", "range", "azimuth", "rcs", "static Doppler residual spread", "non-static",
                 "ghost rate"):
        assert name in text
    data = json.loads((out / "realism_lrr30f.json").read_text())
    rows = {r["statistic"]: r for r in data["rows"]}
    assert rows["points per scan (mean)"]["real"] == pytest.approx(327.4, abs=0.1)  # 104 RaFlow scans
    assert all(r["distance"] is None or r["distance"] >= 0 for r in data["rows"])
    assert (out / "realism_lrr30f.md").read_text().startswith("| statistic (lrr30f)")
    pytest.importorskip("matplotlib")
    assert (out / "realism_lrr30f.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_realism_runs_on_the_ti_data(realdata_dir, capsys):
    assert main(["realism", "iwr6843aop", "--realdata", str(realdata_dir), "--seeds", "0", "--duration", "20"]) == 0
    text = capsys.readouterr().out
    assert "| snr (dB) |" in text and "43.38" in text  # the rio demo's mean count per scan


@pytest.mark.slow
def test_realism_runs_on_the_radarscenes_data(realdata_dir, capsys):
    assert main(["realism", "corner2d", "--realdata", str(realdata_dir), "--seeds", "0", "--duration", "3"]) == 0
    text = capsys.readouterr().out
    assert "| rcs (dBsm) |" in text and "elevation" not in text.split("note:")[0]  # a 2D radar


@pytest.mark.parametrize("argv, needles", [
    (["realism", "nope"], ("unknown sensor profile 'nope'", "lrr30f")),
    (["realism", "generic"], ("no real data", "lrr30f, iwr6843aop, corner2d")),
    (["realism", "lrr30f", "--seeds", "a"], ("--seeds",)),
    (["realism", "lrr30f", "--seeds", "-1"], ("--seeds",)),
    (["realism", "lrr30f", "--duration", "0"], ("--duration",)),
    (["realism", "lrr30f", "--realdata", "/nonexistent/realdata"], ("--realdata", "not found")),
])
def test_realism_bad_input_exits_2(capsys, argv, needles):
    fails(capsys, argv, *needles)


def test_ks_distance_and_relative_difference():
    rng = np.random.default_rng(0)
    a = rng.normal(size=4000)
    assert realism.ks_distance(a, a) == 0.0
    assert realism.ks_distance(a, a + 100) == 1.0
    # N(0, 1) vs N(0.5, 1): sup |F - G| = 2 Phi(0.25) - 1 = 0.197; sampling error ~ 1.36 sqrt(2 / 4000) = 0.03
    assert realism.ks_distance(a, rng.normal(0.5, 1, 4000)) == pytest.approx(0.197, abs=0.04)
    assert realism.relative(12.0, 10.0) == pytest.approx(0.2)


def test_pooled_statistics_on_a_synthetic_static_scene():
    """A sensor at 5 m/s through static points with 0.05 m/s Doppler noise and 10 % outliers: the spread is the
    noise (1.4826 MAD, 15 % at 2,000 residuals) and the non-static fraction about 10 %."""
    rng = np.random.default_rng(1)
    v = np.array([5.0, 0.0, 0.0])
    scans = []
    for k in range(20):
        n = 100
        az, el = rng.uniform(-1, 1, n), rng.uniform(-0.2, 0.2, n)
        u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        vr = -u @ v + rng.normal(0, 0.05, n)
        vr[:10] += rng.choice([-1, 1], 10) * rng.uniform(1, 5, 10)
        scans.append(RadarScan(k, 0.1 * k, rng.uniform(1, 50, n), az, el, vr, extra={"rcs": rng.normal(0, 5, n)}))
    p = realism.pooled(scans, "rcs", crop=40.0)
    assert p.counts.mean() == pytest.approx(100 * 39 / 49, rel=0.1)  # the crop at 40 m of U(1, 50) ranges
    assert realism.spread(p.residual) == pytest.approx(0.05, rel=0.15)
    assert p.nonstatic == pytest.approx(0.1, abs=0.03)
    assert np.all(p.range <= 40.0) and p.value.size == p.range.size
