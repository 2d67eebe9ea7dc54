"""A sensor behind an impaired link, for tests/test_sensor_faults.py: ``zentrack sensor`` (``truth/sensor.py``)
unchanged, but each detection it puts on the wire between run times FROM_S and TO_S (seconds after the run's t0)
is dropped with probability DROP, or else leaves DELAY_MS later, give or take a uniform JITTER_MS, as on a
congested, lossy link (seeded: SEED); the ones put before and after leave at once. The netns harness impairs links
between its services (``zentrack netns impair``) but runs no sensors of their own, so the link is impaired here,
at the sensor's publisher.

It writes REPORT (JSON) at the end: per detection, its sequence number, its measurement time and the time it left
(run time, s; None: dropped), and whether it was in the impaired stretch.
usage: python impaired_sensor.py REPORT FROM_S TO_S DELAY_MS JITTER_MS DROP SEED -- sensor --id S <its flags>
"""
from __future__ import annotations

import heapq
import itertools
import json
import random
import sys
import threading
import time

import msgpack

from zentrack.cli import main as zentrack_main
from zentrack.truth import sensor as sensor_module


class ImpairedLink:
    """The sensor's publisher behind the impairment (module docstring): ``put`` decides each detection's fate;
    a thread puts the delayed ones when they are due."""

    def __init__(self, pub, owner, window: tuple[float, float], delay_s: float, jitter_s: float, drop: float,
                 seed: int) -> None:
        self.pub, self.owner, self.window = pub, owner, window
        self.delay_s, self.jitter_s, self.drop = delay_s, jitter_s, drop
        self.rng = random.Random(seed)
        self.due: list[tuple[float, int, bytes, dict]] = []
        self.order = itertools.count()
        self.cv = threading.Condition()
        self.closed = False
        self.log: list[dict] = []
        self.thread = threading.Thread(target=self._send_due, daemon=True)
        self.thread.start()

    def put(self, payload: bytes) -> None:
        t0 = self.owner.start.t0
        now = time.time()
        det = msgpack.unpackb(payload, raw=False)
        entry = {"seq": int(det["k"]), "t": det["t"] - t0 - self.owner.spec.offset_s, "put": now - t0,
                 "impaired": self.window[0] <= now - t0 < self.window[1], "left": None}
        self.log.append(entry)
        if not entry["impaired"]:
            self.pub.put(payload)
            entry["left"] = entry["put"]
        elif self.rng.random() >= self.drop:
            delay = self.delay_s + self.rng.uniform(-self.jitter_s, self.jitter_s)
            with self.cv:
                heapq.heappush(self.due, (now + delay, next(self.order), payload, entry))
                self.cv.notify()

    def _send_due(self) -> None:
        with self.cv:
            while not self.closed:
                wait = self.due[0][0] - time.time() if self.due else 0.2
                if wait > 0:
                    self.cv.wait(min(wait, 0.2))
                    continue
                _, _, payload, entry = heapq.heappop(self.due)
                self.pub.put(payload)
                entry["left"] = time.time() - self.owner.start.t0

    def undeclare(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify()
        self.thread.join(2.0)
        self.pub.undeclare()


def main() -> int:
    split = sys.argv.index("--")
    report, start, end, delay_ms, jitter_ms, drop, seed = sys.argv[1:split]
    links: list[ImpairedLink] = []

    class ImpairedSensor(sensor_module.Sensor):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            self.pub = ImpairedLink(self.pub, self, (float(start), float(end)), float(delay_ms) / 1e3,
                                    float(jitter_ms) / 1e3, float(drop), int(seed))
            links.append(self.pub)

    sensor_module.Sensor = ImpairedSensor  # type: ignore[misc]  # the process's own sensor, impaired
    code = zentrack_main(sys.argv[split + 1:])
    with open(report, "w") as f:
        json.dump({"detections": links[0].log if links else []}, f)
    return code


if __name__ == "__main__":
    sys.exit(main())
