"""Bad input of the classes of issue 17 not covered elsewhere: converter options that were accepted silently
(`--t-max nan` kept everything, `--rate 1e-300`) and a campaign whose worker process dies (a clear message and
the way to resume, not a BrokenProcessPool traceback)."""

import pytest

from rodo.cli import main
from rodo.validation.campaign import read_results
from tests.cli.helpers import fails
from tests.validation.test_campaign_failures import DyingTrial


@pytest.mark.parametrize("fmt, extra, needle", [
    ("radarscenes", ["--t-max", "nan"], "--t-max"),
    ("radarscenes", ["--t-max", "-1"], "--t-max"),
    ("radarscenes", ["--t-max", "inf"], "--t-max"),
    ("vod", ["--rate", "1e-300"], "--rate"),
    ("vod", ["--rate", "inf"], "--rate"),
    ("vod", ["--rate", "nan"], "--rate"),
])
def test_converter_options_out_of_range(tmp_path, capsys, fmt, extra, needle):
    fails(capsys, ["convert", fmt, tmp_path, "--out", tmp_path / "c", *extra], needle)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("command", ["montecarlo", "table1"])
def test_a_dead_worker_is_reported_with_the_way_to_resume(tmp_path, capsys, monkeypatch, command):
    from rodo.commands import montecarlo, table1

    dying = lambda *a, **k: DyingTrial(1)  # noqa: E731 - trial 1's worker process exits, as if killed
    monkeypatch.setattr(montecarlo, "ScenarioTrial", dying)
    monkeypatch.setattr(table1, "Table1Trial", dying)
    out = tmp_path / "c"
    argv = ["montecarlo", "city"] if command == "montecarlo" else ["table1", "--scenarios", "city"]
    rc = main(argv + ["--runs", "3", "--jobs", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith(f"rodo {command}: error: a worker process died (BrokenProcessPool") and "--resume" in err
    csv = out / "results.csv" if command == "montecarlo" else out / "city" / "results.csv"
    rows = read_results(csv)
    assert {int(r["trial"]) for r in rows} <= {0} and all(r["status"] == "ok" for r in rows)


def _forge(cache, **changes):
    """Rewrite the cache's columns (keeping its signature), as a damaged or forged cache."""
    import numpy as np

    with np.load(cache, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    names = [str(n) for n in arrays["names"]]
    for name, fn in changes.items():
        key = f"col{names.index(name)}"
        arrays[key] = fn(arrays[key])
    np.savez(cache, **arrays)


def test_radar_cache_is_verified_against_the_whole_file_and_revalidated(tmp_path):
    import os

    import numpy as np

    from rodo import scenarios
    from rodo.sim.sequence import cache_path, read_sequence

    scenarios.simulate_to("city", 0, tmp_path, duration=0.5)
    csv = tmp_path / "radar.csv"
    ref = read_sequence(tmp_path)  # writes the cache
    cache = cache_path(csv)
    # an edit in the middle of the file, same size, old mtime restored: the content hash notices it
    st = os.stat(csv)
    text = csv.read_text()
    lines = text.split("\n")
    mid = len(lines) // 2
    fields = lines[mid].split(",")
    fields[2] = fields[2][:-1] + ("1" if fields[2][-1] != "1" else "2")  # the range, one digit changed
    lines[mid] = ",".join(fields)
    edited = "\n".join(lines)
    assert len(edited) == len(text) and st.st_size > 4096
    csv.write_text(edited)
    os.utime(csv, ns=(st.st_atime_ns, st.st_mtime_ns))
    got = np.concatenate([s.range for s in read_sequence(tmp_path).scans])
    want = np.concatenate([s.range for s in ref.scans])
    assert np.sum(got != want) == 1 and got[mid - 1] == float(fields[2])
    # a cache with the right signature but values the reader would refuse is not used: the CSV is parsed
    _forge(cache, range=lambda r: -r)
    assert np.array_equal(np.concatenate([s.range for s in read_sequence(tmp_path).scans]), got)
    _forge(cache, scan=lambda s: s.astype(np.float64))
    assert np.array_equal(np.concatenate([s.range for s in read_sequence(tmp_path).scans]), got)


def test_view_refuses_a_file_that_is_not_a_recording(tmp_path, capsys):
    for name, data in (("text.rrd", b"hello\n"), ("empty.rrd", b""), ("states.npz", b"PK\x03\x04rest")):
        (tmp_path / name).write_bytes(data)
        fails(capsys, ["view", tmp_path / name], str(tmp_path / name), "not a Rerun recording")


@pytest.mark.parametrize("key, value", [("radar_frame_ms", ".inf"), ("radar_frame_ms", ".NaN"),
                                        ("radar_frame_ms", "-1"), ("l_b_r_y", "-.inf")])
def test_ti_calibration_special_floats_are_named_not_missing(tmp_path, key, value):
    import re

    import numpy as np

    from rodo.estimator.errors import InputError
    from rodo.sim.convert import ti_mmwave
    from tests.sim.test_convert import CALIB, _write_ti

    calib = re.sub(rf"^{key}: .*$", f"{key}: {value}", CALIB, flags=re.M)
    assert calib != CALIB
    _write_ti(tmp_path, np.random.default_rng(0), calib=calib)
    with pytest.raises(InputError, match=rf"line \d+, field '{key}': must be a finite number"):
        ti_mmwave.convert(tmp_path)


def test_evaluate_says_how_many_scans_its_nees_skipped(tmp_path, capsys):
    import numpy as np

    from rodo import scenarios

    seq = tmp_path / "seq"
    scenarios.simulate_to("city", 0, seq, duration=0.5)
    assert main(["run", str(seq), "--model", "cv-cartesian", "--out", str(tmp_path / "o")]) == 0
    with np.load(tmp_path / "o" / "states.npz", allow_pickle=False) as z:
        states = dict(z)
    states["P"][2, 0, 0] = np.nan  # one scan's covariance broken
    np.savez(tmp_path / "bad.npz", **states)
    argv = ["evaluate", "--gt", str(seq / "groundtruth.txt"), "--est", str(tmp_path / "o" / "estimate.txt"),
            "--truth", str(seq / "truth.npz"), "--states"]
    capsys.readouterr()
    assert main(argv + [str(tmp_path / "o" / "states.npz")]) == 0
    n = len(states["t"])
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("NEES (d="))
    assert line.endswith(f"(over {n} of {n} scans)"), line
    assert main(argv + [str(tmp_path / "bad.npz")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("NEES (d="))
    assert line.endswith(f"(over {n - 1} of {n} scans; 1 skipped: NEES not finite (NaN or inf in P or the state))")


def test_run_warns_about_degenerate_input(tmp_path, capsys):
    from rodo import scenarios

    seq = tmp_path / "seq"
    scenarios.simulate_to("city", 0, seq, duration=0.5)
    assert main(["run", str(seq), "--out", str(tmp_path / "good")]) == 0
    assert "warning" not in capsys.readouterr().err
    lines = (seq / "radar.csv").read_text().splitlines()
    col = lines[0].split(",").index("range")
    zeroed = [lines[0]] + [",".join(f if i != col else "0.0" for i, f in enumerate(x.split(","))) for x in lines[1:]]
    (seq / "radar.csv").write_text("\n".join(zeroed) + "\n")
    assert main(["run", str(seq), "--out", str(tmp_path / "zero")]) == 0  # it runs, and says what is wrong
    err = capsys.readouterr().err
    assert "rodo run: warning: every detection in radar.csv has range 0 m" in err
    assert "associated no detection" in err and (tmp_path / "zero" / "estimate.txt").exists()
