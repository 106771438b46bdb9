"""Every estimator config value is checked when the config is loaded (estimator/config_rules.py): wrong type,
NaN, infinity and out-of-range values are an InputError naming the file, the section and the key (exit code 2
from the CLI, before any work), never a FloatingPointError or a silently accepted value deep in the estimator."""

import dataclasses
import math

import pytest

from rodo.cli import main
from rodo.estimator import config_rules
from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.config_rules import RULES
from rodo.estimator.errors import InputError


def _default(name: str):
    section, _, key = name.rpartition(".")
    base = OdometryConfig()
    return getattr(getattr(base, section), key) if section else getattr(base, key)


def _bad_values(name: str) -> list[str]:
    """TOML texts of values the rule of `name` must refuse: non-finite, outside the range, of another type."""
    rule, default = RULES[name], _default(name)
    is_int = isinstance(default, int) and not isinstance(default, bool)
    outside = []
    if rule.lo > -math.inf:
        outside.append(rule.lo - 1 if rule.lo_closed else rule.lo)
    if rule.hi < math.inf:
        outside.append(rule.hi + 1 if rule.hi_closed else rule.hi)
    outside = [x for x in outside if x not in rule.also]
    if isinstance(default, tuple):
        good = [repr(float(v)) for v in default]
        lists = [good[:-1] + [v] for v in ("nan", "inf", "-inf", *(repr(float(x)) for x in outside))]
        return ["[" + ", ".join(v) + "]" for v in lists] + ["[" + ", ".join(good + good) + "]", "1.0"]
    texts = [str(int(x)) if is_int else repr(float(x)) for x in outside] + ['"1"', "true"]
    return texts + (["nan", "2.5", "1e400"] if is_int else ["nan", "inf", "-inf"])


CASES = [(name, text) for name in RULES for text in _bad_values(name)]


def _toml(name: str, text: str) -> str:
    section, _, key = name.rpartition(".")
    return f"[{section}]\n{key} = {text}\n" if section else f"{key} = {text}\n"


def test_the_rules_cover_every_value_and_accept_the_defaults():
    for model in MODELS:
        OdometryConfig.for_model(model)  # the defaults pass their own rules
    cfg = OdometryConfig()
    sections = [f.name for f in dataclasses.fields(cfg) if dataclasses.is_dataclass(getattr(cfg, f.name))]
    names = {f"{s}.{g.name}" for s in sections
             for g in dataclasses.fields(getattr(cfg, s)) if not isinstance(getattr(getattr(cfg, s), g.name), bool)}
    missing = sorted(names - set(RULES))
    assert not missing, f"config values without a range in estimator/config_rules.py RULES: {missing}"
    assert len(CASES) > 250


@pytest.mark.parametrize("name, text", CASES, ids=[f"{n}={t}" for n, t in CASES])
def test_every_rule_refuses_out_of_range_and_non_finite_values(tmp_path, name, text):
    path = tmp_path / "bad.toml"
    path.write_text(_toml(name, text))
    with pytest.raises(InputError) as exc:
        OdometryConfig.from_toml(path)
    msg = str(exc.value)
    section, _, key = name.rpartition(".")
    assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
    assert (f"[{section}] {key}" in msg or f"{name}" in msg) if section else key in msg, msg


def test_a_value_without_a_rule_is_still_checked_for_type_and_finiteness(monkeypatch):
    monkeypatch.delitem(config_rules.RULES, "noise.map_sigma_polar")  # as a key added without a rule
    with pytest.raises(InputError, match=r"^x.toml: \[noise\] map_sigma_polar = nan: must be a finite number$"):
        OdometryConfig.from_dict({"noise": {"map_sigma_polar": float("nan")}}, source="x.toml")
    assert OdometryConfig.from_dict({"noise": {"map_sigma_polar": 1e6}}).noise.map_sigma_polar == 1e6


def test_configs_built_in_python_are_checked_too():
    noise = dataclasses.replace(OdometryConfig().noise, map_sigma_polar="0.1")
    with pytest.raises(InputError, match=r"\[noise\] map_sigma_polar = '0.1': expected a number"):
        OdometryConfig(noise=noise)
    solver = dataclasses.replace(OdometryConfig().solver, init_rate_sigma=(0.02, float("nan"), 0.2))
    with pytest.raises(InputError, match=r"\[solver\] init_rate_sigma = \[0.02, nan, 0.2\]: each element must be "
                                         "a finite number > 0"):
        OdometryConfig(solver=solver)


def test_edges_of_the_ranges_are_accepted(tmp_path):
    cfg = OdometryConfig.from_dict({"standstill": {"speed": 0.0}, "solver": {"robust_c": 0.0},
                                    "map": {"max_fused": 0, "capacity": 10}, "uncertainty": {"inflation": 1.0},
                                    "window": 1000})
    assert cfg.standstill.speed == 0.0 and cfg.map.max_fused == 0 and cfg.window == 1000


@pytest.mark.parametrize("text, needle", [
    ("[noise]\nmap_sigma_polar = nan\n", "[noise] map_sigma_polar = nan: must be a finite number >= 0"),
    ("[solver]\ninit_rate_sigma = [0.02, nan, 0.2]\n", "[solver] init_rate_sigma = [0.02, nan, 0.2]"),
    ("[solver]\nrobust_c = nan\n", "[solver] robust_c = nan"),
    ("[standstill]\nspeed = inf\n", "[standstill] speed = inf"),
    ("[uncertainty]\nvelocity_correlation_time = -inf\n",
     "[uncertainty] velocity_correlation_time = -inf: must be a finite number >= 0"),
    ("[uncertainty]\nprior_memory = -1.0\n", "[uncertainty] prior_memory = -1.0: must be >= 0"),
    ("window = 1000000\n", "window = 1000000: must be >= 2 and <= 1000"),
])
def test_cli_refuses_a_bad_value_before_any_work(seq, tmp_path, capsys, text, needle):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    rc = main(["run", str(seq), "--config", str(cfg), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith(f"rodo run: error: {cfg}: ") and needle in err, err
    assert "Traceback" not in err and not (tmp_path / "o").exists()
    rc = main(["montecarlo", "city", "--runs", "1", "--models", f"x={cfg}", "--out", str(tmp_path / "mc")])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and not (tmp_path / "mc" / "results.csv").exists(), err
