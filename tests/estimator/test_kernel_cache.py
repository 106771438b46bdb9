"""The numba cache key of `rodo.estimator.jit`: editing a kernel's callee in another file recompiles the caller."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rodo.estimator import jit

ESTIMATOR = Path(jit.__file__).resolve().parent

RUNNER = """
import sys
root, register = sys.argv[1], sys.argv[2] == "1"
sys.path.insert(0, root)
from rodo.estimator import jit
if register:
    jit.register_kernel_root(root + "/kpkg", "kpkg")
from kpkg import b
print(b.g())
"""


def _package(root: Path) -> None:
    """kpkg: a.f (cached kernel returning 1) and b.g (cached kernel in another file calling a.f)."""
    pkg = root / "kpkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from numba import njit\n\n\n@njit(cache=True)\ndef f():\n    return 1\n")
    (pkg / "b.py").write_text("from numba import njit\n\nfrom .a import f\n\n\n@njit(cache=True)\ndef g():\n"
                              "    return f()\n")


def _run(root: Path, register: bool) -> str:
    """b.g() in a fresh interpreter (-B: no .pyc, so Python itself never runs a stale a.py)."""
    out = subprocess.run([sys.executable, "-B", str(root / "run.py"), str(root), "1" if register else "0"],
                         capture_output=True, text=True, timeout=300, check=True)
    return out.stdout.strip().splitlines()[-1]


def _edit_callee(root: Path) -> None:
    a = root / "kpkg" / "a.py"
    a.write_text(a.read_text().replace("return 1", "return 2"))


@pytest.mark.slow
def test_editing_a_callee_in_another_file_recompiles_the_caller(tmp_path):
    """With the root registered, the caller's cache entry is invalidated by the callee's edit; without (the
    control, numba's own key: the caller's file only, numba issue 9483) the second run returns the stale 1."""
    assert jit.LOCATOR_INSTALLED
    results = {}
    for register in (True, False):
        root = tmp_path / ("registered" if register else "control")
        _package(root)
        (root / "run.py").write_text(RUNNER)
        first = _run(root, register)
        _edit_callee(root)
        results[register] = (first, _run(root, register))
    assert results[True] == ("1", "2")
    # the control proves the test can fail: numba 0.68 keeps the stale machine code of b.g
    assert results[False] == ("1", "1")


def _copy_estimator(dst: Path) -> Path:
    shutil.copytree(ESTIMATOR, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nb[ic]"))
    return dst


# (edited file, kernel file whose key must change); each kernel reaches the edited file through its imports
DEPENDENT = [
    ("lie/kernels.py", "motion_kernels.py"),
    ("lie/kernels.py", "priors/kernels.py"),
    ("lie/_series.py", "priors/kernels.py"),  # Taylor tables the kernels freeze as constants
    ("priors/kernels.py", "priors/constant_velocity.py"),
    ("measurement_kernels.py", "association_kernels.py"),
    ("jit.py", "measurement_kernels.py"),
    ("motion_kernels.py", "motion_kernels.py"),
]


@pytest.mark.parametrize("edited, kernel", DEPENDENT)
def test_package_digest_changes_with_any_kernel_file(tmp_path, edited, kernel):
    """The real package's key of `kernel` changes when the text of `edited` changes (a copy is edited)."""
    copy = _copy_estimator(tmp_path / "estimator")
    before = jit.source_digest(copy, "rodo.estimator", copy / kernel)
    assert before == jit.source_digest(ESTIMATOR, "rodo.estimator", ESTIMATOR / kernel)  # paths do not enter
    target = copy / edited
    target.write_text(target.read_text() + "\n# edited\n")
    assert jit.source_digest(copy, "rodo.estimator", copy / kernel) != before


def test_digest_ignores_files_the_kernel_does_not_import(tmp_path):
    """Editing the per-scan loop (no kernel imports it) keeps every kernel's cache: no needless recompilation."""
    copy = _copy_estimator(tmp_path / "estimator")
    kernels = ["lie/kernels.py", "priors/kernels.py", "motion_kernels.py", "measurement_kernels.py",
               "association_kernels.py"]
    before = [jit.source_digest(copy, "rodo.estimator", copy / k) for k in kernels]
    odometry = copy / "odometry.py"
    odometry.write_text(odometry.read_text() + "\n# edited\n")
    assert [jit.source_digest(copy, "rodo.estimator", copy / k) for k in kernels] == before


def test_the_package_kernels_are_keyed_on_the_digest():
    """Every module of the estimator that defines cached kernels lies under the registered root."""
    for name in ("lie/kernels.py", "priors/kernels.py", "priors/constant_acceleration.py", "motion_kernels.py",
                 "measurement_kernels.py", "association_kernels.py"):
        stamp = jit.source_stamp(ESTIMATOR / name)
        assert stamp == "rodo-digest-" + jit.source_digest(ESTIMATOR, "rodo.estimator", ESTIMATOR / name)
    assert jit.source_stamp(Path(shutil.__file__)) is None


def test_kernel_modules_take_njit_from_jit():
    """A module that took numba's `njit` directly could decorate kernels before the locator is installed."""
    for path in ESTIMATOR.rglob("*.py"):
        if path.name != "jit.py":
            assert "from numba import" not in path.read_text(), path


def test_first_compilation_says_so_once_and_a_cached_run_is_silent(tmp_path):
    """A registered root's kernels compiling (two here) print `jit.COMPILE_NOTICE` once on stderr; the second
    run loads the cache and prints nothing; kernels outside every registered root (the control) never do."""
    said = {}
    for register in (True, False):
        root = tmp_path / ("registered" if register else "control")
        _package(root)
        (root / "run.py").write_text(RUNNER)
        runs = [subprocess.run([sys.executable, "-B", str(root / "run.py"), str(root), "1" if register else "0"],
                               capture_output=True, text=True, timeout=300, check=True) for _ in range(2)]
        said[register] = [r.stderr.count(jit.COMPILE_NOTICE) for r in runs]
    assert said == {True: [1, 0], False: [0, 0]}


def test_batch_prediction_is_compiled_for_writable_arrays_only():
    """Read-only inputs (a broadcast view, a frozen array of the batch's own shape) reach the batch kernel as
    writable C arrays: one numba specialisation, the one the warm-up compiles (a read-only dt was a second one,
    compiled by `make demo` after `make install`), with the same results as writable inputs."""
    import numpy as np
    from numba import types

    from rodo.estimator.priors import ConstantAccelerationPrior, ConstantVelocityPrior
    from rodo.estimator.priors import kernels as K

    n = 5
    dt = np.linspace(0.05, 0.2, n)
    frozen = dt.copy()
    frozen.setflags(write=False)
    T = np.broadcast_to(np.eye(4), (n, 4, 4))
    varpi = np.tile(np.array([3.0, 0.1, 0.0, 0.01, 0.0, 0.2]), (n, 1))
    ca = ConstantAccelerationPrior(np.diag([1.0, 0.1, 0.1, 0.01, 0.01, 0.05]))
    cv = ConstantVelocityPrior(np.diag([1.0, 0.1, 0.1, 0.01, 0.01, 0.05]))
    for a, b in ((ca.predict(T, varpi, 0.5 * varpi, frozen), ca.predict(T.copy(), varpi, 0.5 * varpi, dt)),
                 (cv.predict(T, varpi, frozen), cv.predict(T.copy(), varpi, dt))):
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    assert K.predict_batch.signatures
    for sig in K.predict_batch.signatures:
        assert all(t.mutable for t in sig if isinstance(t, types.Array)), sig


ODOMETRY_RUNNER = """
import sys
import numpy as np
from rodo import scenarios
from rodo.estimator.config import OdometryConfig
from rodo.validation.driver import run_sequence
seq, _ = scenarios.get("city").simulate(0, duration=1.5)
out = {}
for model in ("ca-polar", "cv-cartesian"):
    est = run_sequence(seq, OdometryConfig.for_model(model)).estimates
    out[model + "/T"] = np.array([e.T_vehicle_world for e in est])
    out[model + "/P"] = np.array([e.P for e in est])
np.savez(sys.argv[1], **out)
"""


@pytest.mark.slow
def test_kernels_compiled_afresh_and_loaded_from_the_cache_give_the_same_estimates(tmp_path):
    """Bit for bit, the odometry (both models, 1.5 s of city) with every kernel compiled afresh (an empty
    NUMBA_CACHE_DIR) and with every kernel loaded from the cache that run wrote. Fast-math flags on the window
    kernel's helpers once made the two differ by rounding: the first run after an edit or an install was not the
    runs after it."""
    import os

    import numpy as np

    script = tmp_path / "run.py"
    script.write_text(ODOMETRY_RUNNER)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    runs = []
    for k in range(2):
        subprocess.run([sys.executable, str(script), str(tmp_path / f"out{k}.npz")], env=env, cwd=tmp_path,
                       capture_output=True, text=True, timeout=900, check=True)
        runs.append(np.load(tmp_path / f"out{k}.npz"))
    assert any((tmp_path / "cache").rglob("*.nbc"))  # the first run compiled into the empty cache, the second read it
    for key in runs[0].files:
        np.testing.assert_array_equal(runs[0][key], runs[1][key], err_msg=key)
