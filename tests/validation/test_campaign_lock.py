"""Campaign directories: one writer at a time (a lock held by another process refuses montecarlo, table1 and
run_campaign, fresh or resumed), released on exit, error or interruption; resume extends a campaign to more
runs exactly as a fresh one, refuses to shrink it, and names campaign.json when it is missing or corrupt."""

import json
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from rodo.estimator.errors import InputError
from rodo.validation.campaign import make_trials, read_results, run_campaign, summarize_campaign
from rodo.validation.campaign_dir import LOCK_NAME, campaign_lock
from tests.validation.test_campaign import MODELS, FakeTrial, InterruptAfter

HOLDER = """
import sys
from rodo.validation.campaign_dir import campaign_lock
with campaign_lock(sys.argv[1]):
    print("locked", flush=True)
    sys.stdin.read()  # hold the lock until the test closes our stdin
"""

PROBE = """
import fcntl, os, sys
fd = os.open(os.path.join(sys.argv[1], sys.argv[2]), os.O_RDWR | os.O_CREAT)
try:
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
except BlockingIOError:
    print("held")
else:
    print("free")
"""


class Holder:
    """Another process that holds a directory's campaign lock until close() (synchronised by pipes, no sleep)."""

    def __init__(self, directory: Path):
        self.proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(directory)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        assert self.proc.stdout.readline().strip() == "locked"

    def close(self) -> None:
        self.proc.stdin.close()
        assert self.proc.wait() == 0
        self.proc.stdout.close()


def lock_state(directory: Path) -> str:
    """'held' or 'free', as seen by a fresh process trying the lock without waiting."""
    out = subprocess.run([sys.executable, "-c", PROBE, str(directory), LOCK_NAME], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip()


def test_second_writer_is_refused_while_the_first_runs(tmp_path, capsys):
    from rodo.cli import main
    from rodo.commands import montecarlo, table1

    out = tmp_path / "city"
    holder = Holder(out)
    try:
        for resume in (False, True):
            with pytest.raises(InputError, match=f"{out} is in use by another campaign .*pid"):
                with ProcessPoolExecutor(1) as ex:
                    run_campaign(FakeTrial(), make_trials(0, 2, MODELS), ex, out, resume=resume)
        for extra in ([], ["--resume"]):
            argv = ["montecarlo", "city", "--runs", "1", "--duration", "1", "--jobs", "1", "--out", str(out)]
            assert main(argv + extra, commands=[montecarlo]) == 2
            err = capsys.readouterr().err
            assert f"--out: {out} is in use by another campaign" in err and "choose another directory" in err
        # table1 locks DIR and every DIR/<scenario>: a campaign running in DIR/city keeps it out too
        for extra in ([], ["--resume"]):
            assert main(["table1", "--runs", "1", "--scenarios", "city", "--out", str(tmp_path)] + extra,
                        commands=[table1]) == 2
            assert f"{out} is in use by another campaign" in capsys.readouterr().err
        assert not (out / "results.csv").exists() and not (out / "campaign.json").exists()
    finally:
        holder.close()
    assert lock_state(out) == "free"  # the holder's exit released it
    with ProcessPoolExecutor(1) as ex:
        rep = run_campaign(FakeTrial(), make_trials(0, 2, MODELS), ex, out)
    assert rep.ran == 4


def test_lock_is_held_during_the_run_and_released_on_interruption(tmp_path):
    seen = []

    class Probe(InterruptAfter):
        def update(self, k=1):
            seen.append(lock_state(tmp_path))
            super().update(k)

    with pytest.raises(KeyboardInterrupt):
        with ProcessPoolExecutor(1) as ex:
            run_campaign(FakeTrial(), make_trials(1, 4, MODELS), ex, tmp_path, progress=Probe(3))
    assert seen == ["held", "held"]
    assert lock_state(tmp_path) == "free"
    with ProcessPoolExecutor(1) as ex:  # workers forked while the lock was held do not keep it
        run_campaign(FakeTrial(), make_trials(1, 4, MODELS), ex, tmp_path, resume=True)
        assert lock_state(tmp_path) == "free"
    with pytest.raises(InputError):  # an error inside the locked region releases it too
        with campaign_lock(tmp_path):
            raise InputError("boom")
    assert lock_state(tmp_path) == "free"


def test_lock_is_reentrant_within_one_process_and_refuses_a_file(tmp_path):
    with campaign_lock(tmp_path):
        with campaign_lock(tmp_path):  # montecarlo holds it and run_campaign takes it again
            assert lock_state(tmp_path) == "held"
        assert lock_state(tmp_path) == "held"  # the inner exit did not release the outer hold
    assert lock_state(tmp_path) == "free"
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InputError, match=f"--out: {f} exists and is not a directory"):
        with campaign_lock(f):
            pass


def _campaign(out: Path, runs: int, resume: bool = False, seed: int = 5):
    with ProcessPoolExecutor(2) as ex:
        return run_campaign(FakeTrial(fail=frozenset({2})), make_trials(seed, runs, MODELS), ex, out, resume=resume,
                            meta={"scenario": "fake", "runs": runs, "seed": seed})


def test_extended_resume_equals_a_fresh_campaign(tmp_path):
    _campaign(tmp_path / "grown", 3)
    rep = _campaign(tmp_path / "grown", 7, resume=True)
    assert rep.skipped == 6 and rep.ran == 8
    _campaign(tmp_path / "fresh", 7)
    grown, fresh = (read_results(tmp_path / d / "results.csv") for d in ("grown", "fresh"))
    key = lambda r: (int(r["trial"]), r["model"])  # noqa: E731
    assert sorted(grown, key=key) == sorted(fresh, key=key)  # every column: seeds, metrics, errors
    assert summarize_campaign(tmp_path / "grown") == summarize_campaign(tmp_path / "fresh")  # bit for bit
    assert json.loads((tmp_path / "grown" / "campaign.json").read_text())["runs"] == 7
    assert _campaign(tmp_path / "grown", 7, resume=True).ran == 0


def test_resume_refuses_to_shrink_or_to_guess_the_campaign(tmp_path):
    _campaign(tmp_path, 4)
    with pytest.raises(InputError, match=r"--runs: 3 is fewer than the 4 runs .* pass --runs 4, or more"):
        _campaign(tmp_path, 3, resume=True)
    meta = tmp_path / "campaign.json"
    text = meta.read_text()
    meta.write_text(text[:-5])
    with pytest.raises(InputError, match=f"{meta}: line .* not valid JSON .* another directory"):
        _campaign(tmp_path, 4, resume=True)
    meta.write_text("[1, 2]")
    with pytest.raises(InputError, match=f"{meta}: expected a JSON object"):
        _campaign(tmp_path, 4, resume=True)
    meta.unlink()
    with pytest.raises(InputError, match=f"{meta} is missing, so nothing says which campaign .* restore it"):
        _campaign(tmp_path, 4, resume=True)
    meta.write_text(text)
    assert _campaign(tmp_path, 4, resume=True).ran == 0
    with pytest.raises(InputError, match="different campaign .* seed"):
        _campaign(tmp_path, 4, resume=True, seed=6)
    # without campaign.json (the API without meta), the rows' seeds still tell another campaign apart
    with pytest.raises(InputError, match=r"results.csv: line 2: trial \d was run with seed \d+, but .* seed"):
        with ProcessPoolExecutor(1) as ex:
            run_campaign(FakeTrial(), make_trials(6, 4, MODELS), ex, tmp_path, resume=True)


def test_cli_resume_with_a_corrupt_campaign_json_exits_2(tmp_path, capsys):
    from rodo.cli import main
    from rodo.commands import montecarlo

    _campaign(tmp_path, 1)
    (tmp_path / "campaign.json").write_text("{not json")
    argv = ["montecarlo", "city", "--runs", "1", "--jobs", "1", "--out", str(tmp_path), "--resume"]
    assert main(argv, commands=[montecarlo]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'campaign.json'}: line 1 column 2: not valid JSON" in err and "Traceback" not in err


TIMING = {"ms_per_scan", "wall_s"}  # measured, so different in any two runs


def _without_timing(summary: dict) -> dict:
    models = {m: {**e, "metrics": {k: v for k, v in e["metrics"].items() if k not in TIMING}}
              for m, e in summary["models"].items()}
    comparisons = [c for c in summary["comparisons"] if c.get("metric") not in TIMING]
    return {**summary, "models": models, "comparisons": comparisons}


@pytest.mark.slow
def test_cli_resume_with_more_runs_equals_a_fresh_campaign(tmp_path, capsys):
    from rodo.cli import main
    from rodo.commands import montecarlo

    def argv(out, runs):
        return ["montecarlo", "yaw_accel", "--runs", str(runs), "--duration", "1.0", "--jobs", "1", "--seed", "3",
                "--out", str(out)]

    assert main(argv(tmp_path / "grown", 1), commands=[montecarlo]) == 0
    assert main(argv(tmp_path / "grown", 2) + ["--resume"], commands=[montecarlo]) == 0
    assert "ran 2 (trial, model) runs, skipped 2 already done" in capsys.readouterr().out
    assert main(argv(tmp_path / "grown", 1) + ["--resume"], commands=[montecarlo]) == 2
    assert "--runs: 1 is fewer than the 2 runs" in capsys.readouterr().err
    assert main(argv(tmp_path / "fresh", 2), commands=[montecarlo]) == 0
    grown, fresh = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("grown", "fresh"))
    assert grown["trials"] == 2 and _without_timing(grown) == _without_timing(fresh)
    rows = {d: {(r["trial"], r["model"]): r for r in read_results(tmp_path / d / "results.csv")}
            for d in ("grown", "fresh")}
    assert rows["grown"].keys() == rows["fresh"].keys()
    for key, r in rows["grown"].items():  # every estimate and metric bit for bit, the timings aside
        assert {k: v for k, v in r.items() if k not in TIMING} == \
            {k: v for k, v in rows["fresh"][key].items() if k not in TIMING}


def test_resume_reruns_a_trial_whose_arrays_are_unreadable(tmp_path):
    from rodo.validation.campaign import npz_path, remaining

    _campaign(tmp_path / "fresh", 3)
    _campaign(tmp_path, 3)
    p = npz_path(tmp_path, 1, MODELS[1])
    p.write_bytes(p.read_bytes()[:50])  # truncated, as by a disk full or a careless copy
    with pytest.raises(InputError, match=rf"{p}: unreadable trial arrays .*\(--resume\) to run that trial again"):
        summarize_campaign(tmp_path)
    assert remaining(make_trials(5, 3, MODELS), tmp_path) == 1
    rep = _campaign(tmp_path, 3, resume=True)
    assert rep.ran == 1 and rep.skipped == 5
    assert p.read_bytes() == npz_path(tmp_path / "fresh", 1, MODELS[1]).read_bytes()
    assert summarize_campaign(tmp_path) == summarize_campaign(tmp_path / "fresh")
