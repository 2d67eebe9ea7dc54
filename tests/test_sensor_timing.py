"""Sensors of their own (issue 52), configured and planned: the scenario file's ``[sensor_timing]`` (its keys, one
line per bad value, the refusal of what cannot run asynchronously), what it gives the trackers' slices and the
sensor processes, the cluster's sensor processes as named, and the sensor process's pure part (which detection
is due when, its clock), all without Zenoh. The live run is ``tests/test_sensors_live.py``."""
from __future__ import annotations

import re

import numpy as np
import pytest

from zentrack.cli import build_parser, main
from zentrack.config import catalogue
from zentrack.config.node_config import NodeConfigError
from zentrack.config.run_setup import resolve_setup
from zentrack.config.scenario_config import ScenarioConfigError, load_scenario_config, parse, resize
from zentrack.transport.detection_messages import Detection
from zentrack.transport.keys import Keys, node_id, sensor_name
from zentrack.truth.sensor import DetectionPlan, SensorClock, detection, stream_spec
from zentrack.truth.simulation.sensor_stream import SimulatedDetection, sensor_stream

ASYNC = catalogue.text("exp2-async") or ""
#: exp2-async's [sensor_timing] with its keys replaced (``key = value`` lines; None: the key left out)
BASE = {"rate_hz": "[10.0, 4.0, 1.0, 10.0, 4.0, 1.0]", "phase_s": "0.0", "offset_s": "0.0", "latency": '"uniform"',
        "latency_low_ms": "10.0", "latency_high_ms": "300.0", "reorder": "0.1", "lag_ms": "350.0"}


def with_timing(**keys: str | None) -> str:
    """exp2-async with its [sensor_timing] made of ``BASE`` updated by ``keys``."""
    values = {**BASE, **keys}
    section = "\n".join(f"{k} = {v}" for k, v in values.items() if v is not None)
    return ASYNC.split("[sensor_timing]")[0] + "[sensor_timing]\n" + section + "\n"


def refused(text: str, label: str = "mine.toml") -> str:
    with pytest.raises(ScenarioConfigError) as err:
        parse(label, text)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{label}: "), message
    return message


def setup_of(*argv: str):
    args = build_parser(["run", *argv]).parse_args(["run", *argv, "--out", "unused"])
    return resolve_setup(args)


# ---------------------------------------------------------------- the section
def test_the_catalogue_scenario_gives_six_sensors_of_their_own_and_each_tracker_its_own() -> None:
    cfg = load_scenario_config("exp2-async")
    timing = cfg.sensor_timing
    assert timing is not None and timing.sensors == 6 and timing.lag_ms == 350.0 and timing.clock == "estimated"
    assert [s.rate_hz for s in timing.streams] == [10.0, 4.0, 1.0, 10.0, 4.0, 1.0]
    assert all(abs(s.offset_s) <= 0.2 and s.latency.kind == "uniform" and (s.latency.low_s, s.latency.high_s)
               == (0.01, 0.3) and s.reorder == 0.1 for s in timing.streams)
    assert timing.takes == tuple((i,) for i in range(6))
    setup = setup_of("--scenario", "exp2-async")
    assert [s.sensor for s in setup.sensor_streams()] == list(range(6)) and setup.own_sensors() == set(range(6))
    det = setup.node_config(2).detections
    assert det == {"lag_ms": 350.0, "clock": "estimated", "sensors": [{"sensor": 2, "rate_hz": 1.0, "offset_s": None,
                                                 "min_latency_s": 0.01}]}
    cfg = setup.node_config(2)  # a slice whose clock is neither is refused, naming the key
    cfg.detections = {**det, "clock": "ntp"}
    with pytest.raises(NodeConfigError, match="detections.clock: must be one of estimated, configured, got 'ntp'"):
        cfg.validate()
    # a synchronous scenario: no sensors of their own, no detections in any slice
    plain = setup_of("--scenario", "exp2", "--nodes", "4")
    assert plain.sensor_streams() == [] and plain.node_config(0).detections is None and plain.own_sensors() == set()


def test_one_value_for_all_a_list_each_configured_clocks_and_takes() -> None:
    cfg = parse("mine.toml", with_timing(rate_hz="4.0", offset_s="[0.1, 0.0, -0.1, 0.2, 0.0, 0.05]",
                                         clock='"configured"', takes="[[0, 1], [1], [2], [3, 4, 5], [4], [5]]",
                                         latency='["fixed", "uniform", "exponential", "fixed", "fixed", "fixed"]',
                                         latency_mean_ms="40.0"))
    timing = cfg.sensor_timing
    assert timing is not None and {s.rate_hz for s in timing.streams} == {4.0}
    assert [s.latency.kind for s in timing.streams[:3]] == ["fixed", "uniform", "exponential"]
    assert timing.streams[0].latency.high_s == 0.01 and timing.streams[2].latency.mean_s == 0.04
    assert timing.streams[2].latency.high_s == 0.3  # (the exponential's cap)
    det = timing.detections(0)
    assert [link["sensor"] for link in det["sensors"]] == [0, 1]
    assert [link["offset_s"] for link in det["sensors"]] == [0.1, 0.0]  # configured: the trackers are told
    assert det["clock"] == "configured"  # (and take their neighbours' clocks as synchronised)
    assert [link["sensor"] for link in timing.detections(3)["sensors"]] == [3, 4, 5]
    # rate_hz left out: the run's rate
    assert {s.rate_hz for s in parse("mine.toml", with_timing(rate_hz=None)).sensor_timing.streams} == {10.0}


@pytest.mark.parametrize(("keys", "key", "says"), [
    ({"rate_hz": "[10.0, 4.0]"}, "rate_hz", "lists 2 value(s); give one value for every sensor or one per sensor (6)"),
    ({"offset_s": "[0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]"}, "offset_s", "lists 7 value(s)"),
    ({"rate_hz": "0.0"}, "rate_hz", "must be above 0 to 1000"),
    ({"rate_hz": '"fast"'}, "rate_hz", "must be a finite number"),
    ({"reorder": "1.5"}, "reorder", "must be from 0 to 1"),
    ({"detection_prob": "0.0"}, "detection_prob", "must be above 0 to 1"),
    ({"phase_s": "[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]"}, "phase_s", "below one period of sensor 1 (0.25 s)"),
    ({"latency": '"unifrom"'}, "latency", "did you mean 'uniform'?"),
    ({"latency_high_ms": None}, "latency_high_ms", "missing: sensor 0's uniform latency needs its upper end"),
    ({"latency_high_ms": "5.0"}, "latency_high_ms", "must be at least latency_low_ms"),
    ({"latency": '"exponential"'}, "latency_mean_ms", "missing: sensor 0's exponential latency needs its mean"),
    ({"latency_mean_ms": "20.0"}, "latency_mean_ms", "no sensor's latency takes it (only exponential"),
    ({"latency": '"fixed"'}, "latency_high_ms", "no sensor's latency takes it"),
    ({"lag_ms": None}, "lag_ms", "missing"),
    ({"lag_ms": "-1.0"}, "lag_ms", "must be from 0 to 10000 ms"),
    ({"clock": '"configred"'}, "clock", "did you mean 'configured'?"),
    ({"takes": "[[0], [1]]"}, "takes", "lists 2 tracker(s); give one list of sensor ids per tracker (6)"),
    ({"takes": "[[0], [1], [2], [3], [4], [9]]"}, "takes", "tracker 5 must take at least one sensor, distinct ids "
                                                             "from 0 to 5, got [9]"),
    ({"takes": "[[0], [1], [2], [3], [4], []]"}, "takes", "tracker 5 must take at least one sensor"),
    ({"takes": "[0, 1, 2, 3, 4, 5]"}, "takes", "must be one list of sensor ids per tracker"),
    ({"rate_hzz": "4.0"}, "rate_hzz", "unknown key; did you mean 'rate_hz'?"),
])
def test_a_bad_value_is_one_line_naming_the_file_and_the_key(keys, key, says) -> None:
    message = refused(with_timing(**keys))
    assert message.startswith(f"mine.toml: sensor_timing.{key}: ") and says in message, message


ASYNC_SECTION = "\n[sensor_timing]\nlag_ms = 100.0\n"


@pytest.mark.parametrize(("name", "change", "says"), [
    ("exp2", ('mode = "realtime"', 'mode = "lockstep"'), "realtime only; timing 'lockstep'"),
    ("exp2", ("[timing]", '[fusion]\nrule = "ci"\nshare_scans = true\n\n[timing]'), "exchanges scans"),
    ("exp2", ("[timing]", '[fusion]\nrule = "ci"\nshare_scans = true\nrelay_scans = true\n\n[timing]'),
     "exchanges scans"),
    ("exp2", ("[timing]", '[fusion]\nrule = "ci"\nrounds = 2\n\n[timing]'), "runs several rounds a step"),
    ("exp2", ("[timing]", '[fusion]\nrule = "ci3"\n\n[timing]'), "runs several rounds a step"),
    ("exp1", None, "plant 'exp1' is defined on its sample period only"),
    ("eot-s2", None, "plant 'eot' is defined on its sample period only"),
    ("exp2-relays", None, "relay nodes"),
    ("mt-bearing", None, "many-target bearing sensors start their tracks by triangulating"),
    ("ais-nyharbor", None, "many-target bearing sensors"),  # (a mixed network: its cameras)
    ("dce-ici", None, "moving sensors"),
])
def test_what_cannot_run_asynchronously_is_refused_in_one_line(name, change, says) -> None:
    text = catalogue.text(name) or ""
    if change is not None:
        assert change[0] in text
        text = text.replace(change[0], change[1], 1)
    message = refused(text + ASYNC_SECTION, f"{name}.toml")
    assert message.startswith(f"{name}.toml: sensor_timing: ") and says in message, message


@pytest.mark.parametrize("name", ["mt-crossing", "mt-birth-death", "fpf-clutter"])
def test_many_point_targets_and_clutter_run_with_sensors_of_their_own(name) -> None:
    """Many targets of point sensors and one target in clutter: the sensor applies P_D, noise and clutter
    (tests/test_sensor_world.py), the trackers take its scans (tests/test_multitarget_windows.py)."""
    text = (catalogue.text(name) or "").replace('mode = "lockstep"', 'mode = "realtime"')
    cfg = parse(f"{name}.toml", text + ASYNC_SECTION)
    assert cfg.sensor_timing is not None and cfg.sensor_timing.sensors == cfg.spec.nodes


def test_a_rule_that_fuses_posteriors_is_refused() -> None:
    from types import SimpleNamespace

    from zentrack.config.scenario_sensor_timing import asynchronous_refusal

    spec = SimpleNamespace(plant="cv3d", clutter=None, roles=None, moving=False)
    assert "fuses posteriors" in asynchronous_refusal("realtime", "eot-ci", {}, spec, False)
    assert asynchronous_refusal("realtime", "ci", {}, spec, False) is None
    assert asynchronous_refusal("realtime", "ci-fast", {}, spec, False) is None


@pytest.mark.parametrize(("flags", "says"), [
    (["--timing", "lockstep"], "realtime only"),
    (["--fusion", "ci3"], "several rounds"),
    (["--rounds", "2"], "several rounds"),
    (["--fusion-param", "share_scans=true"], "exchanges scans"),
    (["--period", "0.2"], "drop --period"),
    (["--nodes", "4"], "sensor_timing.rate_hz: lists 6 value(s)"),
])
def test_flags_that_make_the_run_synchronous_are_refused_in_one_line_exit_2(flags, says, tmp_path, capsys) -> None:
    for command in (["run", "--out", str(tmp_path / "o")], ["truth"], ["node", "--id", "0"], ["sensor", "--id", "0"]):
        assert main([*command, "--scenario", "exp2-async", *flags]) == 2, command
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and says in err, (command, err)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("flags", "says"), [(["--timing", "lockstep"], "realtime only"),
                                             (["--period", "0.5"], "drop --period")])
def test_a_many_target_run_of_sensors_of_their_own_refuses_the_flags_that_make_it_synchronous(flags, says, tmp_path,
                                                                                              capsys) -> None:
    for command in (["run", "--out", str(tmp_path / "o")], ["truth"], ["sensor", "--id", "0"]):
        assert main([*command, "--scenario", "mt-async", *flags]) == 2, command
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and says in err, (command, err)


def test_one_value_for_every_sensor_follows_nodes_and_a_list_fixes_them() -> None:
    text = with_timing(rate_hz="4.0")
    cfg = resize(parse("mine.toml", text), nodes=9)
    assert cfg.sensor_timing is not None and cfg.sensor_timing.sensors == 9
    with pytest.raises(ValueError, match=r"mine.toml: sensor_timing.rate_hz: lists 6 value\(s\).*--nodes 4"):
        resize(parse("mine.toml", with_timing()), nodes=4)
    with pytest.raises(ValueError, match=r"sensor_timing.takes: lists 6 tracker"):
        resize(parse("mine.toml", with_timing(rate_hz="4.0", takes="[[0], [1], [2], [3], [4], [5]]")), nodes=8)


# ---------------------------------------------------------------- the sensor process's pure part
def test_a_sensor_token_is_a_name_never_a_node_id() -> None:
    keys = Keys("r1")
    assert keys.alive(sensor_name(3)) == "zentrack/r1/alive/sensor-3"
    assert keys.node_of(keys.alive(sensor_name(3))) is None and node_id(sensor_name(3)) is None


def test_the_plan_hands_out_every_detection_once_in_publication_order() -> None:
    cfg = resize(load_scenario_config("exp2-async"), None, 80)
    scn = cfg.scenario_data()
    spec = cfg.sensor_timing.stream(0)
    stream = sensor_stream(scn, spec, cfg.seed)
    plan = DetectionPlan(stream)
    out: list[SimulatedDetection] = []
    now = -0.5
    while not plan.done:
        got = plan.due(now)
        assert all(d.t_publish <= now for d in got)
        out += got
        nxt = plan.next_time()
        assert nxt is None or nxt > now
        now += 0.013
    assert sorted(d.seq for d in out) == [d.seq for d in stream]  # each once
    assert [d.t_publish for d in out] == sorted(d.t_publish for d in out)
    assert [d.seq for d in out] != sorted(d.seq for d in out)  # reordered: published out of measurement order
    assert plan.due(1e9) == [] and plan.next_time() is None


def test_a_restarted_sensor_skips_what_is_past_and_resumes_at_the_current_time() -> None:
    cfg = resize(load_scenario_config("exp2-async"), None, 80)
    stream = sensor_stream(cfg.scenario_data(), cfg.sensor_timing.stream(1), cfg.seed)
    plan = DetectionPlan(stream)
    skipped = plan.skip_past(3.0)
    assert skipped == sum(d.t_publish < 3.0 for d in stream) > 5 and plan.skipped == skipped
    rest = plan.due(1e9)
    assert {d.seq for d in rest} == {d.seq for d in stream if d.t_publish >= 3.0}
    fresh = DetectionPlan(stream)
    assert fresh.skip_past(-0.5) == 0  # a sensor up before t0 skips nothing


def test_the_sensors_clock_and_the_detection_on_the_wire_are_the_streams() -> None:
    cfg = parse("mine.toml", with_timing(offset_s="-0.15", drift_ppm="50.0"))
    scn = resize(cfg, None, 40).scenario_data()
    spec = cfg.sensor_timing.stream(4)
    t0 = 1.75e9
    clock = SensorClock(t0, spec.offset_s, spec.drift_ppm)
    for d in sensor_stream(scn, spec, cfg.seed):
        assert clock.reading(t0 + d.t) == pytest.approx(t0 + d.stamp, abs=1e-6)  # (epoch seconds: 0.24 us apart)
    d = sensor_stream(scn, spec, cfg.seed)[3]
    wire = detection(d, 4, t0, scn.sensors[4], scn.noise_cov[4], clock.reading(t0 + d.t_publish))
    back = Detection.decode(wire.encode(), 4, 2)
    assert back.seq == d.seq and back.t_meas == t0 + d.stamp and back.sensor == 4
    assert np.array_equal(back.returns, d.returns) and np.array_equal(back.pose, scn.sensors[4])
    assert back.t_pub == pytest.approx(t0 + d.t_publish - 0.15 + 50e-6 * d.t_publish)


def test_a_sensor_of_a_scenario_without_sensor_timing_or_beyond_its_sensors_exits_2_in_one_line(capsys) -> None:
    with pytest.raises(ValueError, match="no \\[sensor_timing\\] section"):
        stream_spec(setup_of("--scenario", "exp2", "--nodes", "3"), 0)
    for argv, says in ((["--scenario", "exp2", "--nodes", "3"], "no [sensor_timing] section"),
                       (["--scenario", "exp2-async", "--id", "6"], "outside the scenario's sensors 0..5")):
        argv = argv if "--id" in argv else [*argv, "--id", "0"]
        assert main(["sensor", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and says in err, err
    with pytest.raises(SystemExit) as done:
        main(["sensor", "--id", "-1", "--scenario", "exp2-async"])
    assert done.value.code == 2 and len(capsys.readouterr().err.strip().splitlines()) == 1


# ---------------------------------------------------------------- the cluster's sensor processes
def test_the_cluster_names_a_sensor_process_per_sensor(tmp_path) -> None:
    from zentrack.cluster.run.cluster import Cluster

    setup = setup_of("--scenario", "exp2-async", "--steps", "20")
    cluster = Cluster(setup, tmp_path / "out")
    assert cluster.sensor_ids == list(range(6))
    args = cluster._scenario_args()  # the scenario file itself (a .npz holds no [sensor_timing])
    assert args[:2] == ["--scenario", "exp2-async"] and "--steps" in args and args[args.index("--steps") + 1] == "20"
    # (in secure mode too: tests/test_secure_sensors_live.py)
    assert Cluster(setup_of("--scenario", "exp2", "--nodes", "3"), tmp_path / "o3").sensor_ids == []
    assert re.fullmatch(r"sensor-\d+", sensor_name(5))
