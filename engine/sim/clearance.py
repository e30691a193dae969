"""Where the WhiskEye fits: its footprint (a body disc and a head disc ahead of it), the
footprint's clearance from a world's obstacles, and the route loops it can drive clear of them.

Works on any `DistanceField` (an environment's `ObstacleMap` is one), so that the
environment schema can check its route here without this module knowing the schema.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal, Protocol

import numpy as np

from vitaplace.engine.sim.robot import BODY_RADIUS, HEAD_HALF, HEAD_POS


class DistanceField(Protocol):
    """Distances from points to the nearest obstacle (negative inside one)."""

    def distance_many(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (n,) of ``points`` (n, 2) [m]."""


HEAD_CENTRE = HEAD_POS[0]  #: the head is modelled as a disc at this distance ahead of the base centre
HEAD_RADIUS = math.hypot(HEAD_HALF[0], HEAD_HALF[1])  #: ... with this radius (covers the head box)


def footprint_clearance(obstacles: DistanceField, xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Smallest clearance (n,) of the body and the head of the robot at positions ``xy``
    (n, 2) facing ``heading`` (n,) [rad]: obstacle distance minus the disc's radius [m]."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    heading = np.asarray(heading, dtype=float).reshape(-1)
    head = xy + HEAD_CENTRE * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    dist = obstacles.distance_many(np.concatenate([xy, head]))
    return np.minimum(dist[: len(xy)] - BODY_RADIUS, dist[len(xy):] - HEAD_RADIUS)


#: Length of the sum of two unit normals below which a waypoint counts as a reversal: the
#: sum's length is 2 cos(turn / 2), so this is a turn within 1e-9 rad of 180°, where its
#: direction would be rounding noise.
_REVERSAL = 1e-9


class Route:
    """A closed polyline with arc-length parametrisation."""

    def __init__(self, waypoints: Sequence[tuple[float, float]] | np.ndarray) -> None:
        pts = np.asarray(waypoints, dtype=float)
        if len(pts) < 2:
            raise ValueError("a route needs at least 2 waypoints")
        if np.allclose(pts[0], pts[-1]):
            pts = pts[:-1]
        self.points = pts
        self.seg_a = pts
        self.seg_b = np.roll(pts, -1, axis=0)
        seg = self.seg_b - self.seg_a
        self.seg_len = np.linalg.norm(seg, axis=1)
        self.seg_dir = seg / self.seg_len[:, None]
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.length = float(self.cum[-1])

    def at(self, s: np.ndarray) -> np.ndarray:
        """Positions (n, 2) at arc lengths ``s`` (n,), wrapped around the loop."""
        return self.offset_at(s, 0.0)

    def offset_at(self, s: np.ndarray, offset: float) -> np.ndarray:
        """Positions (n, 2) at arc lengths ``s``, moved ``offset`` metres to the left of the
        direction of travel (the segment's normal)."""
        s = np.asarray(s, dtype=float) % self.length
        i = np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.seg_len) - 1)
        normal = np.stack([-self.seg_dir[i, 1], self.seg_dir[i, 0]], axis=1)
        return self.seg_a[i] + (s - self.cum[i])[:, None] * self.seg_dir[i] + offset * normal

    def point(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and unit tangent at arc length ``s`` (wrapped around the loop)."""
        s = s % self.length
        i = int(np.searchsorted(self.cum, s, side="right") - 1)
        i = min(max(i, 0), len(self.seg_len) - 1)
        return self.seg_a[i] + (s - self.cum[i]) * self.seg_dir[i], self.seg_dir[i]

    def project(self, p: np.ndarray) -> tuple[float, float]:
        """Arc length of the closest route point to ``p`` and the distance to it."""
        ap = p[None, :] - self.seg_a
        t = np.clip(np.einsum("ij,ij->i", ap, self.seg_dir), 0, self.seg_len)
        closest = self.seg_a + t[:, None] * self.seg_dir
        dist = np.linalg.norm(closest - p[None, :], axis=1)
        i = int(np.argmin(dist))
        return float(self.cum[i] + t[i]), float(dist[i])

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of each of ``points`` (n, 2) to the route polyline."""
        p = np.asarray(points, dtype=float)[:, None, :]
        ap = p - self.seg_a[None]
        t = np.clip(np.einsum("nij,ij->ni", ap, self.seg_dir), 0, self.seg_len[None])
        closest = self.seg_a[None] + t[..., None] * self.seg_dir[None]
        return np.linalg.norm(closest - p, axis=2).min(axis=1)

    def sample(self, step: float = 0.05) -> np.ndarray:
        """Points every ``step`` metres along the loop, (n, 2)."""
        return np.array([self.point(s)[0] for s in np.arange(0.0, self.length, step)])

    def segment_of(self, s: np.ndarray | float) -> np.ndarray:
        """Index (n,) of the segment (from waypoint i to i + 1) holding arc lengths ``s``."""
        s = np.asarray(s, dtype=float) % self.length
        return np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.seg_len) - 1)

    def waypoint_normals(self) -> np.ndarray:
        """Unit normals (n, 2) at the waypoints, to the left of travel: the bisectors of the
        adjacent segments' normals. Where the route turns back on itself (a 180° turn: both
        waypoints of a two-waypoint route, the tip of a spike) the two normals cancel and
        there is no bisector: there the incoming segment's own normal."""
        seg_normal = np.stack([-self.seg_dir[:, 1], self.seg_dir[:, 0]], axis=1)
        incoming = np.roll(seg_normal, 1, axis=0)
        n = seg_normal + incoming
        length = np.linalg.norm(n, axis=1, keepdims=True)
        reverses = length < _REVERSAL  # (no division by a zero length there)
        return np.where(reverses, incoming, n / np.where(reverses, 1.0, length))


#: Clearance [m] that the body and the head must keep along a route loop, driven as the route
#: kinds drive it: the followers cut corners and wander by a few cm.
ROUTE_MIN_CLEARANCE = 0.03
#: Pure-pursuit look-ahead [m] that sets the heading of a loop driven facing the direction of travel.
ROUTE_LOOKAHEAD = 0.3


def loop_clearance(
    obstacles: DistanceField, route: Route, outward: np.ndarray | None, step: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths (n,) every ``step`` metres along ``route`` and the robot's footprint
    clearance (n,) there, facing away from ``outward`` or, when that is None, towards the
    loop point `ROUTE_LOOKAHEAD` further on (pure pursuit)."""
    s = np.arange(0.0, route.length, step)
    points = route.at(s)
    rel = points - outward if outward is not None else route.at(s + ROUTE_LOOKAHEAD) - points
    return s, footprint_clearance(obstacles, points, np.arctan2(rel[:, 1], rel[:, 0]))


def route_collision(
    waypoints: Sequence[tuple[float, float]], facing: Literal["travel", "outward"], obstacles: DistanceField
) -> str | None:
    """Why the WhiskEye cannot drive the route loop ``waypoints``, ``facing`` as an
    environment's ``route_facing`` says, clear of ``obstacles`` (one line naming the waypoint),
    or None when it can. Two consecutive waypoints at one point (`Route`'s ``np.allclose``) leave a
    segment without length, and no direction to drive: named before any arithmetic on it."""
    for i in range(1, len(waypoints)):
        if np.allclose(waypoints[i], waypoints[i - 1]):
            return (f"route.{i}: waypoint {i} ({waypoints[i][0]:g}, {waypoints[i][1]:g}) is where waypoint {i - 1} "
                    "is; expected consecutive waypoints at different points (the segment between them has no length)")
    route = Route(waypoints)
    outward = np.mean(waypoints, axis=0) if facing == "outward" else None
    s, clearance = loop_clearance(obstacles, route, outward)
    bad = np.flatnonzero(clearance < ROUTE_MIN_CLEARANCE)
    if not len(bad):
        return None
    k = int(bad[0])
    i = int(route.segment_of(s[k]))
    if s[k] - route.cum[i] > 0.5 * route.seg_len[i]:  # name the nearer end of the segment
        i = (i + 1) % len(route.points)
    x, y = waypoints[i]
    how = "sideways facing outward" if outward is not None else "facing the direction of travel"
    where = f"{-clearance[k]:.2f} m inside" if clearance[k] < 0 else f"{clearance[k]:.2f} m from"
    return (
        f"route.{i}: the WhiskEye cannot drive this loop clear of the walls and landmarks: near waypoint {i} "
        f"({x:g}, {y:g}), driven {how}, its body or head comes {where} an obstacle "
        f"(it needs {ROUTE_MIN_CLEARANCE:g} m all along the loop)"
    )
