"""Follow one measurement of the default run from the truth to the viewer, and list every file the path enters.

The path is the real code with only Zenoh cut out: the truth's ``publish_step`` (its publishers replaced by
lists), the tracker's inbox callback (fed the truth's bytes as a Zenoh sample), its process's ``deliver``, the
schedule and its payload (``advance``), and the viewer's core handling the estimate the tracker published. A
profiler (``sys.setprofile``) notes every function entered in a file of this repository while the measurement
travels; files entered only by the set-up (building the scenario, the node, the viewer) are not counted.

``trace()`` returns ``{file: [functions]}`` in the order the path first enters each file; ``render_files()`` the
Markdown list the mkdocs hook puts where ``docs/data-path.md`` has ``<!-- data-path-files -->``;
``tests/test_data_path.py`` checks the page against it.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
HARNESS = Path(__file__).resolve()  # this file's stand-ins for Zenoh are not the path
#: the default run: paper 0's Experiment 2 (TESKF trackers, CI diffusion), three nodes, realtime
SCENARIO, NODES, FILTER = "exp2", 3, "teskf"
WALL_PERIOD_S = 10.0


class _Publisher:
    """A Zenoh publisher's stand-in: keeps what is put."""

    def __init__(self) -> None:
        self.out: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.out.append(payload)


class _Sample:
    """A received Zenoh sample's stand-in (the key and the payload's bytes)."""

    class _Payload:
        def __init__(self, data: bytes) -> None:
            self.data = data

        def __len__(self) -> int:
            return len(self.data)

        def to_bytes(self) -> bytes:
            return self.data

    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr, self.payload = key, self._Payload(data)


def _node_side(setup: Any, keys: Any, t0: float) -> tuple[Any, Any, list[tuple[str, bytes]]]:
    """Node 0 of a run starting at ``t0`` (the wall clock's), its process (no session opened) and what it sends,
    started and waiting for step 0."""
    from zentrack.common.procs import StopFlag
    from zentrack.node.clock_offset import RunClock
    from zentrack.node.diffusion.tracker import Tracker
    from zentrack.node.process import NodeProcess
    from zentrack.node.schedule import NodeSchedule
    from zentrack.transport.codec import Message
    from zentrack.transport.messages import Start

    sent: list[tuple[str, bytes]] = []
    cfg = setup.node_config(0)
    clock = RunClock(0, sampling=True)
    schedule = NodeSchedule.diffusion(keys, cfg, Tracker(cfg), clock=clock, send=lambda ch, d: sent.append((ch, d)))
    args = argparse.Namespace(reconnect_s=2.0, truth_timeout=30.0)
    proc = NodeProcess(args, schedule, keys, StopFlag(), clock)
    for j in range(NODES):
        proc.deliver(Message("alive", keys.alive(j), b"put", time.time()))
    proc.deliver(Message("alive", keys.alive("truth"), b"put", time.time()))
    scn = setup.scenario
    # a wall period of WALL_PERIOD_S: step 0's deadline is seconds away, however loaded the machine
    start = Start(t0, WALL_PERIOD_S, scn.steps, "realtime", tuple(range(NODES)), setup.deadline_frac,
                  scn.x0_estimate[0]).encode()
    proc.deliver(Message("start", keys.start, start, time.time()))
    return schedule, proc, sent


def trace() -> dict[str, list[str]]:
    """Every repository file the measurement's path enters -> the functions entered there (module docstring)."""
    import rerun as rr

    from zentrack.config.run_setup import RunSetup
    from zentrack.config.scenario_config import builtin_spec
    from zentrack.transport import inbox as inbox_module
    from zentrack.transport.keys import Keys
    from zentrack.truth.process import Truth
    from zentrack.truth.simulation.simulate import simulate
    from zentrack.viewer.core import Viewer
    from zentrack.viewer.single_target import single_target

    scn = simulate(builtin_spec(SCENARIO, nodes=NODES, steps=20), runs=1, seed=1)
    setup = RunSetup.from_data(scn, FILTER, 1e-6, None, "realtime", 0.5, "path")
    keys = Keys("path")
    truth = Truth.__new__(Truth)  # the truth process's step without its session
    truth.scn, truth.mt, truth.pub_truth = scn, None, _Publisher()
    truth.pub_meas = {i: _Publisher() for i in range(NODES)}
    viewer = Viewer(None, keys, *single_target(setup, rr.RecordingStream("zentrack-data-path")))
    t0 = time.time() + 0.05
    schedule, proc, sent = _node_side(setup, keys, t0)
    direct, inbox_module.direct = inbox_module.direct, lambda f: f  # the inbox's callback as a plain function
    try:
        on_sample = proc.inbox.callback("meas")
    finally:
        inbox_module.direct = direct
    from zentrack.transport.codec import Message

    entered: dict[str, list[str]] = {}

    def note(frame: FrameType, event: str, arg: object) -> None:
        if event != "call":
            return
        path = Path(frame.f_code.co_filename)
        if path.is_absolute() and path.is_relative_to(ROOT) and ".venv" not in path.parts and path != HARNESS:
            names = entered.setdefault(path.relative_to(ROOT).as_posix(), [])
            if frame.f_code.co_name not in names:
                names.append(frame.f_code.co_name)

    time.sleep(max(0.0, t0 + 0.002 - time.time()))  # step 0's sample time has come
    sys.setprofile(note)
    try:
        truth.publish_step(0, t0)
        on_sample(_Sample(keys.meas(0), truth.pub_meas[0].out[0]))
        proc.deliver(proc.inbox.get(0.0))
        schedule.advance()
        estimate = next(d for ch, d in sent if ch == "est")
        viewer.handle(Message("est", keys.est(0), estimate, time.time()))
    finally:
        sys.setprofile(None)
    if viewer.canvas.logged["est"] != 1:
        raise RuntimeError("the data path's estimate did not reach the viewer")
    return entered


def render_files(entered: dict[str, list[str]] | None = None) -> str:
    """The page's list: how many files, then each with the functions entered, in the path's order."""
    entered = trace() if entered is None else entered
    rows = [f"| {i} | `{path}` | {', '.join(f'`{name}`' for name in names)} |"
            for i, (path, names) in enumerate(entered.items(), 1)]
    return "\n".join([f"The path enters **{len(entered)} files** (generated at each build of this site by "
                      "`docs/hooks/data_path.py`, which follows the calls):", "",
                      "| # | file | functions entered |", "|---|---|---|", *rows])


if __name__ == "__main__":
    print(render_files())
