"""Package metadata: one version (pyproject.toml, `rodo --version`, rodo.__version__, CITATION.cff), the SPDX
license with its LICENSE file, the citation of the paper, and rerun-sdk pinned to one minor version."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import rodo
from rodo.estimator.tomlcompat import tomllib

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def test_version_is_one_number_everywhere():
    out = subprocess.run([sys.executable, "-m", "rodo", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"rodo {PROJECT['version']}"
    assert rodo.__version__ == PROJECT["version"]
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert str(cff["version"]) == PROJECT["version"]


def test_license_is_spdx_mit_with_its_file():
    assert PROJECT["license"] == "MIT" and PROJECT["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "Copyright (c) 2026 the rodo authors" in text
    assert "Permission is hereby granted, free of charge" in text


def test_citation_prefers_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software" and cff["license"] == "MIT"
    paper = cff["preferred-citation"]
    first_line = (ROOT.parent / "shared" / "paper").glob("*.txt")
    title = next((p.read_text().strip().splitlines()[0] for p in first_line), None)
    if title is not None:  # the paper's own title line (with its TeX $SE(3)$), where the paper text is present
        assert paper["title"] == title.replace("$", "")
    assert [a["family-names"] for a in paper["authors"]] == ["Retan", "Loshaj", "Heizmann"]


def test_rerun_is_pinned_to_one_minor_version():
    viz = PROJECT["optional-dependencies"]["viz"]
    pin = next(d for d in viz if d.startswith("rerun-sdk"))
    lower, upper = (part.lstrip("<>=") for part in pin.removeprefix("rerun-sdk").split(","))
    major, minor = map(int, lower.split(".")[:2])
    assert upper == f"{major}.{minor + 1}"
    from importlib.metadata import PackageNotFoundError, version

    try:
        installed = version("rerun-sdk")
    except PackageNotFoundError:
        pytest.skip("rerun-sdk (the viz extra) is not installed: its pin is checked, not an installed version")
    assert installed.startswith(f"{major}.{minor}.")  # the installed one is inside the range


def test_toml_reader_on_this_python():
    """`tomlcompat.tomllib` parses TOML on every supported Python (the standard library's from 3.11, tomli on 3.10),
    and pyproject declares tomli exactly where it is needed."""
    from rodo.estimator.tomlcompat import tomllib as reader

    assert reader.loads('a = [1, 2]\n[b]\nc = "x"\n') == {"a": [1, 2], "b": {"c": "x"}}
    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    assert project["requires-python"] == ">=3.10"
    assert "tomli>=1.1; python_version < '3.11'" in project["dependencies"]
    if sys.version_info >= (3, 11):
        import tomllib as stdlib

        assert reader is stdlib
