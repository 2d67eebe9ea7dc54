"""A patrol: one target flying a loop inside the sensors' field, with process noise, for any duration (issue 36).

A single-target scenario's ``[trajectory]`` with ``kind = "patrol"`` (:class:`PatrolSpec`) makes the target fly
an ellipse about ``centre`` (semi-axes ``semi_axes`` in x and y, climbing and descending by ``climb`` twice a
lap) at ``speed`` along a reference point, while a random acceleration of ``sigma_a`` per axis pushes it off
the loop and a critically damped pull of rate ``pull`` (1/s) brings it back. The reference point's own
acceleration is fed forward, so the target's offset from the loop is a stationary process: about
``sigma_a * sqrt(ts / (4 pull^3))`` per axis, whatever the run's length. Unlike the plant's random walk (exp2's
target drifts kilometres out of its 400 m ring over ten minutes), a patrol stays where the sensors see it.

Run r's path (:func:`patrol_paths`) comes from child r of its own seed stream (``seed`` with
:data:`PATROL_STREAM`), so the measurement noise and initial estimates of a run are drawn as for any other
scenario, and a run is identical whatever the number of runs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Array = np.ndarray

#: run r's path noise comes from child r of ``SeedSequence([seed, PATROL_STREAM])``
PATROL_STREAM = 36
#: the keys ``[trajectory]`` takes with ``kind = "patrol"``
PATROL_KEYS = ("kind", "centre", "semi_axes", "climb", "speed", "sigma_a", "pull")


@dataclass(frozen=True)
class PatrolSpec:
    """A patrol loop (module docstring): metres, m/s, m/s^2 and 1/s."""

    centre: tuple[float, float, float]
    semi_axes: tuple[float, float]
    climb: float = 0.0
    speed: float = 15.0
    sigma_a: float = 2.0
    pull: float = 0.1

    def validate(self) -> None:
        numbers = [*self.centre, *self.semi_axes, self.climb, self.speed, self.sigma_a, self.pull]
        if not all(np.isfinite(numbers)):
            raise ValueError(f"patrol: every figure must be finite, got {numbers}")
        if min(self.semi_axes) <= 0 or self.speed <= 0 or self.pull <= 0 or self.sigma_a < 0 or self.climb < 0:
            raise ValueError("patrol: semi_axes, speed and pull must be positive, sigma_a and climb not negative")

    def offset_std(self, ts: float) -> float:
        """The stationary standard deviation (m, per axis) of the target's offset from the loop."""
        return float(self.sigma_a * np.sqrt(ts / (4.0 * self.pull**3)))


def _loop(spec: PatrolSpec, phase: Array, rate: float) -> tuple[Array, Array, Array]:
    """The reference point's position, velocity and acceleration ``(K, 3)`` at ``phase`` (rad) turning at
    ``rate`` (rad/s)."""
    a, b = spec.semi_axes
    c, s, c2, s2 = np.cos(phase), np.sin(phase), np.cos(2 * phase), np.sin(2 * phase)
    h = spec.climb
    pos = np.stack([spec.centre[0] + a * c, spec.centre[1] + b * s, spec.centre[2] + h * s2], axis=-1)
    vel = rate * np.stack([-a * s, b * c, 2 * h * c2], axis=-1)
    acc = rate**2 * np.stack([-a * c, -b * s, -4 * h * s2], axis=-1)
    return pos, vel, acc


def patrol_paths(spec: PatrolSpec, runs: int, steps: int, ts: float, seed: int) -> Array:
    """The true states ``(runs, steps, 6)`` (position, velocity) of ``runs`` patrols of ``steps`` steps."""
    spec.validate()
    a, b = spec.semi_axes
    rate = spec.speed / float(np.sqrt(0.5 * (a * a + b * b)))  # about ``speed`` along the loop
    ref_pos, ref_vel, ref_acc = _loop(spec, rate * ts * np.arange(steps), rate)
    k = spec.pull
    out = np.empty((runs, steps, 6))
    for r, child in enumerate(np.random.SeedSequence([seed, PATROL_STREAM]).spawn(runs)):
        noise = spec.sigma_a * np.random.default_rng(child).standard_normal((steps, 3))
        p, v = ref_pos[0].copy(), ref_vel[0].copy()
        for i in range(steps):
            out[r, i, :3], out[r, i, 3:] = p, v
            acc = ref_acc[i] + k * k * (ref_pos[i] - p) + 2 * k * (ref_vel[i] - v) + noise[i]
            v = v + ts * acc  # semi-implicit Euler: stable for pull * ts << 1
            p = p + ts * v
    return out
