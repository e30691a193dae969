"""What every controller shares: the `Observation` it is called with, seeded
Ornstein-Uhlenbeck noise (`OU`), the command rate limiter (`Limiter`) and angle wrapping."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import overload

import numpy as np

from vitaplace.engine.sim.robot import HEAD_HALF, HEAD_POS

HEAD_REACH = HEAD_POS[0] + HEAD_HALF[0]  #: distance from the base centre to the snout [m]


@dataclass
class Observation:
    """What a controller sees at a control tick."""

    time: float
    pose: np.ndarray  #: (3,) x, y, yaw
    contacts: np.ndarray  #: (k, 3) whisker contact points (world frame) at this tick
    deflection: np.ndarray  #: (24,) |xy| per whisker [rad]


class OU:
    """Ornstein-Uhlenbeck process with stationary std ``sigma`` and time constant ``tau``."""

    def __init__(self, rng: np.random.Generator, sigma: float, tau: float, x0: float | None = None) -> None:
        self.rng, self.sigma, self.tau = rng, sigma, tau
        self.x = float(rng.normal(0.0, sigma)) if x0 is None else x0

    def step(self, dt: float) -> float:
        a = math.exp(-dt / self.tau)
        self.x = a * self.x + self.sigma * math.sqrt(1 - a * a) * float(self.rng.normal())
        return self.x


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class Limiter:
    """Rate-limits each command component (so the base accelerates smoothly and whisker
    inertial noise stays low): ``limits`` are the largest changes per second."""

    def __init__(self, *limits: float) -> None:
        self.limits = np.asarray(limits, dtype=float)
        self.state = np.zeros(len(limits))

    @overload
    def __call__(self, v: float, w: float, /, *, dt: float) -> tuple[float, float]: ...

    @overload
    def __call__(self, v: float, w: float, side: float, /, *, dt: float) -> tuple[float, float, float]: ...

    def __call__(self, *command: float, dt: float) -> tuple[float, ...]:  # one component per limit
        step = self.limits * dt
        self.state += np.clip(np.asarray(command, dtype=float) - self.state, -step, step)
        return tuple(float(c) for c in self.state)
