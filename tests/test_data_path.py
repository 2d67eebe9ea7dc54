"""The data path page (docs/data-path.md) against the code: one measurement of the default run, followed call by call
from the truth to the viewer (``docs/hooks/data_path.py``), enters every file the page's table names, and the page
lists every file it enters (generated at the site's build)."""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "docs" / "hooks"))

import data_path  # noqa: E402 - the hooks' folder, as mkdocs imports it

PAGE = ROOT / "docs" / "data-path.md"


def test_the_measurement_reaches_the_viewer_through_every_file_the_page_names() -> None:
    entered = data_path.trace()
    named = re.findall(r"^\| \d+ \| `([^`]+)` \|", PAGE.read_text(), flags=re.M)
    assert len(named) >= 10 and named[0] == "truth/process.py" and named[-1].startswith("viewer/")
    assert not [f for f in named if f not in entered], "files the page names that the path does not enter"
    order = list(entered)
    assert [f for f in order if f in named] == named, "the page's files in another order than the path's"
    for file in ("node/schedule.py", "node/diffusion/tracker.py", "fusion/filters/extended_state.py",
                 "zentrack/transport/messages.py", "viewer/core.py"):
        assert file in entered, file
    assert "docs/hooks/data_path.py" not in entered  # the harness's stand-ins are not the path


def test_the_page_lists_every_file_entered() -> None:
    assert "<!-- data-path-files -->" in PAGE.read_text()
    entered = {"truth/process.py": ["publish_step"], "node/schedule.py": ["handle", "advance"]}
    text = data_path.render_files(entered)
    assert "**2 files**" in text and "| 2 | `node/schedule.py` | `handle`, `advance` |" in text
