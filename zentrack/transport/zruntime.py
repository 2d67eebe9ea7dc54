"""How many threads Zenoh's receive runtime gets in a zentrack process (``ZENOH_RUNTIME``).

Zenoh reads its runtimes' thread counts from the ``ZENOH_RUNTIME`` environment variable once, when its first
session opens. Its receive runtime (``rx``) has 2 worker threads by default, and a link whose lease expires is
closed on one of them. Zenoh sets ``SO_LINGER`` to 10 s on its TCP links, so closing a link whose far end is
unreachable (a cut cable, a partition) with data still queued blocks that worker thread in
``close()`` for up to 10 s while the kernel tries to deliver it (Zenoh issue 1101, "Drop of
LinkUnicastTcp can stall Runtime"). A router that loses two links at once then has no receive thread left: it
reads nothing from anyone, and dials nothing, until the first close gives up. Measured in
``tests/test_partition.py`` (a host's router cut off for 10 s): that router's two receive threads sat in
``close()`` from 1 s after the cut (its lease) to 11 s, so the far host's trackers heard the truth again 13
steps after the heal; with :data:`RX_WORKER_THREADS` threads, 2 steps.
"""
from __future__ import annotations

import os

#: worker threads of Zenoh's receive runtime: enough that links closing on a dead path (each blocking one
#: thread for up to 10 s) leave some free. Idle workers sleep: measured, a process with two linked sessions has
#: 16 threads instead of 10 and 0.1 MB more resident memory (41.5 MB).
RX_WORKER_THREADS = 8
RUNTIME_ENV = "ZENOH_RUNTIME"


def runtime_setting(rx_workers: int = RX_WORKER_THREADS) -> str:
    """The ``ZENOH_RUNTIME`` value (RON) that gives Zenoh's receive runtime ``rx_workers`` worker threads."""
    if rx_workers < 1:
        raise ValueError(f"rx_workers must be at least 1, got {rx_workers}")
    return f"(rx: (worker_threads: {int(rx_workers)}))"


def ensure_runtime_threads() -> str:
    """Set ``ZENOH_RUNTIME`` to :func:`runtime_setting` unless the user set it; call before the first session
    opens (later calls change nothing Zenoh reads). Returns the value in effect. Processes this one starts
    inherit it."""
    current = os.environ.get(RUNTIME_ENV)
    if current is None:
        os.environ[RUNTIME_ENV] = current = runtime_setting()
    return current
