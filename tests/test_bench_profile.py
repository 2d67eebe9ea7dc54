"""``zentrack bench profile`` (issue 55, item 1): py-spy's stacks sorted into the parts of a tracker step, and the
kernel's per-thread CPU beside them."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import pytest

from zentrack.bench.profile import load_of
from zentrack.bench.profile_parts import (
    OTHER,
    cpu_by_kind,
    parse_raw,
    parts,
    sample_part,
    samples_per_thread,
    thread_cpu,
    thread_kind,
)
from zentrack.config.run_setup import scenario_setup

RAW = """\
thread (100): MainThread;run (/repo/node/process.py:10);handle (/repo/node/schedule.py:5);RoundMessage.decode (/repo/transport/messages.py:3);unpack_symmetric (/repo/transport/codec_arrays.py:8) 7
thread (100): MainThread;run (/repo/node/process.py:10);Tracker.fuse (/repo/node/diffusion/tracker.py:40);ci_fuse_one (/repo/fusion/covariance_intersection.py:9);spd_mean_cov_one (/repo/fusion/linalg.py:2);inv (/venv/site-packages/numpy/linalg/_linalg.py:600) 5
thread (100): MainThread;run (/venv/site-packages/zentrack/node/process.py:10);update (/venv/site-packages/zentrack/fusion/filters/extended_state.py:7) 3
thread (100): MainThread;run (/repo/node/process.py:10);get (/usr/lib/python3.11/queue.py:180) 2
thread (101): Dummy-1;callback (/repo/transport/inbox.py:30);put (/usr/lib/python3.11/queue.py:150) 4
thread (101): Dummy-1;info (/usr/lib/python3.11/logging/__init__.py:1400);emit (/usr/lib/python3.11/logging/__init__.py:1100) 1
thread (102): Dummy-2;<module> (/usr/lib/python3.11/threading.py:1) 1
a line of another shape
"""


def test_raw_lines_become_samples_with_their_threads_and_frames():
    samples = parse_raw(RAW)
    assert len(samples) == 7
    first = samples[0]
    assert (first.tid, first.thread, first.count) == (100, "MainThread", 7)
    assert first.frames[0] == ("run", "/repo/node/process.py")
    assert first.frames[-1] == ("unpack_symmetric", "/repo/transport/codec_arrays.py")
    assert samples_per_thread(samples) == {100: 17, 101: 5, 102: 1}


def test_a_sample_goes_to_its_innermost_part_and_a_helper_to_its_caller():
    samples = parse_raw(RAW)
    # array unpacking is a helper: its time is the decoding of the message that called it
    assert sample_part(samples[0]) == "decoding"
    # numpy and the linear-algebra helper go to the CI fusion that called them
    assert sample_part(samples[1]) == "fusion (CI, gate)"
    # an installed package's paths name the same parts as a repository's
    assert sample_part(samples[2]) == "local filter"
    # waiting on the inbox's queue is the loop's own
    assert sample_part(samples[3]) == "timers and wake-ups"
    assert sample_part(samples[4]) == "receiving (Zenoh callbacks, inbox)"
    assert sample_part(samples[5]) == "logging"
    assert sample_part(samples[6]) == OTHER
    assert parts(samples) == {"decoding": 7, "fusion (CI, gate)": 5, "local filter": 3, "timers and wake-ups": 2,
                              "receiving (Zenoh callbacks, inbox)": 4, "logging": 1, OTHER: 1}


def test_threads_are_named_by_kind_and_their_cpu_is_read_from_the_kernel():
    assert thread_kind(50, 50, "zentrack") == "main (Python)"
    assert thread_kind(50, 51, "rx-0") == "rx"
    assert thread_kind(50, 52, "tx-13") == "tx"
    assert thread_kind(50, 53, "acc") == "acc"
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            sum(range(1000))

    worker = threading.Thread(target=spin, name="spinner")
    before = thread_cpu(os.getpid())
    started = time.monotonic()
    worker.start()
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        time.sleep(0.01)
    after = thread_cpu(os.getpid())
    wall = time.monotonic() - started
    stop.set()
    worker.join()
    assert os.getpid() in after and worker.native_id in after
    by_kind = cpu_by_kind(os.getpid(), before, after)
    # the spinning thread, born between the samples, counts from zero and ran most of the 0.3 s; the sleeping main
    # thread did not
    spinner = after[worker.native_id][1]
    assert 0.05 < spinner <= wall + 0.01
    assert by_kind["main (Python)"] < spinner
    assert thread_cpu(2**22 + 1) == {}  # no such process


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="py-spy attaches with ptrace (CI runs as root)")
def test_the_live_profile_sorts_a_trackers_cpu_into_parts_and_threads(tmp_path):
    out = tmp_path / "profile.json"
    done = subprocess.run([sys.executable, "-m", "zentrack", "bench", "profile", "--nodes", "4", "--duration", "40",
                           "--profiled", "1", "--router", "--floor", "--json", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    r = json.loads(out.read_text())
    print(done.stdout)
    total = r["tracker_ms_per_step"]
    assert 0.2 < total < 50  # a tracker works every step, and a step is 100 ms
    threads = r["threads_ms_per_step"]
    assert "main (Python)" in threads and len(threads) >= 3  # the main thread and Zenoh's own
    assert abs(sum(threads.values()) - total) < 1e-6 * max(1.0, total)
    parts_ms = r["parts_ms_per_step"]
    # 25 s sampled: the smallest part asked for (encoding, 0.1 ms a step) is about 25 samples at the full rate. With
    # 10 s sampled, beside the screenshot test's Chromium and 20 tracker processes (run 54), py-spy saw half the main
    # thread's Python and encoding got none
    for part in ("decoding", "local filter", "fusion (CI, gate)", "encoding"):
        assert parts_ms.get(part, 0.0) > 0, (part, parts_ms)
    # what py-spy saw of Python is a share of the threads' CPU, never more
    assert sum(parts_ms.values()) <= total * 1.05
    # sampling never pauses a tracker (--nonblocking): the sampled tracker costs what the others of the same run do
    # (1.03 times measured; 5.5 times with py-spy pausing it at each sample). The run's deadline misses are the
    # host's (5 beside the screenshot test's Chromium in run 53, 0 with py-spy pausing the tracker on an idle host):
    # reported, and said to make it the profile of a loaded host, not judged here.
    assert r["sampled_tracker_ms_per_step"] <= 1.25 * r["unsampled_tracker_ms_per_step"], r
    assert "sampling costs its process" in done.stdout
    assert r["lost_estimates"] == 0
    assert (r["deadline_misses"] > 0) == ("profile of a loaded host" in done.stderr), (r["deadline_misses"], done.stderr[-500:])
    assert "a tracker costs" in done.stdout and "ms/step" in done.stdout
    # the null trackers of `bench floor` right after: the messaging alone costs less than a tracker
    assert 0.05 < r["null_tracker_ms_per_step"] < total
    assert r["over_floor"] == pytest.approx(total / r["null_tracker_ms_per_step"])
    assert "times the floor" in done.stdout


@pytest.mark.slow
@pytest.mark.cpu_only
@pytest.mark.skipif(os.geteuid() != 0, reason="py-spy attaches with ptrace (CI runs as root)")
def test_the_in_process_profile_counts_only_the_trackers_work(tmp_path):
    out = tmp_path / "step.json"
    done = subprocess.run([sys.executable, "-m", "zentrack", "bench", "profile", "--form", "step", "--nodes", "4",
                           "--json", str(out)], capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    r = json.loads(out.read_text())
    shares = r["parts_share"]
    assert abs(sum(shares.values()) - 1.0) < 1e-9
    assert r["samples"] > 50
    for part in ("decoding", "local filter", "fusion (CI, gate)"):
        assert shares.get(part, 0.0) > 0.02, (part, shares)
    assert shares.get(OTHER, 0.0) < 0.05  # the bus and the bench are left out: little falls outside the parts


@pytest.mark.parametrize("scenario", ["mt-50", "mt-birth-death"])
def test_a_many_target_profile_is_put_per_target_and_per_return(scenario):
    """The load a many-target profile divides by: the targets present per step, and the returns per scan of one
    sensor, which are the detections of its targets in view (P_D each) and its clutter; a single-target run has none."""
    def setup(name):
        return scenario_setup(name, steps=30)

    s = setup(scenario)
    load, data, sensing = load_of(s), s.multitarget_data, s.multitarget.sensing
    assert load["targets_per_step"] == pytest.approx(data.alive.sum(axis=1).mean()) and load["targets_per_step"] >= 2
    expected = sensing.detection_prob * data.in_view.sum(axis=2).mean() + sensing.clutter_rate
    assert abs(load["returns_per_scan"] - expected) < 1.0, (load, expected)  # (240 scans: ~4 standard errors)
    assert load_of(setup("exp2")) == {}
