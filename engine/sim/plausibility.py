"""Physical plausibility of a simulated run in its environment, checked before anything runs.

A run specification is valid field by field (`RunSpec`, `RobotSpec`: ranges as pydantic
constraints); what depends on the arena and the robot together is checked here, where the
scenario knows both (`vitaplace.engine.config.loading.load_scenario`):

* ``start``: the robot's body (a disc of `BODY_RADIUS`) inside the arena's walls, its centre
  not inside a landmark;
* ``orbit_centre`` inside the arena, and the orbit of ``orbit_radius`` with the body inside it;
* ``off_route_offset`` (when a part of the run is driven off the path): the detoured path
  (the route or orbit moved that far to the left of travel) with the body inside the arena;
* ``control_hz`` at least ``whisk_hz``: the controller acts at least once per sample;
* a stations run: the environment has a route and tactile landmarks, ``stations`` names
  tactile landmarks of it, ``station_count`` is no more than there are (`station_indices`);
  a visits run: the environment has a route (its visitor is the station driver) and tactile
  landmarks.

`estimated_seconds` says how long a run takes on one core, from the simulator's measured
rates (docs/PERFORMANCE.md), so a long simulation is announced with an estimate.
"""

from __future__ import annotations

import math

import numpy as np

from vitaplace.engine.sim.clearance import Route
from vitaplace.engine.sim.controllers import OrbitRun, RouteRun, RunSpec, StationsRun, TeleopRun
from vitaplace.engine.sim.controllers.stations import StationError, station_indices
from vitaplace.engine.sim.environment import EnvironmentSpec
from vitaplace.engine.sim.robot import BODY_RADIUS, RobotSpec

#: seconds per physics step and per rendered frame on one core (docs/PERFORMANCE.md,
#: "Simulator throughput": 5.4 ms of physics per 250-step sample, 0.8 ms per frame; rounded up)
STEP_SECONDS = 25e-6
FRAME_SECONDS = 1e-3
#: points per metre at which a detoured route is checked
_ROUTE_DENSITY = 50


class ImplausibleRun(ValueError):
    """A run that cannot be right in its arena; ``key`` is the setting at fault (under ``run``)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


def _outside(points: np.ndarray, env: EnvironmentSpec) -> np.ndarray:
    """Which of ``points`` (n, 2) put the robot's body beyond a wall."""
    half = np.array([env.arena.half_x, env.arena.half_y])
    return np.any(np.abs(points) + BODY_RADIUS > half, axis=1)


def _arena(env: EnvironmentSpec) -> str:
    return f"the {2 * env.arena.half_x:g} x {2 * env.arena.half_y:g} m arena of {env.name!r}"


def check_run(env: EnvironmentSpec, run: RunSpec, robot: RobotSpec) -> None:
    """Raise `ImplausibleRun` naming the first setting of ``run`` that cannot be right in ``env``."""
    if run.kind in ("route", "teleop") and len(env.route) < 2:  # both drive along the environment's loop
        raise ImplausibleRun("kind", f"a {run.kind} run needs the environment's route; {env.name!r} has none")
    if run.kind == "visits" and (len(env.route) < 2 or not any(lm.tactile for lm in env.landmarks)):
        raise ImplausibleRun("kind", f"a visits run needs the environment's route and tactile landmarks; "
                             f"{env.name!r} has {len(env.route)} route waypoints and "
                             f"{sum(lm.tactile for lm in env.landmarks)} tactile landmarks")
    if run.kind == "stations":
        try:
            station_indices(env, run)
        except StationError as exc:
            raise ImplausibleRun(exc.key, str(exc)) from None
    if run.start is not None:
        _check_start(env, run.start)
    if run.control_hz < robot.whisk_hz:
        raise ImplausibleRun("control_hz", f"{run.control_hz:g} Hz is below the whisking rate robot.whisk_hz = "
                             f"{robot.whisk_hz:g} Hz: the controller must act at least once per sample")
    if run.kind == "orbit":
        centre = np.array(run.orbit_centre, dtype=float)
        half = np.array([env.arena.half_x, env.arena.half_y])
        if np.any(np.abs(centre) >= half):
            raise ImplausibleRun("orbit_centre", f"({centre[0]:g}, {centre[1]:g}) is outside {_arena(env)}")
        if np.any(np.abs(centre) + run.orbit_radius + BODY_RADIUS > half):
            raise ImplausibleRun("orbit_radius", f"an orbit of {run.orbit_radius:g} m around ({centre[0]:g}, "
                                 f"{centre[1]:g}) takes the robot (radius {BODY_RADIUS} m) outside {_arena(env)}")
    if isinstance(run, (TeleopRun, StationsRun, RouteRun, OrbitRun)) and run.off_route_fraction > 0:
        detour = _detour(env, run)
        bad = _outside(detour, env)
        if bad.any():
            x, y = detour[int(np.argmax(bad))]
            raise ImplausibleRun("off_route_offset", f"{run.off_route_offset:g} m off the path takes the robot (radius "
                                 f"{BODY_RADIUS} m) to ({x:.2f}, {y:.2f}), outside {_arena(env)}")


def _check_start(env: EnvironmentSpec, start: tuple[float, float, float]) -> None:
    """A run's own start: the robot's body inside the walls, its centre on free floor."""
    if _outside(np.array([start[:2]]), env)[0]:
        raise ImplausibleRun("start", f"({start[0]:g}, {start[1]:g}) puts the robot (radius {BODY_RADIUS} m) "
                             f"outside {_arena(env)}")
    if env.obstacles.distance(np.array(start[:2])) < 0:
        raise ImplausibleRun("start", f"({start[0]:g}, {start[1]:g}) is inside a landmark of {env.name!r}; "
                             "expected free floor")


def _detour(env: EnvironmentSpec, run: TeleopRun | StationsRun | RouteRun | OrbitRun) -> np.ndarray:
    """Points of the path moved ``off_route_offset`` to the left of travel (towards the
    centre of a counter-clockwise orbit): where the off-route part of the run drives."""
    if run.kind == "orbit":
        phi = np.linspace(0.0, 2 * math.pi, 360, endpoint=False)
        radius = run.orbit_radius - run.off_route_offset
        return np.asarray(run.orbit_centre) + radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    route = Route(env.route)
    return route.offset_at(np.linspace(0.0, route.length, max(2, int(route.length * _ROUTE_DENSITY))),
                           run.off_route_offset)


#: a simulation estimated to take longer than this is announced, with its estimate
LONG_SECONDS = 600.0


def duration(seconds: float) -> str:
    """``seconds`` as people read a duration: 40 s, 12 min, 3.1 h."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h"


def estimated_seconds(run: RunSpec, robot: RobotSpec) -> float:
    """Roughly how long simulating ``run`` takes on one core: physics steps and frames."""
    cycles = run.n_samples + run.warmup_cycles
    return cycles * robot.steps_per_cycle * STEP_SECONDS + run.n_samples * FRAME_SECONDS
