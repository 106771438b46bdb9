"""The structural rules of the code base, checked by reading the source (ast), not by convention.

1. One import namespace: the folders import only as rodo.sim, rodo.estimator, ...; no module loaded twice.
2. Every package folder is listed in pyproject's [tool.setuptools] packages, and vice versa.
3. Layers: estimator <- sim <- scenarios <- validation <- viz <- CLI (rodo/cli.py, rodo/commands); imports
   anywhere in a file count (also inside functions); no import cycle between modules.
4. No private name taken from another module (tests exempt).
5. No module over 400 lines, no function over 60 lines (compiled kernels exempt).
6. Every "Checked by:" reference names an existing test file and test function.
7. Paper corrections the code relies on are cited inside the repository (docs/paper_notes.md), never outside.

Each check collects every violation as "file:line: what" and fails with the whole list. The checkers are plain
functions of (path, source) so `test_checkers_catch_violations` can show that each one can fail.
"""

from __future__ import annotations

import ast
import fnmatch
import json
import os
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
SETUPTOOLS = PYPROJECT["tool"]["setuptools"]
PACKAGE_DIR: dict[str, str] = SETUPTOOLS["package-dir"]  # "rodo.sim" -> "sim"
PACKAGES: list[str] = SETUPTOOLS["packages"]
LAYERS = ("estimator", "sim", "scenarios", "validation", "viz")  # bottom to top; the CLI sits above all
BARE = LAYERS
SOURCE_DIRS = ("rodo", *LAYERS)
SIZE_DIRS = (*SOURCE_DIRS, "bench")
OWN_DIRS = [*SIZE_DIRS, "tests", "scripts"]  # the repository's own code (not .venv)
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60
NUMBA_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "cfunc", "stencil", "generated_jit"}


# ------------------------------------------------------------------------------------------------ the source

def _py_files(*dirs: str) -> list[Path]:
    return sorted(p for d in dirs for p in (ROOT / d).rglob("*.py") if "__pycache__" not in p.parts)


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def module_name(path: Path) -> str:
    """Dotted import name of a source file: sim/convert/vod.py -> rodo.sim.convert.vod (longest package-dir
    match); files outside the mapped folders (bench/, tests/) are named after their path."""
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    best = None
    for package, folder in PACKAGE_DIR.items():
        fparts = Path(folder).parts
        if tuple(parts[:len(fparts)]) == fparts and (best is None or len(fparts) > len(best[1])):
            best = (package, fparts)
    if best is not None:
        parts = best[0].split(".") + parts[len(best[1]):]
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


SOURCES = {module_name(p): p for p in _py_files(*SOURCE_DIRS)}
KNOWN_MODULES = set(SOURCES) | {module_name(p) for p in _py_files("bench", "tests")}


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _absolute(module: str | None, level: int, current: str, current_is_package: bool) -> str:
    """The absolute name of `from <level dots><module> import ...` written in module `current`."""
    if level == 0:
        return module or ""
    base = current.split(".")
    if not current_is_package:
        base = base[:-1]
    base = base[:len(base) - (level - 1)] if level > 1 else base
    return ".".join(base + ([module] if module else []))


def imports(tree: ast.AST, current: str, is_package: bool, known=KNOWN_MODULES, top_level_only: bool = False):
    """(line, imported module, imported name or None) for every import in the tree (inside functions too,
    unless top_level_only; `if TYPE_CHECKING:` blocks skipped there), plus importlib.import_module("literal").
    `from pkg import name` yields pkg.name as the module when that is a module of the repository."""
    nodes = _top_level_nodes(tree) if top_level_only else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node.module, node.level, current, is_package)
            for alias in node.names:
                full = f"{base}.{alias.name}" if base else alias.name
                if full in known:
                    yield node.lineno, full, None
                else:
                    yield node.lineno, base, alias.name
        elif (not top_level_only and isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name))
              and (node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id) == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            yield node.lineno, node.args[0].value, None


def _top_level_nodes(tree: ast.AST):
    """Statements executed at import time: the module body, into if/try/with blocks but not into functions,
    classes' methods or `if TYPE_CHECKING:`."""
    stack = list(getattr(tree, "body", []))
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack.extend(node.orelse)
            continue
        yield node
        stack.extend(ast.iter_child_nodes(node))


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


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


# ------------------------------------------------------------------------------------------------ 3. layers

def layer_of(module: str) -> str | None:
    """'estimator', 'sim', 'scenarios', 'validation', 'viz', 'cli' (rodo itself, rodo.cli, rodo.commands,
    rodo.progress), or None for modules outside rodo."""
    parts = module.split(".")
    if parts[0] != "rodo":
        return None
    if len(parts) > 1 and parts[1] in LAYERS:
        return parts[1]
    return "cli"


ALLOWED = {
    "estimator": {"estimator"},
    "sim": {"estimator", "sim"},
    "scenarios": {"estimator", "sim", "scenarios"},
    "validation": {"estimator", "sim", "scenarios", "validation"},
    "viz": {"estimator", "sim", "scenarios", "validation", "viz"},
    "cli": {"estimator", "sim", "scenarios", "validation", "viz", "cli"},
}


def layer_problems(path_name: str, source: str, current: str, is_package: bool) -> list[str]:
    """Imports (anywhere in the file) of a layer above the file's own, or of a bare folder name."""
    own = layer_of(current)
    problems = []
    for line, module, _ in imports(ast.parse(source), current, is_package):
        if module.split(".")[0] in BARE:
            problems.append(f"{path_name}:{line}: imports bare `{module}` (use rodo.{module})")
            continue
        target = layer_of(module)
        if own is not None and target is not None and target not in ALLOWED[own]:
            problems.append(f"{path_name}:{line}: {own} imports {module} ({target} is above {own})")
    return problems


def test_imports_follow_the_layers():
    problems = []
    for name, path in SOURCES.items():
        problems += layer_problems(_rel(path), path.read_text(), name, _is_package(path))
    assert not problems, "\n".join(problems)


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, out, counter = {}, {}, set(), [], [], [0]
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def import_graph(sources: dict[str, Path]) -> tuple[dict[str, set[str]], dict[tuple[str, str], int]]:
    """Module -> modules of the repository it imports at import time (top level), and the line of each edge."""
    graph, lines = {}, {}
    for name, path in sources.items():
        edges = set()
        for line, module, _ in imports(_parse(path), name, _is_package(path), top_level_only=True):
            if module in sources and module != name:
                edges.add(module)
                lines.setdefault((name, module), line)
        graph[name] = edges
    return graph, lines


def test_no_import_cycles():
    graph, lines = import_graph(SOURCES)
    edges = sum(len(v) for v in graph.values())
    assert edges > 50, f"only {edges} import edges found: is the resolver still reading the imports?"
    problems = []
    for component in import_cycles(graph):
        edges = [f"{_rel(SOURCES[a])}:{lines[(a, b)]}: {a} -> {b}" for a in component for b in sorted(graph[a])
                 if b in component]
        problems.append("import cycle between " + ", ".join(component) + ":\n    " + "\n    ".join(edges))
    assert not problems, "\n".join(problems)


# ---------------------------------------------------------------------------------------- 4. private names

def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _ours(module: str, known) -> bool:
    """A module of this repository (rodo.*, bench.*, tests.*): the rules are about our own interfaces, not
    about the standard library's or third parties' (e.g. `argparse._SubParsersAction` in type hints)."""
    return module.split(".")[0] in {"rodo", "bench", "tests"} or module in known


def private_problems(path_name: str, source: str, current: str, is_package: bool, known=KNOWN_MODULES) -> list[str]:
    """`from X import _name` (X another module of ours), imports of a private module of ours (last component
    `_x`) from outside its package, and `mod._private` on a name bound by an import of one of our modules."""
    tree = ast.parse(source)
    own_package = current if is_package else current.rpartition(".")[0]
    problems = []
    for line, module, name in imports(tree, current, is_package, known):
        if not _ours(module, known):
            continue
        if name is not None and _private(name) and module != current:
            problems.append(f"{path_name}:{line}: imports the private name {name} from {module}")
        parent, _, last = module.rpartition(".")
        if _private(last) and parent != own_package:
            problems.append(f"{path_name}:{line}: imports the private module {module} from outside its package")
    bound = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                top = alias.name.split(".")[0]
                bound[alias.asname or top] = alias.name if alias.asname else top
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node.module, node.level, current, is_package)
            for alias in node.names:
                bound[alias.asname or alias.name] = f"{base}.{alias.name}" if base else alias.name
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound
                and _private(node.attr) and _ours(bound[node.value.id], known) and bound[node.value.id] != current):
            problems.append(f"{path_name}:{node.lineno}: uses the private {node.value.id}.{node.attr} of the "
                            f"imported {bound[node.value.id]}")
    return sorted(set(problems), key=lambda p: (int(p.split(":")[1]), p))


def test_no_private_names_from_other_modules():
    problems = []
    for path in _py_files(*SIZE_DIRS):
        problems += private_problems(_rel(path), path.read_text(), module_name(path), _is_package(path))
    assert not problems, "\n".join(problems)


# ---------------------------------------------------------------------------------------------- 5. sizes

def kernel_decorators(root: Path = ROOT) -> set[str]:
    """numba's decorators and the names an estimator/jit.py module exports (if there is one)."""
    names = set(NUMBA_DECORATORS)
    jit = root / "estimator" / "jit.py"
    if jit.exists():
        tree = _parse(jit)
        exported = None
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
                exported = set(ast.literal_eval(node.value))
        if exported is None:
            exported = set()
            for node in tree.body:
                if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                    exported.add(node.name)
                elif isinstance(node, ast.Assign):
                    exported |= {t.id for t in node.targets if isinstance(t, ast.Name)}
            exported = {n for n in exported if not n.startswith("_")}
        names |= exported
    return names


def _decorator_name(node: ast.expr) -> str:
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def size_problems(path_name: str, source: str, kernels: set[str]) -> list[str]:
    """Modules over MAX_MODULE_LINES lines; functions (methods, nested functions) over MAX_FUNCTION_LINES
    lines from `def` to their last line, except compiled kernels (and what they contain)."""
    problems = []
    n = len(source.splitlines())
    if n > MAX_MODULE_LINES:
        problems.append(f"{path_name}:1: module has {n} lines (limit {MAX_MODULE_LINES})")
    stack = [ast.parse(source)]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if any(_decorator_name(d) in kernels for d in node.decorator_list):
                continue
            length = node.end_lineno - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                problems.append(f"{path_name}:{node.lineno}: function {node.name} has {length} lines "
                                f"(limit {MAX_FUNCTION_LINES})")
        stack.extend(ast.iter_child_nodes(node))
    return sorted(problems)


def test_module_and_function_sizes():
    kernels = kernel_decorators()
    problems = []
    for path in _py_files(*SIZE_DIRS):
        problems += size_problems(_rel(path), path.read_text(), kernels)
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------ 6. "Checked by:" links

CHECKED_BY = re.compile(r"Checked by:?")
REFERENCE = re.compile(r"(tests/[\w/]+\.py)(?:::([\w*]+))?|::([\w*]+)")


def _docstrings(tree: ast.AST):
    """(first line, text) of every module, class and function docstring."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                yield first.lineno, first.value.value


def checked_by_references(source: str):
    """(line, test file, test name or None) for each reference: `Checked by: tests/a.py::test_x, ::test_y`,
    continued on the next line while a line ends with a comma."""
    for first_line, doc in _docstrings(ast.parse(source)):
        lines = doc.splitlines()
        for i, text in enumerate(lines):
            m = CHECKED_BY.search(text)
            if not m:
                continue
            chunk, j = [(i, text[m.end():])], i
            while chunk[-1][1].rstrip().endswith(",") and j + 1 < len(lines):
                j += 1
                chunk.append((j, lines[j]))
            current = None
            for k, part in chunk:
                for ref in REFERENCE.finditer(part):
                    file, name, cont = ref.groups()
                    if file:
                        current = file
                        yield first_line + k, file, name
                    else:
                        yield first_line + k, current, cont


def _test_names(path: Path) -> set[str]:
    names = set()
    for node in _parse(path).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(node.name)
        elif isinstance(node, ast.ClassDef):
            names |= {f"{node.name}::{f.name}" for f in node.body if isinstance(f, ast.FunctionDef)}
    return names


def checked_by_problems(path_name: str, source: str, root: Path = ROOT) -> list[str]:
    problems = []
    for line, file, name in checked_by_references(source):
        if file is None:
            problems.append(f"{path_name}:{line}: 'Checked by' ::{name} without a test file before it")
            continue
        test_file = root / file
        if not test_file.is_file():
            problems.append(f"{path_name}:{line}: 'Checked by' names {file}, which does not exist")
            continue
        if name is not None and not fnmatch.filter(_test_names(test_file), name):
            problems.append(f"{path_name}:{line}: 'Checked by' names {file}::{name}, which {file} does not define")
    return problems


def test_checked_by_references_exist():
    problems, count = [], 0
    for path in _py_files(*SIZE_DIRS):
        source = path.read_text()
        count += sum(1 for _ in checked_by_references(source))
        problems += checked_by_problems(_rel(path), source)
    assert count > 50, f"only {count} 'Checked by' references found: is the parser still reading them?"
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------- 7. paper citations

OUTSIDE = re.compile(r"shared/paper|(?<![\w/])NOTES\.md|(?<![\w.])\.\./(?!shared/realdata)[\w./-]+|/work/\w+")
DOCS = re.compile(r"(?<![\w./-])docs/[\w./-]*\w")


def citation_problems(path_name: str, source: str, root: Path = ROOT) -> list[str]:
    """Citations of files outside the repository (the paper's notes, ../ paths; the real-data folder
    ../shared/realdata is data, not a citation) and cited docs/ files that do not exist."""
    problems = []
    for i, text in enumerate(source.splitlines(), 1):
        for m in OUTSIDE.finditer(text):
            problems.append(f"{path_name}:{i}: cites {m.group(0)!r}, outside the repository (cite docs/paper_notes.md "
                            "or another file in docs/)")
        for m in DOCS.finditer(text):
            cited = m.group(0).split("#")[0]
            if not (root / cited).exists():
                problems.append(f"{path_name}:{i}: cites {cited}, which does not exist")
    return problems


def test_paper_citations_stay_in_the_repository():
    assert (ROOT / "docs" / "paper_notes.md").is_file()
    problems = []
    for path in _py_files(*SIZE_DIRS, "tests"):
        if path == Path(__file__).resolve():
            continue
        problems += citation_problems(_rel(path), path.read_text())
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------------------------ the checks can fail

def test_checkers_catch_violations(tmp_path):
    """Each checker reports a planted violation with its file and line (and passes the clean variant)."""
    bad_layer = "import numpy\n\ndef f():\n    from rodo.viz import figures\n"
    assert layer_problems("x.py", bad_layer, "rodo.estimator.x", False) == [
        "x.py:4: estimator imports rodo.viz.figures (viz is above estimator)"]
    assert layer_problems("x.py", "from .. import lie\n", "rodo.estimator.priors.x", False) == []
    assert layer_problems("x.py", "import sim.radar\n", "rodo.viz.x", False)[0].startswith("x.py:1: imports bare")
    assert layer_problems("x.py", "import importlib\nimportlib.import_module('rodo.validation.metrics')\n",
                          "rodo.sim.x", False) == ["x.py:2: sim imports rodo.validation.metrics "
                                                   "(validation is above sim)"]

    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []

    known = {"rodo.sim._seqio", "rodo.estimator.lie._series"}
    assert private_problems("x.py", "from rodo.sim.radar import _Cull\n", "rodo.viz.x", False, known) == [
        "x.py:1: imports the private name _Cull from rodo.sim.radar"]
    assert private_problems("x.py", "from ..lie import _series\n", "rodo.estimator.priors.x", False, known) == [
        "x.py:1: imports the private module rodo.estimator.lie._series from outside its package"]
    assert private_problems("x.py", "from . import _seqio\n", "rodo.sim.x", False, known) == []
    assert private_problems("x.py", "from rodo.sim import radar\nradar._Cull\n", "rodo.viz.x", False, known) == [
        "x.py:2: uses the private radar._Cull of the imported rodo.sim.radar"]
    assert private_problems("x.py", "import argparse\nargparse._SubParsersAction\n", "rodo.x", False, known) == []
    assert private_problems("x.py", "from __future__ import annotations\nx = __name__\n", "rodo.x", False) == []

    long_fn = "def f():\n" + "    x = 1\n" * 60
    assert size_problems("x.py", long_fn, NUMBA_DECORATORS) == ["x.py:1: function f has 61 lines (limit 60)"]
    assert size_problems("x.py", "@numba.njit(cache=True)\n" + long_fn, NUMBA_DECORATORS) == []
    assert size_problems("x.py", "x = 1\n" * 401, NUMBA_DECORATORS) == ["x.py:1: module has 401 lines (limit 400)"]

    test_file = tmp_path / "tests" / "test_a.py"
    test_file.parent.mkdir()
    test_file.write_text("def test_one():\n    pass\n\ndef test_two_b():\n    pass\n")
    doc = ('"""Doc.\n\nChecked by: tests/test_a.py::test_one,\n    ::test_two_*, ::test_three\n"""\n\n'
           'def f():\n    """Checked by: tests/test_b.py"""\n')
    assert checked_by_problems("x.py", doc, tmp_path) == [
        "x.py:4: 'Checked by' names tests/test_a.py::test_three, which tests/test_a.py does not define",
        "x.py:8: 'Checked by' names tests/test_b.py, which does not exist"]

    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "paper_notes.md").write_text("notes\n")
    cite = '"""Eq. 71 corrected, see shared/paper/NOTES.md.\n\nDetails: docs/paper_notes.md, docs/gone.md."""\n'
    assert citation_problems("x.py", "# see NOTES.md\n", tmp_path)[0].startswith("x.py:1: cites 'NOTES.md'")
    assert citation_problems("x.py", cite, tmp_path) == [
        "x.py:1: cites 'shared/paper', outside the repository (cite docs/paper_notes.md or another file in docs/)",
        "x.py:3: cites docs/gone.md, which does not exist"]
    assert citation_problems("x.py", "'../shared/realdata is the data folder'\n", tmp_path) == []

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


@pytest.mark.parametrize("path, expected", [("sim/convert/vod.py", "rodo.sim.convert.vod"),
                                            ("rodo/commands/__init__.py", "rodo.commands"),
                                            ("estimator/lie/se3.py", "rodo.estimator.lie.se3"),
                                            ("bench/priors.py", "bench.priors"),
                                            ("tests/sim/test_radar.py", "tests.sim.test_radar")])
def test_module_names(path, expected):
    assert module_name(ROOT / path) == expected


# ------------------------------------------------------------------------------------- 8. docs/architecture.md

def test_architecture_doc_references_exist():
    """Every `rodo.` object and every `tests/...py::test` named in docs/architecture.md exists."""
    import importlib

    text = (ROOT / "docs" / "architecture.md").read_text()
    objects = set(re.findall(r"`(rodo\.[\w.]+)`", text))
    tests = set(re.findall(r"(tests/[\w/]+\.py)::(\w+)", text))
    assert len(objects) > 15 and len(tests) > 15, (len(objects), len(tests))
    problems = []
    for dotted in sorted(objects):
        parts = dotted.split(".")
        for cut in range(len(parts), 0, -1):  # the longest importable prefix, then attributes
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            try:
                for attr in parts[cut:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                problems.append(f"docs/architecture.md names {dotted}, which does not exist")
            break
        else:
            problems.append(f"docs/architecture.md names {dotted}, which cannot be imported")
    for file, name in sorted(tests):
        if not (ROOT / file).is_file() or name not in _test_names(ROOT / file):
            problems.append(f"docs/architecture.md names {file}::{name}, which does not exist")
    assert not problems, "\n".join(problems)
