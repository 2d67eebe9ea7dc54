"""The rules a run with sensors of its own follows under faults (tests/test_sensor_faults.py runs them live), below
the process: detections that never came are counted ``missing`` (gaps in a sensor's sequence numbers); a tracker
whose truth has gone keeps its links while its detections come, and stops by itself at the run's end; and the
cluster records the trackers of such a run to their end when its truth fails mid-run.

Stepped by hand on the in-memory network of :mod:`schedule_net` (no Zenoh) and with stand-in processes."""
from __future__ import annotations

import argparse

import pytest
from schedule_net import T0, TS
from test_detections import LAG, async_net, det

from zentrack.node.detections import MAX_SEQ_GAP, DetectionIntake, SensorLink
from zentrack.node.process import NodeProcess


# ---------------------------------------------------------------- missing detections
def test_gaps_in_a_sensors_sequence_are_missing_until_they_come_late() -> None:
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0), SensorLink(1, 4.0, offset_s=0.0)])

    def arrive(seq: int, sensor: int = 0) -> None:
        intake.admit(det(seq, 10.2, sensor), t_recv=10.5, processed_upto=None)

    for seq in (5, 4, 6):  # the first ones out of order: nothing was skipped
        arrive(seq)
    assert intake.counts.missing == 0
    arrive(10)  # 7, 8 and 9 lost on the way
    assert intake.counts.missing == 3
    arrive(8)  # one of them was only late
    assert intake.counts.missing == 2
    arrive(12, sensor=1)
    arrive(14, sensor=1)  # each sensor its own count
    assert intake.counts.missing == 3
    arrive(11 + MAX_SEQ_GAP)  # a jump no outage makes (a forged number, a restarted count): no gap
    arrive(14 + MAX_SEQ_GAP)
    arrive(20)  # and back: a count of its own again
    assert intake.counts.missing == 5  # the two skipped inside the new count only
    assert intake.counts.det_rx == 10 and intake.period_s == pytest.approx(0.1)


def test_every_detection_that_came_is_kept_or_too_old_once_and_the_ones_that_did_not_are_missing() -> None:
    """Kept, too old and missing part a sensor's detections: one kept whose window a tracker skipped (it fell
    behind) is too old, no longer kept."""
    intake = DetectionIntake([SensorLink(0, 10.0, offset_s=0.0)])
    for seq in (0, 1, 2, 4, 5):  # 3 lost
        intake.admit(det(seq, 10.0 + 0.1 * seq), t_recv=10.0 + 0.1 * seq + 0.05, processed_upto=10.0)
    intake.admit(det(6, 10.05), t_recv=10.7, processed_upto=10.1)  # after its window: too old at once
    assert [round(d.t, 2) for d in intake.take(10.0, 10.1)] == [10.0]
    assert [round(d.t, 2) for d in intake.take(10.35, 10.5)] == [10.4]  # windows skipped: 10.1, 10.2 too old
    c = intake.counts
    assert (c.det_rx, c.too_old, c.missing) == (3, 3, 1) and c.det_rx + c.too_old + c.missing == 7  # 6 came
    assert intake.pending() == 1  # (10.5: kept, waiting for its window)


# ---------------------------------------------------------------- a tracker whose truth has gone
def _orphaned(steps_done: int):
    """Node 0 of the three-node network with sensors of their own, ``steps_done`` periods into the run, its
    truth's token gone at the start of the last of them; and its process side (no session)."""
    net = async_net()
    net.start()
    node = net.nodes[0]
    net.at(T0 + LAG + (steps_done - 1) * TS)
    node.handle(net.msg("alive", net.keys.alive("truth"), b"delete"))
    net.at(T0 + LAG + steps_done * TS)
    return net, node, NodeProcess(argparse.Namespace(reconnect_s=2.0, truth_timeout=30.0), node, net.keys, stop=None)


def test_a_tracker_whose_detections_come_is_not_cut_off_by_its_truths_absence() -> None:
    net, node, proc = _orphaned(10)
    gone_at = net.now - TS
    for later in (5.0, 40.0):  # its sensor's detections still come (every 0.1 s), long after the truth went
        proc.last_det = gone_at + later - 0.05
        assert proc.truth_silence(gone_at + later) is None
    # no detection either for more than the sensor's period: the links may be gone (a router restarted)
    quiet, why = proc.truth_silence(gone_at + 40.0 - 0.05 + 0.1 + 2.5)
    assert quiet == pytest.approx(2.5) and "no detection" in why
    # a tracker of the truth's measurements: the token's absence is silence at once, as before
    proc.schedule.payload.intake = None
    gone, why = proc.truth_silence(gone_at + 3.0)
    assert gone == pytest.approx(3.0) and "liveliness token is gone" in why


def test_a_many_target_tracker_watches_its_detections_or_the_truths_measurements_as_its_kind_has_them() -> None:
    """A many-target tracker's payload says the same as a single-target one's: its sensors' period with sensors of
    its own (mt-async: tracker 0 takes its 4 Hz sensor), None for the truth's measurements, whose silence (no
    measurement message past the period) is then what it watches."""
    import numpy as np

    from zentrack.config.run_setup import resolve_setup
    from zentrack.config.scenario_flags import add_scenario_arguments
    from zentrack.node.schedule import NodeSchedule
    from zentrack.transport.keys import Keys
    from zentrack.transport.messages import Start
    from zentrack.transport.wire import Message

    parser = argparse.ArgumentParser()
    add_scenario_arguments(parser)
    for own, period in ((True, 0.25), (False, None)):
        setup = resolve_setup(parser.parse_args(["--scenario", "mt-async", "--steps", "20"]))
        if not own:
            setup.sensor_timing = None
        keys = Keys("unit")
        node = NodeSchedule.track_lists(keys, setup.node_config(0), lambda: T0, lambda ch, b: None)
        assert node.payload.detection_period_s() == (None if period is None else pytest.approx(period))
        node.handle(Message("alive", keys.alive("truth"), b"put", T0))
        node.handle(Message("start", keys.start, Start(T0, TS, 20, "realtime", tuple(range(8)), 0.5,
                                                        np.zeros(6)).encode(), T0))
        proc = NodeProcess(argparse.Namespace(reconnect_s=2.0, truth_timeout=30.0), node, keys, stop=None)
        proc.last_meas = proc.last_det = T0 + 0.5
        silence = proc.truth_silence(T0 + 1.0)  # the truth there, a measurement half a second ago
        assert silence == (None if own else (pytest.approx(0.5 - TS), "no measurement message from the truth"))


def test_a_tracker_whose_truth_has_gone_stops_by_itself_at_the_runs_end_and_not_before() -> None:
    net, node, _ = _orphaned(10)
    steps = node.ctx.steps
    net.at(node.ctx.timing.deadline(steps - 2))
    assert not node.done()  # the run goes on: it tracks on its sensor's detections
    net.at(node.ctx.timing.deadline(steps - 1) + 0.001)
    assert node.done()
    other = async_net()  # the truth still there at the run's end: it waits for the truth's stop
    other.start()
    other.at(other.nodes[0].ctx.timing.deadline(steps - 1) + 0.001)
    assert not other.nodes[0].done()


# ---------------------------------------------------------------- the cluster records them to the end
class _Proc:
    """A stand-in child process: exits with ``code`` once ``alive`` returns False."""

    def __init__(self, code: int | None, alive=lambda: False) -> None:
        self.code, self.alive = code, alive

    def poll(self) -> int | None:
        return None if self.alive() else self.code

    @property
    def returncode(self) -> int | None:
        return self.poll()


class _Recorder:
    """A stand-in recorder that hears an estimate at every drain until ``until`` drains have been made; each
    drain takes 0.1 s of ``clock``."""

    def __init__(self, clock: list[float], until: int) -> None:
        self.clock, self.drains, self.until = clock, 0, until

    def drain(self, timeout: float = 0.0) -> int:
        self.clock[0] += 0.1
        self.drains += 1
        return int(self.drains <= self.until)

    def steps_reached(self) -> int:
        return 0


@pytest.mark.parametrize("sensors_of_their_own", [True, False])
def test_a_cluster_whose_truth_died_records_trackers_that_track_on(tmp_path, monkeypatch, sensors_of_their_own):
    """The truth killed (-9) while its trackers still publish: a run with sensors of their own is recorded as long
    as estimates come (past the 10 s a run waits for its processes to leave), a synchronous one for those 10 s."""
    import zentrack.cluster.run.cluster as cluster_module
    from zentrack.cli import build_parser
    from zentrack.cluster.run.cluster import Cluster
    from zentrack.config.run_setup import resolve_setup

    argv = ["run", "--scenario", "exp2-async", "--steps", "20", "--out", "unused"]
    setup = resolve_setup(build_parser(argv).parse_args(argv))
    if not sensors_of_their_own:
        setup.sensor_timing = None
    clock = [0.0]
    monkeypatch.setattr(cluster_module.time, "time", lambda: clock[0])
    cluster = Cluster(setup, tmp_path / "out")
    recorder = _Recorder(clock, until=150)  # estimates for 15 s after the truth died
    cluster.recorder = recorder  # type: ignore[assignment]
    cluster.procs = {"truth": _Proc(-9), "node-0": _Proc(0, alive=lambda: recorder.drains < 400)}
    assert cluster.wait(timeout=100.0) == -9
    waited = clock[0]
    if sensors_of_their_own:
        assert 15.0 + 10.0 - 0.5 <= waited <= 15.0 + 10.0 + 0.5, waited  # as long as estimates came, then 10 s
    else:
        assert 10.0 - 0.5 <= waited <= 10.0 + 0.5, waited
