"""Installing zentrack prints no deprecation from the project's own files (issue 31): ``project.license`` is an
SPDX string (a TOML table made setuptools print a 12-line deprecation box three times per install)."""
from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_the_licence_is_an_spdx_string_and_the_build_backend_reads_it():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "Apache-2.0"
    assert "setuptools>=77" in project["build-system"]["requires"]  # the first to read an SPDX licence string


@pytest.mark.slow
def test_building_the_package_prints_no_deprecation(tmp_path):
    """What ``pip install`` runs (metadata, then the wheel), in an isolated build environment as a fresh
    clone gets it."""
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--wheel-dir", str(tmp_path), str(ROOT)],
                          capture_output=True, text=True, timeout=300)
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output
    assert "deprecated" not in output.lower() and "project.license" not in output, output
    assert list(tmp_path.glob("zentrack-*.whl"))
