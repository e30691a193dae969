"""Environments as data: YAML files loaded into validated pydantic models.

An environment file describes a square arena (walls with a visual pattern, a floor),
landmark objects (``box``, ``cylinder``, ``rock`` = convex hull of a seeded random point
cloud) and an evaluation ``route`` (closed loop of waypoints). A file may ``extends:``
another file (path relative to the extending file's folder): mappings are deep-merged,
lists are replaced.

Angles in the files are in degrees, lengths in metres, colours in [0, 1].

>>> env = load_environment("scenarios/environments/e1.yaml")   # doctest: +SKIP
>>> env.top_view()["landmarks"][0]                              # doctest: +SKIP
{'name': 'box_a', 'type': 'box', 'pos': [...], 'size': [1.0, 1.0], 'yaw': 0.0, 'tactile': True}
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pydantic
from pydantic import ConfigDict, Field

from vitaplace.engine.base.configfile import (
    ConfigError,
    Degrees,
    NumbersNotBooleans,
    format_validation_error,
    load_yaml,
)
from vitaplace.engine.base.shipped import ENVIRONMENTS_DIR, environment_files, shipped_file, shipped_names_hint
from vitaplace.engine.sim.clearance import route_collision
from vitaplace.engine.sim.textures import png_problem

__all__ = ["EnvironmentSpecError", "EnvironmentSpec", "ArenaSpec", "MaterialSpec", "TextureSpec", "BoxLandmark",
           "CylinderLandmark", "RockLandmark", "load_environment", "environment_files", "ENVIRONMENTS_DIR"]

# Collision bit masks (MuJoCo: two geoms collide when (contype1 & conaffinity2) or
# (contype2 & conaffinity1) is non-zero).
BIT_BODY = 2  #: robot chassis/head: collides with every world object
BIT_WHISKER = 4  #: whisker shafts: collide with tactile world objects only
WORLD_TACTILE_AFFINITY = BIT_BODY | BIT_WHISKER
WORLD_VISUAL_AFFINITY = BIT_BODY

RGB = tuple[
    Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(ge=0, le=1)]
]
RGBA = tuple[
    Annotated[float, Field(ge=0, le=1)],
    Annotated[float, Field(ge=0, le=1)],
    Annotated[float, Field(ge=0, le=1)],
    Annotated[float, Field(ge=0, le=1)],
]
Positive = Annotated[float, Field(gt=0)]
XY = tuple[float, float]


class EnvironmentSpecError(ConfigError):
    """An environment file that cannot be loaded; the message names the file and the key path."""


class _Model(NumbersNotBooleans):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TextureSpec(_Model):
    """A MuJoCo procedural texture (``builtin``) or a PNG file (``file``, relative to the YAML;
    `load_environment` checks that it is one)."""

    builtin: Literal["checker", "gradient", "flat", "none"] = Field("checker", description="MuJoCo procedural texture")
    file: str | None = Field(None, description="PNG file instead, relative to the YAML")
    rgb1: RGB = Field((0.8, 0.8, 0.8), description="first colour")
    rgb2: RGB = Field((0.5, 0.5, 0.5), description="second colour")
    mark: Literal["none", "edge", "cross", "random"] = Field("none", description="marks drawn on the texture")
    markrgb: RGB = Field((0.0, 0.0, 0.0), description="colour of the marks")
    random: Annotated[float, Field(ge=0, le=1)] = Field(0.01, description="fraction of random pixels (mark: random)")
    width: Annotated[int, Field(ge=2, le=2048)] = Field(64, description="texture width [px]")
    height: Annotated[int, Field(ge=2, le=2048)] = Field(64, description="texture height [px]")


class MaterialSpec(_Model):
    """A render material: colour, optional texture, repetition. Reflectance is always 0 (fast rendering)."""

    rgba: RGBA = Field((1.0, 1.0, 1.0, 1.0), description="colour (multiplies the texture)")
    texture: TextureSpec | None = Field(None, description="optional texture")
    texrepeat: tuple[Positive, Positive] = Field(
        (1.0, 1.0),
        description="how often the 2-D texture repeats over the textured face (``texuniform``: per metre)",
    )
    texuniform: bool = Field(False, description="texture repeats per metre rather than per face")
    specular: Annotated[float, Field(ge=0, le=1)] = Field(0.1, description="specular reflection")
    shininess: Annotated[float, Field(ge=0, le=1)] = Field(0.2, description="specular exponent (0-1)")


class PanelSpec(_Model):
    """A box fixed to a wall's inner face (e.g. a coloured sign): ``width`` along the wall,
    from ``bottom`` to ``top`` above the floor, ``depth`` thick, its front face
    ``protrusion`` in front of the wall's inner face, centred ``offset`` from the wall's middle."""

    width: Positive = Field(description="extent along the wall")
    bottom: Annotated[float, Field(ge=0)] = Field(description="height of its lower edge above the floor")
    top: Positive = Field(description="height of its upper edge")
    depth: Positive = Field(description="thickness of the box")
    protrusion: Annotated[float, Field(ge=0)] = Field(
        description="distance its front stands in front of the wall's inner face",
    )
    offset: float = Field(0.0, description="shift along the wall from the wall's middle")
    rgba: RGBA = Field((1.0, 0.0, 0.0, 1.0), description="colour")

    @pydantic.model_validator(mode="after")
    def _check(self) -> PanelSpec:
        if self.top <= self.bottom:
            raise ValueError("top must be above bottom")
        return self


class WallSpec(_Model):
    """One wall's look: a plain colour, or a material (a textured material repeats
    ``ArenaSpec.wall_panels`` times along the wall), and an optional panel."""

    rgba: RGBA = Field((0.8, 0.8, 0.8, 1.0), description="plain colour of the wall (when no material)")
    material: str | None = Field(None, description="a material instead of the plain colour")
    panel: PanelSpec | None = Field(None, description="an optional box on the wall's inner face")


class ArenaSpec(_Model):
    """Rectangular arena centred on the origin: ``width`` (x) by ``depth`` (y) inside the
    walls, or a ``size`` x ``size`` square when those are not given."""

    size: Annotated[float, Field(gt=1.0, le=50.0)] = Field(6.0, description="inner side of a square arena")
    width: Annotated[float, Field(gt=1.0, le=50.0)] | None = Field(
        None,
        description="inner extent along x (with depth: a rectangle)",
    )
    depth: Annotated[float, Field(gt=1.0, le=50.0)] | None = Field(None, description="inner extent along y")
    wall_height: Positive = Field(1.5, description="height of the walls")
    wall_thickness: Positive = Field(0.1, description="thickness of the walls (outside the inner extent)")
    wall_panels: Annotated[int, Field(ge=1, le=64)] = Field(
        6,
        description="number of identical panels along each wall (visual aliasing: every wall looks the same)",
    )
    wall_material: str = Field("wall", description="material of every wall without its own entry in ``walls``")
    walls: dict[Literal["north", "south", "east", "west"], WallSpec] = Field(
        default_factory=dict,
        description="per-wall look (keys: north, south, east, west); missing walls use ``wall_material``",
    )
    floor_material: str = Field("floor", description="material of the floor")

    @pydantic.model_validator(mode="after")
    def _both_extents(self) -> ArenaSpec:
        if (self.width is None) != (self.depth is None):  # one alone would take the other from size, unsaid
            raise ValueError(f"{'width' if self.depth is None else 'depth'} alone: a rectangular arena needs width "
                             "and depth (or neither: the size x size square)")
        return self

    @property
    def half_x(self) -> float:
        return (self.width or self.size) / 2

    @property
    def half_y(self) -> float:
        return (self.depth or self.size) / 2


class LightSpec(_Model):
    """A directional light (sun): direction of travel of the light, diffuse and specular level."""

    direction: tuple[float, float, float] = Field((0.3, 0.2, -1.0), description="direction the light travels")
    diffuse: Annotated[float, Field(ge=0, le=1)] = Field(0.5, description="diffuse level")
    specular: Annotated[float, Field(ge=0, le=1)] = Field(0.0, description="specular level")

    @pydantic.field_validator("direction")
    @classmethod
    def _nonzero(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not any(v):
            raise ValueError("direction must not be zero")
        return v


class LightingSpec(_Model):
    """Directional lights, a uniform ambient level, the camera-mounted headlight (diffuse
    only) and shadows. The defaults are vitaplace's original look (sun 0.5, ambient 0.45,
    headlight 0.35, no shadows)."""

    lights: list[LightSpec] = Field(
        default_factory=lambda: [LightSpec()], max_length=6,
        description="directional lights",
    )
    ambient: Annotated[float, Field(ge=0, le=1)] = Field(0.45, description="uniform ambient light level")
    headlight: Annotated[float, Field(ge=0, le=1)] = Field(
        0.35,
        description="diffuse level of the camera-mounted light (0: off)",
    )
    shadows: bool = Field(False, description="cast shadows")


class BoardSpec(_Model):
    """A flat board standing upright (render only, no collision), e.g. a banner seen over a
    wall: ``width`` x ``height`` x ``thickness``, its front facing ``yaw`` (degrees from +x,
    counter-clockwise; -90 faces -y), its bottom edge at ``bottom`` (may be below the
    floor), and a horizontal strip of ``strip_rgba`` ``strip_height`` high on its front,
    centred ``strip_below_top`` under the top edge."""

    pos: XY = Field(description="position of its centre")
    yaw: float = Field(0.0, description="direction its front faces, degrees from +x")
    width: Positive = Field(description="width")
    height: Positive = Field(description="height")
    thickness: Positive = Field(0.05, description="thickness")
    bottom: float = Field(0.0, description="height of its bottom edge (may be below the floor)")
    rgba: RGBA = Field((0.6, 0.6, 0.6, 1.0), description="colour of the board")
    strip_rgba: RGBA = Field((0.05, 0.05, 0.05, 1.0), description="colour of the strip")
    strip_height: Annotated[float, Field(ge=0)] = Field(0.0, description="height of the strip (0: none)")
    strip_below_top: Annotated[float, Field(ge=0)] = Field(
        0.0,
        description="distance of the strip's centre below the top edge",
    )


class _LandmarkBase(_Model):
    name: str | None = Field(None, description="unique name (default: type and index)")
    pos: XY = Field(description="position of its centre on the floor")
    yaw: float = Field(0.0, description="degrees, counter-clockwise")
    rgba: RGBA = Field((0.6, 0.6, 0.6, 1.0), description="colour (when no material)")
    material: str | None = Field(
        None,
        description="name of an entry of ``materials`` (overrides rgba for rendering when given)",
    )
    tactile: bool = Field(
        True,
        description="reachable by whiskers (collides with whisker shafts); always an obstacle for the body",
    )
    z: Annotated[float, Field(ge=0)] = Field(
        0.0,
        description="height of the landmark's bottom above the floor [m] (a floating box)",
    )


class BoxLandmark(_LandmarkBase):
    type: Literal["box"] = Field(description="box")
    size: tuple[Positive, Positive, Positive] = Field(description="full extents x, y, z [m]")


class CylinderLandmark(_LandmarkBase):
    type: Literal["cylinder"] = Field(description="cylinder")
    radius: Positive = Field(description="radius")
    height: Positive = Field(description="height")


class RockLandmark(_LandmarkBase):
    """Convex hull of a seeded random point cloud on a lumpy, sheared ellipsoid (asymmetric)."""

    type: Literal["rock"] = Field(description="rock")
    seed: int = Field(0, ge=0, lt=2**32, description="seed of its point cloud: the same seed, the same rock")
    size: tuple[Positive, Positive, Positive] = Field(description="full extents of the envelope x, y, z [m]")
    roughness: Annotated[float, Field(ge=0, le=0.6)] = Field(0.25, description="amplitude of the lumps")
    lean: Annotated[float, Field(ge=-1, le=1)] = Field(
        0.3,
        description="shear of the upper part along x (makes the rock lean: asymmetric from every side)",
    )
    n_points: Annotated[int, Field(ge=8, le=400)] = Field(
        48,
        description="points of the cloud whose convex hull is the rock",
    )

    def vertices(self) -> np.ndarray:
        """(n, 3) vertices in the landmark frame; the lowest point sits on the floor (z = 0)."""
        rng = np.random.default_rng(self.seed)
        n = self.n_points
        # Fibonacci sphere + jitter: evenly spread directions, reproducible from the seed.
        k = np.arange(n) + 0.5
        z = 1 - 2 * k / n
        phi = math.pi * (1 + 5**0.5) * k + rng.uniform(-0.3, 0.3, n)
        r = np.sqrt(np.clip(1 - z**2, 0, 1))
        d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        # Smooth lumps: a few random low-frequency waves over the sphere.
        waves = rng.normal(size=(4, 3)) * 2.0
        phases = rng.uniform(0, 2 * math.pi, 4)
        lumps = np.sin(d @ waves.T + phases).mean(axis=1)
        radius = 1 + self.roughness * (lumps + 0.5 * rng.uniform(-1, 1, n))
        p = d * radius[:, None]
        p[:, 2] = np.maximum(p[:, 2], -0.6)  # flattened base
        p -= p.min(axis=0)
        p /= p.max(axis=0)  # unit box [0,1]^3
        p[:, 0] += self.lean * (p[:, 2] ** 2) * 0.5 - 0.5 * p[:, 1] * self.lean * 0.3  # lean + twist
        p -= p.min(axis=0)
        p /= p.max(axis=0)
        sx, sy, sz = self.size
        p = (p - [0.5, 0.5, 0.0]) * [sx, sy, sz]
        return p

    def footprint(self) -> np.ndarray:
        """Convex outline (k, 2) of the rock on the floor, in the landmark frame, counter-clockwise."""
        from scipy.spatial import ConvexHull

        pts = self.vertices()[:, :2]
        hull = ConvexHull(pts)
        return pts[hull.vertices]


Landmark = Annotated[BoxLandmark | CylinderLandmark | RockLandmark, Field(discriminator="type")]


def _default_materials() -> dict[str, MaterialSpec]:
    return {
        "wall": MaterialSpec(
            texture=TextureSpec(builtin="checker", rgb1=(0.75, 0.72, 0.65), rgb2=(0.35, 0.4, 0.5), mark="edge"),
        ),
        "floor": MaterialSpec(
            texture=TextureSpec(builtin="checker", rgb1=(0.45, 0.45, 0.45), rgb2=(0.4, 0.4, 0.4)),
            texrepeat=(1.0, 1.0),
            texuniform=True,
        ),
    }


class EnvironmentSpec(_Model):
    """A validated environment. Build one with `load_environment` (or ``model_validate`` a dict)."""

    name: str = Field(description="the environment's name (defaults to the file stem)")
    description: str = Field("", description="free text")
    arena: ArenaSpec = Field(ArenaSpec(), description="walls and floor")
    materials: dict[str, MaterialSpec] = Field(
        default_factory=_default_materials,
        description="render materials by name (walls, floor and landmarks refer to them)",
    )
    landmarks: list[Landmark] = Field(
        default_factory=list,
        description="free-standing objects: boxes, cylinders, rocks",
    )
    route: list[XY] = Field(
        default_factory=list,
        description="closed loop of waypoints [x, y] for evaluation runs (driven in order, back to the first)",
    )
    route_facing: Literal["travel", "outward"] = Field(
        "travel",
        description="how route runs drive the loop: facing the direction of travel, or sideways with the camera "
        "facing away from the loop's centroid (towards the walls)",
    )
    start: tuple[float, float, Degrees] = Field((0.0, 0.0, 0.0), description="foraging runs' start: [x, y, yaw_deg]")
    background_rgb: RGB = Field((0.55, 0.65, 0.8), description="flat background colour seen above the walls")
    lighting: LightingSpec = Field(LightingSpec(), description="lights of the scene")
    boards: list[BoardSpec] = Field(
        default_factory=list,
        description="render-only boards (e.g. a banner behind a wall)",
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> EnvironmentSpec:
        self._check_landmarks()
        self._check_arena_materials()
        self._check_walls()
        self._check_route()
        self._check_start()
        return self

    def _check_landmarks(self) -> None:
        """Unique names, inside the arena, known materials (in that order, landmark by landmark)."""
        names: set[str] = set()
        for i, lm in enumerate(self.landmarks):
            name = lm.name or f"{lm.type}{i}"
            if name in names:
                raise ValueError(f"landmarks.{i}.name: duplicate landmark name {name!r}")
            names.add(name)
            self._check_landmark_inside(i, name, lm)
            if lm.material is not None and lm.material not in self.materials:
                raise ValueError(f"landmarks.{i}.material: unknown material {lm.material!r}")

    def _check_landmark_inside(self, i: int, name: str, lm: BoxLandmark | CylinderLandmark | RockLandmark) -> None:
        hx, hy = self.arena.half_x, self.arena.half_y
        r = _bounding_radius(lm)
        if abs(lm.pos[0]) + r > hx + 1e-9 or abs(lm.pos[1]) + r > hy + 1e-9:
            # exact test on the footprint (the bounding circle is conservative)
            poly = _footprint_world(lm)
            if np.any(np.abs(poly[:, 0]) > hx + 1e-9) or np.any(np.abs(poly[:, 1]) > hy + 1e-9):
                raise ValueError(
                    f"landmarks.{i}.pos: landmark {name!r} sticks out of the {2 * hx:g} x {2 * hy:g} m arena"
                )

    def _check_arena_materials(self) -> None:
        for key in ("wall_material", "floor_material"):
            if getattr(self.arena, key) not in self.materials:
                raise ValueError(f"arena.{key}: unknown material {getattr(self.arena, key)!r}")

    def _check_walls(self) -> None:
        """Each wall's own material is known and its panel fits on the wall."""
        hx, hy = self.arena.half_x, self.arena.half_y
        for wall, spec in self.arena.walls.items():
            if spec.material is not None and spec.material not in self.materials:
                raise ValueError(f"arena.walls.{wall}.material: unknown material {spec.material!r}")
            length = 2 * (hx if wall in ("north", "south") else hy)
            if spec.panel is not None and abs(spec.panel.offset) + spec.panel.width / 2 > length / 2:
                raise ValueError(f"arena.walls.{wall}.panel: wider than the {length:g} m wall")

    def _check_route(self) -> None:
        """Waypoints inside the arena, none or at least 2 of them, and a loop the robot can drive."""
        hx, hy = self.arena.half_x, self.arena.half_y
        for i, (x, y) in enumerate(self.route):
            if abs(x) >= hx or abs(y) >= hy:
                raise ValueError(f"route.{i}: waypoint ({x}, {y}) is outside the arena")
        if len(self.route) == 1:
            raise ValueError("route: a route needs at least 2 waypoints")
        if self.route:
            problem = route_collision(self.route, self.route_facing, self.obstacles)
            if problem is not None:
                raise ValueError(problem)

    def _check_start(self) -> None:
        if abs(self.start[0]) >= self.arena.half_x or abs(self.start[1]) >= self.arena.half_y:
            raise ValueError("start: start position is outside the arena")
        if self.obstacles.distance(np.array(self.start[:2])) < 0:  # the robot's centre in a landmark: stuck
            raise ValueError(f"start: ({self.start[0]:g}, {self.start[1]:g}) is inside a landmark; expected free floor")

    # ------------------------------------------------------------------ geometry
    def landmark_names(self) -> list[str]:
        return [lm.name or f"{lm.type}{i}" for i, lm in enumerate(self.landmarks)]

    def top_view(self) -> dict[str, Any]:
        """Plain-data top view for plotting.

        ``{"name", "width", "depth": arena inside [m], "route": [[x, y], ...], "landmarks": [{"name", "type",
        "pos": [x, y], "yaw": deg, "tactile": bool, "size": [sx, sy] (box, rock: full extents) or
        "radius": r (cylinder), "polygon": [[x, y], ...] (rock: world-frame outline)}]}``
        """
        landmarks = []
        for name, lm in zip(self.landmark_names(), self.landmarks, strict=True):
            item: dict[str, Any] = {
                "name": name,
                "type": lm.type,
                "pos": [float(lm.pos[0]), float(lm.pos[1])],
                "yaw": float(lm.yaw),
                "tactile": bool(lm.tactile),
                "rgba": [float(c) for c in lm.rgba],
            }
            if isinstance(lm, CylinderLandmark):
                item["radius"] = float(lm.radius)
            else:
                item["size"] = [float(lm.size[0]), float(lm.size[1])]
            if isinstance(lm, RockLandmark):
                item["polygon"] = _footprint_world(lm).round(4).tolist()
            landmarks.append(item)
        return {
            "name": self.name,
            "width": 2 * self.arena.half_x,
            "depth": 2 * self.arena.half_y,
            "route": [[float(x), float(y)] for x, y in self.route],
            "landmarks": landmarks,
        }

    @cached_property
    def obstacles(self) -> ObstacleMap:
        """2-D signed-distance model of walls and landmarks (used by the controllers)."""
        return ObstacleMap(self)


def _bounding_radius(lm: BoxLandmark | CylinderLandmark | RockLandmark) -> float:
    if isinstance(lm, CylinderLandmark):
        return float(lm.radius)
    return float(math.hypot(lm.size[0], lm.size[1]) / 2)


def _rot2(yaw_deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[c, -s], [s, c]])


def _footprint_world(lm: BoxLandmark | CylinderLandmark | RockLandmark) -> np.ndarray:
    """Outline polygon (k, 2) of a landmark in world coordinates (cylinders: 32-gon)."""
    if isinstance(lm, CylinderLandmark):
        a = np.linspace(0, 2 * math.pi, 32, endpoint=False)
        local = lm.radius * np.stack([np.cos(a), np.sin(a)], axis=1)
    elif isinstance(lm, BoxLandmark):
        sx, sy = lm.size[0] / 2, lm.size[1] / 2
        local = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
    else:
        local = lm.footprint()
    return local @ _rot2(lm.yaw).T + np.asarray(lm.pos)


class ObstacleMap:
    """Signed 2-D distance from points to the nearest wall or landmark outline (negative inside).

    Vectorised over points; landmarks are approximated by their convex outlines (cylinders
    exactly, by centre and radius).
    """

    def __init__(self, env: EnvironmentSpec) -> None:
        self.half = np.array([env.arena.half_x, env.arena.half_y])
        is_circle = [isinstance(lm, CylinderLandmark) for lm in env.landmarks]
        #: landmark index of each circle, then of each polygon (the order of `landmark_distance_many`)
        self._order = np.argsort(np.concatenate([np.flatnonzero(is_circle), np.flatnonzero(np.logical_not(is_circle))]))
        circles = [(lm.pos[0], lm.pos[1], lm.radius) for lm in env.landmarks if isinstance(lm, CylinderLandmark)]
        self.circles = np.array(circles, dtype=float).reshape(-1, 3)
        a_list, b_list, pid = [], [], []
        for k, lm in enumerate(lm for lm in env.landmarks if not isinstance(lm, CylinderLandmark)):
            poly = _footprint_world(lm)
            if _signed_area(poly) < 0:
                poly = poly[::-1]
            a_list.append(poly)
            b_list.append(np.roll(poly, -1, axis=0))
            pid.append(np.full(len(poly), k))
        self.n_polygons = len(a_list)
        self.edge_a = np.concatenate(a_list) if a_list else np.zeros((0, 2))
        self.edge_e = (np.concatenate(b_list) if b_list else np.zeros((0, 2))) - self.edge_a
        self.edge_ee = np.einsum("ij,ij->i", self.edge_e, self.edge_e)
        self.edge_poly = np.concatenate(pid) if pid else np.zeros(0, dtype=int)
        self.edge_start = np.flatnonzero(np.diff(np.concatenate([[-1], self.edge_poly])))

    def distance_many(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (n,) of ``points`` (n, 2) to the closest obstacle surface [m]."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        walls = (self.half[None] - np.abs(p)).min(axis=1)
        landmarks = self.landmark_distance_many(p)
        return np.minimum(walls, landmarks.min(axis=1)) if landmarks.shape[1] else walls

    def landmark_distance_many(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (n, L) of ``points`` (n, 2) to each landmark's outline, in the
        environment's landmark order [m]."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        parts = []
        if len(self.circles):
            dc = np.hypot(p[:, None, 0] - self.circles[None, :, 0], p[:, None, 1] - self.circles[None, :, 1])
            parts.append(dc - self.circles[None, :, 2])
        if self.n_polygons:
            w = p[:, None, :] - self.edge_a[None]  # (n, E, 2)
            t = np.clip(np.einsum("nij,ij->ni", w, self.edge_e) / self.edge_ee, 0, 1)
            diff = w - t[..., None] * self.edge_e[None]
            dist = np.hypot(diff[..., 0], diff[..., 1])  # (n, E)
            cross = self.edge_e[None, :, 0] * w[..., 1] - self.edge_e[None, :, 1] * w[..., 0]
            # edges are stored polygon by polygon: reduce each contiguous block
            outside_count = np.add.reduceat((cross < 0).astype(np.int32), self.edge_start, axis=1)
            dmin = np.minimum.reduceat(dist, self.edge_start, axis=1)
            parts.append(np.where(outside_count > 0, dmin, -dmin))
        if not parts:
            return np.zeros((len(p), 0))
        return np.concatenate(parts, axis=1)[:, self._order]

    def distance(self, p: np.ndarray) -> float:
        """Signed distance [m] from point ``p`` (x, y) to the closest obstacle surface."""
        return float(self.distance_many(np.asarray(p, dtype=float)[None])[0])

    def query(
        self, points: np.ndarray, eps: float = 1e-3, landmark: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (n,) and unit gradients (n, 2) of ``points`` (n, 2) in one batch:
        to the closest obstacle, or to landmark number ``landmark`` alone."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        offsets = np.array([[0, 0], [eps, 0], [-eps, 0], [0, eps], [0, -eps]])
        q = (p[:, None, :] + offsets[None]).reshape(-1, 2)
        d = (self.distance_many(q) if landmark is None
             else self.landmark_distance_many(q)[:, landmark]).reshape(len(p), 5)
        g = np.stack([d[:, 1] - d[:, 2], d[:, 3] - d[:, 4]], axis=1)
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        return d[:, 0], np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


# ---------------------------------------------------------------------- loading
def _localise_textures(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """Relative texture files resolve against the file that names them (``path``)."""
    materials = data.get("materials")
    for mat in materials.values() if isinstance(materials, dict) else []:
        tex = mat.get("texture") if isinstance(mat, dict) else None
        if isinstance(tex, dict) and isinstance(tex.get("file"), str):
            tex["file"] = str((path.parent / tex["file"]).resolve())
    return data


def load_environment(path: str | Path) -> EnvironmentSpec:
    """Load and validate an environment YAML file (resolving ``extends:``).

    A bare name such as ``"e1"`` refers to a shipped environment
    (``scenarios/environments/e1.yaml``). Errors raise `EnvironmentSpecError` naming the file and
    the key path, e.g. ``e2.yaml: landmarks.3.size: Field required``.
    """
    p = Path(path)
    if not p.suffix and not p.exists():
        p = shipped_file(p.name, (ENVIRONMENTS_DIR,)) or p
    if not p.exists():
        raise EnvironmentSpecError(f"{path}: no such environment file ({shipped_names_hint(path)})")
    p = p.resolve()
    data = load_yaml(p, EnvironmentSpecError, _localise_textures)
    data.setdefault("name", p.stem)
    try:
        env = EnvironmentSpec.model_validate(data)
    except pydantic.ValidationError as exc:
        raise EnvironmentSpecError(format_validation_error(p, exc, EnvironmentSpec)) from None
    for name, mat in env.materials.items():  # files: checked here, not in a run file's recorded spec
        file = None if mat.texture is None else mat.texture.file
        if file is not None and (problem := png_problem(Path(file))) is not None:
            raise EnvironmentSpecError(f"{p}: materials.{name}.texture.file: {file!r}: {problem}; expected a PNG image "
                                       "file (a relative path is relative to the folder of the file that names it)")
    return env

