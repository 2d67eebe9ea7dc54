"""One way to build a Zenoh config: zentrack's safe defaults, a user's file merged over them, then the flags."""
from __future__ import annotations

import json
import logging

import pytest
import zenoh

from zentrack.transport.zsession import DEFAULT_LISTEN, build_config, describe_config, open_zenoh


def _get(conf: zenoh.Config, key: str):
    return json.loads(conf.get_json(key))


def test_an_empty_file_keeps_loopback_and_no_multicast(tmp_path):
    f = tmp_path / "empty.json5"
    f.write_text("{}")
    for mode, listen in (("peer", DEFAULT_LISTEN), ("router", "tcp/127.0.0.1:7447")):
        conf = build_config(mode, file=str(f))
        assert _get(conf, "listen/endpoints") == [listen]
        assert _get(conf, "scouting/multicast/enabled") is False
    # what the same file gives in Zenoh alone: every interface, multicast scouting on (null: its default)
    stock = zenoh.Config.from_file(str(f))
    assert "[::]" in stock.get_json("listen/endpoints") and _get(stock, "scouting/multicast/enabled") is None


def test_what_a_file_sets_wins_and_flags_win_over_the_file(tmp_path):
    f = tmp_path / "mine.json5"
    f.write_text('{ listen: { endpoints: ["tcp/127.0.0.1:17447"] }, scouting: { multicast: { enabled: true } },'
                 ' connect: { endpoints: ["tcp/127.0.0.1:17448"] } }')
    conf = build_config("peer", file=str(f))
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:17447"]
    assert _get(conf, "scouting/multicast/enabled") is True
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:17448"]
    conf = build_config("peer", listen=["tcp/127.0.0.1:0"], connect=["tcp/127.0.0.1:9"], file=str(f))
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:9"]


def test_a_client_listens_nowhere_and_bad_endpoints_are_refused():
    conf = build_config("client", connect=["tcp/127.0.0.1:7447"])
    assert "127.0.0.1" not in json.dumps(_get(conf, "listen/endpoints"))
    with pytest.raises(ValueError, match="--listen"):
        build_config("peer", listen=["127.0.0.1:7447"])


def test_the_effective_settings_are_logged_when_a_session_opens(caplog):
    conf = build_config("peer")
    assert describe_config(conf) == (f"mode peer, listen ['{DEFAULT_LISTEN}'], connect [], multicast scouting off, "
                                     "gossip on")
    with caplog.at_level(logging.INFO, logger="zentrack.zenoh"):
        session = open_zenoh(conf, "test")
        session.close()
    assert any("multicast scouting off" in r.getMessage() and DEFAULT_LISTEN in r.getMessage() for r in caplog.records)


def test_run_hands_its_zenoh_file_to_every_process_and_each_logs_what_it_listens_on(tmp_path):
    import subprocess
    import sys

    f = tmp_path / "empty.json5"
    f.write_text("{}")
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "zentrack", "run", "--scenario", "exp2", "--nodes", "3", "--steps", "20",
                           "--timing", "lockstep", "--zenoh-config", str(f), "--out", str(out)],
                          capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    logs = {p.name: p.read_text() for p in (out / "logs").glob("*.log")}
    assert set(logs) == {"truth.log", "node-0.log", "node-1.log", "node-2.log"}
    for name, text in logs.items():
        lines = [line for line in text.splitlines() if "zenoh session" in line]
        assert lines, name
        assert all("multicast scouting off" in line and "listen ['tcp/127.0.0.1:0']" in line for line in lines), lines
    bad = subprocess.run([sys.executable, "-m", "zentrack", "run", "--zenoh-config", str(tmp_path / "missing.json5"),
                          "--out", str(tmp_path / "x")], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "missing.json5" in bad.stderr and not (tmp_path / "x").exists()



def test_a_client_takes_the_first_endpoint_that_answers_and_falls_back_when_it_does_not(caplog):
    """A swarm tracker's ``--connect`` is its own host's router, then the hub: Zenoh's client retries only the
    first endpoint until its connect timeout, so zentrack drops it then and tries the next."""
    from zentrack.common.ports import free_port

    hub_port, dead_port = free_port(), free_port()
    hub = open_zenoh(build_config("router", [f"tcp/127.0.0.1:{hub_port}"]), "hub")
    try:
        with caplog.at_level(logging.INFO, logger="zentrack.zenoh"):
            client = open_zenoh(build_config("client", [], [f"tcp/127.0.0.1:{dead_port},tcp/127.0.0.1:{hub_port}"],
                                             connect_timeout_ms=1500), "client")
        try:
            assert [str(z) for z in client.info.routers_zid()] == [str(hub.zid())]
        finally:
            client.close()
        said = [r.getMessage() for r in caplog.records]
        assert any(f"no router answered at tcp/127.0.0.1:{dead_port}" in m for m in said), said
        assert any(f"client of router {hub.zid()}" in m for m in said), said
        with pytest.raises(ValueError, match="cannot open a Zenoh session"):  # nothing left to fall back to
            open_zenoh(build_config("client", [], [f"tcp/127.0.0.1:{dead_port}"], connect_timeout_ms=500), "c")
    finally:
        hub.close()


@pytest.mark.parametrize("mode", ["client", "peer", "router"])
def test_every_process_re_dials_a_lost_endpoint_every_0_1_s(tmp_path, mode):
    """A restarted router is re-dialed by each of its clients (the recorder, the truth, every tracker) at this
    period: at 0.25 s growing to 1 s they re-linked on a 1 s grid, 10 steps after its restart, and a cap of
    0.2 s cost half a step more than 0.1 s (tests/test_router_restart.py, docs/soak.md). A config file's own
    retry is overridden too."""
    file = tmp_path / "z.json5"
    file.write_text('{connect: {retry: {period_init_ms: 1000, period_max_ms: 4000, period_increase_factor: 2}}}')
    for conf in (build_config(mode, [], ["tcp/127.0.0.1:7447"]),
                 build_config(mode, [], ["tcp/127.0.0.1:7447"], file=str(file))):
        retry = _get(conf, "connect/retry")
        assert retry["period_init_ms"] <= 100 and retry["period_max_ms"] <= 100, retry
