"""A hostile process for the runtime tests: publishes malformed messages on prior/** and meas/** of a run.

Every message is invalid in one of the ways the wire codec must catch (garbage, truncated msgpack, wrong
shapes, NaN/Inf, non-PD or asymmetric matrices, stale and future steps, a sender that does not match its
key). Writes a JSON report of how many messages went to each key.

No fixed sleeps: it waits (with timeouts) for every key to have a subscriber before the attack, and after it
for every node to publish ROUNDS more posteriors before closing its session (see ``linger``).
usage: python hostile_publisher.py ENDPOINT RUN NODES STATE_DIM MEAS_DIM COUNT REPORT
"""
from __future__ import annotations

import json
import sys
import threading
import time

import msgpack
import numpy as np
import zenoh

from zentrack.transport.zsession import loopback_config

ROUNDS = 10  # posteriors every node must publish after the attack before the session closes


def main() -> int:
    endpoint, run, nodes, n, m, count, report = sys.argv[1:8]
    nodes, n, m, count = int(nodes), int(n), int(m), int(count)
    rng = np.random.default_rng(0)
    conf = loopback_config("peer", listen=["tcp/127.0.0.1:0"], connect=[endpoint])
    sent = {"prior": [0] * nodes, "meas": [0] * nodes}
    posteriors = [0] * nodes  # posteriors published by each node, counted from est/<i>
    counted = threading.Condition()

    def on_est(sample) -> None:
        i = str(sample.key_expr).rsplit("/", 1)[-1]
        if i.isdigit() and int(i) < nodes:
            with counted:
                posteriors[int(i)] += 1
                counted.notify_all()

    with zenoh.open(conf) as session:
        block = zenoh.CongestionControl.BLOCK
        pubs = {(kind, i): session.declare_publisher(f"zentrack/{run}/{kind}/{i}", congestion_control=block)
                for kind in ("prior", "meas") for i in range(nodes)}
        est = session.declare_subscriber(f"zentrack/{run}/est/*", on_est)
        deadline = time.time() + 20
        while not all(p.matching_status.matching for p in pubs.values()):  # a condition wait, 20 s at most
            if time.time() > deadline:
                print("hostile: no subscribers on some keys", file=sys.stderr)
                return 2
            time.sleep(0.05)  # polling interval of the wait above

        def arr(a):
            a = np.ascontiguousarray(a, dtype="<f8")
            return {"shape": list(a.shape), "data": a.tobytes()}

        def sym(a):
            iu = np.triu_indices(a.shape[0])
            return {"sym": a.shape[0], "data": np.ascontiguousarray(a[iu], dtype="<f8").tobytes()}

        spd = np.eye(n) * 2.0

        def prior(j, **over):
            msg = {"v": 1, "kind": "prior", "k": 10**6, "t": 0.0, "sender": j, "t_pub": 0.0, "Y": sym(spd), "y": arr(np.zeros(n))}
            msg.update(over)
            return msgpack.packb(msg, use_bin_type=True)

        def meas(i, **over):
            msg = {"v": 1, "kind": "meas", "k": 10**6, "t": 0.0, "sender": "truth", "node": i, "present": True,
                   "t_pub": 0.0, "z": arr(np.zeros(m))}
            msg.update(over)
            return msgpack.packb(msg, use_bin_type=True)

        nan_y = np.zeros(n)
        nan_y[0] = np.nan
        inf_m = spd.copy()
        inf_m[1, 1] = np.inf
        asym = spd.copy()
        asym[0, 1] = 0.5
        bad_prior = [
            lambda j: rng.bytes(int(rng.integers(1, 200))),                    # garbage
            lambda j: prior(j, k=0)[: int(rng.integers(5, 60))],                # truncated
            lambda j: prior(j, k=0, Y=sym(np.eye(n + 1))),                      # wrong shape
            lambda j: prior(j, k=0, y=arr(nan_y)),                              # NaN
            lambda j: prior(j, k=0, Y=sym(inf_m)),                              # Inf
            lambda j: prior(j, k=0, Y=sym(-spd)),                               # not PD
            lambda j: prior(j, k=0),                                            # stale step
            lambda j: prior(j, k=10**6),                                        # future step
            lambda j: prior(j, k=0, sender=(j + 1) % nodes),                    # spoofed sender
            lambda j: prior(j, k=0, Y=arr(asym)),                               # asymmetric
        ]
        bad_meas = [
            lambda i: rng.bytes(int(rng.integers(1, 200))),
            lambda i: meas(i)[: int(rng.integers(5, 40))],
            lambda i: meas(i, k=-1, z=arr(np.zeros(m + 1))),
            lambda i: meas(i, k=-1, z=arr(np.full(m, np.nan))),
            lambda i: meas(i, k=-1, z=arr(np.full(m, np.inf))),
            lambda i: meas(i, k=-1),
            lambda i: meas(i, k=10**6),
            lambda i: meas(i, k=-1, node=(i + 1) % nodes),
            lambda i: meas(i, k=-1, sender="node"),
            lambda i: meas(i, k=-1, v=7),
        ]
        for c in range(count):
            i = c % nodes
            if c % 2 == 0:
                pubs[("prior", i)].put(bad_prior[(c // 2) % len(bad_prior)](i))
                sent["prior"][i] += 1
            else:
                pubs[("meas", i)].put(bad_meas[(c // 2) % len(bad_meas)](i))
                sent["meas"][i] += 1

        # linger: a put has no delivery acknowledgement, and closing the session at once could cut the last
        # batches still queued in the transport. Keep it open until every node has published ROUNDS more
        # posteriors, i.e. the cluster has exchanged that many rounds of data since the last put (10 s at most).
        t_last = time.time()
        with counted:
            after = list(posteriors)
            if counted.wait_for(lambda: all(p >= a + ROUNDS for p, a in zip(posteriors, after)), timeout=10.0):
                print(f"hostile: every node published {ROUNDS} more posteriors {time.time() - t_last:.2f} s after the "
                      "attack", file=sys.stderr)
            else:
                print(f"hostile: nodes published {[p - a for p, a in zip(posteriors, after)]} posteriors in the "
                      "10 s after the attack", file=sys.stderr)
        est.undeclare()
    with open(report, "w") as f:
        json.dump(sent, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
