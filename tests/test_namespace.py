"""One import namespace, checked from outside: the folders import only as rodo.sim, rodo.estimator, ... (a bare
`import sim` fails outside the repository, no module is loaded twice under two names), and every package folder
is listed in pyproject's [tool.setuptools] packages, and vice versa. The import rules between modules (layers,
cycles, private names, sizes) are in tests/test_architecture.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from tests.test_architecture import BARE, OWN_DIRS, PACKAGE_DIR, PACKAGES, ROOT, _py_files, module_name


# --------------------------------------------------------------------------------------- 1. one namespace

def test_bare_folder_names_do_not_import_outside_the_repository(tmp_path):
    """From a directory outside the repository, `import sim` etc. fail and `import rodo.sim` etc. work."""
    code = textwrap.dedent(f"""
        import importlib, json
        out = {{}}
        for name in {list(BARE)!r}:
            for full in (name, "rodo." + name):
                try:
                    importlib.import_module(full)
                    out[full] = "ok"
                except ModuleNotFoundError as e:
                    out[full] = "ModuleNotFoundError: " + str(e)
                except Exception as e:
                    out[full] = type(e).__name__ + ": " + str(e)
        print(json.dumps(out))
    """)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    problems = [f"`import {name}` works from outside the repository (it must be rodo.{name} only)"
                for name in BARE if not result[name].startswith("ModuleNotFoundError")]
    problems += [f"`import rodo.{name}` fails: {result['rodo.' + name]}" for name in BARE
                 if result["rodo." + name] != "ok"]
    assert not problems, "\n".join(problems)


def test_no_module_is_loaded_twice_under_two_names():
    """With the repository root on sys.path (as pytest has it), importing every module of rodo and every test
    module loads each repository file once, and never as a bare `sim`, `estimator`, ..."""
    code = textwrap.dedent(f"""
        import importlib, json, os, pkgutil, sys
        sys.path.insert(0, {str(ROOT)!r})
        failed = []
        names = {sorted(PACKAGES)!r}
        for package in list(names):
            mod = importlib.import_module(package)
            for info in pkgutil.walk_packages(mod.__path__, package + ".", onerror=failed.append):
                if not info.name.endswith("__main__"):  # importing it would run the program
                    names.append(info.name)
        names += {sorted(module_name(p) for p in _py_files("tests"))!r}
        for name in names:
            try:
                importlib.import_module(name)
            except Exception as e:
                failed.append(name + ": " + type(e).__name__ + ": " + str(e))
        files = {{}}
        for name, mod in list(sys.modules.items()):
            f = getattr(mod, "__file__", None)
            f = os.path.realpath(f) if f else ""
            if f.startswith({str(ROOT) + os.sep!r}) and f[{len(str(ROOT)) + 1}:].split(os.sep)[0] in {OWN_DIRS!r}:
                files.setdefault(f, []).append(name)
        print(json.dumps({{"failed": [str(x) for x in failed], "files": files,
                           "bare": sorted(m for m in sys.modules if m.split(".")[0] in {list(BARE)!r})}}))
    """)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    problems = [f"import failed: {f}" for f in result["failed"]]
    problems += [f"{Path(f).relative_to(ROOT)}: loaded as {sorted(names)}" for f, names in result["files"].items()
                 if len(names) > 1]
    problems += [f"bare top-level module in sys.modules: {m}" for m in result["bare"]]
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------ 2. packages listed

def package_problems(root: Path, package_dir: dict[str, str], packages: list[str]) -> list[str]:
    """Folders with an __init__.py that pyproject does not list, listed packages without one, and folders
    of .py files that are not packages (they would not be installed)."""
    def name_of(folder: Path) -> str | None:
        rel = folder.relative_to(root).parts
        for package, pfolder in sorted(package_dir.items(), key=lambda kv: -len(Path(kv[1]).parts)):
            fparts = Path(pfolder).parts
            if rel[:len(fparts)] == fparts:
                return ".".join([package, *rel[len(fparts):]])
        return None

    problems = []
    found = {}
    for top in {Path(f).parts[0] for f in package_dir.values()}:
        for folder in [root / top, *sorted(p for p in (root / top).rglob("*")
                                           if p.is_dir() and "__pycache__" not in p.parts)]:
            has_init = (folder / "__init__.py").exists()
            name = name_of(folder)
            if has_init and name is not None:
                found[name] = folder
            elif not has_init and any(folder.glob("*.py")):
                problems.append(f"{folder.relative_to(root)}/: .py files but no __init__.py (not installed)")
    for name, folder in sorted(found.items()):
        if name not in packages:
            problems.append(f"{folder.relative_to(root)}/__init__.py: package {name} is not in pyproject's "
                            "[tool.setuptools] packages")
    for name in packages:
        if name not in found:
            problems.append(f"pyproject.toml: [tool.setuptools] packages lists {name}, which has no folder "
                            "with an __init__.py")
    return problems


def test_every_package_folder_is_listed_in_pyproject():
    problems = package_problems(ROOT, PACKAGE_DIR, PACKAGES)
    assert not problems, "\n".join(problems)


def test_package_checker_catches_violations(tmp_path):
    """`package_problems` reports a planted unlisted package, a listed one without a folder and a folder of .py
    files that is no package."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "loose").mkdir()
    (pkg / "loose" / "m.py").write_text("")
    assert package_problems(tmp_path, {"rodo.pkg": "pkg"}, ["rodo.pkg", "rodo.gone"]) == [
        "pkg/loose/: .py files but no __init__.py (not installed)",
        "pkg/sub/__init__.py: package rodo.pkg.sub is not in pyproject's [tool.setuptools] packages",
        "pyproject.toml: [tool.setuptools] packages lists rodo.gone, which has no folder with an __init__.py"]
