"""Landmark visits (``visits``, `VisitsController`): tactile-attention foraging that breaks off
to whisk the environment's tactile landmarks the way station drives do, for a training run
whose touch covers what station drives press (approach until the whiskers bend with the head
within ``touch_gap``, hold for several whisk cycles, tap back onto it), which foraging's
glancing contour following does not.

Two drivers share the robot: a `ForagingController` (the run's foraging settings,
`VisitsRun.foraging`) and a `Visitor`, the station driver of `stations` (its `ToStation`,
`StationApproach`, `Hold` and `Leave`, with the run's ``hold_cycles``, ``touch_gap`` and
``visit_heading_jitter_deg``: `VisitsRun.stations`). Whenever the time spent visiting so far
is below ``visit_share`` of the run's time and the forager is wandering (not attending to an
object), a visit starts:

* the approach pose (`VisitsController.draw_station`): facing the landmark with the head
  ``visit_distance`` (uniform) from its outline, from a direction within ``visit_spread_deg``
  (uniform) of the robot's heading, so that the teleoperator's slow turn keys have little to
  turn; of the tactile landmarks other than the one visited last, the one whose approach pose
  lies nearest the robot, among those where the body and the head stay a quarter of
  ``avoid_margin`` (the teleoperator's safety guard) clear of everything and whose straight
  approach touches nothing; with none, another direction and distance are drawn (up to
  `DRAWS` times; none fits: no visit at this tick);
* the visit: drive there, approach, hold for ``hold_cycles`` whisk cycles with contact, back
  off; then foraging resumes, contacts ignored for ``refractory_time`` (as after leaving an
  object).

Every draw comes from the run's generator, so a seed reproduces the run; every whisk cycle is
a sample. The controller's ``mode`` is the forager's state, or ``visit <mode>`` during a visit.
"""

from __future__ import annotations

import math

import numpy as np

from vitaplace.engine.sim.clearance import HEAD_CENTRE, HEAD_RADIUS, footprint_clearance
from vitaplace.engine.sim.controllers.common import Observation
from vitaplace.engine.sim.controllers.foraging import ForagingController
from vitaplace.engine.sim.controllers.settings import StationsRun, VisitsRun
from vitaplace.engine.sim.controllers.stations import Station, StationDriver, approach_clearance
from vitaplace.engine.sim.environment import EnvironmentSpec

__all__ = ["VisitsController", "Visitor", "DRAWS"]

DRAWS = 20  #: approach directions drawn per visit before the visit is put off
_OUTLINE_STEPS = 6  #: fixed-point steps placing a point at a distance from a landmark's outline


class Visitor(StationDriver):
    """The station driver visiting the stations it is given (`visit`) instead of those along
    its loop; ``stations`` lists them in order (``arrivals`` index it)."""

    def __init__(self, spec: StationsRun, env: EnvironmentSpec, rng: np.random.Generator,
                 sample_period: float) -> None:
        super().__init__(spec, env, rng, sample_period)
        self.stations = []

    def _start_visit(self, t: float, pose: np.ndarray) -> bool:
        return False  # it visits only what `visit` gives it

    def visit(self, station: Station, t: float, pose: np.ndarray, current: tuple[float, ...]) -> None:
        """Drive to ``station`` from time ``t``, the base moving at ``current`` (forward speed
        and turn rate: the command the forager gave last)."""
        self.stations.append(station)
        self.station, self.target_landmark, self.mode = station, station.landmark, "to_station"
        self.modes[self.mode].enter(t, pose)
        self._limit.state[:] = (current[0], current[1], 0.0)
        self._last_t, self.next_decision, self.press_until = t, t, t
        self.key, self.touched, self.released = "k", False, ""


class VisitsController:
    """Foraging alternating with station-style landmark visits (module docstring);
    ``seconds`` keeps the time spent foraging and visiting."""

    def __init__(self, spec: VisitsRun, env: EnvironmentSpec, rng: np.random.Generator,
                 sample_period: float) -> None:
        self.spec, self.env, self.rng = spec, env, rng
        self.forager = ForagingController(spec.foraging(), env.obstacles, rng)
        self.visitor = Visitor(spec.stations(), env, rng, sample_period)
        self.tactile = [i for i, lm in enumerate(env.landmarks) if lm.tactile]
        self.visiting, self.last = False, -1  #: the landmark visited last
        self.seconds = {"forage": 0.0, "visit": 0.0}
        self.command: tuple[float, ...] = (0.0, 0.0)  #: the command given last
        self._last_t: float | None = None

    @property
    def mode(self) -> str:
        return f"visit {self.visitor.mode}" if self.visiting else self.forager.mode

    def start_pose(self, default: tuple[float, float, float]) -> tuple[float, float, float]:
        return self.forager.start_pose(default)

    def _due(self) -> bool:
        """A visit is due: the forager wanders and visits had less than ``visit_share`` of the time so far."""
        total = self.seconds["forage"] + self.seconds["visit"]
        return self.forager.mode == "wander" and self.seconds["visit"] < self.spec.visit_share * total

    def _at_distance(self, landmark: int, centre: np.ndarray, direction: np.ndarray, distance: float) -> np.ndarray:
        """The point along ``direction`` from ``centre`` at ``distance`` from the landmark's outline."""
        reach = distance
        for _ in range(_OUTLINE_STEPS):  # the outline distance grows along the ray with slope in (0, 1]
            point = centre + reach * direction
            reach += distance - float(self.env.obstacles.landmark_distance_many(point[None])[0, landmark])
        return centre + reach * direction

    def draw_station(self, pose: np.ndarray) -> Station | None:
        """This visit's approach pose as a `Station` (module docstring), or None when none of
        `DRAWS` draws fits."""
        spec, obstacles = self.spec, self.env.obstacles
        candidates = [i for i in self.tactile if i != self.last] or self.tactile
        for _ in range(DRAWS):
            angle = float(pose[2]) + math.pi + math.radians(spec.visit_spread_deg) * float(self.rng.uniform(-1.0, 1.0))
            distance = float(self.rng.uniform(*spec.visit_distance)) + HEAD_CENTRE + HEAD_RADIUS  # of the base
            fits = [st for st in (self._station(i, angle, distance) for i in candidates)
                    if footprint_clearance(obstacles, np.array([st.point]), np.array([st.facing]))[0]
                    >= 0.25 * spec.avoid_margin and approach_clearance(self.env, st, spec.touch_gap) >= 0]
            if fits:
                return min(fits, key=lambda st: math.dist(st.point, pose[:2]))
        return None

    def _station(self, landmark: int, angle: float, distance: float) -> Station:
        """The station of ``landmark`` in direction ``angle`` from its centre, ``distance`` from
        its outline, facing its nearest point."""
        centre = np.asarray(self.env.landmarks[landmark].pos[:2], dtype=float)
        point = self._at_distance(landmark, centre, np.array([math.cos(angle), math.sin(angle)]), distance)
        dist, grad = self.env.obstacles.query(point[None], landmark=landmark)
        nearest = point - dist[0] * grad[0]
        facing = math.atan2(nearest[1] - point[1], nearest[0] - point[0])
        return Station(self.env.landmark_names()[landmark], landmark, (float(point[0]), float(point[1])), facing)

    def __call__(self, obs: Observation) -> tuple[float, ...]:
        dt = 0.0 if self._last_t is None else obs.time - self._last_t
        self._last_t = obs.time
        self.seconds["visit" if self.visiting else "forage"] += dt
        if not self.visiting and self._due():
            station = self.draw_station(obs.pose)
            if station is not None:
                self.visiting, self.last = True, station.landmark
                self.visitor.visit(station, obs.time, obs.pose, self.command)
        if self.visiting:
            command = self.visitor(obs)
            if self.visitor.mode != "drive":
                self.command = command
                return command
            self.visiting = False  # backed off the landmark: forage on
            self.forager.resume(obs.time, obs.pose, self.command[:2])
        self.command = self.forager(obs)
        return self.command
