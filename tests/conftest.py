"""Test-suite configuration: hypothesis profiles and the real-data location."""

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# no profile may fail on time (a loaded machine): no deadline, and the too_slow health check off
settings.register_profile("dev", max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "ci",
    max_examples=25,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("nightly", max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))

# distributed warns when creating a worker's scratch directory takes over 1 s of wall-clock time, as on a loaded
# machine; with warnings as errors the dask cluster then failed to start (tests/validation/test_under_load.py)
SLOW_SCRATCH_WARNING = "ignore:Creating scratch directories is taking a surprisingly long time:UserWarning"


def pytest_configure(config):
    config.addinivalue_line("filterwarnings", SLOW_SCRATCH_WARNING)


REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"


@pytest.fixture(scope="session")
def realdata_dir() -> Path:
    """../shared/realdata, or skip the test with a message saying where it was looked for."""
    if not REALDATA.is_dir():
        pytest.skip(f"real radar data not found at {REALDATA} (see docs/realdata.md); skipping")
    return REALDATA
