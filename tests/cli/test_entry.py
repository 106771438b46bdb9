"""The `rodo` command's entry point (rodo.entry): a Ctrl-C while the command line imports (numba, the kernels,
the commands: about a second and a half) is `rodo: interrupted` and exit 130, not a traceback."""

import importlib.abc
import subprocess
import sys

import pytest

from rodo import entry


class _InterruptedImport(importlib.abc.MetaPathFinder):
    """An import of rodo.cli that a Ctrl-C interrupts."""

    def find_spec(self, name, path=None, target=None):
        if name == "rodo.cli":
            raise KeyboardInterrupt
        return None


def test_a_ctrl_c_during_the_imports_is_interrupted_and_130(monkeypatch, capsys):
    monkeypatch.delitem(sys.modules, "rodo.cli", raising=False)
    monkeypatch.setattr(sys, "meta_path", [_InterruptedImport(), *sys.meta_path])
    assert entry.main() == 130
    assert capsys.readouterr().err == "rodo: interrupted\n"


def test_the_entry_runs_the_command_line(monkeypatch):
    monkeypatch.setattr(sys, "argv", ["rodo", "--version"])
    with pytest.raises(SystemExit) as exc:
        entry.main()
    assert exc.value.code == 0


def test_the_installed_command_is_the_entry():
    """The console script and `python -m rodo` both start at rodo.entry:main."""
    from importlib.metadata import entry_points

    (script,) = [ep for ep in entry_points(group="console_scripts") if ep.name == "rodo"]
    assert script.value == "rodo.entry:main"
    out = subprocess.run([sys.executable, "-m", "rodo", "--version"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.startswith("rodo ")
