"""Tests that hold under load: nothing in the suite may depend on how fast the machine is.

distributed warns (`distributed.utils.warn_on_duration`, a wall-clock check) when creating a worker's scratch
directory takes over a second, which happens when other work loads the machine (or another test session holds
the shared dask-scratch-space locks). The suite turns warnings into errors, so on a loaded machine the warning
failed the dask campaign tests (`test_resume_after_interruption_loses_nothing_and_duplicates_nothing[True]`:
the cluster did not start, and its half-built cluster's ResourceWarning errored the teardown). tests/conftest.py
ignores exactly that warning. Here the check is made to fire every time, as under load, deterministically.
"""

import contextlib
import warnings

import pytest

distributed = pytest.importorskip("distributed", reason="needs the dask extra: pip install 'rodo[dask]'")
import distributed.core  # noqa: E402

from rodo.validation.campaign import make_executor, make_trials, read_results, remaining, run_campaign
from tests.validation.test_campaign import MODELS, FakeTrial, InterruptAfter


@contextlib.contextmanager
def always_slow(duration, msg):
    """distributed's warn_on_duration as on a loaded machine: the operation always took too long."""
    yield
    warnings.warn(msg.format(duration=99.0), stacklevel=2)


def test_a_slow_scratch_directory_does_not_fail_a_dask_campaign(tmp_path, monkeypatch):
    monkeypatch.setattr(distributed.core, "warn_on_duration", always_slow)
    trials = make_trials(11, 6, MODELS)
    with pytest.raises(KeyboardInterrupt):
        with make_executor(2, "local", processes=False) as ex:
            run_campaign(FakeTrial(), trials, ex, tmp_path, progress=InterruptAfter(3), meta={"seed": 11})
    assert len(read_results(tmp_path / "results.csv")) == 4  # interrupted after the second trial's rows
    with make_executor(2, "local", processes=False) as ex:
        rep = run_campaign(FakeTrial(), trials, ex, tmp_path, resume=True, meta={"seed": 11})
    assert rep.ran == 8 and remaining(trials, tmp_path) == 0


def test_the_hypothesis_profiles_never_fail_on_time():
    from hypothesis import HealthCheck, settings

    for name in ("dev", "ci", "nightly"):
        profile = settings.get_profile(name)
        assert profile.deadline is None and HealthCheck.too_slow in profile.suppress_health_check, name
