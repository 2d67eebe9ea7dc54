"""A hostile sensor for the runtime tests: puts detections with hostile time on ``det/<s>`` of a live run.

Beside the genuine sensor ``s`` (its sequence numbers far above the genuine ones, so only the deliberate copy
is a duplicate), one phase after another: a detection from the future, with a NaN, negative or zero time, far in
the past, a clock that jumped back 10 s (2 s of detections at 10 Hz), a flood at 1000 Hz (2 s), a forged sensor
id, an exact copy. Every phase waits for the target tracker to publish 5 more estimates before the next (no
fixed sleeps), and at the end for 20 more. Writes a JSON report: how many detections each phase sent.
usage: python hostile_sensor.py ENDPOINT RUN SENSOR NODE REPORT
"""
from __future__ import annotations

import json
import math
import struct
import sys
import threading
import time

import msgpack
import zenoh

from zentrack.transport.zsession import loopback_config

WAIT_S = 30.0  # the longest wait for the tracker's estimates


def main() -> int:
    endpoint, run, sensor, node, report = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
    conf = loopback_config("peer", listen=["tcp/127.0.0.1:0"], connect=[endpoint])
    published = [0]
    seen = threading.Condition()

    def on_est(sample) -> None:
        with seen:
            published[0] += 1
            seen.notify_all()

    def after(estimates: int) -> bool:
        """Wait until the tracker has published ``estimates`` more (False after WAIT_S)."""
        with seen:
            goal = published[0] + estimates
            return seen.wait_for(lambda: published[0] >= goal, WAIT_S)

    def f64(values, shape):
        return {"shape": shape, "data": struct.pack(f"<{len(values)}d", *values)}

    seq = [10**9]

    def det(t: float, sender: int = sensor, copy_of: bytes | None = None) -> bytes:
        if copy_of is not None:
            return copy_of
        seq[0] += 1
        return msgpack.packb({"v": 2, "kind": "det", "k": seq[0], "t": t, "sender": sender,
                              "returns": f64([0.1, 0.05], [1, 2]), "pose": f64([400.0, 0.0, 0.0], [3]),
                              "noise_cov": f64([3e-4, 0.0, 0.0, 3e-4], [2, 2]), "t_pub": time.time()},
                             use_bin_type=True)

    sent: dict[str, int] = {}
    with zenoh.open(conf) as session:
        est = session.declare_subscriber(f"zentrack/{run}/est/{node}", on_est)
        pub = session.declare_publisher(f"zentrack/{run}/det/{sensor}", congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.time() + WAIT_S
        while not pub.matching_status.matching:  # a condition wait: the tracker's subscription is known
            if time.time() > deadline:
                print("hostile sensor: no subscriber on the detection key", file=sys.stderr)
                return 2
            time.sleep(0.05)  # polling interval of the wait above
        if not after(10):
            print("hostile sensor: the tracker publishes no estimates", file=sys.stderr)
            return 2
        first = det(time.time() - 0.05)
        phases = {
            "future": lambda: [det(time.time() + 30.0)],
            "nan": lambda: [det(math.nan)],
            "negative": lambda: [det(-5.0), det(0.0)],
            "far_past": lambda: [det(time.time() - 1000.0)],
            "forged_id": lambda: [det(time.time() - 0.05, sender=sensor + 1)],
            "duplicate": lambda: [first, det(0.0, copy_of=first)],
        }
        for name, make in phases.items():
            messages = make()
            for payload in messages:
                pub.put(payload)
            sent[name] = len(messages)
            after(5)
        sent["clock_back_10s"] = 0
        for _ in range(20):  # a clock that jumped back 10 s: 2 s at 10 Hz
            pub.put(det(time.time() - 10.0))
            sent["clock_back_10s"] += 1
            time.sleep(0.1)  # the sensor's own period
        after(5)
        sent["flood_1000hz"] = 0
        end = time.time() + 2.0
        while time.time() < end:  # a sensor at 1000 Hz: plausible times, far too many
            pub.put(det(time.time() - 0.02))
            sent["flood_1000hz"] += 1
            time.sleep(0.001)  # the flood's period
        served = after(20)
        est.undeclare()
    with open(report, "w") as f:
        json.dump({"sent": sent, "served_after": served}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
