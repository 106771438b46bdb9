"""Output paths are checked before any work starts (exit code 2 naming the option and the path), outputs are
written atomically with the permissions open() gives (0666 less the umask, not mkstemp's 0600), temporary
files never outlive a failure, and unreadable campaign arrays are an error naming the file."""

import os
import stat

import numpy as np
import pytest

from rodo import scenarios
from rodo.estimator.errors import InputError
from rodo.sim.sequence import atomic_write_bytes
from rodo.validation.campaign import make_trials, npz_path, run_campaign, summarize_campaign
from tests.cli.helpers import fails
from tests.validation.test_campaign import MODELS, FakeTrial


@pytest.fixture
def umask():
    """Set a umask for the test and restore the previous one."""
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def _leftovers(directory) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.endswith((".tmp", ".probe"))]


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_sequence_files_respect_the_umask(tmp_path, umask, mask, mode):
    umask(mask)
    scenarios.simulate_to("city", 0, tmp_path, duration=0.3)
    for name in ("radar.csv", "sensor.toml", "groundtruth.txt"):
        assert _mode(tmp_path / name) == mode, name
    assert not _leftovers(tmp_path)


def test_run_outputs_respect_the_umask(seq, tmp_path, umask, capsys):
    from rodo.cli import main

    umask(0o022)
    assert main(["run", str(seq), "--model", "cv-cartesian", "--out", str(tmp_path / "o")]) == 0
    for name in ("estimate.txt", "states.npz", "summary.json"):
        assert _mode(tmp_path / "o" / name) == 0o644, name
    assert not _leftovers(tmp_path / "o")
    gt = seq / "groundtruth.txt"
    assert main(["evaluate", "--gt", str(gt), "--est", str(tmp_path / "o" / "estimate.txt"), "--json",
                 str(tmp_path / "ev.json")]) == 0
    assert _mode(tmp_path / "ev.json") == 0o644 and not _leftovers(tmp_path)


def test_atomic_write_removes_its_temporary_file_on_failure_and_follows_no_symlink(tmp_path, monkeypatch):
    target = tmp_path / "victim.txt"
    target.write_text("keep me\n")
    link = tmp_path / "out.txt"
    link.symlink_to(target)
    atomic_write_bytes(link, b"new\n")  # replaces the link itself, never writes through it
    assert target.read_text() == "keep me\n" and not link.is_symlink() and link.read_text() == "new\n"

    def fail(*_):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space"):
        atomic_write_bytes(tmp_path / "x.txt", b"data")
    assert not (tmp_path / "x.txt").exists() and not _leftovers(tmp_path)


def test_evaluate_json_path_is_checked_before_any_work(seq, tmp_path, capsys):
    gt = seq / "groundtruth.txt"
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    argv = ["evaluate", "--gt", gt, "--est", gt, "--json"]
    fails(capsys, argv + [tmp_path], "--json", "is a directory")
    fails(capsys, argv + [tmp_path / "missing" / "r.json"], "--json", "missing", "does not exist")
    fails(capsys, argv + [a_file / "r.json"], "--json", "is not a directory")
    fails(capsys, argv + ["/proc/r.json"], "--json", "/proc", "not writable")
    assert not _leftovers(tmp_path)


def test_rerun_path_is_checked_before_the_run(seq, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    bad = a_file / "sub" / "run.rrd"  # missing directories are created, but not under a file
    fails(capsys, ["run", seq, "--out", tmp_path / "o", "--rerun", bad], "--rerun", str(a_file), "not a directory")
    assert not (tmp_path / "o").exists()  # refused before the estimate was written
    fails(capsys, ["simulate", "city", "--duration", "0.3", "--out", tmp_path / "s", "--rerun", "/proc/x.rrd"],
           "--rerun", "not writable")
    assert not (tmp_path / "s").exists()


def test_campaign_out_that_is_a_file_or_unwritable(tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x\n")
    for cmd in (["montecarlo", "city", "--runs", "1"], ["table1", "--runs", "1", "--scenarios", "city"]):
        fails(capsys, cmd + ["--out", a_file], "--out", str(a_file), "not a directory")
        fails(capsys, cmd + ["--out", a_file / "sub"], "--out", "cannot create")
        fails(capsys, cmd + ["--out", "/proc/campaign"], "--out", "/proc/campaign")
    assert a_file.read_text() == "x\n"


def test_unreadable_trial_arrays_name_the_file(tmp_path):
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), make_trials(0, 2, MODELS), ex, tmp_path)
    p = npz_path(tmp_path, 1, MODELS[0])
    p.write_bytes(p.read_bytes()[:100])  # truncated
    with pytest.raises(InputError, match=f"{p}: unreadable trial arrays .*BadZipFile.*--resume"):
        summarize_campaign(tmp_path)
    np.savez(p, t=np.zeros(3))  # readable, but not a trial's arrays
    with pytest.raises(InputError, match=f"{p}: no nees, nees_dim array"):
        summarize_campaign(tmp_path)


def test_results_with_a_run_twice_or_a_word_for_a_number_name_the_line(tmp_path):
    """results.csv with a (trial, model) row twice (a summary would count it twice) or a metric that is not a
    number: an error naming the file, the line and the field, not a summary or a traceback."""
    import csv
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), make_trials(0, 2, MODELS), ex, tmp_path)
    path = tmp_path / "results.csv"
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    path.write_text(text + lines[1])
    with pytest.raises(InputError, match=rf"{path}: line {len(lines) + 1}: trial \d+, model \S+ again "
                                         r"\(first on line 2\)"):
        summarize_campaign(tmp_path)
    rows = list(csv.DictReader(text.splitlines()))
    rows[0]["ate_rmse_m"] = "abc"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with pytest.raises(InputError, match=rf"{path}: line 2: ate_rmse_m is 'abc', not a number"):
        summarize_campaign(tmp_path)


def test_a_missing_trial_file_is_redone_on_resume_not_summarised_over_fewer_runs(tmp_path):
    """An ok run whose trial arrays are gone (deleted) while the campaign's other runs have theirs: the summary
    refuses (it would average fewer runs than the table counts) and a resume runs it again."""
    from concurrent.futures import ProcessPoolExecutor

    from rodo.validation.campaign import remaining

    trials = make_trials(0, 2, MODELS)
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), trials, ex, tmp_path)
    p = npz_path(tmp_path, 1, MODELS[0])
    p.unlink()
    with pytest.raises(InputError, match=f"{p}: missing .*--resume"):
        summarize_campaign(tmp_path)
    assert remaining(trials, tmp_path) == 1
    with ProcessPoolExecutor(1) as ex:
        report = run_campaign(FakeTrial(), trials, ex, tmp_path, resume=True)
    assert report.ran == 1 and p.exists()
    assert summarize_campaign(tmp_path)["models"][MODELS[0]]["ok"] == 2


def test_campaign_files_are_written_atomically_without_leftovers(tmp_path, monkeypatch, umask):
    from concurrent.futures import ProcessPoolExecutor

    from rodo.validation.campaign_files import rewrite_results, save_arrays

    umask(0o022)
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), make_trials(0, 2, MODELS), ex, tmp_path, meta={"runs": 2})
    for p in (tmp_path / "results.csv", tmp_path / "campaign.json", npz_path(tmp_path, 0, MODELS[0])):
        assert _mode(p) == 0o644, p
    before = (tmp_path / "results.csv").read_bytes()

    def fail(*_):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space"):
        rewrite_results(tmp_path / "results.csv", [])
    with pytest.raises(OSError, match="No space"):
        save_arrays(npz_path(tmp_path, 5, MODELS[0]), {"t": np.zeros(2)})
    assert (tmp_path / "results.csv").read_bytes() == before  # the old file stands
    assert not _leftovers(tmp_path) and not _leftovers(tmp_path / "trials")


def test_an_output_never_overwrites_an_input_or_another_output(seq, tmp_path, capsys):
    """An output path that is one of the command's inputs (the sequence's files, through a link too) or another of
    its outputs (the run's summary) is refused before any work: exit 2 naming the option and the path, and every
    file of the sequence unchanged."""
    import shutil

    copy = tmp_path / "seq"
    shutil.copytree(seq, copy)
    before = {p.name: p.read_bytes() for p in copy.iterdir() if p.is_file()}
    gt, radar = copy / "groundtruth.txt", copy / "radar.csv"
    out = tmp_path / "o"
    fails(capsys, ["run", copy, "--out", out, "--rerun", out / "summary.json"], "--rerun", "summary.json", "overwrite")
    assert not out.exists()
    fails(capsys, ["run", copy, "--out", out, "--rerun", radar], "--rerun", str(radar), "overwrite")
    fails(capsys, ["ego-velocity", copy, "--out", radar], "--out", str(radar))
    odom = copy / "odom.csv"  # a converter's oracle odometry, no file rodo can write again (review 55)
    odom.write_bytes(b"t,x,y\n0.0,0.0,0.0\n")
    before[odom.name] = odom.read_bytes()
    fails(capsys, ["ego-velocity", copy, "--out", odom], "--out", str(odom))
    link = tmp_path / "link.csv"
    link.symlink_to(radar)
    fails(capsys, ["ego-velocity", copy, "--out", link], "--out", str(link), f"the same file as {radar}")
    fails(capsys, ["evaluate", "--gt", gt, "--est", gt, "--json", gt], "--json", str(gt))
    fails(capsys, ["calibrate", copy, "--no-consistency", "--out", copy / "sensor.toml"], "--out", "sensor.toml")
    fails(capsys, ["simulate", "city", "--duration", "0.3", "--out", copy, "--rerun", radar], "--rerun", "radar.csv")
    assert {p.name: p.read_bytes() for p in copy.iterdir() if p.is_file()} == before
    assert not out.exists() and not _leftovers(copy)


def test_a_rig_and_a_sequence_are_not_written_over_each_other(seq, tmp_path, capsys):
    """simulate or convert a sequence into a rig's directory, or a rig into a sequence's, is refused before the
    work (every reader refuses a directory that is both); a rig run does not write its merged ground truth over
    one of its radars' own."""
    from tests.sim.test_rig import Rig, _radar, write_rig

    rig = tmp_path / "rig"
    write_rig(rig, Rig(["a", "b"], [_radar(0.0, [0.0, 0.1, 0.2]), _radar(1.0, [0.05, 0.15])]))
    before = (rig / "a" / "groundtruth.txt").read_bytes()
    fails(capsys, ["simulate", "city", "--duration", "0.3", "--out", rig], "--out", "holds a rig", "rig.toml")
    fails(capsys, ["simulate", "city", "--duration", "0.3", "--rig", "front-corners", "--out", seq], "--out",
          "holds a single sequence", "radar.csv")
    fails(capsys, ["run", rig, "--out", rig / "a"], "--out", "groundtruth.txt")
    assert (rig / "a" / "groundtruth.txt").read_bytes() == before and not (rig / "radar.csv").exists()


def test_an_unwritable_output_directory_fails_before_the_work(seq, tmp_path, capsys):
    """A directory the command cannot write in (/proc, where even root cannot create a file) is refused before the
    work, for the commands that write a directory and for calibrate's config, not with a traceback after it."""
    for argv in (["run", seq, "--out", "/proc/rodo_run"], ["simulate", "city", "--duration", "0.3", "--out",
                                                            "/proc/rodo_sim"],
                 ["figures", "--quick", "--out", "/proc/rodo_figures"],
                 ["calibrate", seq, "--no-consistency", "--out", "/proc/rodo.toml"],
                 ["ego-velocity", seq, "--out", "/proc/rodo_ego.csv"]):
        fails(capsys, argv, "--out", "/proc", "not writable")


def test_an_unreadable_truth_file_is_an_error_naming_it_before_the_work(seq, tmp_path, capsys):
    """A truncated truth.npz, one whose states hold NaN, or one whose poses are not rigid: an error naming the file
    (and the array), from calibrate and from a run that records it, before the run writes anything."""
    import shutil

    copy = tmp_path / "seq"
    shutil.copytree(seq, copy)
    truth = copy / "truth.npz"
    whole = truth.read_bytes()
    truth.write_bytes(whole[:len(whole) // 3])
    fails(capsys, ["calibrate", copy, "--no-consistency", "--out", tmp_path / "c.toml"], str(truth), "not a readable")
    fails(capsys, ["run", copy, "--out", tmp_path / "o", "--rerun", tmp_path / "r.rrd"], str(truth), "not a readable")
    assert not (tmp_path / "o").exists()
    with np.load(seq / "truth.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["varpi"][3, 1] = np.nan
    np.savez(truth, **arrays)
    fails(capsys, ["calibrate", copy, "--no-consistency", "--out", tmp_path / "c.toml"], str(truth), "varpi", "NaN")
    fails(capsys, ["run", copy, "--out", tmp_path / "o", "--rerun", tmp_path / "r.rrd"], str(truth), "varpi")
    assert not (tmp_path / "o").exists()
    arrays["varpi"][3, 1] = 0.0
    arrays["T_vehicle_world"][5, :3, :3] *= 2.0  # not a rotation: calibrate would fit Qc to it
    np.savez(truth, **arrays)
    fails(capsys, ["calibrate", copy, "--no-consistency", "--out", tmp_path / "c.toml"], str(truth),
          "T_vehicle_world", "not a proper rotation")
