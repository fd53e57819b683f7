"""How the release's robots move (``release-behaviour.md`` §4), for every robot at once.

The behaviours write only one vector per robot, the resultant velocity ``rv``; the actuator
turns it into motion every iteration. Each function here is one of the release's methods,
applied to the robots an array selects.
"""

from __future__ import annotations

import math

import numpy as np

BIAS = 1e-4
"""``ActuatorControl`` adds (0.0001, 0, 0) to the normalised heading, so a zero ``rv`` faces
+x (§4.1)."""


class Actuator:
    """Stop-and-turn velocity control (§4.1): a robot whose heading is within the tolerance of
    ``rv`` drives at full speed along ``rv`` and does not turn; any other robot stands still and
    turns toward ``rv`` by at most ``max_turn * dt``."""

    def __init__(self, speed: float, turn_deg: float, tolerance_deg: float) -> None:
        self.speed = speed
        self.turn = math.radians(turn_deg)
        self.tolerance = math.radians(tolerance_deg)

    def __call__(self, rv: np.ndarray, heading: np.ndarray, out: np.ndarray) -> None:
        """Write each robot's velocity into ``out`` (n, 2) and turn ``heading`` in place."""
        x, y = rv[:, 0], rv[:, 1]
        norm = np.hypot(x, y)
        want = np.arctan2(y, x + BIAS * norm)  # the angle of unit(rv) + (BIAS, 0)
        error = want - heading
        error += math.pi
        error %= 2 * math.pi
        error -= math.pi
        aligned = np.abs(error) < self.tolerance
        gain = aligned * self.speed
        gain /= np.where(norm > 0.0, norm, 1.0)
        np.multiply(rv, gain[:, None], out=out)
        aligned ^= True
        heading += np.clip(error, -self.turn, self.turn) * aligned


_TURNS = np.exp(1j * np.radians(np.arange(-360, 361)))
"""The unit rotation of every whole degree from -360 to 360, as a complex number."""


def rotate(v: np.ndarray, degrees: np.ndarray) -> np.ndarray:
    """Rotate each row of ``v`` (k, 2) counter-clockwise by its whole number of degrees: a
    vector as a complex number times a looked-up unit rotation."""
    z = np.ascontiguousarray(v).view(np.complex128)[:, 0] * _TURNS[degrees + 360]
    out: np.ndarray = z.view(np.float64).reshape(-1, 2)
    return out


def random_goals(rng: np.random.Generator, k: int, span: int) -> np.ndarray:
    """``RandomWalk``'s new goals: integer points with each coordinate ``Range(-span, span)``,
    i.e. uniform in [-span, span - 1], far outside the arena (§4.2)."""
    return rng.integers(-span, span, size=(k, 2)).astype(np.float64)


def carry_aim(rng: np.random.Generator, to_zone: np.ndarray, jitter: tuple[int, int]) -> np.ndarray:
    """``WalkToCollection`` (§4.4): aim at the zone's centre, turned by an integer angle drawn
    every tick from ``jitter`` (the release's {-5, …, 4} degrees)."""
    angles = rng.integers(jitter[0], jitter[1] + 1, size=len(to_zone))
    return rotate(to_zone, angles)


def avoidance(rng: np.random.Generator, away: np.ndarray, turn: tuple[int, int]) -> np.ndarray:
    """``CollisionAvoidance`` (§4.6): Σ(self - collider), turned counter-clockwise by an integer
    angle drawn every tick from ``turn`` (the release's {70, …, 79} degrees): mostly sideways,
    always the same way."""
    angles = rng.integers(turn[0], turn[1] + 1, size=len(away))
    return rotate(away, angles)
