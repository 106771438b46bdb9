"""The command line explains itself: every command has a one-line help and a description, the commands a help
text names exist, `run --help` and the README list every model, and the commands rodo prints for the user to
run next work from the user's shell (a `.venv/bin/rodo` that is not on PATH is printed as that path)."""

import os
import re
import sys
from pathlib import Path

from rodo import cli
from rodo.commands.run import rodo_command
from rodo.estimator.config import MODELS

ROOT = Path(__file__).resolve().parents[2]


def _commands():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    helps = {a.dest: a.help for a in sub._choices_actions}
    return sub.choices, helps


def test_every_command_has_a_help_line_and_a_description():
    choices, helps = _commands()
    assert [n for n in choices if not helps.get(n)] == []
    assert [n for n, p in choices.items() if not (p.description and len(p.description) > 20)] == []


def test_commands_named_in_help_texts_exist():
    choices, _ = _commands()
    for name, parser in choices.items():
        text = parser.format_help()
        for named in re.findall(r"`rodo ([a-z][a-z0-9-]*)", text):
            assert named in choices, f"`rodo {name} --help` names `rodo {named}`, which does not exist"
        assert "--list" not in text  # `rodo simulate --list` never existed
    assert "rodo scenarios" in choices["montecarlo"].format_help()


def test_run_help_and_readme_list_every_model():
    choices, _ = _commands()
    run_help = re.sub(r"-\s+", "-", " ".join(choices["run"].format_help().split()))  # undo wraps at hyphens
    readme = (ROOT / "README.md").read_text()
    row = next(line for line in readme.splitlines() if line.startswith("| `rodo run "))
    for model in MODELS:
        assert model in run_help and model in row, model


def test_printed_commands_work_from_the_users_shell(tmp_path, monkeypatch):
    """With the interpreter's bin folder off PATH (a fresh shell after `make demo`) the printed command is the
    script's path, relative to the working directory when below it; on PATH it is plain `rodo`."""
    bin_dir = Path(sys.executable).parent
    assert (bin_dir / "rodo").is_file()
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing called rodo there
    monkeypatch.chdir(bin_dir.parent.parent)
    printed = rodo_command()
    assert printed == str((bin_dir / "rodo").relative_to(Path.cwd())) or printed == str(bin_dir / "rodo")
    assert Path(printed).resolve() == (bin_dir / "rodo").resolve() and os.access(printed, os.X_OK)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{tmp_path}")
    assert rodo_command() == "rodo"
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.chdir(tmp_path)  # outside the venv: the absolute path
    assert rodo_command() == str(bin_dir / "rodo")


def test_outputs_follow_one_metavar_convention():
    """--out is SEQ_DIR for a sequence, DIR for another directory, NAME.ext for a file."""
    choices, _ = _commands()
    for name, parser in choices.items():
        for action in parser._actions:
            if "--out" in action.option_strings:
                mv = action.metavar
                assert mv in ("DIR", "SEQ_DIR") or re.fullmatch(r"[A-Z_]+\.[a-z]+", mv or ""), (name, mv)
