"""The wire type of an independent sensor's detection (``det/<s>``, sensor s -> the trackers it feeds).

A sensor process (``zentrack sensor``, or any program that speaks this format: docs/sensors.md) samples the
world at its own rate and phase and publishes each scan as one :class:`Detection` after its own latency. Nothing
in it is a step of the run: the header's ``k`` is the sensor's **sequence number** of the scan (0, 1, 2, ... per
sensor incarnation), its ``t`` the **measurement time on the sensor's own clock** (seconds since the Unix
epoch; the tracker maps it to its own clock, ``node/detections.py``). The rest is the scan itself: the returns
``(J, m)`` (J = 0: looked, saw nothing), the sensor's position, and the noise covariance of one return, so a
tracker needs nothing configured about a sensor but its id.

Decoding checks every field like every other kind (``zentrack/transport/messages.py``): the sender must be the
sensor whose key it came on (a forged id is refused ``sender_mismatch``), the time finite and positive, the
returns finite and within range, the pose finite, the covariance symmetric positive definite.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Self

import numpy as np

from zentrack.transport.codec import (
    WireError,
    built,
    check_pd,
    field,
    header,
    number,
    pack_array,
    pack_symmetric,
    packed,
    short,
    unpack,
    unpack_pose,
    unpack_returns,
    unpack_symmetric,
    wire_kind,
)

#: the most sensors a run addresses (``det/<s>``, s from 0)
MAX_SENSORS = 10_000


@wire_kind("det")
@dataclass(frozen=True, eq=False)
class Detection:
    """Sensor ``sensor``'s scan number ``seq``, measured at ``t_meas`` on its own clock (module docstring);
    ``t_pub``: when it was put on the wire, on the same clock."""

    seq: int
    t_meas: float
    sensor: int
    returns: np.ndarray
    pose: np.ndarray
    noise_cov: np.ndarray
    t_pub: float

    def encode(self) -> bytes:
        msg = header("det", self.seq, self.t_meas, self.sensor)
        msg["returns"] = pack_array(np.asarray(self.returns, dtype=float).reshape(-1, self.noise_cov.shape[0]))
        msg["pose"] = pack_array(self.pose)
        msg["noise_cov"] = pack_symmetric(np.asarray(self.noise_cov, dtype=float))
        msg["t_pub"] = float(self.t_pub)
        return packed(msg)

    @classmethod
    def decode(cls, payload: bytes, key_sensor: int, m: int) -> Self:
        """A detection from ``det/<key_sensor>`` with returns of width ``m``."""
        msg = unpack(payload)
        if msg["kind"] != "det":
            raise WireError("kind", f"kind {msg['kind']!r} on a detection key")
        sender = msg.get("sender")
        if type(sender) is not int or sender != key_sensor:
            raise WireError("sender_mismatch", f"sender {short(sender)} on the key of sensor {key_sensor}")
        t_meas = float(msg["t"])
        if t_meas <= 0:
            raise WireError("range", f"measurement time {t_meas!r} is not a positive clock reading")
        returns = unpack_returns(msg.get("returns"), m)
        pose = unpack_pose(msg.get("pose"))
        cov = unpack_symmetric(msg.get("noise_cov"), m, "noise_cov")
        check_pd(cov, "noise_cov")
        field(msg, "t_pub", (int, float))
        return built(cls, {"seq": msg["k"], "t_meas": t_meas, "sensor": sender, "returns": returns, "pose": pose,
                           "noise_cov": cov, "t_pub": number(msg, "t_pub")})
