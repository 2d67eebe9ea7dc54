"""Run mypy on the ``zentrack`` package as it is installed.

pyproject maps top-level folders to ``zentrack.*`` (package-dir), which an editable install resolves with an
import hook that mypy cannot see. This script lays the same package out as symlinks in a temporary folder and
runs ``mypy -p zentrack`` there, with the settings of ``[tool.mypy]`` in pyproject.toml.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())
    package_dir: dict[str, str] = conf["tool"]["setuptools"]["package-dir"]
    with tempfile.TemporaryDirectory(prefix="zentrack-typecheck-") as tmp:
        top = Path(tmp) / "zentrack"
        top.mkdir()
        for entry in (ROOT / package_dir["zentrack"]).glob("*.py"):
            (top / entry.name).symlink_to(entry)
        for name, folder in sorted(package_dir.items()):
            if name == "zentrack" or name.count(".") != 1:
                continue  # nested packages come with their parent's folder
            (top / name.split(".", 1)[1]).symlink_to(ROOT / folder, target_is_directory=True)
        env = {**os.environ, "MYPYPATH": tmp}
        cmd = [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"), "--cache-dir",
               str(Path(tmp) / ".mypy_cache"), "-p", "zentrack"]
        return subprocess.run(cmd, env=env, cwd=tmp).returncode


if __name__ == "__main__":
    sys.exit(main())
