"""Kinds in one place: a message kind is declared by its class alone, a data key by its channel entry alone.

A new wire kind touches its message class (``@wire_kind``), its key (an entry of ``keys.CHANNELS``) and the parts
that publish and consume it; the framing check, the key scheme and a secure run's access control follow from
those two declarations (``docs/architecture.md``)."""
from __future__ import annotations

from dataclasses import dataclass

import msgpack
import pytest

from zentrack.transport import codec, keys, secure, wire
from zentrack.transport.codec import KINDS, WireError, check_framing, wire_kind


def framed(kind: str) -> bytes:
    return msgpack.packb({"v": codec.SCHEMA_VERSION, "kind": kind, "k": 3, "t": 0.3, "sender": 1}, use_bin_type=True)


def test_every_message_class_declares_its_kind_once() -> None:
    from zentrack.transport import detection_messages, track_messages  # noqa: F401 - declare their kinds on import
    assert set(KINDS) == {"meas", "prior", "scan", "relay", "est", "truth", "start", "stop", "tracks", "targets",
                          "det"}
    assert KINDS["est"] is wire.EstimateMessage and KINDS["relay"] is wire.Relay
    with pytest.raises(ValueError, match="declared by EstimateMessage and Impostor"):
        wire_kind("est")(type("Impostor", (), {}))


def test_a_kind_is_framed_once_its_class_declares_it() -> None:
    with pytest.raises(WireError) as err:
        check_framing(framed("health"))
    assert err.value.reason == "kind"

    @dataclass(frozen=True)
    class Health:
        k: int

    try:
        wire_kind("health")(Health)
        check_framing(framed("health"))  # no other file named the kind
    finally:
        KINDS.pop("health", None)


def test_a_channel_entry_gives_its_key_and_the_routers_access_control(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(keys.CHANNELS, "health", keys.Channel("health", True, "node", ("truth",)))
    k = keys.Keys("r")
    assert k.of("health", 4) == "zentrack/r/health/4" and k.est(4) == "zentrack/r/est/4"
    with pytest.raises(ValueError, match="one key per node"):
        k.of("health")
    rules = {r["id"]: r["key_exprs"] for r in secure.access_control("r", 2)["rules"]}
    assert "zentrack/r/health/1" in rules["node-1/publish"] and "zentrack/r/health/0" not in rules["node-1/publish"]
    assert "zentrack/r/health/*" in rules["truth/subscribe"]
    assert not any("health" in key for key in rules["node-1/subscribe"])  # nodes do not read it


def test_the_access_control_is_the_channels_and_nothing_else() -> None:
    rules = {r["id"]: r["key_exprs"] for r in secure.access_control("r", 2)["rules"]}
    assert rules["node-1/publish"] == [f"zentrack/r/{c}/1" for c in ("prior", "est", "scan", "tracks")]
    assert rules["node-1/subscribe"] == ["zentrack/r/meas/1", "zentrack/r/prior/*", "zentrack/r/scan/*",
                                         "zentrack/r/tracks/*", "zentrack/r/ctl/**"]
    assert rules["truth/publish"] == ["zentrack/r/meas/**", "zentrack/r/truth", "zentrack/r/ctl/**"]
    assert rules["truth/subscribe"] == ["zentrack/r/est/*", "zentrack/r/tracks/*"]
    sensors = {r["id"]: r["key_exprs"] for r in secure.access_control("r", 2, sensors=2)["rules"]}
    assert sensors["sensor-1/publish"] == ["zentrack/r/det/1"] and sensors["sensor-1/subscribe"] == ["zentrack/r/ctl/**"]
    assert sensors["sensor-1/token"] == ["zentrack/r/alive/sensor-1"] and "sensor-0/publish" in sensors
    assert "zentrack/r/det/1" in sensors["node-1/subscribe"]  # the sensor it takes (by default sensor i) only
    assert "zentrack/r/det/0" not in sensors["node-1/subscribe"]
    assert not any(k.startswith("sensor-") for k in rules)  # a run without sensors of their own has no such role
