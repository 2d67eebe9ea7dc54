"""Where a tracker's CPU goes, by part: py-spy's sampled stacks and the kernel's per-thread CPU, sorted into the
parts of a tracker step (``zentrack bench profile``, :mod:`~zentrack.bench.profile`).

A py-spy sample (``--format raw``: ``thread (tid): name;outermost (file:line);...;innermost (file:line) count``) is
one stack of one thread that was running (py-spy leaves idle threads out). Its part is the part of its innermost
frame that names one (:data:`PARTS`, first rule first): a numpy or msgpack frame names none, so its time goes to
the zentrack code that called it, and the tracker's main loop names "timers and wake-ups" only for what no deeper
frame claims. Native work that never enters Python (Zenoh's own threads reading, writing and routing) has no
Python frame; it is the kernel's per-thread CPU (``/proc/<pid>/task/<tid>/schedstat``) of each thread less what
py-spy saw of it there.
"""
from __future__ import annotations

import os
import re
from collections import Counter, defaultdict
from dataclasses import dataclass

#: (part, file suffix or "" for any file, function-name pattern or "" for any): the first rule a frame matches
#: names its part; a part of None marks a helper (linear algebra, array packing, estimate types) whose time is its
#: caller's. Files are matched by their path's end, so an editable install (``<repo>/node/...``) and an installed
#: package (``site-packages/zentrack/node/...``) give the same parts; a rule without a file holds for zentrack's own
#: frames only.
PARTS: tuple[tuple[str | None, str, str], ...] = (
    ("logging", "logging/__init__.py", ""),
    ("covariance checks (SPD)", "fusion/linalg.py", r"^is_spd$"),
    ("covariance checks (SPD)", "transport/codec_arrays.py", r"^check_p"),
    (None, "fusion/linalg.py", ""),
    (None, "fusion/estimates.py", ""),
    (None, "transport/codec_arrays.py", ""),
    (None, "transport/codec_types.py", ""),
    (None, "transport/codec.py", ""),
    ("decoding", "", r"(^|\.)_?(decode|from_wire|from_map)"),
    ("decoding", "transport/track_messages.py", r"^_"),
    ("encoding", "", r"(^|\.)_?(encode|to_wire|to_map)"),
    ("receiving (Zenoh callbacks, inbox)", "transport/inbox.py", ""),
    ("publishing", "node/process.py", r"(^|\.)send$"),
    ("local filter", "fusion/filters/", ""),
    ("local filter", "fusion/measurement.py", ""),
    ("local filter", "fusion/motion.py", ""),
    ("fusion (CI, gate)", "fusion/covariance_intersection.py", ""),
    ("fusion (CI, gate)", "fusion/rules/", ""),
    ("fusion (CI, gate)", "fusion/gate.py", ""),
    ("fusion (CI, gate)", "node/diffusion/fusion_policy.py", ""),
    ("fusion (CI, gate)", "node/diffusion/rounds.py", ""),
    ("fusion (CI, gate)", "node/diffusion/tracker.py", r"fuse|gate"),
    ("admission and counters", "node/diffusion/admission.py", ""),
    ("admission and counters", "node/track_lists/admission.py", ""),
    ("admission and counters", "node/diffusion/neighbour_clocks.py", ""),
    ("admission and counters", "node/diffusion/tracker.py", r"usable"),
    ("admission and counters", "node/counters.py", ""),
    ("admission and counters", "node/detections.py", ""),
    ("run clock", "node/clock_offset.py", ""),
    ("track-to-track fusion", "fusion/track_to_track/", ""),
    ("track-to-track fusion", "fusion/multitarget/network.py", r"fuse|network_ids|predicted"),
    ("association (gating, assignment)", "fusion/multitarget/gating.py", ""),
    ("association (gating, assignment)", "fusion/multitarget/gnn.py", ""),
    ("association (gating, assignment)", "fusion/multitarget/jpda.py", ""),
    ("association (gating, assignment)", "fusion/multitarget/murty.py", ""),
    ("many-target tracker (update, births, lifecycle)", "fusion/multitarget/", ""),
    ("local step and estimate", "node/diffusion/", ""),
    ("local step and estimate", "node/track_lists/", ""),
    ("local step and estimate", "fusion/", ""),
    ("timers and wake-ups", "node/", ""),
    ("timers and wake-ups", "transport/", ""),
)
OTHER = "other (outside the tracker's code)"
_RULES = [(part, suffix, re.compile(pattern) if pattern else None) for part, suffix, pattern in PARTS]
_LINE = re.compile(r"^thread \((?P<tid>\d+)\): (?P<stack>.*) (?P<count>\d+)$")
_FRAME = re.compile(r"^(?P<func>.*) \((?P<file>[^()]*):\d+\)$")


@dataclass(frozen=True)
class Sample:
    """One line of py-spy's raw output: ``count`` samples of one stack of thread ``tid``."""

    tid: int
    thread: str
    frames: tuple[tuple[str, str], ...]  # (function, file), outermost first
    count: int


def parse_raw(text: str) -> list[Sample]:
    """The samples of py-spy's ``--format raw --threads`` output (lines of another shape are skipped)."""
    out = []
    for line in text.splitlines():
        m = _LINE.match(line.strip())
        if m is None:
            continue
        name, *frames = m.group("stack").split(";")
        parsed = []
        for frame in frames:
            f = _FRAME.match(frame)
            parsed.append((f.group("func"), f.group("file")) if f else (frame, ""))
        out.append(Sample(int(m.group("tid")), name, tuple(parsed), int(m.group("count"))))
    return out


def frame_rule(func: str, file: str) -> tuple[str | None] | None:
    """The part a frame names (:data:`PARTS`) as a 1-tuple (its part None for a helper), None when no rule holds
    (a library's frame)."""
    path = file.replace(os.sep, "/")
    for part, suffix, pattern in _RULES:
        if suffix and not (path.endswith(suffix) if suffix.endswith(".py") else f"/{suffix}" in f"/{path}"):
            continue
        if pattern is not None and pattern.search(func) is None:
            continue
        if not suffix and not _is_zentrack(path):  # a name-only rule holds for the project's own frames
            continue
        return (part,)
    return None


_ZENTRACK_DIRS = ("node/", "fusion/", "transport/", "common/", "config/", "truth/", "viewer/", "bench/", "study/",
                  "zentrack/")


def _is_zentrack(path: str) -> bool:
    return any(f"/{d}" in f"/{path}" for d in _ZENTRACK_DIRS) and "site-packages/numpy" not in path


def sample_part(sample: Sample) -> str:
    """The part of a sample: that of its innermost frame naming one (a helper's goes to its caller), else
    :data:`OTHER`."""
    for func, file in reversed(sample.frames):
        rule = frame_rule(func, file)
        if rule is not None and rule[0] is not None:
            return rule[0]
    return OTHER


def parts(samples: list[Sample]) -> Counter[str]:
    """Samples per part."""
    out: Counter[str] = Counter()
    for s in samples:
        out[sample_part(s)] += s.count
    return out


def samples_per_thread(samples: list[Sample]) -> Counter[int]:
    out: Counter[int] = Counter()
    for s in samples:
        out[s.tid] += s.count
    return out


def thread_kind(pid: int, tid: int, name: str) -> str:
    """A thread's kind: ``main`` for the process's first thread, else its name without a trailing number
    (Zenoh's ``rx-0``, ``tx-1``, ``acc-0`` become ``rx``, ``tx``, ``acc``)."""
    if tid == pid:
        return "main (Python)"
    return re.sub(r"[-_ ]?\d+$", "", name.strip()) or name.strip()


def thread_cpu(pid: int) -> dict[int, tuple[str, float]]:
    """Per thread of process ``pid``: (its name, CPU seconds it has run so far, to the nanosecond); {} once gone."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return {}
    out = {}
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                ns = int(f.read().split()[0])
            with open(f"/proc/{pid}/task/{tid}/comm") as f:
                name = f.read().strip()
        except (OSError, ValueError, IndexError):
            continue
        out[int(tid)] = (name, ns / 1e9)
    return out


def cpu_delta(before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]]) -> dict[int, float]:
    """CPU seconds per thread between two :func:`thread_cpu` samples (a thread born between them counts from zero)."""
    return {tid: seconds - before.get(tid, (name, 0.0))[1] for tid, (name, seconds) in after.items()}


def cpu_by_kind(pid: int, before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]]) -> dict[str, float]:
    """CPU seconds per thread kind of ``pid`` between two :func:`thread_cpu` samples."""
    out: defaultdict[str, float] = defaultdict(float)
    for tid, seconds in cpu_delta(before, after).items():
        out[thread_kind(pid, tid, after[tid][0])] += seconds
    return dict(out)
