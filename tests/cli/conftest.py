"""Fixtures of the CLI tests."""

import pytest

from rodo import scenarios


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    """A 0.5 s city sequence (7 scans), one per test module (read, never written, by the tests)."""
    d = tmp_path_factory.mktemp("seq")
    scenarios.simulate_to("city", 0, d, duration=0.5)
    return d


@pytest.fixture(scope="module")
def cal_seq(tmp_path_factory):
    """A 2 s city sequence (27 scans) with truth.npz, for `rodo calibrate` (with and without the truth)."""
    d = tmp_path_factory.mktemp("cal") / "city"
    scenarios.simulate_to("city", 2, d, duration=2.0)
    return d
