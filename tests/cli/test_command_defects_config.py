"""Huge finite config values: every key set to 1e200 is either refused when the config is read (naming the key and
its bound) or runs cleanly, and every noise sigma and variance has an upper bound at which a run is still finite.
Before the bounds, `[noise] cartesian_sigma = 1e200` crashed `rodo run` with an OverflowError.

Sizing: the 0.5 s `seq` fixture (7 scans), run about 150 times in all (all four models); about 10 s.
"""

import math

import numpy as np
import pytest

from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.config_rules import RULES
from rodo.estimator.errors import InputError
from rodo.sim.sequence import read_sequence
from rodo.validation.driver import run_sequence
from tests.cli.helpers import fails

BASE = OdometryConfig()
# named after a sigma but thresholds compared with one (never squared): 1e200 means "always", and runs
THRESHOLDS = {"association.ransac_above_sigma", "solver.step_sigma_tolerance"}


def _default(name: str):
    section, _, key = name.rpartition(".")
    return getattr(getattr(BASE, section), key) if section else getattr(BASE, key)


def _setting(name: str, value) -> dict:
    """{section: {key: value}} (every element of a list key set to value) for OdometryConfig.from_dict."""
    default = _default(name)
    if isinstance(default, tuple):
        value = [value] * len(default)
    section, _, key = name.rpartition(".")
    return {section: {key: value}} if section else {key: value}


def _is_int(name: str) -> bool:
    d = _default(name)
    return isinstance(d, int) and not isinstance(d, bool)


def _runs_cleanly(seq, setting: dict) -> None:
    """Every model runs the sequence with this setting to finite poses and covariances (warnings are errors in
    this test suite: an overflow warning fails too)."""
    for model in MODELS:
        res = run_sequence(seq, OdometryConfig.from_dict({**setting, "model": model}))
        assert np.isfinite(res.trajectory().T_world_vehicle).all(), (setting, model)
        assert np.isfinite(res.state_arrays()["P"]).all(), (setting, model)


def test_every_key_at_1e200_is_refused_naming_it_or_runs_cleanly(seq):
    sequence = read_sequence(seq)
    accepted = []
    for name in RULES:
        setting = _setting(name, 10**200 if _is_int(name) else 1e200)
        try:
            OdometryConfig.from_dict(setting, source="c.toml")
        except InputError as exc:
            section, _, key = name.rpartition(".")
            msg = str(exc)
            assert msg.startswith("c.toml: ") and "\n" not in msg, msg
            assert (f"[{section}] {key}" in msg or name in msg) if section else key in msg, msg
            continue
        accepted.append(name)
        _runs_cleanly(sequence, setting)
    squared = [n for n in accepted if ("sigma" in n or "variance" in n or "velocity_lag_per" in n)
               and n not in THRESHOLDS]
    assert not squared, f"sigmas and variances without an upper bound: {squared}"
    assert len(accepted) < len(RULES) / 2  # most keys have a bound


@pytest.mark.parametrize("name", [n for n in RULES if not _is_int(n) and math.isfinite(RULES[n].hi)
                                  and RULES[n].hi >= 1e3])
def test_a_sigma_at_its_upper_bound_still_runs(seq, name):
    """The bounds are where a run still works (checked at the bound itself and, for the signed lag terms, at the
    lower one), not merely where the overflow begins."""
    rule = RULES[name]
    _runs_cleanly(read_sequence(seq), _setting(name, rule.hi))
    if rule.lo < 0:
        _runs_cleanly(read_sequence(seq), _setting(name, rule.lo))


@pytest.mark.parametrize("model, key, bound", [("cv-cartesian", "cartesian_sigma", "<= 1000"),
                                               ("ca-polar", "map_sigma_polar", "<= 1000"),
                                               ("ca-polar", "doppler_common_sigma", "<= 1000000")])
def test_rodo_run_refuses_a_huge_noise_sigma_before_any_work(seq, tmp_path, capsys, model, key, bound):
    cfg = tmp_path / "big.toml"
    cfg.write_text(f'model = "{model}"\n[noise]\n{key} = 1e200\n')
    out = tmp_path / "out"
    fails(capsys, ["run", seq, "--config", cfg, "--out", out], str(cfg), f"[noise] {key} = 1e+200", bound)
    assert not out.exists()


def test_every_key_at_the_smallest_positive_double_is_refused_naming_it_or_runs_cleanly(seq):
    """The other end: a sigma's information is 1 / sigma^2, so 5e-324 overflowed it to inf (a divide-by-zero
    warning, then NaN) where the key allowed any positive value."""
    sequence = read_sequence(seq)
    for name in RULES:
        if _is_int(name):
            continue
        setting = _setting(name, 5e-324)
        try:
            OdometryConfig.from_dict(setting, source="c.toml")
        except InputError as exc:
            section, _, key = name.rpartition(".")
            msg = str(exc)
            assert (f"[{section}] {key}" in msg or name in msg) if section else key in msg, msg
            continue
        _runs_cleanly(sequence, setting)
