"""A campaign's failures: a trial or a model run that raises is a recorded error row, a dead worker or a full disk
stops the campaign without a row for what it did not finish (and --resume runs it), a torn results.csv row."""

from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import pytest

from rodo.estimator.errors import InputError
from rodo.validation.campaign import make_trials, read_results, run_campaign, summarize_campaign
from tests.validation.test_campaign import MODELS, FakeTrial


def test_failing_trial_is_recorded_and_does_not_stop_the_campaign(tmp_path):
    trials = make_trials(0, 5, MODELS)
    fn = FakeTrial(fail=frozenset({1}), model_fail=frozenset({(3, "cv-cartesian")}))
    with ProcessPoolExecutor(2) as ex:
        rep = run_campaign(fn, trials, ex, tmp_path)
    rows = {(int(r["trial"]), r["model"]): r for r in read_results(tmp_path / "results.csv")}
    assert len(rows) == 10
    for m in MODELS:
        assert rows[1, m]["status"] == "error"
        assert rows[1, m]["error"] == "ValueError: simulated failure in trial 1"
    assert rows[3, "cv-cartesian"]["status"] == "error" and "non-finite" in rows[3, "cv-cartesian"]["error"]
    assert rows[3, "ca-polar"]["status"] == "ok" and rows[3, "ca-polar"]["error"] == ""
    assert sum(r["status"] == "ok" for r in rep.rows) == 7
    s = summarize_campaign(tmp_path)
    assert s["models"]["cv-cartesian"]["errors"] == 2 and s["models"]["ca-polar"]["errors"] == 1


@dataclass(frozen=True)
class DyingTrial:
    """A worker process that dies (as by the OOM killer) in one trial."""

    die: int

    def __call__(self, trial):
        if trial.index == self.die:
            import os

            os._exit(1)
        return FakeTrial()(trial)


@dataclass(frozen=True)
class FullDiskTrial:
    """A trial that meets a full disk (or a quota) in its worker, as numba's cache save does on a full disk."""

    full: int
    code: int = 28

    def __call__(self, trial):
        if trial.index == self.full:
            raise OSError(self.code, "No space left on device" if self.code == 28 else "Disk quota exceeded")
        return FakeTrial()(trial)


@pytest.mark.parametrize("code", [28, 122])
def test_a_full_disk_in_a_worker_stops_the_campaign_and_resume_runs_the_trial(tmp_path, code):
    """A trial that met a full disk did not fail: the campaign stops with the OSError (the CLI's one line, exit 1),
    no error row records it, and --resume runs it once there is room. (It was an error row, exit 0, and a resume
    skipped it for ever: the review of session 56, finding 1.) Any other exception stays a recorded failure."""
    trials = make_trials(4, 6, MODELS)
    with pytest.raises(OSError) as raised:
        with ProcessPoolExecutor(1) as ex:
            run_campaign(FullDiskTrial(3, code), trials, ex, tmp_path)
    assert raised.value.errno == code
    rows = read_results(tmp_path / "results.csv")
    assert all(r["status"] == "ok" for r in rows) and 3 not in {int(r["trial"]) for r in rows}
    with ProcessPoolExecutor(2) as ex:
        run_campaign(FakeTrial(), trials, ex, tmp_path, resume=True)
    rows = read_results(tmp_path / "results.csv")
    assert len(rows) == 12 and all(r["status"] == "ok" for r in rows)


def test_dead_worker_stops_the_campaign_without_recording_unfinished_trials(tmp_path):
    from concurrent.futures.process import BrokenProcessPool

    trials = make_trials(4, 6, MODELS)
    with pytest.raises(BrokenProcessPool):
        with ProcessPoolExecutor(1) as ex:
            run_campaign(DyingTrial(3), trials, ex, tmp_path)
    rows = read_results(tmp_path / "results.csv")
    assert all(r["status"] == "ok" for r in rows) and {int(r["trial"]) for r in rows} <= {0, 1, 2}
    with ProcessPoolExecutor(2) as ex:
        run_campaign(FakeTrial(), trials, ex, tmp_path, resume=True)
    assert len(read_results(tmp_path / "results.csv")) == 12


def test_read_results_drops_only_a_torn_final_row(tmp_path):
    with ProcessPoolExecutor(1) as ex:
        run_campaign(FakeTrial(), make_trials(0, 2, MODELS[:1]), ex, tmp_path)
    path = tmp_path / "results.csv"
    good = path.read_text()
    last = good.splitlines()[-1]
    path.write_text(good + last.rstrip("\r"))  # all fields present (the error field is empty), no newline
    assert len(read_results(path)) == 2
    path.write_text(good.replace(",ok,", ",?,", 1))
    with pytest.raises(InputError, match="results.csv: line 2: malformed row"):
        read_results(path)


def test_a_model_run_that_meets_a_full_disk_raises_and_other_failures_are_recorded(monkeypatch):
    """ScenarioTrial records a model whose run raises as status=error, but not a full disk, a quota or a forbidden
    place (`estimator.errors.is_environment_error`): those propagate, so the campaign stops instead of keeping an
    error row that --resume would skip."""
    from rodo.validation import driver
    from rodo.validation.trial import ScenarioTrial

    trial = make_trials(4, 1, ("ca-polar",))[0]

    def raising(exc):
        def run(*args, **kwargs):
            raise exc
        return run

    monkeypatch.setattr(driver, "run_sequence", raising(OSError(122, "Disk quota exceeded")))
    with pytest.raises(OSError, match="quota"):
        ScenarioTrial("city", 0.3)(trial)
    monkeypatch.setattr(driver, "run_sequence", raising(OSError(5, "Input/output error")))
    [out] = ScenarioTrial("city", 0.3)(trial)
    assert out.error.startswith("OSError: [Errno 5] Input/output error")
