"""`make_controller`: the controller of a run's kind and its start pose."""

from __future__ import annotations

import math

import numpy as np

from vitaplace.engine.sim.clearance import Route
from vitaplace.engine.sim.controllers.foraging import ForagingController
from vitaplace.engine.sim.controllers.route import RouteFollower
from vitaplace.engine.sim.controllers.settings import RunSpec
from vitaplace.engine.sim.controllers.stations import StationDriver
from vitaplace.engine.sim.controllers.teleop import TeleopDriver
from vitaplace.engine.sim.controllers.visits import VisitsController
from vitaplace.engine.sim.environment import EnvironmentSpec


def make_controller(
    env: EnvironmentSpec, spec: RunSpec, rng: np.random.Generator, sample_period: float = 0.5
) -> tuple[ForagingController | VisitsController | TeleopDriver | StationDriver | RouteFollower,
           tuple[float, float, float]]:
    """The controller for ``spec.kind`` and its start pose ``(x, y, yaw_rad)``; ``sample_period``
    [s] (one whisk cycle) places the off-route part (route, orbit: at the end of the run;
    teleop, stations: their detours) and sets the teleoperator's hold times."""
    if spec.kind == "foraging":
        ctrl = ForagingController(spec, env.obstacles, rng)
        return ctrl, ctrl.start_pose(env.start)
    if spec.kind in ("teleop", "stations", "visits", "route") and not env.route:
        raise ValueError(f"environment {env.name!r} has no route: a {spec.kind!r} run needs route waypoints")
    if spec.kind == "visits":
        visits = VisitsController(spec, env, rng, sample_period)
        return visits, visits.start_pose(env.start)
    if spec.kind == "teleop":
        driver = TeleopDriver(spec, env, rng, sample_period)
        return driver, driver.start_pose()
    if spec.kind == "stations":
        stations = StationDriver(spec, env, rng, sample_period)
        return stations, stations.start_pose()
    off_from = (spec.warmup_cycles + (1.0 - spec.off_route_fraction) * spec.n_samples) * sample_period
    off_from = off_from if spec.off_route_fraction > 0 else math.inf
    if spec.kind == "orbit":
        phi = np.radians(np.arange(0.0, 360.0, 5.0))
        centre = np.asarray(spec.orbit_centre, dtype=float)
        circle = centre + spec.orbit_radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)
        follower = RouteFollower(spec, Route(circle), env.obstacles, rng, off_from, outward=centre)
        return follower, follower.start_pose()
    outward = np.mean(env.route, axis=0) if env.route_facing == "outward" else None
    follower = RouteFollower(spec, Route(env.route), env.obstacles, rng, off_from, outward)
    return follower, follower.start_pose()
