"""The look-ahead `SafetyGuard` that foraging and teleop share (it keeps the body and the
head off obstacles), and `Headway`: whether a robot is getting anywhere."""

from __future__ import annotations

import math

import numpy as np

from vitaplace.engine.sim.clearance import footprint_clearance
from vitaplace.engine.sim.controllers.common import wrap as _wrap
from vitaplace.engine.sim.environment import ObstacleMap


class SafetyGuard:
    """The look-ahead safety guard shared by the controllers that drive near obstacles: a
    command (v, w, lateral) is safe when, driven for ``horizon`` seconds, it leaves the body
    and the head at least ``floor`` clear of every obstacle - or, where the robot is already
    closer than that, no closer than it is now (so it can always back away).

    With ``braking`` [m/s^2] (the base's rate limit) the look-ahead follows the base's
    speed: from its ``current`` (v, lateral) it ramps to the command, holds it to the end of
    the horizon and then brakes to a stop; without, the command is driven for the horizon."""

    HORIZON = 0.5  #: default look-ahead [s]

    def __init__(self, obstacles: ObstacleMap, floor: float, braking: float | None = None) -> None:
        self.obstacles, self.floor, self.braking = obstacles, floor, braking

    def _travel(self, start: float, command: float, horizon: float) -> np.ndarray:
        """Distances [m] along one axis at a quarter, half, three quarters and the end of
        ``horizon`` (ramp from ``start`` to ``command`` at ``braking``, then hold) and after
        braking to a stop from there (5,)."""
        a = self.braking
        assert a is not None  # called only with braking
        tau = horizon * np.array([0.25, 0.5, 0.75, 1.0])
        ramp = np.minimum(abs(command - start) / a, tau)
        reached = start + np.copysign(a * ramp, command - start)
        travel = 0.5 * (start + reached) * ramp + reached * (tau - ramp)
        return np.append(travel, travel[-1] + reached[-1] * abs(reached[-1]) / (2 * a))

    def clearance(
        self, pose: np.ndarray, v: float, w: float, lateral: float = 0.0, horizon: float = HORIZON,
        current: tuple[float, float] = (0.0, 0.0),
    ) -> float:
        """Smallest clearance of the body and the head at the end of the look-ahead (with
        ``braking``: anywhere along it)."""
        x, y, yaw = pose
        if self.braking:
            forward, left = self._travel(current[0], v, horizon), self._travel(current[1], lateral, horizon)
            turned = w * horizon * np.array([0.25, 0.5, 0.75, 1.0, 1.0])
        else:
            forward, left, turned = np.array([v * horizon]), np.array([lateral * horizon]), np.array([w * horizon])
        mid = yaw + 0.5 * turned
        c, s = np.cos(mid), np.sin(mid)
        pos = np.stack([x + forward * c - left * s, y + forward * s + left * c], axis=1)
        return float(footprint_clearance(self.obstacles, pos, yaw + turned).min())

    def safe(
        self, pose: np.ndarray, v: float, w: float, lateral: float = 0.0, horizon: float = HORIZON,
        current: tuple[float, float] = (0.0, 0.0),
    ) -> bool:
        return self.first_safe(pose, [(v, w, lateral)], horizon, current) == (v, w, lateral)

    def first_safe(
        self, pose: np.ndarray, candidates: list[tuple[float, float, float]], horizon: float = HORIZON,
        current: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[float, float, float]:
        """The first safe command of ``candidates``, else standing still (the last resort)."""
        floor = min(self.clearance(pose, 0.0, 0.0, 0.0, 0.0), self.floor)
        for cand in candidates:
            if self.clearance(pose, *cand, horizon=horizon, current=current) >= floor:
                return cand
        return (0.0, 0.0, 0.0)


class Headway:
    """Whether a robot is getting anywhere: it has moved `DISTANCE` or turned `TURN` since the
    pose it last did (its anchor). `stalled` when that was `STALL_TIME` ago or more: it is
    stuck (standing, or dithering between commands the guard lets through one by one)."""

    DISTANCE, TURN, STALL_TIME = 0.1, 0.3, 3.0  #: [m], [rad], [s]

    def __init__(self) -> None:
        self.pose, self.since = np.zeros(3), 0.0

    def restart(self, pose: np.ndarray, t: float) -> None:
        self.pose, self.since = np.array(pose, dtype=float), t

    def stalled(self, pose: np.ndarray, t: float) -> bool:
        moved = (math.hypot(*(pose[:2] - self.pose[:2])) > self.DISTANCE
                 or abs(_wrap(pose[2] - self.pose[2])) > self.TURN)
        if moved:
            self.restart(pose, t)
        return not moved and t - self.since >= self.STALL_TIME
