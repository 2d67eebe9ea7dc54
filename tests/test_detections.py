"""Sensors of their own (issue 52), below the process: the detection's wire type, the tracker's intake of
detections (its clock, hostile time, the buffer in time order) and the schedule that updates at each detection's
time, stepped by hand on the in-memory network of ``tests/schedule_net.py``."""
from __future__ import annotations

import numpy as np
import pytest
from schedule_net import T0, TS, Net, deadline

from zentrack.node.detections import FOLLOW_FORWARD, FUTURE_S, STALE_S, DetectionIntake, SensorLink
from zentrack.node.diffusion.tracker import GATE_LIFT_S
from zentrack.transport.codec import WireError
from zentrack.transport.detection_messages import Detection
from zentrack.transport.messages import EstimateMessage, Measurement

R = np.diag([1e-4, 1e-4])
POSE = np.array([400.0, 0.0, 0.0])


def det(seq: int, t: float, sensor: int = 0, returns=None, scn=None) -> Detection:
    """Sensor ``sensor``'s detection ``seq`` at ``t`` (its pose and noise ``scn``'s, when given)."""
    z = np.array([[0.1, 0.2]]) if returns is None else returns
    pose, cov = (POSE, R) if scn is None else (scn.sensors[sensor], scn.noise_cov[sensor])
    return Detection(seq, t, sensor, z, pose, cov, t)


# ---------------------------------------------------------------- the wire type
def test_a_detection_round_trips_and_every_field_is_checked() -> None:
    d = Detection.decode(det(7, 1.7e9 + 0.25).encode(), 0, 2)
    assert (d.seq, d.t_meas, d.sensor) == (7, 1.7e9 + 0.25, 0)
    assert np.array_equal(d.returns, [[0.1, 0.2]]) and np.array_equal(d.noise_cov, R)
    for bad, reason in ((det(1, float("nan")), "nonfinite"), (det(1, -5.0), "range"), (det(1, 0.0), "range")):
        with pytest.raises(WireError) as err:
            Detection.decode(bad.encode(), 0, 2)
        assert err.value.reason == reason
    with pytest.raises(WireError) as err:  # a forged id: sensor 3's detection on sensor 0's key
        Detection.decode(det(1, 5.0, sensor=3).encode(), 0, 2)
    assert err.value.reason == "sender_mismatch"
    with pytest.raises(WireError) as err:
        Detection.decode(Detection(1, 5.0, 0, np.array([[0.1, 0.2]]), POSE, -R, 5.0).encode(), 0, 2)
    assert err.value.reason == "not_pd"
    with pytest.raises(WireError):  # a measurement is no detection
        Detection.decode(Measurement(3, 0.3, 0, np.array([0.1, 0.2]), None, 1.0).encode(), 0, 2)


# ---------------------------------------------------------------- the intake
def test_the_intake_hands_out_a_window_in_time_order_whatever_the_arrival_order() -> None:
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0), SensorLink(1, 4.0, offset_s=0.5)])
    times = [(0, 10.02), (1, 10.55), (0, 10.01), (0, 10.07), (1, 10.53)]  # sensor 1's clock 0.5 s ahead
    for seq, (sensor, t) in enumerate(times):
        intake.admit(det(seq, t, sensor), t_recv=10.2, processed_upto=10.0)
    assert intake.counts.out_of_order == 2  # 10.01 after 10.02, sensor 1's 10.53 after 10.55
    taken = intake.take(10.0, 10.06)
    assert [round(d.t, 3) for d in taken] == [10.01, 10.02, 10.03, 10.05]
    assert [d.det.sensor for d in taken] == [0, 0, 1, 1]
    assert [round(d.t, 3) for d in intake.take(10.06, 10.1)] == [10.07] and intake.pending() == 0


def test_a_detection_older_than_the_processed_window_is_counted_too_old_not_refused() -> None:
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0)])
    assert intake.admit(det(1, 9.95), t_recv=10.3, processed_upto=10.0) is None
    assert intake.counts.too_old == 1 and intake.counts.det_rx == 0 and intake.pending() == 0


def test_hostile_time_is_refused_and_named() -> None:
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0)])
    cases = [(det(1, 100.0 + FUTURE_S + 0.1), "future"), (det(2, 100.0 - STALE_S - 0.1), "stale"),
             (det(3, 100.0, sensor=5), "sender_mismatch")]
    for d, reason in cases:
        with pytest.raises(WireError) as err:
            intake.admit(d, t_recv=100.0, processed_upto=99.0)
        assert err.value.reason == reason, d
    intake.admit(det(4, 99.5), t_recv=100.0, processed_upto=99.0)
    with pytest.raises(WireError) as err:
        intake.admit(det(4, 99.5), t_recv=100.01, processed_upto=99.0)
    assert err.value.reason == "duplicate"


def test_a_sensor_flooding_at_1000_hz_is_rate_limited_and_a_sensor_at_its_rate_never() -> None:
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0), SensorLink(1, 10.0, offset_s=0.0)])
    limited = 0
    for n in range(2000):  # two seconds at 1000 Hz
        try:
            intake.admit(det(n, 100.0 + n * 1e-3, 0), t_recv=100.0 + n * 1e-3 + 0.01, processed_upto=99.0)
        except WireError as err:
            assert err.reason == "rate"
            limited += 1
    assert 2000 - limited <= 3.0 * 10.0 * 2 + 30 and limited > 1900  # at most 3x the rate, plus the burst
    for n in range(20):  # the other sensor at its rate: nothing refused
        intake.admit(det(n, 100.0 + n * 0.1, 1), t_recv=100.0 + n * 0.1 + 0.01, processed_upto=99.0)


def test_a_sensor_clock_offset_is_estimated_from_the_stream_and_a_jump_back_or_forward_is_followed() -> None:
    rng = np.random.default_rng(1)
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=None, min_latency_s=0.01)])
    offset = -0.2  # the sensor's clock is 200 ms behind the tracker's
    for n in range(40):
        t = 100.0 + n * 0.1
        intake.admit(det(n, t + offset), t_recv=t + 0.01 + rng.uniform(0, 0.3), processed_upto=None)
    assert intake.offset(0) == pytest.approx(offset, abs=0.05)  # (the 5 % quantile of a 0-300 ms latency above the least)
    stale = kept = 0
    for n in range(40, 140):  # the sensor's clock jumps back 10 s: refused stale until the estimate follows
        t = 100.0 + n * 0.1
        try:
            intake.admit(det(n, t + offset - 10.0), t_recv=t + 0.01 + rng.uniform(0, 0.3), processed_upto=None)
            kept += 1
        except WireError as err:
            assert err.reason == "stale"
            stale += 1
    assert stale > 10 and kept > 40, (stale, kept)
    assert intake.offset(0) == pytest.approx(offset - 10.0, abs=0.05)
    with pytest.raises(WireError) as err:  # one forged stamp from the future: refused, and the estimate unmoved
        intake.admit(det(999, 200.0), t_recv=114.0, processed_upto=None)
    assert err.value.reason == "future" and intake.offset(0) == pytest.approx(offset - 10.0, abs=0.05)
    future = kept = 0
    for n in range(140, 240):  # the clock steps forward 30 s: refused from the future until FOLLOW_FORWARD in a row
        t = 100.0 + n * 0.1
        try:
            intake.admit(det(n, t + offset + 20.0), t_recv=t + 0.01 + rng.uniform(0, 0.3), processed_upto=None)
            kept += 1
        except WireError as err:
            assert err.reason == "future"
            future += 1
    # (the forged one above is the first of the run: nothing was kept since)
    assert future == FOLLOW_FORWARD - 1 and kept == 100 - future, (future, kept)
    assert intake.offset(0) == pytest.approx(offset + 20.0, abs=0.05)


# ---------------------------------------------------------------- the schedule
LAG = 0.05


def async_net(**links) -> Net:
    """The three-node network, each tracker taking its own sensor's detections (``links`` change the sensor's
    link) with the lag :data:`LAG`."""
    def configure(cfg) -> None:
        cfg.detections = {"lag_ms": LAG * 1e3, "clock": "estimated",
                          "sensors": [{"sensor": cfg.node, "rate_hz": 10.0, "offset_s": 0.0, "min_latency_s": 0.0,
                                       **links}]}

    return Net(configure=configure)


def run_async(net: Net, steps: int, arrivals) -> dict[int, dict[int, tuple]]:
    """Steps 0..steps-1 of ``net``: ``arrivals(k)`` lists (node, detection) put in during step k's period; returns
    node -> step -> the prior it fused for that step (mean, covariance)."""
    fused: dict[int, dict[int, tuple]] = {i: {} for i in range(len(net.nodes))}
    for k in range(steps):
        base = T0 + LAG + k * TS
        net.at(base - 0.5 * TS)
        for i, d in arrivals(k):
            net.nodes[i].handle(net.msg("det", net.keys.det(d.sensor), d.encode()))
        for t in (base + 0.001, base + 0.002, deadline(k) + LAG, deadline(k) + LAG + 0.001):
            net.at(t)
            for i, ch, data in net.sent:  # every estimate decodes as the recorder and viewer decode it
                if ch == "est":
                    est = EstimateMessage.decode(data, i)
                    assert est.counters is None or "too_old" in est.counters["detections"]
            net.deliver()
        for i, node in enumerate(net.nodes):
            tr = node.payload.tracker
            if tr.prior is not None:
                kin = tr.kinematic(tr.prior)
                fused[i][tr.prior_step] = (kin.mean.copy(), kin.cov.copy())
    return fused


def test_detections_on_the_run_grid_fuse_to_the_synchronous_trackers_priors() -> None:
    """The synchronous run is the special case: one sensor per tracker sampling at the run's period, phase 0.
    The prior a synchronous tracker fuses for step k + 1 (valid at t_(k+1)) is the prior of step k + 2 of a
    tracker of its own sensor's detections (valid at its window's start, t_(k+1)), to rounding."""
    steps = 30
    sync = Net()
    sync.start()
    sync_fused: dict[int, dict[int, tuple]] = {i: {} for i in range(3)}
    for k in range(steps):
        sync.at(T0 + k * TS + 0.001)
        sync.measure(k)
        for t in (T0 + k * TS + 0.002, deadline(k), deadline(k) + 0.001):
            sync.at(t)
            sync.deliver()
        for i, node in enumerate(sync.nodes):
            tr = node.payload.tracker
            kin = tr.kinematic(tr.prior)
            sync_fused[i][tr.prior_step] = (kin.mean.copy(), kin.cov.copy())
    net = async_net()
    net.start()
    scn = net.scn

    def grid(k):  # step k's window [t_(k-1), t_k) holds the scan of step k - 1, sent during step k's period
        return [] if k == 0 else [(i, det(k - 1, T0 + (k - 1) * TS, i, scn.measurements[0, k - 1, i][None], scn))
                                  for i in range(3)]

    fused = run_async(net, steps, grid)
    compared = 0
    for i in range(3):
        for k in range(1, steps - 2):
            if k in sync_fused[i] and k + 1 in fused[i]:
                np.testing.assert_allclose(fused[i][k + 1][0], sync_fused[i][k][0], rtol=1e-9, atol=1e-9)
                np.testing.assert_allclose(fused[i][k + 1][1], sync_fused[i][k][1], rtol=1e-9, atol=1e-9)
                compared += 1
    assert compared >= 3 * (steps - 5)


def test_detections_out_of_order_within_the_lag_give_the_same_estimates_as_in_order() -> None:
    """Mixed times inside each window (two detections a period at their own phases), delivered in time order and
    reversed: the lag puts them back in order, every prior equal."""
    runs = []
    for reverse in (False, True):
        net = async_net(rate_hz=20.0)
        net.start()

        def two(k, reverse=reverse, scn=net.scn):
            if k == 0:
                return []
            out = [(i, det(2 * k + j, T0 + (k - 1) * TS + j * 0.05 + 0.013 * i, i,
                           scn.measurements[0, k - 1, i][None], scn)) for i in range(3) for j in range(2)]
            return out[::-1] if reverse else out

        runs.append(run_async(net, 20, two))
        counts = [node.payload.intake.counts for node in net.nodes]
        assert all(c.det_rx == 2 * 19 and c.too_old == 0 for c in counts)
        assert all(c.out_of_order == (19 if reverse else 0) for c in counts)
    for i in range(3):
        assert set(runs[0][i]) == set(runs[1][i]) and len(runs[0][i]) >= 15
        for k in runs[0][i]:
            np.testing.assert_array_equal(runs[0][i][k][0], runs[1][i][k][0])


def test_a_detection_after_its_window_is_counted_too_old_and_the_tracker_serves_on() -> None:
    net = async_net()
    net.start()
    scn = net.scn

    def late(k):  # node 0's scans arrive two periods late: after their window was taken
        out = [(i, det(k - 1, T0 + (k - 1) * TS, i, scn.measurements[0, k - 1, i][None], scn)) for i in (1, 2) if k]
        if k >= 2:
            out.append((0, det(k - 2, T0 + (k - 3) * TS, 0, scn.measurements[0, k - 3, 0][None], scn)))
        return out

    fused = run_async(net, 20, late)
    counts = net.nodes[0].payload.intake.counts
    assert counts.too_old >= 17 and counts.det_rx <= 1
    assert len(fused[0]) >= 18  # it fused every step from its neighbours' estimates
    assert net.nodes[0].payload.counters.coasted >= 17


def test_a_forged_detection_in_time_and_form_is_held_off_by_the_gate_until_the_sensor_is_lost_for_3_s() -> None:
    """Node 0's sensor is joined by a forger whose detections come in time, in form, with a bearing 0.5 rad off:
    each is outside the validation gate and moves nothing (the priors equal those of the run without it). A sensor
    whose detections are all outside for GATE_LIFT_S (a tracker that lost its target) is taken again."""
    def scans(k, scn, forged: bool):
        out = [(i, det(k - 1, T0 + (k - 1) * TS, i, scn.measurements[0, k - 1, i][None], scn)) for i in range(3) if k]
        if forged and k:
            z = scn.measurements[0, k - 1, 0] + np.array([0.5, 0.0])
            out.append((0, det(10_000 + k, T0 + (k - 1) * TS, 0, z[None], scn)))  # (at the same time: no new interval)
        return out

    runs, nets = [], []
    for forged in (False, True):
        net = async_net(rate_hz=20.0)
        net.start()
        runs.append(run_async(net, 20, lambda k, scn=net.scn, forged=forged: scans(k, scn, forged)))
        nets.append(net)
    assert nets[1].nodes[0].payload.tracker.gated_detections == 19 and nets[0].nodes[0].payload.tracker.gated_detections == 0
    for k in runs[0][0]:
        np.testing.assert_array_equal(runs[0][0][k][0], runs[1][0][k][0])

    net = async_net()  # only the forger from step 1 on: outside the gate until 3 s have passed, then taken
    net.start()
    lift = int(GATE_LIFT_S / TS)
    run_async(net, lift + 5, lambda k, scn=net.scn: [(0, det(k, T0 + (k - 1) * TS, 0, (scn.measurements[0, k - 1, 0]
                                                      + np.array([0.5, 0.0]))[None], scn))] if k else [])
    assert net.nodes[0].payload.tracker.gated_detections == lift
