"""A sensor's clock that jumps back (issue 52, item 7: the soak's ``--clock-jump-every``), without Zenoh: the sensor
process's pure clock (:class:`~zentrack.truth.sensor.SensorClock`) stepped back at a wall time and staying there,
the stamps of the detections measured after the step (not of those measured before it and published after),
the SIGUSR1 that asks for a step (:class:`~zentrack.truth.sensor.ClockSteps`: noted by the handler, taken by the
loop), a tracker's intake fed that stream (it refuses the stepped detections as ``stale`` until its offset
estimate follows, at the 61st: ``FOLLOW_DETECTIONS``, the length of the fault's window; a smaller step is dropped
as ``too_old`` instead), and the cluster's bookkeeping: a sensor restarted after a step keeps it (its host's
clock), so its tracker sees no step forward, which it would refuse as ``future`` until ``FOLLOW_FORWARD`` of them."""
from __future__ import annotations

import os
import signal
from collections import Counter

import pytest

from zentrack.cluster.soak.fault_kinds import FOLLOW_DETECTIONS
from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.node.detections import FOLLOW_FORWARD, STALE_S, DetectionIntake, SensorLink
from zentrack.transport.codec import WireError
from zentrack.transport.detection_messages import Detection
from zentrack.truth.sensor import CLOCK_JUMP_S, ClockSteps, SensorClock, detection
from zentrack.truth.simulation.sensor_stream import sensor_stream

T0 = 1.75e9


def test_a_stepped_clock_reads_back_from_its_step_on_and_stays_there():
    clock = SensorClock(T0, offset_s=0.12, drift_ppm=0.0)
    stepped = clock.stepped_back(30.0, at=T0 + 5.0)
    assert stepped.reading(T0 + 4.999) == clock.reading(T0 + 4.999)  # before the step: as it was
    assert stepped.reading(T0 + 5.0) == pytest.approx(clock.reading(T0 + 5.0) - 30.0)
    assert stepped.reading(T0 + 500.0) == pytest.approx(clock.reading(T0 + 500.0) - 30.0)  # it stays back
    twice = stepped.stepped_back(30.0, at=T0 + 40.0)
    assert [twice.back_at(T0 + t) for t in (0.0, 5.0, 39.9, 40.0, 1e4)] == [0.0, 30.0, 30.0, 60.0, 60.0]
    restarted = SensorClock(T0, 0.12).stepped_back(60.0)  # --clock-back-s 60: the host's steps before the start
    assert restarted.back_at(T0) == 60.0 and restarted.reading(T0 + 50.0) == pytest.approx(twice.reading(T0 + 50.0))
    assert clock.steps == () and stepped.steps == ((T0 + 5.0, 30.0),), "a clock is a value: stepping makes another"
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError):
            clock.stepped_back(bad, T0)


def _stream(sensor: int = 0):
    cfg = resize(load_scenario_config("exp2-async"), None, 300)
    scn = cfg.scenario_data()
    spec = cfg.sensor_timing.stream(sensor)
    return scn, spec, sensor_stream(scn, spec, cfg.seed)


def test_detections_measured_after_the_step_carry_the_stepped_stamp_those_before_it_their_own():
    scn, spec, stream = _stream(0)
    clock = SensorClock(T0, spec.offset_s, spec.drift_ppm).stepped_back(CLOCK_JUMP_S, at=T0 + 10.0)
    late = [d for d in stream if d.t < 10.0 <= d.t_publish]  # measured before the step, published after it
    assert late, "the stream has detections in flight at the step (latency up to 300 ms)"
    for d in stream:
        wire = detection(d, 0, T0, scn.sensors[0], scn.noise_cov[0], clock.reading(T0 + d.t_publish),
                         clock.back_at(T0 + d.t))
        back = CLOCK_JUMP_S if d.t >= 10.0 else 0.0
        assert wire.t_meas == T0 + d.stamp - back
        assert wire.t_pub == pytest.approx(T0 + d.t_publish + spec.offset_s - (CLOCK_JUMP_S if d.t_publish >= 10 else 0))


def test_a_sigusr1_is_noted_by_the_handler_and_taken_once_by_the_loop():
    times = iter([100.0, 101.5])
    steps = ClockSteps(clock=lambda: next(times))
    old = signal.getsignal(signal.SIGUSR1)
    try:
        steps.install()
        os.kill(os.getpid(), signal.SIGUSR1)  # the soak's jump_clock: the process runs on
        os.kill(os.getpid(), signal.SIGUSR1)
        assert steps.take() == [100.0, 101.5] and steps.take() == []
    finally:
        signal.signal(signal.SIGUSR1, old)
    clock = SensorClock(T0)
    for at in [100.0, 101.5]:
        clock = clock.stepped_back(CLOCK_JUMP_S, at)
    assert clock.back_at(102.0) == 2 * CLOCK_JUMP_S


def _feed(jump_s: float, sensor: int = 0, after_s: float = 10.0) -> tuple[Counter, list[str]]:
    """A tracker's intake fed sensor ``sensor``'s stream whose clock steps back ``jump_s`` at ``after_s``: the
    outcome of each detection measured after the step, in order, and their count."""
    scn, spec, stream = _stream(sensor)
    intake = DetectionIntake([SensorLink(sensor, spec.rate_hz, None, spec.latency.low_s)])
    clock = SensorClock(T0, spec.offset_s, spec.drift_ppm).stepped_back(jump_s, at=T0 + after_s)
    after: list[str] = []
    for d in sorted(stream, key=lambda d: d.t_publish):
        wire = detection(d, sensor, T0, scn.sensors[sensor], scn.noise_cov[sensor], clock.reading(T0 + d.t_publish),
                         clock.back_at(T0 + d.t))
        processed = T0 + d.t_publish - 0.35 - 0.1  # the tracker's last window, a lag behind
        try:
            kept = intake.admit(Detection.decode(wire.encode(), sensor, 2), T0 + d.t_publish, processed)
            outcome = "kept" if kept is not None else "too_old"
        except WireError as err:
            outcome = err.reason
        if d.t >= after_s:
            after.append(outcome)
    return Counter(after), after


def test_the_tracker_refuses_the_stepped_detections_as_stale_until_its_offset_follows_then_keeps_them():
    counts, order = _feed(CLOCK_JUMP_S)
    first_kept = order.index("kept")
    assert set(order[:first_kept]) == {"stale"} and first_kept == FOLLOW_DETECTIONS - 1 == 60, order[:70]
    assert counts["stale"] == FOLLOW_DETECTIONS - 1 and "future" not in counts
    assert counts["kept"] >= 0.9 * (len(order) - first_kept), counts  # back: a tenth reordered late, dropped old


def test_a_step_within_the_stale_limit_is_dropped_as_too_old_until_the_tracker_follows():
    assert 2.0 < STALE_S
    counts, order = _feed(2.0)
    first_kept = order.index("kept")
    assert set(order[:first_kept]) == {"too_old"} and first_kept == FOLLOW_DETECTIONS - 1, order[:70]
    assert "stale" not in counts


def test_a_clock_that_returns_after_its_tracker_followed_is_refused_as_future_until_it_follows_that_too():
    """A return is a step forward: the intake takes no sample from a stamp from its future once its estimate is
    established (a forged future stamp must move nothing), so it refuses the returned clock's detections as
    ``future`` until ``FOLLOW_FORWARD`` of them in a row say it stepped, then starts its estimate again from the
    next (a second fault: the soak's clock jump stays back, so that each fault is one step)."""
    scn, spec, stream = _stream(0)
    intake = DetectionIntake([SensorLink(0, spec.rate_hz, None, spec.latency.low_s)])
    clock = SensorClock(T0, spec.offset_s).stepped_back(CLOCK_JUMP_S, at=T0 + 5.0)
    outcomes = []
    for d in sorted(stream, key=lambda d: d.t_publish):
        back = clock.back_at(T0 + d.t) if d.t < 20.0 else 0.0  # the clock comes back at 20 s
        wire = detection(d, 0, T0, scn.sensors[0], scn.noise_cov[0], T0 + d.t_publish, back)
        try:
            intake.admit(wire, T0 + d.t_publish, None)
            outcomes.append((d.t, "kept"))
        except WireError as err:
            outcomes.append((d.t, err.reason))
    assert {r for t, r in outcomes if 12.0 < t < 20.0} == {"kept"}, "followed the step by 12 s (61 at 10 Hz)"
    after = [r for t, r in outcomes if t >= 20.0]
    assert after[:FOLLOW_FORWARD] == ["future"] * FOLLOW_FORWARD, after[:40]
    assert set(after[FOLLOW_FORWARD:]) <= {"kept", "too_old"} and after.count("kept") > len(after) - FOLLOW_FORWARD - 5


def test_the_cluster_steps_a_sensors_clock_and_a_restarted_sensor_keeps_the_steps(tmp_path):
    from zentrack.cli import build_parser
    from zentrack.cluster.run.cluster import Cluster
    from zentrack.config.run_setup import resolve_setup

    argv = ["run", "--scenario", "exp2-async", "--steps", "20", "--out", "unused"]
    cluster = Cluster(resolve_setup(build_parser(argv).parse_args(argv)), tmp_path / "out", clock_jump_s=12.5)
    spawned: list[tuple[str, list[str]]] = []
    signalled: list[tuple[str, int]] = []
    cluster._spawn = lambda name, args: spawned.append((name, args))  # type: ignore[method-assign]
    cluster.signal_process = lambda name, sig: signalled.append((name, sig))  # type: ignore[method-assign]
    cluster.start_sensor(2)
    args = spawned[-1][1]
    assert args[args.index("--clock-jump-s") + 1] == "12.5" and "--clock-back-s" not in args
    assert cluster.jump_sensor_clock("sensor-2") == 12.5 and cluster.jump_sensor_clock("sensor-2") == 25.0
    assert signalled == [("sensor-2", signal.SIGUSR1)] * 2
    cluster.restart_process("sensor-2")  # killed and started again: its host's clock is still 25 s back
    assert signalled[-1] == ("sensor-2", signal.SIGKILL) and spawned[-1][0] == "sensor-2"
    args = spawned[-1][1]
    assert args[args.index("--clock-back-s") + 1] == "25.0" and args[args.index("--id") + 1] == "2"
    cluster.restart_process("sensor-3")
    assert "--clock-back-s" not in spawned[-1][1], "only the stepped sensor's clock is back"
    with pytest.raises(ValueError, match="no sensor of this run"):
        cluster.jump_sensor_clock("sensor-9")


def test_the_sensor_takes_its_jump_and_its_steps_as_flags():
    from zentrack.cli import build_parser

    argv = ["sensor", "--id", "1", "--scenario", "exp2-async", "--clock-jump-s", "12", "--clock-back-s", "24"]
    args = build_parser(argv).parse_args(argv)
    assert args.clock_jump_s == 12.0 and args.clock_back_s == 24.0
    plain = argv[:5]
    args = build_parser(plain).parse_args(plain)
    assert args.clock_jump_s == CLOCK_JUMP_S and args.clock_back_s == 0.0
    assert CLOCK_JUMP_S > STALE_S + 0.3, "the default step is refused as stale whatever the latency (up to 300 ms)"


# ---------------------------------------------------------------- what the soak reports and judges of them
def _sensors_report(offset_moved: float = 30.0, stale: int = 60):
    from types import SimpleNamespace

    from zentrack.cluster.soak.sensor_counts import sensor_report, tracker_counts

    def run(offset_0: float, stale_0: int):
        totals = {0: {"detections": {"det_rx": 500, "too_old": 1, "out_of_order": 9}, "rejected": {"stale": stale_0}},
                  1: {"detections": {"det_rx": 200, "too_old": 5, "out_of_order": 0}, "rejected": {"early": 2}}}
        rec = SimpleNamespace(scn=SimpleNamespace(nodes=2),
                              counters=SimpleNamespace(summed=lambda i, report: totals[i]))
        reports = {0: {"sensor_offsets_s": {"0": offset_0}}, 1: {"sensor_offsets_s": {"1": -0.1}}}
        return tracker_counts(rec, reports)

    faults = [{"t": 20.0, "action": "jump", "node": "sensor-0", "step": 200, "trackers": [0]},
              {"t": 27.1, "action": "followed", "node": "sensor-0", "step": 271},
              {"t": 40.0, "action": "kill", "node": "sensor-1", "step": 400, "trackers": [1]},
              {"t": 42.0, "action": "restart", "node": "sensor-1", "step": 420}]
    return sensor_report(faults, run(0.1 - offset_moved, stale), run(0.1, 0), {0: [0], 1: [1]}, {0: 0.12, 1: -0.08},
                         30.0)


def test_the_soak_reports_each_trackers_detections_and_judges_that_it_followed_the_stepped_clock():
    from zentrack.cluster.soak.sensor_counts import clocks_followed, followed_lines, sensor_lines

    sensors = _sensors_report()
    assert sensors["sensors"]["0"]["clock_jumps_at_s"] == [20.0] and sensors["sensors"]["0"]["clock_back_s"] == 30.0
    assert sensors["sensors"]["1"]["kills_at_s"] == [40.0] and sensors["follow_detections"] == FOLLOW_DETECTIONS
    assert sensors["trackers"]["faulty"]["0"]["refused"] == {"stale": 60}
    assert sensors["trackers"]["faulty"]["1"]["refused"] == {}, "a prior refused early is no detection's refusal"
    lines = sensor_lines(sensors)
    assert lines[0].startswith("sensor-0 (1 clock jump(s) of 30 s back at 20.0 s): node 0 kept 500 detections "
                               "(reference 500), 1 too old (reference 1), 60 stale (reference 0); offset at its exit "
                               "-29.900 s (configured less the steps -29.880 s)"), lines
    assert lines[1].startswith("sensor-1 (killed at 40.0 s): node 1 kept 200") and "none refused" in lines[1]
    c = clocks_followed(sensors)
    assert c["pass"] and c["trackers"][0]["offset_moved_s"] == pytest.approx(30.0) and len(c["trackers"]) == 1
    assert followed_lines(c)[0].startswith("1 tracker(s) followed their sensor's stepped clock: 60 stale")
    # a tracker that never followed: its offset stayed, every later detection refused
    never = clocks_followed(_sensors_report(offset_moved=0.0, stale=400))
    assert not never["pass"]
    assert followed_lines(never) == ["node 0 (sensor-0, 1 step(s), 30 s back): its offset moved 0.000 s, 400 stale "
                                     "(limit 63)"]
    assert not clocks_followed(_sensors_report(stale=70))["pass"], "followed, but late"
