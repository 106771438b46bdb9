"""The estimator's compiled-code conventions: numba's `njit`, the shared fast-math flags, a sound cache key.

Numba's on-disk cache (`cache=True`) keys a kernel on the source of its own file only, so a kernel whose callee
lives in another file keeps its stale machine code when only the callee changes (numba issue 9483). Importing this
module installs, once, a cache locator that keys every kernel of a registered root on a digest over its own file
and every file of the root it imports, transitively (`source_digest`): editing a callee, or a table of constants
a kernel reads, invalidates every cache entry that depends on it. Kernel modules import `njit` from here, which is
numba's own decorator; importing it guarantees the locator is in place before any kernel is decorated (numba
picks the locator and reads the source stamp at decoration time).

If numba's (private) caching API is not the one expected, nothing is installed and numba's plain behaviour
remains.

Compiling every kernel takes a minute or more (77-81 s on a 2-core machine); it happens once, on the first run after an
install or an edit (then the cache loads in a second). The first compilation of a registered root's kernel in a
process prints COMPILE_NOTICE on stderr (a numba compile event: numba fires it only on a cache miss), so a
first run does not look hung. `make install` compiles them all (`python -m rodo.warmup`).

Checked by: tests/estimator/test_kernel_cache.py
"""

from __future__ import annotations

import ast
import hashlib
import os
import sys
from pathlib import Path

from numba import njit
from numba.core import event

__all__ = ["COMPILE_NOTICE", "FASTMATH", "LOCATOR_INSTALLED", "njit", "register_kernel_root", "source_digest",
           "source_stamp"]

COMPILE_NOTICE = ("rodo: compiling kernels (first run after an install or an edit only: a minute or more, then "
                  "cached)")

# IEEE-safe fast-math subset shared by the kernels (no nnan/ninf: finiteness checks must survive)
FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

_ROOTS: dict[Path, str] = {}  # registered root directory -> its import name
_DIGESTS: dict[tuple, str] = {}  # (root, file, stat signature of the root's files) -> digest


def register_kernel_root(path, package: str) -> None:
    """Key the numba cache of every kernel defined under `path` on `source_digest` (see the module docstring).

    Args:
        path: directory of a package whose kernels should get the digest as their cache key.
        package: the import name of that package (e.g. "rodo.estimator"), to resolve absolute imports.

    Register before the package's kernel modules are imported.

    Checked by: tests/estimator/test_kernel_cache.py::test_editing_a_callee_in_another_file_recompiles_the_caller
    """
    _ROOTS[Path(path).resolve()] = package


def _module_files(root: Path, parts: tuple[str, ...]) -> list[Path]:
    """The files that importing root's module `parts` executes: the packages' __init__ files and the module."""
    out = [root.joinpath(*parts[:i], "__init__.py") for i in range(len(parts) + 1)]
    out.append(root.joinpath(*parts).with_suffix(".py") if parts else root / "__init__.py")
    return [p for p in out if p.is_file()]


def _imports(root: Path, package: str, file: Path) -> set[Path]:
    """Files under root that `file` imports (directly), resolved from its import statements."""
    pkg = file.relative_to(root).parts[:-1]  # the package the file belongs to (for relative imports)
    prefix = package.split(".")
    targets: list[tuple[str, ...]] = []
    tree = ast.parse(file.read_bytes(), filename=str(file))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [(a.name.split("."), ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if node.level - 1 > len(pkg):
                    continue
                base = list(pkg[:len(pkg) - (node.level - 1)])
                names = [(prefix + base + (node.module.split(".") if node.module else []),
                          tuple(a.name for a in node.names))]
            else:
                names = [(node.module.split("."), tuple(a.name for a in node.names))]
        else:
            continue
        for dotted, members in names:
            if dotted[:len(prefix)] != prefix:
                continue
            mod = tuple(dotted[len(prefix):])
            targets.append(mod)
            targets.extend(mod + (m,) for m in members if m != "*")
    found: set[Path] = set()
    for t in targets:
        found.update(_module_files(root, t))
    return found


def source_digest(root, package: str, file) -> str:
    """SHA-256 over `file` and every file under `root` it imports, transitively (paths and contents).

    Args:
        root: the registered package directory.
        package: its import name.
        file: a .py file under root (where a kernel is defined).

    Returns:
        hex digest; it changes when any of those files' text changes.

    Checked by: tests/estimator/test_kernel_cache.py::test_package_digest_changes_with_any_kernel_file
    """
    root, file = Path(root).resolve(), Path(file).resolve()
    stats = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in sorted(root.rglob("*.py")))
    key = (root, file, stats)
    if key not in _DIGESTS:
        seen: set[Path] = set()
        todo = [file]
        while todo:
            f = todo.pop()
            if f in seen:
                continue
            seen.add(f)
            todo.extend(_imports(root, package, f) - seen)
        h = hashlib.sha256()
        for f in sorted(seen):
            h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
        _DIGESTS[key] = h.hexdigest()
    return _DIGESTS[key]


def source_stamp(py_file) -> str | None:
    """The cache key of the kernels defined in `py_file`: its `source_digest` if the file lies under a registered
    root, else None (numba's own key applies).

    Checked by: tests/estimator/test_kernel_cache.py::test_the_package_kernels_are_keyed_on_the_digest
    """
    path = Path(py_file).resolve()
    for root, package in _ROOTS.items():
        if root in path.parents:
            return "rodo-digest-" + source_digest(root, package, path)
    return None


def _install() -> bool:
    """Put the digest-keyed locators in front of numba's; False (plain numba) if its API is not as expected."""
    try:
        from numba.core import caching
    except ImportError:
        return False
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    bases = [getattr(caching, n, None) or getattr(caching, "_" + n, None)
             for n in ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator")]
    classes = getattr(impl, "_locator_classes", None)
    if impl is None or not isinstance(classes, list) or any(b is None for b in bases):
        return False
    if any(getattr(c, "rodo_digest_locator", False) for c in classes):
        return True

    class DigestMixin:
        """Source stamp = `source_digest` of the kernel's file, for files under a registered root only."""

        rodo_digest_locator = True

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                if source_stamp(py_file) is None:
                    return None
            except (OSError, SyntaxError, ValueError):  # unreadable sources: numba's own locators take it
                return None
            self = super().from_function(py_func, py_file)
            if self is not None:
                self.rodo_file = py_file
            return self

        def get_source_stamp(self):
            return source_stamp(self.rodo_file)

    made = [type("Digest" + b.__name__, (DigestMixin, b), {}) for b in bases]
    classes[:0] = made
    return True


class _CompileNotice(event.Listener):
    """Prints COMPILE_NOTICE once per process, at the first compilation of a kernel under a registered root."""

    said = False

    def on_start(self, ev):
        if _CompileNotice.said:
            return
        func = getattr(ev.data.get("dispatcher"), "py_func", None) if isinstance(ev.data, dict) else None
        file = getattr(getattr(func, "__code__", None), "co_filename", None)
        if file and any(root in Path(file).resolve().parents for root in _ROOTS):
            _CompileNotice.said = True
            print(COMPILE_NOTICE, file=sys.stderr, flush=True)

    def on_end(self, ev):
        pass


event.register("numba:compile", _CompileNotice())
LOCATOR_INSTALLED = _install()
register_kernel_root(os.path.dirname(os.path.abspath(__file__)), __package__ or "rodo.estimator")
