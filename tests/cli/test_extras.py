"""The core without the extras: rodo imports and `rodo simulate` / `rodo run` / `rodo evaluate` work with rerun,
matplotlib, open3d and dask absent; every command or flag that needs an extra exits 2 naming it, before any work.

The absence is real for the interpreter: a subprocess puts a finder first on sys.meta_path that refuses the
extras' top-level modules (as an environment without them would: ModuleNotFoundError on import, find_spec
None or an error), then calls rodo's entry point. The same refusal in this process shows `run_icp`'s message.
Sizing: one 1.5 s city sequence simulated and run once (about 15 s with the subprocess start-ups).
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rodo import extras, scenarios
from rodo.estimator.tomlcompat import tomllib

ROOT = Path(__file__).resolve().parents[2]
ALL_EXTRA_MODULES = sorted({m for mods in extras.EXTRAS.values() for m in mods})

BLOCKED_RUN = """
import sys

class Absent:
    \"\"\"Refuses the listed top-level modules and their submodules, as if they were not installed.\"\"\"

    def __init__(self, names):
        self.names = names

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, Absent(set(sys.argv[1].split(","))))
import rodo, rodo.viz, rodo.validation  # the packages import without the extras
from rodo.cli import main

code = main(sys.argv[2:])
loaded = sorted(m for m in sys.modules if m.split(".")[0] in sys.argv[1].split(","))
assert not loaded, loaded
sys.exit(code)
"""


def rodo_without(modules, *argv, cwd=None) -> subprocess.CompletedProcess:
    """`rodo ARGV` in a fresh interpreter where `modules` cannot be imported."""
    return subprocess.run([sys.executable, "-c", BLOCKED_RUN, ",".join(modules), *map(str, argv)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)


@pytest.fixture(scope="module")
def core_run(tmp_path_factory):
    """simulate -> run -> evaluate of a 1.5 s city sequence without any extra: (seq_dir, run_dir, processes)."""
    d = tmp_path_factory.mktemp("core")
    seq, out = d / "seq", d / "run"
    sim = rodo_without(ALL_EXTRA_MODULES, "simulate", "city", "--seed", 3, "--duration", 1.5, "--out", seq)
    run = rodo_without(ALL_EXTRA_MODULES, "run", seq, "--model", "cv-cartesian", "--out", out)
    ev = rodo_without(ALL_EXTRA_MODULES, "evaluate", "--gt", seq / "groundtruth.txt", "--est", out / "estimate.txt",
                      "--lengths", "5,10")
    return seq, out, (sim, run, ev)


def test_core_commands_run_without_any_extra(core_run):
    seq, out, procs = core_run
    for proc in procs:
        assert proc.returncode == 0, proc.stderr
    assert (seq / "radar.csv").stat().st_size > 0
    est = np.loadtxt(out / "estimate.txt")
    gt = np.loadtxt(seq / "groundtruth.txt")
    assert est.shape == gt.shape and est.shape[1] == 8  # one TUM pose per scan
    # the estimate follows the truth: the driven distance agrees within 5 %
    dist = [np.sum(np.linalg.norm(np.diff(a[:, 1:4], axis=0), axis=1)) for a in (est, gt)]
    assert dist[1] > 2 and abs(dist[0] - dist[1]) < 0.05 * dist[1], dist
    assert "KITTI t_err" in procs[2].stdout


def test_a_campaign_runs_on_the_core_and_says_how_to_get_its_plots(tmp_path):
    """montecarlo on a process pool needs no extra; its summary names the extra that adds the NEES plots."""
    out = tmp_path / "mc"
    proc = rodo_without(ALL_EXTRA_MODULES, "montecarlo", "city", "--runs", 1, "--duration", 1, "--jobs", 1,
                        "--models", "cv-cartesian", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "cv-cartesian   ok    1/1" in proc.stdout
    summary = (out / "summary.md").read_text()
    assert "No NEES plot: matplotlib is not installed (pip install 'rodo[viz]' adds the plots)" in summary
    assert not list(out.glob("*.png"))


@pytest.mark.parametrize("argv, extra, absent", [
    (["simulate", "city", "--duration", "1", "--out", "{tmp}/seq", "--rerun", "{tmp}/x.rrd"], "viz", ["rerun"]),
    (["run", "{tmp}/seq", "--out", "{tmp}/run", "--rerun", "{tmp}/x.rrd"], "viz", ["matplotlib"]),
    (["run", "{tmp}/seq", "--out", "{tmp}/run", "--connect"], "viz", ["rerun"]),
    (["run", "{tmp}/seq", "--out", "{tmp}/run", "--serve"], "viz", ["rerun"]),
    (["figures", "--out", "{tmp}/fig", "--quick"], "viz", ["matplotlib"]),
    (["demo", "--out", "{tmp}/demo"], "viz", ["rerun", "matplotlib"]),
    (["montecarlo", "city", "--runs", "1", "--dask", "local", "--out", "{tmp}/mc"], "dask", ["distributed"]),
    (["table1", "--runs", "1", "--dask", "tcp://127.0.0.1:1", "--out", "{tmp}/t1"], "dask", ["dask"]),
])
def test_commands_needing_an_extra_name_it_and_exit_2_before_any_work(tmp_path, argv, extra, absent):
    argv = [a.format(tmp=tmp_path) for a in argv]
    proc = rodo_without(absent, *argv)
    assert proc.returncode == 2, proc.stderr
    assert f"pip install 'rodo[{extra}]'" in proc.stderr
    assert all(m in proc.stderr for m in absent)
    assert list(tmp_path.iterdir()) == []  # nothing was written: the check comes first


def test_the_extras_with_them_installed_pass_the_check(tmp_path):
    """In this environment (make test installs rodo[all]) the same check lets every command through."""
    for extra in extras.EXTRAS:
        assert extras.missing(extra) == []
        extras.require(extra, "this test")


def test_run_icp_names_the_icp_extra_without_open3d(monkeypatch):
    from rodo import scenarios
    from rodo.validation.icp_baseline import run_icp

    seq, _ = scenarios.get("city").simulate(0, duration=0.3)
    monkeypatch.setitem(sys.modules, "open3d", None)  # `import open3d` now fails as if it were not installed
    with pytest.raises(ModuleNotFoundError, match=r"pip install 'rodo\[icp\]'"):
        run_icp(seq)


def test_pyproject_extras_match_the_module_map():
    """Every extra of rodo/extras.py is declared in pyproject.toml and provides its modules' distributions,
    `all` is their union, and no core dependency is one of them."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    optional = project["optional-dependencies"]
    dist_of = {"rerun": "rerun-sdk", "matplotlib": "matplotlib", "open3d": "open3d", "kiss_icp": "kiss-icp",
               "dask": "dask",
               "distributed": "dask[distributed]", "rosbags": "rosbags"}
    for extra, modules in extras.EXTRAS.items():
        declared = " ".join(optional[extra])
        assert all(dist_of[m] in declared for m in modules), (extra, declared)
    assert optional["all"] == [f"rodo[{','.join(extras.EXTRAS)}]"]
    core = " ".join(project["dependencies"])
    assert not any(dist_of[m].split("[")[0] in core for m in ALL_EXTRA_MODULES), core


def test_extra_for_maps_submodules():
    assert extras.extra_for("rerun.blueprint") == "viz"
    assert extras.extra_for("matplotlib.backends.backend_agg") == "viz"
    assert extras.extra_for("open3d") == "icp" and extras.extra_for("kiss_icp.pipeline") == "icp"
    assert extras.extra_for("distributed") == "dask"
    assert extras.extra_for("numpy") is None and extras.extra_for(None) is None


@pytest.mark.slow
def test_calibrate_without_truth_and_matplotlib_writes_everything_but_the_figure(tmp_path):
    """EM's check of the velocity's growth draws a figure; without matplotlib the calibration is written all the
    same and the figure is skipped with a hint (it failed with exit 2 after the whole EM had run)."""
    d, out = tmp_path / "drive", tmp_path / "em.toml"
    scenarios.simulate_to("prior_ca_points", 3, d, duration=8.0)
    p = rodo_without(["matplotlib"], "calibrate", d, "--no-truth", "--iterations", 1, "--out", out)
    assert p.returncode == 0, p.stderr
    assert "no growth figure: matplotlib is not installed" in p.stdout
    assert out.exists() and isinstance(json.loads(out.with_suffix(".json").read_text())["velocity_growth"], list)
    assert not (tmp_path / "em_growth.png").exists()
