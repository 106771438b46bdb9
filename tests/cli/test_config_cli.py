"""`rodo config dump`: the complete default configuration as commented TOML that `--config` accepts (round trip
to the default config of every model), every key of the dataclasses in it with a description, and
docs/configuration.md generated from the same schema and up to date."""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import pytest

from rodo import config_schema
from rodo.cli import main
from rodo.commands import config as config_cmd
from rodo.estimator.config import MODELS, OdometryConfig
from rodo.estimator.tomlcompat import tomllib

ROOT = Path(__file__).resolve().parents[2]


def _field_names(cls, prefix="") -> set[str]:
    """Every leaf key of a config dataclass: "window", "noise.qc_ca", ..."""
    out = set()
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default):
            out |= _field_names(type(default), f"{prefix}{f.name}.")
        else:
            out.add(f"{prefix}{f.name}")
    return out


def _toml_keys(data: dict, prefix="") -> set[str]:
    out = set()
    for k, v in data.items():
        out |= _toml_keys(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}"}
    return out


@pytest.mark.parametrize("model", MODELS)
def test_dump_round_trips_to_the_default_config(tmp_path, capsys, model):
    assert main(["config", "dump", "--model", model], commands=[config_cmd]) == 0
    text = capsys.readouterr().out
    path = tmp_path / "defaults.toml"
    path.write_text(text)
    assert OdometryConfig.from_toml(path) == OdometryConfig.for_model(model)  # what `rodo run --config` reads
    assert _toml_keys(tomllib.loads(text)) == _field_names(OdometryConfig)  # every key, no other
    assert text.count("\n# ") > len(_field_names(OdometryConfig))  # commented


def test_a_dumped_file_is_a_working_config(tmp_path):
    """Editing a value of the dump changes the loaded config, and only that value."""
    text = config_schema.render_toml("ca-polar")
    edited = text.replace("\nwindow = 4\n", "\nwindow = 6\n").replace("\nmeasurement_inflation = 1.0\n",
                                                                    "\nmeasurement_inflation = 3.0\n")
    assert edited.count("window = 6") == 1 and edited.count("measurement_inflation = 3.0") == 1
    path = tmp_path / "edited.toml"
    path.write_text(edited)
    default = OdometryConfig.for_model("ca-polar")
    want = default.replace(window=6, uncertainty=dataclasses.replace(default.uncertainty, measurement_inflation=3.0))
    assert OdometryConfig.from_toml(path) == want


def test_every_key_is_described_and_the_tables_name_real_keys():
    keys = [k for s in config_schema.schema() for k in s.keys]
    assert {k.name for k in keys} == _field_names(OdometryConfig)
    assert [k.name for k in keys if not k.description] == []
    for table in (config_schema.UNITS, config_schema.DESCRIPTIONS, config_schema.USED_BY):
        assert set(table) <= _field_names(OdometryConfig), set(table) - _field_names(OdometryConfig)
    assert all(s.description for s in config_schema.schema())


def test_keys_not_read_by_the_model_are_marked():
    text = config_schema.render_toml("cv-cartesian")
    block = text[:text.index("\nqc_ca =")].rsplit("\n# qc_ca", 1)[1]
    assert "not used by cv-cartesian" in block
    assert "not used by" not in text[:text.index("\nqc_cv =")].rsplit("\n# qc_cv", 1)[1]


def test_the_example_file_loads_and_changes_only_what_it_says():
    cfg = OdometryConfig.from_toml(ROOT / "docs" / "examples" / "handheld.toml")
    default = OdometryConfig.for_model("ca-polar")
    assert cfg == default.replace(vehicle=dataclasses.replace(default.vehicle, sigma_roll_rate=0.0,
                                                              sigma_pitch_rate=0.0))


@dataclass(frozen=True)
class _NewSection:
    """A section as another engineer might add one.

    alpha: documented in the docstring.
    """

    alpha: float = 1.5
    beta: tuple[float, ...] = (1.0, 2.0)  # m/s, documented by its comment
    # and the comment line under it


def test_a_new_key_appears_with_its_comment_and_unit():
    described, keys = config_schema.section_keys(_NewSection, _NewSection(), "new.")
    assert described == "A section as another engineer might add one."
    alpha, beta = keys
    assert (alpha.name, alpha.default, alpha.description) == ("new.alpha", 1.5, "documented in the docstring.")
    assert (beta.unit, beta.description) == ("m/s", "documented by its comment and the comment line under it")
    assert config_schema.toml_value(beta.default) == "[1.0, 2.0]"


def test_docs_configuration_is_up_to_date(capsys):
    assert main(["config", "dump", "--markdown"], commands=[config_cmd]) == 0
    generated = capsys.readouterr().out
    current = (ROOT / "docs" / "configuration.md").read_text()
    assert current == generated, ("docs/configuration.md is out of date: regenerate it with "
                                  "`rodo config dump --markdown > docs/configuration.md`")
    for key in _field_names(OdometryConfig):
        assert f"| `{key.rsplit('.', 1)[-1]}` |" in current


@pytest.mark.parametrize("argv, needle", [
    (["config"], "ACTION"),
    (["config", "show"], "invalid choice: 'show'"),
    (["config", "dump", "--model", "ca-nope"], "invalid choice: 'ca-nope'"),
    (["config", "dump", "--model"], "expected one argument"),
])
def test_config_bad_input(capsys, argv, needle):
    with pytest.raises(SystemExit) as exc:
        main(argv, commands=[config_cmd])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and needle in err and "Traceback" not in err, err
