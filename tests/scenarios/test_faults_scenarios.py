"""Faults as scenario options (Scenario.simulate(faults=), `rodo simulate --fault`): each does what it says,
off changes nothing, same seed same bytes, and the estimator stays finite through each."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from rodo import cli, scenarios
from rodo.commands import simulate as simulate_cmd
from rodo.estimator.config import OdometryConfig
from rodo.sim.faults import GHOST, Faults
from rodo.sim.objects import CLUTTER
from rodo.sim.sequence import read_sequence
from rodo.sim.simulate import load_truth
from rodo.validation.driver import run_sequence

from tests.fingerprint import fingerprint

FILES = ("radar.csv", "groundtruth.txt", "sensor.toml", "truth.npz")
# tests.fingerprint (floats to 1e-6, the same under OpenBLAS's SkylakeX, Zen and Haswell kernels), first 16 hex
# digits, of `simulate_to("city", 7, d, 2.0)`: the code before faults existed (commit 71cd697) gave the same bytes
# until the trajectory's checkpoint grid moved every pose by round-off (< 1e-11 m); since, the first commit with it;
# since city's version 3 (traffic clear of itself and of the parked cars), that commit's
CLEAN_CITY_7 = {"radar.csv": "ad0db3c9d69b03fe", "groundtruth.txt": "d1051c9943dc2d9e",
                "sensor.toml": "d9a5e56a10bebe25", "truth.npz": "f086089c333dfa75"}


def _hashes(d) -> dict:
    return {f: hashlib.sha256((d / f).read_bytes()).hexdigest()[:16] for f in FILES}


def _simulate(tmp_path, name, faults=None, seed=7, duration=2.0):
    out = tmp_path / name
    seq, truth = scenarios.simulate_to("city", seed, out, duration, faults=faults)
    return out, seq, truth


def test_faults_off_leave_the_output_bit_identical(tmp_path):
    """No faults, an all-off Faults() and clutter at the radar's own rate (20) all give the same bytes, and
    the output of the code before faults existed (to round-off: tests.fingerprint)."""
    clean = None
    for name, faults in (("none", None), ("off", Faults()), ("clutter20", Faults(clutter=20.0))):
        out, _, truth = _simulate(tmp_path, name, faults)
        clean = _hashes(out) if clean is None else clean
        assert _hashes(out) == clean, name
        assert {f: h[:16] for f, h in fingerprint(out).items()} == CLEAN_CITY_7, name
        assert "fault_dropped" not in truth


def test_clutter_and_ghost_counts_follow_their_rates(tmp_path):
    _, seq, truth = _simulate(tmp_path, "cg", Faults(clutter=60.0, ghosts=30.0), duration=3.0)
    K = len(truth["t"])
    labels = truth["det_label"]
    assert np.sum(labels == CLUTTER) / K == pytest.approx(60.0, abs=4 * np.sqrt(60.0 / K))
    ghosts = np.sum(labels == GHOST) / K  # ghosts beyond max_range are not reported: a few fewer
    assert 30.0 - 4 * np.sqrt(30.0 / K) - 1.0 < ghosts < 30.0 + 4 * np.sqrt(30.0 / K)
    assert sum(len(s.range) for s in seq.scans) == len(labels)


def test_dropped_scans_are_missing_from_radar_csv_and_kept_in_the_truth(tmp_path):
    out, _, truth = _simulate(tmp_path, "drop", Faults(dropped=0.4), duration=3.0)
    back = read_sequence(out)
    K = len(truth["t"])
    dropped = truth["fault_dropped"]
    assert 0 < dropped.sum() < K and len(back.groundtruth.t) == K == len(truth["T_vehicle_world"])
    assert {s.scan for s in back.scans} == set(np.flatnonzero(~dropped))
    assert np.all(np.diff(truth["scan_offsets"])[dropped] == 0)


def test_jitter_perturbs_the_recorded_times_only(tmp_path):
    """radar.csv and groundtruth.txt carry the recorded (jittered, increasing) times; truth.npz keeps the true
    t_k and the clean detections (the geometry is that of the true time)."""
    sigma = 0.008
    out, _, truth = _simulate(tmp_path, "jit", Faults(jitter=sigma), duration=4.0)
    _, _, clean = _simulate(tmp_path, "clean", None, duration=4.0)
    back = read_sequence(out)
    rec = truth["fault_t_recorded"]
    assert np.array_equal(truth["t"], clean["t"]) and np.array_equal(truth["det_true_polar"], clean["det_true_polar"])
    assert np.all(np.diff(rec) > 0) and np.allclose(back.groundtruth.t, rec, atol=1e-9)
    assert np.allclose([s.t for s in back.scans], rec[[s.scan for s in back.scans]], atol=1e-12)
    e = (rec - truth["t"])[1:]  # the first recorded time is clipped at 0
    assert 0.6 * sigma < np.std(e) < 1.4 * sigma and abs(np.mean(e)) < 4 * sigma / np.sqrt(len(e))


def test_outage_interval_is_empty_and_the_rest_untouched(tmp_path):
    _, seq, truth = _simulate(tmp_path, "out", Faults(outage=((0.5, 1.0),)), duration=2.0)
    _, _, clean = _simulate(tmp_path, "clean", None)
    t = truth["t"]
    counts, clean_counts = np.diff(truth["scan_offsets"]), np.diff(clean["scan_offsets"])
    inside = (t >= 0.5) & (t < 1.5)
    assert inside.sum() == 13 and np.all(counts[inside] == 0) and np.all(clean_counts[inside] > 0)
    assert np.array_equal(counts[~inside], clean_counts[~inside])
    assert all(len(s.range) == 0 for s in seq.scans if 0.5 <= s.t < 1.5)


def test_same_seed_same_bytes_and_faults_independent_of_the_clean_stream(tmp_path):
    f = Faults(dropped=0.3, jitter=0.005, ghosts=5.0)
    a, _, ta = _simulate(tmp_path, "a", f)
    b, _, _ = _simulate(tmp_path, "b", f)
    assert _hashes(a) == _hashes(b)
    _, _, clean = _simulate(tmp_path, "clean", None)
    real = ta["det_label"] != GHOST  # the clean detections of every kept scan, as the clean run drew them
    kept = ~ta["fault_dropped"][clean["det_scan"]]
    assert sorted(map(tuple, ta["det_true_polar"][real])) == sorted(map(tuple, clean["det_true_polar"][kept]))
    _, other = scenarios.get("city").simulate(8, 2.0, faults=f)  # another seed: other fault draws
    assert not np.array_equal(other["fault_t_recorded"], ta["fault_t_recorded"])


@pytest.mark.parametrize("value", ["clutter=nan", "clutter=-2", "ghosts=1e12", "dropped=1.5", "jitter=0.5",
                                   "outage=3", "outage=2:-1", "bogus=1"])
def test_cli_bad_fault_exits_2_naming_the_option(tmp_path, capsys, value):
    out = tmp_path / "x"
    argv = ["simulate", "city", "--duration", "1", "--out", str(out), "--fault", value]
    assert cli.main(argv, commands=[simulate_cmd]) == 2
    err = capsys.readouterr().err
    assert "--fault" in err and (value.split("=")[0] in err or "NAME" in err)
    assert not out.exists()


def test_cli_fault_flags_reach_the_simulation(tmp_path, capsys):
    out = tmp_path / "f"
    argv = ["simulate", "city", "--duration", "1.5", "--out", str(out), "--fault", "clutter=40",
            "--fault", "outage=0:0.5", "--fault", "dropped=0.2", "--fault", "outages=60:0.2"]
    assert cli.main(argv, commands=[simulate_cmd]) == 0
    printed = capsys.readouterr().out
    assert "faults: clutter 40/scan" in printed and "outages 60/min, 0.2 s each" in printed
    truth = load_truth(out)
    assert np.all(np.diff(truth["scan_offsets"])[truth["t"] < 0.5] == 0)
    assert "fault_dropped" in truth


STRONG = {"clutter": Faults(clutter=200.0), "ghosts": Faults(ghosts=100.0), "dropped": Faults(dropped=0.3),
          "jitter": Faults(jitter=0.01), "outage": Faults(outage=((2.0, 2.0),)),
          "outages": Faults(outages=(30.0, 1.0))}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(STRONG))
def test_estimator_stays_finite_through_each_fault(name):
    """ca-polar defaults on 8 s of city (seed 1, ~60 m) with each fault strong: every pose finite. Measured
    final position errors: clean 0.08 m, clutter 200/scan 0.50 m, ghosts 100/scan 0.12 m, dropped 30 % 0.08 m,
    jitter 10 ms 0.11 m, a 2 s outage 1.1 m, 1 s outages at 30 per minute (13 of 105 scans empty) 0.06 m; the
    bound for clutter, ghosts, jitter and outages is a generous 2 m."""
    seq, truth = scenarios.get("city").simulate(1, 8.0, faults=STRONG[name])
    result = run_sequence(seq, OdometryConfig.for_model("ca-polar"))
    assert len(result.estimates) == len(truth["t"])
    T = np.stack([e.T_world_vehicle for e in result.estimates])
    assert np.all(np.isfinite(T)) and all(np.all(np.isfinite(e.P)) for e in result.estimates)
    if name == "outages":
        assert sum(len(scan.range) == 0 for scan in seq.scans) > 0
    if name in ("clutter", "ghosts", "jitter", "outages"):
        T_true = np.linalg.inv(truth["T_vehicle_world"][-1])
        assert np.linalg.norm(T[-1, :3, 3] - T_true[:3, 3]) < 2.0


def test_montecarlo_takes_faults_into_every_trial(tmp_path, capsys):
    """`rodo montecarlo --fault` simulates each trial with the faults (saved in campaign.json); jitter and bad
    values are refused before anything is written."""
    import json

    from rodo.commands import montecarlo
    from rodo.validation.campaign import read_results

    base = ["montecarlo", "city", "--runs", "1", "--models", "ca-polar", "--jobs", "1", "--duration", "1.5"]
    rows = {}
    for name, extra in (("clean", []), ("faulty", ["--fault", "clutter=300", "--fault", "outage=0.5:0.5"])):
        assert cli.main(base + ["--out", str(tmp_path / name)] + extra, commands=[montecarlo]) == 0
        rows[name] = read_results(tmp_path / name / "results.csv")[0]
        assert rows[name]["status"] == "ok"
    meta = json.loads((tmp_path / "faulty" / "campaign.json").read_text())
    assert meta["faults"] == ["clutter=300", "outage=0.5:0.5"]
    assert "faults" not in json.loads((tmp_path / "clean" / "campaign.json").read_text())
    assert rows["clean"]["nis_mean"] != rows["faulty"]["nis_mean"]
    capsys.readouterr()
    assert cli.main(base + ["--out", str(tmp_path / "faulty"), "--resume"], commands=[montecarlo]) == 2
    assert "campaign.json" in capsys.readouterr().err  # resumed without the faults: refused
    for value, named in (("jitter=0.001", "jitter"), ("dropped=2", "dropped")):
        capsys.readouterr()
        assert cli.main(base + ["--out", str(tmp_path / value), "--fault", value], commands=[montecarlo]) == 2
        assert f"--fault {named}" in capsys.readouterr().err and not (tmp_path / value).exists()
