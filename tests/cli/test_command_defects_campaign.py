"""`rodo montecarlo` refuses a built-in model's name as the label of a config that runs another model, and `rodo
verdict`'s floor errors name the option given (--floor-ca, --floor-cv). No simulation: about 1 s."""

from pathlib import Path

import pytest

from rodo.cli import main
from rodo.commands.montecarlo import parse_configs
from rodo.estimator.errors import InputError
from tests.cli.helpers import fails


def _dump(capsys, tmp_path: Path, model: str) -> Path:
    capsys.readouterr()
    assert main(["config", "dump", "--model", model]) == 0
    path = tmp_path / f"{model}.toml"
    path.write_text(capsys.readouterr().out)
    return path


def test_a_model_name_cannot_label_another_models_config(tmp_path, capsys):
    cv = _dump(capsys, tmp_path, "cv-cartesian")
    out = tmp_path / "mcK"
    fails(capsys, ["montecarlo", "city", "--runs", "1", "--duration", "1", "--jobs", "1", "--models",
                   f"ca-polar={cv}", "--out", out], "label 'ca-polar'", str(cv), "runs model 'cv-cartesian'")
    assert not out.exists()  # refused before the campaign directory
    no_model = tmp_path / "no_model.toml"
    no_model.write_text("[noise]\ncartesian_sigma = 0.4\n")  # no model: the default's, ca-polar
    fails(capsys, ["montecarlo", "city", "--runs", "1", "--models", f"cv-cartesian={no_model}", "--out", out],
          "label 'cv-cartesian'", str(no_model), "runs model 'ca-polar'")
    assert not out.exists()


def test_a_model_name_may_label_its_own_models_config_and_any_label_any_model(tmp_path, capsys):
    cv = _dump(capsys, tmp_path, "cv-cartesian")
    text = cv.read_text()
    assert parse_configs(f"cv-cartesian={cv}") == (("cv-cartesian", text),)
    assert parse_configs(f"ca-polar,cv-learned={cv}") == (("cv-learned", text),)
    with pytest.raises(InputError, match="label 'cv-polar'"):
        parse_configs(f"cv-learned={cv},cv-polar={cv}")


@pytest.mark.parametrize("option, value", [("--floor-ca", "1,2"), ("--floor-cv", "-1"), ("--floor-ca", "nan")])
def test_verdict_floor_errors_name_the_option(tmp_path, capsys, option, value):
    out = tmp_path / "verdict"
    err = fails(capsys, ["verdict", option, value, "--out", out], f"{option}: one number or six", repr(value))
    assert "--floor:" not in err and not out.exists()
