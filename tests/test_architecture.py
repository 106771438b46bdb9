"""The structural rules of the code base, checked by reading the source (ast), not by convention.

1.-2. One import namespace and the packages pyproject lists: tests/test_namespace.py.
3. Layers: estimator <- sim <- scenarios <- validation <- viz <- CLI (rodo/cli.py, rodo/commands); imports
   anywhere in a file count (also inside functions); no import cycle between modules.
4. No private name taken from another module (tests exempt).
5. No module over 400 lines, no function over 60 lines (compiled kernels exempt).

The references from code and docs to tests and docs (Checked by, paper citations, docs/architecture.md) are
checked in tests/test_doc_references.py.

Each check collects every violation as "file:line: what" and fails with the whole list. The checkers are plain
functions of (path, source) so `test_checkers_catch_violations` can show that each one can fail.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from rodo.estimator.tomlcompat import tomllib

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


@pytest.mark.parametrize("path, expected", [("sim/convert/vod.py", "rodo.sim.convert.vod"),
                                            ("rodo/commands/__init__.py", "rodo.commands"),
                                            ("estimator/lie/se3.py", "rodo.estimator.lie.se3"),
                                            ("bench/priors.py", "bench.priors"),
                                            ("tests/sim/test_radar.py", "tests.sim.test_radar")])
def test_module_names(path, expected):
    assert module_name(ROOT / path) == expected
