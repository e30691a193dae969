"""Station drives (``stations``, `StationDriver`): the keyboard teleoperator of `teleop`
whisking the same K tactile stations in every drive of an environment, so that a touched
query has a touched true match.

A **station** is derived from a named tactile landmark (`stations_of`): its point is the
point of the environment's route loop in the landmark's direction as seen from the loop's
centroid (every 1 cm along the loop, the one of nearest direction; a landmark at the
centroid gets the loop point due east), its facing the direction from that point to the
landmark's outline point nearest it. Both drives of an evaluation get the same stations
(they depend on the environment and the run's settings only, never on the seed).

The driver is a `TeleopDriver` (its keys, its own jittered loop from a random start, its
speed, heading bias, safety guard, way round and detours) with one more mode,
`ToStation`, and stations in place of the landmarks it happens to pass:

    drive --landmark--> to_station --arrived--> approach --reached--> hold --done--> leave --clear--> drive
                                                approach --gave up--> leave

When the driver's progress along its loop comes within `ROUTE_LOOKAHEAD` before (or 0.5 m
past) a station that it has not visited in the last half lap, it drives to the station's
point moved by a uniform random offset within ``station_jitter`` (`ToStation`, drawn per
visit), then approaches the landmark as teleop does (`Approach`: face the landmark's
nearest point, here plus a uniform heading offset within ``station_heading_jitter_deg``,
drive up until the whiskers touch it with the head within ``touch_gap``, here only with the
key straight towards it: `StationApproach`), holds for
``hold_cycles`` whisk cycles with contact and backs off (`Hold`, `Leave`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vitaplace.engine.sim.clearance import HEAD_CENTRE, HEAD_RADIUS, ROUTE_LOOKAHEAD, Route, footprint_clearance
from vitaplace.engine.sim.controllers.common import wrap as _wrap
from vitaplace.engine.sim.controllers.settings import StationsRun
from vitaplace.engine.sim.controllers.teleop import STOP, Approach, Drive, Hold, Leave, Press, TeleopDriver, TeleopMode
from vitaplace.engine.sim.environment import EnvironmentSpec

__all__ = ["Station", "StationError", "StationDriver", "ToStation", "StationApproach", "STATION_TRANSITIONS",
           "stations_of", "station_indices", "approach_clearance"]

AT_STATION = 0.03  #: the driver has arrived within this distance of its (jittered) station point [m]
_TO_STATION_TIMEOUT = 12.0  #: a station not reached by then is approached from where the robot is [s]
_TAP_WITHIN = 0.15  #: within this distance of the station point, translation keys are tapped [m]
_PASSED = 0.5  #: a station up to this far behind the driver's progress along its loop is still visited [m]
_LOOP_STEP = 0.01  #: the loop is searched for a station's point every this far [m]


class StationError(ValueError):
    """A station setting that does not fit the environment; ``key`` is the setting at fault."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class Station:
    """A tactile station: the landmark, and where and how a drive approaches it."""

    name: str  #: the landmark's name
    landmark: int  #: its index in the environment's landmarks
    point: tuple[float, float]  #: the approach point on the route loop [m]
    facing: float  #: yaw [rad] from the point to the landmark's outline point nearest it


def station_indices(env: EnvironmentSpec, spec: StationsRun) -> list[int]:
    """The indices of the landmarks whose stations ``spec`` whisks: the first ``station_count``
    of ``station_landmarks`` (default: every tactile landmark, in the environment's order); a
    `StationError` naming the setting when they do not fit ``env``."""
    names = env.landmark_names()
    tactile = [name for name, lm in zip(names, env.landmarks, strict=True) if lm.tactile]
    if len(env.route) < 2 or not tactile:
        raise StationError("kind", f"a stations run needs the environment's route and tactile landmarks; "
                           f"{env.name!r} has {len(env.route)} route waypoints and {len(tactile)} tactile landmarks")
    chosen = spec.station_landmarks if spec.station_landmarks is not None else tactile
    for name in chosen:
        if name not in names:
            raise StationError("station_landmarks", f"{name!r} names no landmark of {env.name!r} (its landmarks: "
                               f"{', '.join(names)})")
        if name not in tactile:
            raise StationError("station_landmarks", f"{name!r} of {env.name!r} is not tactile: "
                               "the whiskers cannot touch it")
    count = len(chosen) if spec.station_count is None else spec.station_count
    if count > len(chosen):
        raise StationError("station_count", f"{count} stations asked for, but {env.name!r} has only {len(chosen)} "
                           f"{'named' if spec.station_landmarks is not None else 'tactile'} "
                           "landmarks to make them from")
    return [names.index(name) for name in chosen[:count]]


def stations_of(env: EnvironmentSpec, spec: StationsRun) -> list[Station]:
    """The stations of ``spec`` in ``env`` (the rule in the module docstring)."""
    route = Route(env.route)
    centre = np.mean(route.points, axis=0)
    loop = route.at(np.arange(0.0, route.length, _LOOP_STEP))
    directions = np.arctan2(loop[:, 1] - centre[1], loop[:, 0] - centre[0])
    names = env.landmark_names()
    out = []
    for i in station_indices(env, spec):
        rel = np.asarray(env.landmarks[i].pos, dtype=float) - centre
        towards = math.atan2(rel[1], rel[0])
        point = loop[int(np.argmin(np.abs(np.angle(np.exp(1j * (directions - towards))))))]
        dist, grad = env.obstacles.query(point[None], landmark=i)
        nearest = point - dist[0] * grad[0]
        facing = math.atan2(nearest[1] - point[1], nearest[0] - point[0])
        out.append(Station(names[i], i, (float(point[0]), float(point[1])), facing))
    return out


def approach_clearance(env: EnvironmentSpec, station: Station, gap: float, step: float = 0.01) -> float:
    """The least clearance [m] of the body and the head from every wall and landmark while the
    robot, facing the station's landmark, moves straight from the station's point until its
    head is ``gap`` from the landmark: what an approach without jitter passes through (at most
    ``gap``; negative: it collides on the way)."""
    heading = np.array([math.cos(station.facing), math.sin(station.facing)])
    start = np.asarray(station.point)
    head = (start + HEAD_CENTRE * heading)[None]
    head_gap = env.obstacles.landmark_distance_many(head)[0, station.landmark] - HEAD_RADIUS
    distance = max(head_gap - gap, 0.0)
    travel = np.append(np.arange(0.0, distance, step), distance)
    xy = start + travel[:, None] * heading
    return float(footprint_clearance(env.obstacles, xy, np.full(len(xy), station.facing)).min())


class ToStation(TeleopMode):
    """Drive to the station's point moved by this visit's jitter (translation keys, tapped
    within `_TAP_WITHIN`): arrived within `AT_STATION`, when no key brings it closer, or after
    `_TO_STATION_TIMEOUT`."""

    name = "to_station"

    def enter(self, t: float, pose: np.ndarray) -> None:
        d = self.driver
        assert isinstance(d, StationDriver)
        spec = d.spec
        radius = spec.station_jitter * math.sqrt(float(d.rng.uniform()))  # uniform in the disc
        angle = float(d.rng.uniform(0.0, 2 * math.pi))
        d.heading_offset = math.radians(spec.station_heading_jitter_deg) * float(d.rng.uniform(-1.0, 1.0))
        d.station_target = np.asarray(d.station.point) + radius * np.array([math.cos(angle), math.sin(angle)])
        d.until = t + _TO_STATION_TIMEOUT

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        assert isinstance(d, StationDriver)
        rel = d.station_target - pose[:2]
        dist = float(np.hypot(rel[0], rel[1]))
        if dist <= AT_STATION or t >= d.until:
            return None, "arrived"
        direction = _wrap(math.atan2(rel[1], rel[0]) - float(pose[2]))
        key, duration = d._pick(pose, d._translation_keys(direction)[:3], hold=dist > _TAP_WITHIN)
        if key == "k":
            return (None, "arrived") if d._standing() else (STOP, "")  # no closer: approach from here
        return (key, duration), ""


class StationApproach(Approach):
    """Teleop's `Approach`, driving up only with the key straight towards the landmark (held,
    else tapped): a sideways key would slide along the landmark away from the station."""

    ranked_keys = 1


#: (mode, event) -> next mode of the station driver
STATION_TRANSITIONS: dict[tuple[str, str], str] = {
    ("drive", "landmark"): "to_station",  # a station reached along the loop
    ("to_station", "arrived"): "approach",  # at the jittered station point (or as close as it gets)
    ("approach", "reached"): "hold",
    ("approach", "gave up"): "leave",
    ("hold", "done"): "leave",
    ("leave", "clear"): "drive",
}


class StationDriver(TeleopDriver):
    """The teleoperator whisking the run's stations (module docstring); everything else is
    `TeleopDriver`'s. ``arrivals`` records each visit: (time, station index, pose on arrival)."""

    transitions = STATION_TRANSITIONS
    spec: StationsRun

    def __init__(self, spec: StationsRun, env: EnvironmentSpec, rng: np.random.Generator, sample_period: float) -> None:
        super().__init__(spec, env, rng, sample_period)
        self.stations = stations_of(env, spec)
        self.tactile = [st.landmark for st in self.stations]
        self.modes = {mode.name: mode(self) for mode in (Drive, ToStation, StationApproach, Hold, Leave)}
        self.station_s = [self.loop.project(np.asarray(st.point))[0] for st in self.stations]
        self.station = self.stations[0]  #: the station being visited
        self.station_target = np.asarray(self.station.point)  #: its point with this visit's jitter
        self.heading_offset = 0.0  #: this visit's heading jitter [rad]
        self.arrivals: list[tuple[float, int, np.ndarray]] = []

    def records_sample(self) -> bool:
        """Whether the whisk cycle just ended is a sample: every cycle, or with ``sample_at:
        stations`` only the cycles held whisking a station."""
        return self.spec.sample_at == "cycle" or self.mode == "hold"

    def _start_visit(self, t: float, pose: np.ndarray) -> bool:
        """Visit a station that the progress along the loop has come within `ROUTE_LOOKAHEAD`
        of (or passed by less than `_PASSED`), not visited in the last half lap."""
        laps = self.s / self.loop.length
        for k, s_k in enumerate(self.station_s):
            ahead = (s_k - self.s) % self.loop.length
            near = ahead <= ROUTE_LOOKAHEAD or ahead >= self.loop.length - _PASSED
            if near and laps - self.visited.get(k, -math.inf) >= 0.5:
                self.visited[k], self.station, self.target_landmark = laps, self.stations[k], self.stations[k].landmark
                return True
        return False

    def _bearing(self, pose: np.ndarray, i: int) -> float:
        """As `TeleopDriver._bearing`, plus this visit's heading offset: the approach faces
        the landmark's nearest point that far off."""
        return _wrap(super()._bearing(pose, i) + self.heading_offset)

    def _decide(self, t: float, pose: np.ndarray) -> tuple[str, float]:
        before = self.mode
        press = super()._decide(t, pose)
        if before == "to_station" and self.mode != "to_station":
            self.arrivals.append((t, self.stations.index(self.station), pose.copy()))
        return press
