"""Package metadata: one version (pyproject.toml, `rodo --version`, rodo.__version__, CITATION.cff), the SPDX
license with its LICENSE file, the citation of the paper, and rerun-sdk pinned to one minor version."""

import subprocess
import sys
import tomllib
from pathlib import Path

import yaml

import rodo

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
    from importlib.metadata import version

    assert version("rerun-sdk").startswith(f"{major}.{minor}.")  # the installed one is inside the range
