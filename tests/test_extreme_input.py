"""Well-formed but extreme or contradictory messages: each is refused with its reason, or its unusable result
is kept out of the node's estimate (``refused``), and the network goes on with finite, positive definite
estimates. Before these checks each of them killed a tracker or stalled a lockstep run (found by fuzzing the
node's schedule with forged messages)."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.bench.step import T0, LockstepNetwork
from zentrack.transport import wire
from zentrack.transport.codec import Message
from zentrack.transport.keys import Keys, node_id
from zentrack.transport.messages import EstimateMessage, Measurement, RoundMessage
from zentrack.transport.scan_messages import ForwardedScan

STEPS = 6


def run_with(net: LockstepNetwork, inject, at_step: int = 2) -> None:
    for k in range(STEPS):
        if k == at_step:
            inject(net)
        net.step(k)


def assert_healthy(net: LockstepNetwork) -> None:
    """Every node ran every step; every estimate finite with a positive definite covariance."""
    assert [n.payload.state.step for n in net.nodes] == [STEPS] * len(net.nodes)
    ests = [EstimateMessage.decode(e, wire.unpack(e)["sender"]) for e in net.estimates]
    assert len(ests) == STEPS * len(net.nodes)
    for e in ests:  # decoding itself refuses a non-finite or indefinite covariance
        assert np.isfinite(e.x).all() and np.linalg.eigvalsh(e.P)[0] > 0


def test_node_ids_are_ascii_digits_only():
    assert node_id("12") == 12 and node_id("0") == 0
    for name in ("²", "\u0663", "", "12345", "truth", "-1", "1 "):  # '²'.isdigit() is True, int('²') raises
        assert node_id(name) is None, name
    assert Keys("r").node_of("zentrack/r/alive/3") == 3


def test_a_liveliness_token_named_with_a_unicode_digit_is_ignored():
    net = LockstepNetwork(3, STEPS, "eskf")
    node = net.nodes[0]
    live = set(node.live)
    node.handle(Message("alive", net.keys.alive("²"), b"put", T0))
    assert node.live == live
    run_with(net, lambda net: None)
    assert_healthy(net)


@pytest.mark.parametrize("field,value", [("pose", 1e155), ("returns", 1e13)])
def test_a_measurement_beyond_any_coordinate_is_refused_by_range(field, value):
    z, pose = np.array([0.1, 0.2]), np.zeros(3)
    if field == "pose":
        pose = np.full(3, value)
    else:
        z = np.array([value, 0.2])
    payload = Measurement(0, 0.0, 0, z, pose, 0.0).encode()
    with pytest.raises(wire.WireError) as err:
        Measurement.decode(payload, 0, 2)
    assert err.value.reason == "range"
    edge = np.full(3, wire.MAX_COORDINATE)  # the largest accepted
    assert np.array_equal(Measurement.decode(Measurement(0, 0.0, 0, np.zeros(2), edge, 0.0).encode(), 0, 2).pose, edge)


def test_contradictory_information_blocks_are_kept_out_of_the_prior():
    """diff-ici: a forged round message whose 'state' block is vague (passes any gate) and whose 'moment'
    block is confident makes inverse CI indefinite; the node refuses that fusion and keeps its own estimate."""
    def inject(net: LockstepNetwork) -> None:
        n = net.nodes[0].payload.tracker.block_dims["state"]
        for sender in (1, 3):
            forged = RoundMessage(3, 0.3, sender, 1, {"state": (1e-6 * np.eye(n), np.zeros(n)),
                                                      "moment": (1e-6 * np.eye(n), np.zeros(n))}, 0.0).encode()
            net.nodes[0].handle(Message("prior", net.keys.prior(sender), forged, T0))

    for kind in ("eskf", "ukf"):
        net = LockstepNetwork(4, STEPS, kind, fusion="diff-ici", fusion_params={"relay_scans": True})
        run_with(net, inject)
        assert_healthy(net)
        assert net.nodes[0].payload.tracker.refused["fusion"] >= 1
        assert net.nodes[0].snapshot()["refused"]["fusion"] == net.nodes[0].payload.tracker.refused["fusion"]


def test_a_trace_block_that_overflows_fast_ci_is_kept_out():
    def inject(net: LockstepNetwork) -> None:
        n = net.nodes[0].payload.tracker.block_dims["state"]
        for sender in (1, 3):
            blocks = {"state": (np.eye(n), np.zeros(n)), "trace": (np.array([[1.0]]), np.array([-1e300]))}
            forged = RoundMessage(3, 0.3, sender, 1, blocks, 0.0).encode()
            net.nodes[0].handle(Message("prior", net.keys.prior(sender), forged, T0))

    net = LockstepNetwork(4, STEPS, "eskf", fusion="diff-fci")
    run_with(net, inject)
    assert_healthy(net)
    assert net.nodes[0].payload.tracker.refused["fusion"] >= 1


def test_a_forwarded_scan_with_a_vanishing_noise_cannot_break_the_posterior():
    """R = 1e-300 I is positive definite and passes decoding; with hcmci (scans shared, no gate on them) the
    update it makes has a slightly indefinite posterior (min eigenvalue about -7e-16), which is refused."""
    def inject(net: LockstepNetwork) -> None:
        z = net.scn.measurements[0, 2, 1]
        scan = ForwardedScan(2, 0.2, 1, 1, z, net.scn.sensors[1], 1e-300 * np.eye(2), 0.0).encode()
        net.nodes[0].handle(Message("scan", net.keys.scan(1), scan, T0))

    net = LockstepNetwork(4, STEPS, "eskf", fusion="hcmci")
    run_with(net, inject)
    assert_healthy(net)


def test_an_update_that_raises_is_refused_and_the_node_keeps_its_prior(monkeypatch):
    net = LockstepNetwork(3, STEPS, "eskf")
    tracker = net.nodes[0].payload.tracker

    def failing_update(prior, scans):
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    def inject(net: LockstepNetwork) -> None:
        monkeypatch.setattr(tracker.filter, "update", failing_update)

    run_with(net, inject, at_step=STEPS - 1)
    assert_healthy(net)
    assert tracker.refused == {"update": 1, "fusion": 0}
