"""References from the code and the docs, checked by reading them (ast, regular expressions):

6. Every "Checked by:" reference names an existing test file and test function.
7. Paper corrections the code relies on are cited inside the repository (docs/paper_notes.md), never outside.
8. Every function and test docs/architecture.md names exists.
9. Every section cited by its title (`docs/page.md, "Title"` or `page.md ("Title")`) is a heading of that page.

The structural rules (namespace, layers, cycles, private names, sizes) are in tests/test_architecture.py; the
checkers here are plain functions of (path, source) so `test_reference_checkers_catch_violations` can show
that each one can fail.
"""

from __future__ import annotations

import ast
import fnmatch
import re
from pathlib import Path

from tests.test_architecture import ROOT, SIZE_DIRS, _parse, _py_files, _rel


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


# ------------------------------------------------------------------------------ 9. sections cited by title

SECTION = re.compile(r"\b([\w-]+\.md)(?:,\s*|\s+\(?|\s*\()\"([^\"\s][^\"]{0,159})\"")
WRAP = re.compile(r"\s*\n\s*(?:#\s*)?")


def headings(text: str) -> set[str]:
    """The titles of a markdown page's headings, without their leading #s."""
    return {line.lstrip("#").strip() for line in text.splitlines() if re.match(r"#{1,6} ", line)}


def _opens(heading: str, title: str) -> bool:
    """Whether the heading is the title, or goes on past it after a whole word ("Session 44: ...")."""
    return heading.startswith(title) and (len(heading) == len(title) or not heading[len(title)].isalnum())


def section_problems(path_name: str, source: str, pages: dict[str, set[str]]) -> list[str]:
    """Sections cited by title that are not a heading of the page. A heading may go on past the cited title after a
    whole word, as "The floor per model (`rodo verdict --floor-ca`, ...)" and "Session 44: ..." do. `pages` maps a
    page's file name to its headings; pages not in it (a report's CONFIG.md, a README elsewhere) are not checked. A
    title wrapped over lines, in a docstring or a comment, is read as one line."""
    problems = []
    for m in SECTION.finditer(source):
        page, title = m.group(1), WRAP.sub(" ", m.group(2)).strip()
        if page in pages and not any(_opens(h, title) for h in pages[page]):
            line = source.count("\n", 0, m.start()) + 1
            problems.append(f"{path_name}:{line}: cites {page}, \"{title}\", which is not a heading of {page}")
    return problems


def test_cited_sections_exist():
    pages = {p.name: headings(p.read_text()) for p in (ROOT / "docs").glob("*.md")}
    paths = list(_py_files(*SIZE_DIRS, "tests")) + sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    problems, count = [], 0
    for path in paths:
        source = path.read_text()
        count += sum(1 for m in SECTION.finditer(source) if m.group(1) in pages)
        problems += section_problems(_rel(path), source, pages)
    assert count > 100, f"only {count} sections cited by title found: is the pattern still reading them?"
    assert not problems, "\n".join(problems)


def test_reference_checkers_catch_violations(tmp_path):
    """Each checker reports a planted violation with its file and line (and passes the clean variant)."""
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

    pages = {"a.md": headings("# A\n\n## The floor per model (session 45)\n\nnot ## a heading\n")}
    cited = ('"""See docs/a.md, "The floor per model", a.md ("The floor\n    per model"), b.md, "Anything";\n'
             '    docs/a.md, "The floor per mode" and a.md "not"."""\n')
    assert section_problems("x.py", cited, pages) == [
        'x.py:3: cites a.md, "The floor per mode", which is not a heading of a.md',
        'x.py:3: cites a.md, "not", which is not a heading of a.md']
