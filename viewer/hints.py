"""What a run tells its user about the viewer: where the recording is, the live URL and how to open both
(standard library only: the orchestrator prints these without importing Rerun)."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

#: the web viewer's query switch that leaves out the welcome screen and its online examples
NO_WELCOME = "hide_welcome_screen"


def web_url(bind: str, web_port: int, grpc_port: int) -> str:
    """The address of the web viewer ``zentrack viewer --serve`` serves, streaming its gRPC proxy; without
    Rerun's welcome screen, whose examples list is fetched from the internet (offline: a "Failed to load
    examples" toast)."""
    host = "127.0.0.1" if bind in ("0.0.0.0", "") else bind
    return f"http://{host}:{web_port}/?url=rerun%2Bhttp://{host}:{grpc_port}/proxy&{NO_WELCOME}"


def live_line(url: str) -> str:
    return f"viewer: watch the run live in a browser at {url}"


def rerun_command() -> str:
    """``rerun`` (the viewer command rerun-sdk installs) when it is on PATH, else its path beside this Python
    (a virtual environment that is not activated)."""
    beside = Path(sys.executable).with_name("rerun")
    return "rerun" if shutil.which("rerun") or not beside.exists() else str(beside)


def recording_line(path: Path | str) -> str:
    """How to open a saved recording."""
    return f"viewer: recording in {path}; open it with `{rerun_command()} {path}` (or drag the file into the web viewer)"


def run_lines(recording: Path | str, serve: bool, bind: str = "127.0.0.1") -> list[str]:
    """What ``zentrack run --viewer`` prints as it starts: the recording's path and how to open it, and with
    ``--viewer-serve`` the live URL (the viewer's default ports)."""
    from zentrack.viewer.ports import GRPC_PORT, WEB_PORT

    return [recording_line(recording), *([live_line(web_url(bind, WEB_PORT, GRPC_PORT))] if serve else [])]
