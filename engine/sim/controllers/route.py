"""Route following (``route``): pure pursuit along the environment's closed waypoint loop,
facing the direction of travel; the orbit (``orbit``) drives a circle the same way,
sideways, facing outward (`RouteFollower` with ``outward``). See the package docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vitaplace.engine.sim.clearance import Route
from vitaplace.engine.sim.controllers.common import OU as _OU
from vitaplace.engine.sim.controllers.common import Limiter as _Limiter
from vitaplace.engine.sim.controllers.common import Observation
from vitaplace.engine.sim.controllers.common import wrap as _wrap
from vitaplace.engine.sim.controllers.settings import OrbitRun, RouteRun
from vitaplace.engine.sim.environment import ObstacleMap
from vitaplace.engine.sim.robot import BODY_RADIUS


@dataclass
class RouteFollower:
    """Pure pursuit along a closed route with seeded pose, heading and speed noise; facing the
    direction of travel, or (``outward`` given) driven sideways with the camera facing away
    from that point."""

    spec: RouteRun | OrbitRun
    route: Route
    obstacles: ObstacleMap
    rng: np.random.Generator
    off_route_from: float = math.inf  #: time [s] from which the run leaves the route
    outward: np.ndarray | None = None  #: face away from this point instead of along the route
    s: float = 0.0

    def __post_init__(self) -> None:
        tau = self.spec.noise_time_constant
        self._lateral = _OU(self.rng, self.spec.lateral_noise, tau)
        self._heading = _OU(self.rng, math.radians(self.spec.heading_noise_deg), tau / 2)
        self._speed = _OU(self.rng, self.spec.speed_noise, tau)
        self._limit = _Limiter(self.spec.max_accel, 4.0, self.spec.max_accel)
        self._last_t: float | None = None
        self.mode = self.spec.kind

    def _facing(self, pos: np.ndarray, tangent: np.ndarray) -> float:
        """The heading the robot should have at ``pos`` (noise-free)."""
        if self.outward is None:
            return math.atan2(tangent[1], tangent[0])
        return math.atan2(pos[1] - self.outward[1], pos[0] - self.outward[0])

    def start_pose(self) -> tuple[float, float, float]:
        if self.spec.start is not None:
            x, y, yaw = self.spec.start
            self.s, _ = self.route.project(np.array([x, y]))
            return (x, y, math.radians(yaw))
        s0 = abs(float(self.rng.normal(0.0, self.spec.start_noise)))
        p, t = self.route.point(s0)
        n = np.array([-t[1], t[0]])
        lateral = float(np.clip(self.rng.normal(0.0, self.spec.start_noise), -0.05, 0.05))
        p = p + lateral * n
        yaw = self._facing(p, t) + float(self.rng.normal(0.0, math.radians(self.spec.heading_noise_deg)))
        self.s = s0
        return (float(p[0]), float(p[1]), yaw)

    def __call__(self, obs: Observation) -> tuple[float, float, float]:
        dt = 0.0 if self._last_t is None else obs.time - self._last_t
        self._last_t = obs.time
        spec = self.spec
        if dt > 0:
            self._lateral.step(dt)
            self._heading.step(dt)
            self._speed.step(dt)
        x, y, yaw = obs.pose
        pos = np.array([x, y])
        lateral = float(np.clip(self._lateral.x, -2 * spec.lateral_noise, 2 * spec.lateral_noise))
        detour = spec.off_route_offset if obs.time >= self.off_route_from else 0.0
        # progress: closest point of the (detoured) path, searched only slightly ahead of the last one
        cand = self.s + np.linspace(-0.1, 0.5, 25)
        d = np.linalg.norm(self.route.offset_at(cand, detour) - pos[None], axis=1)
        self.s = max(self.s, float(cand[int(np.argmin(d))]))
        target, tangent = self.route.point(self.s + spec.lookahead)
        normal = np.array([-tangent[1], tangent[0]])
        target = target + (lateral + detour) * normal
        course = math.atan2(target[1] - y, target[0] - x)
        # keep the body clear of obstacles (the route passes close to landmarks)
        dist, grad = self.obstacles.query(pos[None])
        clearance = float(dist[0]) - BODY_RADIUS
        if clearance < spec.avoid_margin:
            g = grad[0]
            course += 0.6 * _wrap(math.atan2(g[1], g[0]) - course) * (1 - clearance / spec.avoid_margin)
        speed = spec.speed * (1.0 + float(np.clip(self._speed.x, -0.5, 0.5)))
        wmax = math.radians(spec.max_turn_rate_deg)
        if self.outward is None:  # drive forward along the course
            err = _wrap(course + self._heading.x - yaw)
            w = float(np.clip(2.5 * err, -wmax, wmax))
            v, side = speed * max(0.0, math.cos(err)) ** 2, 0.0
        else:  # holonomic: move along the course whatever the heading, face outward
            vel = speed * np.array([math.cos(course), math.sin(course)])
            rel = pos - self.outward
            turning = float(rel[0] * vel[1] - rel[1] * vel[0]) / max(float(rel @ rel), 0.01)  # d/dt of the bearing
            err = _wrap(self._facing(pos, tangent) + self._heading.x - yaw)
            w = float(np.clip(turning + 2.5 * err, -wmax, wmax))
            v, side = speed * math.cos(course - yaw), speed * math.sin(course - yaw)
        return self._limit(v, w, side, dt=dt)
