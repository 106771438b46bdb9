"""Plugins: a module of the user's registers scenarios and sensor profiles, and every command sees them through
`rodo --plugin MODULE` or RODO_PLUGINS, the campaigns' spawned workers included (rodo.validation.plugins,
docs/simulator.md, "Custom scenarios and sensor profiles", with its example docs/examples/my_scenarios.py).

The example plugin runs in subprocesses, so its registrations never reach the registries of this test process."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rodo.cli import main
from rodo.validation import plugins
from rodo.validation.workers import spawn_pool

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "docs" / "examples"
SIMULATOR_MD = ROOT / "docs" / "simulator.md"


def rodo(args, cwd, plugins_env: str | None = None, timeout: float = 600):
    """`rodo args` in a fresh process (the installed script), docs/examples on PYTHONPATH, RODO_PLUGINS set to
    `plugins_env` (None: unset)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", plugins.ENV)}
    env["PYTHONPATH"] = str(EXAMPLES)
    if plugins_env is not None:
        env[plugins.ENV] = plugins_env
    script = Path(sys.executable).parent / "rodo"
    command = [str(script)] if script.is_file() else [sys.executable, "-m", "rodo"]
    return subprocess.run(command + [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture
def no_plugins(monkeypatch):
    """RODO_PLUGINS empty for an in-process test, and restored (unset) afterwards: `load` writes into it."""
    monkeypatch.setenv(plugins.ENV, "")


def test_the_cli_sees_a_plugins_scenario_through_the_option_and_the_variable(tmp_path):
    listed = rodo(["--plugin", "my_scenarios", "scenarios"], tmp_path)
    assert listed.returncode == 0, listed.stderr
    assert listed.stdout.splitlines()[-1].startswith("campus ")  # after the built-in ones
    listed = rodo(["profiles"], tmp_path, plugins_env="my_scenarios")
    assert listed.returncode == 0 and "short_range" in listed.stdout, listed.stderr
    out = tmp_path / "campus"
    done = rodo(["--plugin", "my_scenarios", "simulate", "campus", "--seed", "1", "--duration", "1", "--out", out],
                tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"campus v1 seed 1 -> {out}")
    sensor = (out / "sensor.toml").read_text()
    assert "rate_hz = 20.0\n" in sensor and "max_range = 60.0\n" in sensor  # the plugin's own profile
    again = rodo(["simulate", "campus", "--duration", "1", "--out", tmp_path / "again"], tmp_path,
                 plugins_env="my_scenarios")
    assert again.returncode == 0, again.stderr
    assert (tmp_path / "again" / "radar.csv").read_bytes() != b""
    without = rodo(["simulate", "campus", "--duration", "1", "--out", tmp_path / "none"], tmp_path)
    assert without.returncode == 2 and "unknown scenario 'campus'" in without.stderr


def test_spawned_campaign_workers_run_a_plugins_scenario(tmp_path):
    """`rodo --plugin` leaves the module's name in RODO_PLUGINS; the spawned workers import it before a trial
    (without that, each row was an error: unknown scenario 'campus')."""
    out = tmp_path / "mc"
    done = rodo(["--plugin", "my_scenarios", "montecarlo", "campus", "--runs", "2", "--jobs", "2", "--duration", "1",
                 "--models", "ca-polar", "--out", out], tmp_path)
    assert done.returncode == 0, done.stderr
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert sorted(r["trial"] for r in rows) == ["0", "1"]
    assert [r["status"] for r in rows] == ["ok", "ok"], [r.get("error") for r in rows]
    resumed = rodo(["montecarlo", "campus", "--runs", "2", "--jobs", "2", "--duration", "1", "--models", "ca-polar",
                    "--out", out, "--resume"], tmp_path, plugins_env="my_scenarios")
    assert resumed.returncode == 0 and "skipped 2 already done" in resumed.stdout, resumed.stderr


def _known() -> tuple[list[str], list[str]]:
    """In a worker: the scenario and profile names it knows."""
    from rodo import scenarios
    from rodo.sim import profiles

    return scenarios.names(), profiles.names()


def test_a_pools_workers_import_the_plugins_of_the_variable(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))  # the workers get this process's sys.path
    monkeypatch.setenv(plugins.ENV, "my_scenarios")
    with spawn_pool(1) as pool:
        names, profile_names = pool.submit(_known).result(timeout=300)
    assert names[-1] == "campus" and profile_names[-1] == "short_range"
    monkeypatch.setenv(plugins.ENV, "")
    with spawn_pool(1) as pool:
        names, _ = pool.submit(_known).result(timeout=300)
    assert "campus" not in names


@pytest.mark.parametrize("where", ["option", "variable"])
def test_a_plugin_that_is_not_there_is_exit_2_naming_it(capsys, monkeypatch, no_plugins, where):
    if where == "option":
        rc = main(["--plugin", "no_such_rodo_plugin", "scenarios"])
    else:
        monkeypatch.setenv(plugins.ENV, "no_such_rodo_plugin")
        rc = main(["scenarios"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("rodo: error: plugin 'no_such_rodo_plugin': ModuleNotFoundError: No module named "
                          "'no_such_rodo_plugin' (install it, or put its folder on PYTHONPATH)"), err
    assert os.environ[plugins.ENV] == ("" if where == "option" else "no_such_rodo_plugin")  # not written


def test_a_plugin_whose_import_fails_is_named_with_its_error(capsys, monkeypatch, tmp_path, no_plugins):
    (tmp_path / "rodo_broken_plugin.py").write_text("import rodo_missing_dependency\n")
    (tmp_path / "rodo_raising_plugin.py").write_text("raise RuntimeError('boom')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["--plugin", "rodo_broken_plugin", "scenarios"]) == 2
    err = capsys.readouterr().err
    assert err == ("rodo: error: plugin 'rodo_broken_plugin': ModuleNotFoundError: No module named "
                   "'rodo_missing_dependency'\n")  # no PYTHONPATH hint: the plugin itself was found
    assert main(["--plugin", "rodo_raising_plugin", "scenarios"]) == 2
    assert capsys.readouterr().err == "rodo: error: plugin 'rodo_raising_plugin': RuntimeError: boom\n"
    assert main(["--plugin", "not a module", "scenarios"]) == 2
    assert "plugin 'not a module': not a module name" in capsys.readouterr().err


def test_load_imports_each_plugin_once_and_leaves_all_names_for_the_workers(monkeypatch, tmp_path, no_plugins):
    for name in ("rodo_plugin_a", "rodo_plugin_b"):
        (tmp_path / f"{name}.py").write_text("import builtins\n"
                                             "builtins.rodo_plugin_imports = getattr(builtins, "
                                             "'rodo_plugin_imports', []) + [__name__]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import builtins

    monkeypatch.setattr(builtins, "rodo_plugin_imports", [], raising=False)
    environ = {plugins.ENV: " rodo_plugin_a, "}
    assert plugins.load(["rodo_plugin_b,rodo_plugin_a", "rodo_plugin_b"], environ) == ["rodo_plugin_a",
                                                                                      "rodo_plugin_b"]
    assert environ[plugins.ENV] == "rodo_plugin_a,rodo_plugin_b"
    assert plugins.load(["rodo_plugin_a"], environ) == ["rodo_plugin_a", "rodo_plugin_b"]
    assert builtins.rodo_plugin_imports == ["rodo_plugin_a", "rodo_plugin_b"]  # imported once each
    assert plugins.load([], {}) == []
    main(["--plugin", "rodo_plugin_b", "scenarios"])  # the CLI writes them into this process's environment
    assert os.environ[plugins.ENV] == "rodo_plugin_b"


def test_the_documented_example_is_the_file_and_runs_from_python(tmp_path):
    """docs/simulator.md shows docs/examples/my_scenarios.py as it is, and its Python use runs as written (with a
    shorter duration), replace=True included."""
    text = SIMULATOR_MD.read_text()
    section = text[text.index("## Custom scenarios and sensor profiles"):]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks[0].strip() in (EXAMPLES / "my_scenarios.py").read_text()
    use = blocks[1].replace("duration=10.0", "duration=1.0")
    code = use + "\n".join([
        "import dataclasses",
        "campus = scenarios.get('campus')",
        "scenarios.register(dataclasses.replace(campus, version=2), replace=True)",
        "assert scenarios.get('campus').version == 2 and scenarios.names()[-1] == 'campus'",
        "try:",
        "    scenarios.register(dataclasses.replace(scenarios.get('city'), version=9), replace=True)",
        "except ValueError as exc:",
        "    print(exc)",
        "print(len(seq.scans), sorted(p.name for p in __import__('pathlib').Path('runs/campus').iterdir()))"])
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", plugins.ENV)}
    env["PYTHONPATH"] = str(EXAMPLES)
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    refused, files = done.stdout.splitlines()
    assert refused.startswith("scenario 'city' is a built-in, versioned scenario and cannot be replaced")
    assert files == "21 ['groundtruth.txt', 'radar.csv', 'sensor.toml', 'truth.npz']"


def test_dask_workers_import_the_plugins_too(tmp_path):
    """Dask's workers are not spawned by rodo's pool: `make_executor` registers a setup callback on the client
    that imports the plugins on each (without it every row was an error: unknown scenario 'campus')."""
    pytest.importorskip("distributed")
    out = tmp_path / "mc"
    done = rodo(["--plugin", "my_scenarios", "montecarlo", "campus", "--runs", "2", "--jobs", "1", "--dask", "local",
                 "--duration", "1", "--models", "ca-polar", "--out", out], tmp_path)
    assert done.returncode == 0, done.stderr
    with open(out / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["status"] for r in rows] == ["ok", "ok"], [r.get("error") for r in rows]


def test_a_plugin_dask_workers_cannot_import_stops_the_campaign_naming_it(monkeypatch):
    pytest.importorskip("distributed")
    from rodo.estimator.errors import InputError
    from rodo.validation.workers import make_executor

    monkeypatch.setenv(plugins.ENV, "no_such_plugin_for_dask")
    with pytest.raises(InputError, match="dask: the workers cannot import the plugins no_such_plugin_for_dask: "
                                         "plugin 'no_such_plugin_for_dask': ModuleNotFoundError"):
        with make_executor(1, "local", processes=False):
            pass
