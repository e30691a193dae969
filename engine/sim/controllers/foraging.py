"""Tactile-attention foraging (training runs), inspired by rodent exploration (Mitchinson &
Prescott's "orient" behaviour): a state machine over `Wander`, `Orient`, `Explore`,
`Leave` and `Avoid` (`ForagingState`), whose steps return a command and an event that
`TRANSITIONS` maps to the next state. See the package docstring."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from vitaplace.engine.sim.clearance import HEAD_CENTRE, HEAD_RADIUS, footprint_clearance
from vitaplace.engine.sim.controllers.common import HEAD_REACH, Observation
from vitaplace.engine.sim.controllers.common import OU as _OU
from vitaplace.engine.sim.controllers.common import Limiter as _Limiter
from vitaplace.engine.sim.controllers.common import wrap as _wrap
from vitaplace.engine.sim.controllers.safety import Headway, SafetyGuard
from vitaplace.engine.sim.controllers.settings import ForagingRun
from vitaplace.engine.sim.environment import ObstacleMap
from vitaplace.engine.sim.robot import BODY_RADIUS

Command = tuple[float, float]  #: a foraging command: forward speed [m/s], yaw rate [rad/s]


@dataclass(frozen=True)
class Surroundings:
    """What the foraging states act on at one control tick: the observation and the obstacle
    probes of the (stand-in) proximity sensor."""

    time: float
    pose: np.ndarray  #: (3,) x, y, yaw
    contacts: np.ndarray  #: (k, 3) whisker contact points (world frame)
    body_gap: float  #: clearance of the body from the nearest obstacle [m]
    head_gap: float  #: clearance of the head [m]
    ahead_distance: float  #: distance from the point `PROBE_AHEAD` beyond the snout to the nearest obstacle [m]
    ahead_escape: np.ndarray  #: (2,) unit direction away from that obstacle, there
    wander_turn: float  #: the wandering turn rate now [rad/s]

    @property
    def pos(self) -> np.ndarray:
        return self.pose[:2]

    @property
    def yaw(self) -> float:
        return float(self.pose[2])

    @property
    def clearance(self) -> float:
        return min(self.body_gap, self.head_gap)


#: the obstacle probe ahead of the robot lies this far beyond the snout [m]
PROBE_AHEAD = 0.15


@dataclass
class Attention:
    """What the foraging states share: the attended point, the side it is kept on while
    exploring, and until when contacts are ignored (after leaving an object)."""

    target: np.ndarray | None = None  #: (2,) the attended point
    side: float = 1.0  #: +1: the attended point is kept to the left, -1: to the right
    refractory_until: float = 0.0  #: contacts before this time [s] are ignored

    def heeds(self, s: Surroundings) -> bool:
        """Whether this tick has contacts that are not ignored."""
        return bool(len(s.contacts)) and s.time >= self.refractory_until

    def follow(self, s: Surroundings, weight: float) -> None:
        """Move the attended point ``weight`` of the way to the centroid of this tick's heeded
        contacts (re-attending to the newest contacts: contour following); with no attended
        point yet, attend to the centroid."""
        if self.heeds(s):
            centroid = s.contacts[:, :2].mean(axis=0)
            self.target = centroid if self.target is None else (1.0 - weight) * self.target + weight * centroid

    def bearing(self, s: Surroundings) -> float:
        """Direction of the attended point [rad, robot frame]."""
        return _wrap(math.atan2(*(self.target - s.pos)[::-1]) - s.yaw)

    def distance(self, s: Surroundings) -> float:
        return float(np.linalg.norm(self.target - s.pos))


class ForagingState(ABC):
    """One mode of the foraging controller. `step` returns the command for this tick and an
    event ("" for none) that `TRANSITIONS` maps to the next state; a step without a command
    hands over at once (the next state acts in the same tick)."""

    name = ""

    def __init__(self, spec: ForagingRun, attention: Attention) -> None:
        self.spec, self.attention = spec, attention
        self.max_turn = math.radians(spec.max_turn_rate_deg)

    def enter(self, s: Surroundings) -> None:
        """Called when the controller switches to this state; a state without set-up keeps this no-op."""
        return None

    @abstractmethod
    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        """This tick's command (None: hand over at once) and event."""

    def _turn(self, w: float) -> float:
        return float(np.clip(w, -self.max_turn, self.max_turn))


class Wander(ForagingState):
    """Drive forward at ``speed`` with the Ornstein-Uhlenbeck turn rate; an obstacle within
    ``wander_steer_range`` of the probe ahead (with no whisker contact: e.g. a visual-only
    landmark) adds ``wander_steer_gain`` times the turn towards its escape direction."""

    name = "wander"

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        if self.attention.heeds(s):
            return None, "touch"
        spec = self.spec
        w = s.wander_turn
        if s.ahead_distance < spec.gains.wander_steer_range and not len(s.contacts):
            w += spec.gains.wander_steer_gain * _wrap(math.atan2(s.ahead_escape[1], s.ahead_escape[0]) - s.yaw)
        return (spec.speed, self._turn(w)), ""


class Orient(ForagingState):
    """Turn toward the attended contact at ``orient_turn_gain`` times the bearing; when the
    point is inside the head's turning reach (centre to snout plus ``avoid_margin``), back off
    at ``orient_back_gain`` times the shortfall (at most ``orient_back_speed``) and turn
    slower, down to ``orient_slow_share`` with the point at the snout. Facing it within
    ``orient_done_deg``: explore."""

    name = "orient"

    def enter(self, s: Surroundings) -> None:
        self.attention.target = None  # a new object: attend to this tick's contacts

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec, attention = self.spec, self.attention
        attention.follow(s, spec.gains.contact_weight)
        err = attention.bearing(s)
        reach = HEAD_CENTRE + HEAD_RADIUS + spec.avoid_margin
        dist = attention.distance(s)
        v = float(np.clip(spec.gains.orient_back_gain * (dist - reach), -spec.gains.orient_back_speed, 0.0))
        slow = float(np.clip((dist - HEAD_REACH) / (reach - HEAD_REACH), spec.gains.orient_slow_share, 1.0))
        w = self._turn(spec.gains.orient_turn_gain * err * slow)
        return (v, w), "facing" if abs(err) < math.radians(spec.gains.orient_done_deg) else ""


class Explore(ForagingState):
    """Contour following for a bout of ``explore_time`` (uniform): keep the attended point
    ``explore_bearing_deg`` to one side (chosen at random) and ``explore_reach`` beyond the
    head's centre, turning at ``explore_bearing_gain`` x bearing error + ``explore_distance_gain``
    x distance error (x side), and ``explore_snout_gain`` x intrusion away from the object when
    the head is within ``avoid_margin``; forward speed ``explore_speed_share`` x ``speed``,
    ramped down to 0 as the head's clearance falls to a quarter of ``avoid_margin``."""

    name = "explore"

    def __init__(self, spec: ForagingRun, attention: Attention, rng: np.random.Generator) -> None:
        super().__init__(spec, attention)
        self.rng = rng
        self.until = 0.0  #: end of the bout [s]

    def enter(self, s: Surroundings) -> None:
        lo, hi = self.spec.explore_time
        self.until = s.time + float(self.rng.uniform(lo, hi))
        self.attention.side = float(self.rng.choice([-1.0, 1.0]))

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec, attention = self.spec, self.attention
        attention.follow(s, spec.gains.contact_weight)
        if s.time >= self.until:
            return None, "bout over"
        side, margin = attention.side, spec.avoid_margin
        err = _wrap(attention.bearing(s) - side * math.radians(spec.gains.explore_bearing_deg))
        reach_err = attention.distance(s) - (HEAD_CENTRE + spec.gains.explore_reach)
        w = spec.gains.explore_bearing_gain * err + spec.gains.explore_distance_gain * reach_err * side
        if s.head_gap < margin:  # snout too close: steer away from the object's side
            w -= side * spec.gains.explore_snout_gain * (margin - s.head_gap)
        v = (spec.gains.explore_speed_share * spec.speed
             * float(np.clip((s.head_gap - 0.25 * margin) / margin, 0.0, 1.0)))
        return (v, self._turn(w)), ""


class Leave(ForagingState):
    """Turn to a heading away from the attended point (plus a uniform angle within
    ``leave_jitter``) at ``leave_turn_gain`` x error, driving at ``speed`` once within
    ``leave_drive_deg`` of it (backing at ``back_off_speed`` while the head is within
    ``avoid_margin``); contacts are ignored for ``refractory_time``. After ``leave_time`` and
    within ``leave_done_deg`` of the heading: wander."""

    name = "leave"

    def __init__(self, spec: ForagingRun, attention: Attention, rng: np.random.Generator) -> None:
        super().__init__(spec, attention)
        self.rng = rng
        self.until = 0.0  #: earliest end [s]
        self.heading = 0.0  #: the heading it leaves along [rad]

    def enter(self, s: Surroundings) -> None:
        spec = self.spec
        self.until = s.time + spec.gains.leave_time
        self.attention.refractory_until = s.time + spec.refractory_time
        away = s.pos - self.attention.target
        self.heading = (math.atan2(away[1], away[0])
                        + float(self.rng.uniform(-spec.gains.leave_jitter, spec.gains.leave_jitter)))

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec = self.spec
        err = _wrap(self.heading - s.yaw)
        w = self._turn(spec.gains.leave_turn_gain * err)
        v = 0.0 if abs(err) > math.radians(spec.gains.leave_drive_deg) else spec.speed
        if s.head_gap < spec.avoid_margin:
            v = -spec.gains.back_off_speed
        done = s.time >= self.until and abs(err) < math.radians(spec.gains.leave_done_deg)
        return (v, w), "turned away" if done else ""


class Avoid(ForagingState):
    """Entered from any state when the body or head comes closer than ``avoid_margin`` (while
    attending: ``attend_margin_share`` of it). Turn to the free-most escape heading at
    ``avoid_turn_gain`` x error; within ``avoid_drive_deg`` of it drive off at up to
    ``avoid_speed_share`` x ``speed`` (ramped from 0 at half the margin; blocked: pick another
    heading), otherwise back at ``back_off_speed`` when within half the margin. Clear by
    ``avoid_release_gap`` beyond the margin with the probe ahead ``avoid_release_ahead`` free:
    wander.

    The escape heading is judged where the head would be after turning to it. That misses an
    obstacle at the body's flank: every head probe is free, the heading stays the one the
    robot faces, its drive is refused by the guard and the robot dithers there (a training
    run in touch-alike-shapes stayed 958 of its 1000 samples beside a landmark's corner). So
    an avoid that starts where the last one got nowhere (`failed_at`, set when `Headway`
    stalls in avoid; within its distance) also judges each heading by the whole footprint's
    clearance `ESCAPE_STEP` along it."""

    name = "avoid"
    ESCAPE_STEP = 0.1  #: [m] how far along a heading the footprint is probed once an escape failed

    def __init__(self, spec: ForagingRun, attention: Attention, obstacles: ObstacleMap) -> None:
        super().__init__(spec, attention)
        self.obstacles = obstacles
        self.heading = 0.0  #: the escape heading [rad]
        self.failed_at: np.ndarray | None = None  #: (2,) where the last escape got nowhere

    def enter(self, s: Surroundings) -> None:
        retry = self.failed_at is not None and math.hypot(*(s.pos - self.failed_at)) < Headway.DISTANCE
        self.failed_at = None
        self.heading = self._escape_heading(s.pos, s.yaw, footprint=retry)

    def _escape_heading(self, pos: np.ndarray, yaw: float, footprint: bool = False) -> float:
        """The free-most of 12 headings (probed where the head would be; with ``footprint``, also
        the body and head `ESCAPE_STEP` along each), preferring small turns."""
        cand = yaw + np.radians(np.arange(12) * 30.0)
        ways = np.stack([np.cos(cand), np.sin(cand)], axis=1)
        clear = self.obstacles.distance_many(pos[None] + HEAD_CENTRE * ways)
        if footprint:  # in the head probe's units: the distance of the head's centre
            clear = np.minimum(
                clear, footprint_clearance(self.obstacles, pos[None] + self.ESCAPE_STEP * ways, cand) + HEAD_RADIUS
            )
        turn = np.abs((np.arange(12) * 30.0 + 180.0) % 360.0 - 180.0)
        score = np.minimum(clear, HEAD_RADIUS + 0.25) - 1e-3 * turn  # free enough -> the smallest turn wins
        return float(cand[int(np.argmax(score))])

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec = self.spec
        margin = spec.avoid_margin
        if s.clearance >= margin + spec.gains.avoid_release_gap and s.ahead_distance > spec.gains.avoid_release_ahead:
            return None, "clear"
        err = _wrap(self.heading - s.yaw)
        if abs(err) < math.radians(spec.gains.avoid_drive_deg):
            v = (spec.gains.avoid_speed_share * spec.speed
                 * float(np.clip((s.head_gap - 0.5 * margin) / margin, 0.0, 1.0)))
            if v == 0.0:  # blocked in this direction too: look for another way out
                self.heading = self._escape_heading(s.pos, s.yaw + math.pi / 6)
        else:
            v = -spec.gains.back_off_speed if s.clearance < 0.5 * margin else 0.0  # make room to turn
        return (v, self._turn(spec.gains.avoid_turn_gain * err)), ""


#: (state, event) -> next state of the foraging controller
TRANSITIONS: dict[tuple[str, str], str] = {
    ("wander", "touch"): "orient",  # a heeded whisker contact
    ("orient", "facing"): "explore",  # the attended point is ahead
    ("explore", "bout over"): "leave",
    ("leave", "turned away"): "wander",
    ("avoid", "clear"): "wander",
    **{(name, "too close"): "avoid" for name in ("wander", "orient", "explore", "leave")},
    # no `Headway` for 3 s (a turn and its ways out refused in turn): give the state up
    ("wander", "stuck"): "avoid",
    **{(name, "stuck"): "wander" for name in ("orient", "explore", "leave", "avoid")},
}
#: the states that attend to an object (and may come closer to it: ``attend_margin_share``)
ATTENDING = ("orient", "explore", "leave")


@dataclass
class ForagingController:
    """Tactile-attention foraging (see the module docstring): a state machine over `Wander`,
    `Orient`, `Explore`, `Leave` and `Avoid` with the transitions `TRANSITIONS`."""

    spec: ForagingRun
    obstacles: ObstacleMap
    rng: np.random.Generator
    mode: str = "wander"  #: the name of the current state

    def __post_init__(self) -> None:
        spec = self.spec
        self.attention = Attention()
        self.states: dict[str, ForagingState] = {
            state.name: state for state in (
                Wander(spec, self.attention), Orient(spec, self.attention), Explore(spec, self.attention, self.rng),
                Leave(spec, self.attention, self.rng), Avoid(spec, self.attention, self.obstacles),
            )
        }
        self._wander = _OU(self.rng, math.radians(spec.wander_turn_deg), spec.gains.wander_turn_time, x0=0.0)
        self._limit = _Limiter(spec.max_accel, 4.0)
        self._guard = SafetyGuard(self.obstacles, spec.gains.guard_margin_share * spec.avoid_margin)
        self.headway = Headway()  #: is the robot getting anywhere?
        self._last_t: float | None = None

    def start_pose(self, default: tuple[float, float, float]) -> tuple[float, float, float]:
        x, y, yaw = self.spec.start if self.spec.start is not None else default
        return (x, y, math.radians(yaw))

    def resume(self, t: float, pose: np.ndarray, current: tuple[float, ...]) -> None:
        """Take the robot over again at time ``t`` from another driver (`VisitsController`),
        the base moving at ``current`` (forward speed, turn rate): wandering, with contacts
        ignored for ``refractory_time`` as after leaving an object."""
        self.mode = "wander"
        self.attention.refractory_until = t + self.spec.refractory_time
        self.headway.restart(pose, t)
        self._limit.state[:] = current[:2]
        self._last_t = t

    def sense(self, obs: Observation, dt: float) -> Surroundings:
        """The observation with the obstacle distances at the base, the head and
        `PROBE_AHEAD` beyond the snout, and the wandering turn rate advanced by ``dt``."""
        x, y, yaw = obs.pose
        c, s_ = math.cos(yaw), math.sin(yaw)
        ahead = HEAD_REACH + PROBE_AHEAD
        pts = np.array([[x, y], [x + HEAD_CENTRE * c, y + HEAD_CENTRE * s_], [x + ahead * c, y + ahead * s_]])
        dist, grad = self.obstacles.query(pts)
        return Surroundings(
            time=obs.time, pose=obs.pose, contacts=obs.contacts, body_gap=dist[0] - BODY_RADIUS,
            head_gap=dist[1] - HEAD_RADIUS, ahead_distance=dist[2], ahead_escape=grad[2],
            wander_turn=self._wander.step(dt) if dt > 0 else self._wander.x,
        )

    def _switch(self, event: str, s: Surroundings) -> ForagingState:
        self.mode = TRANSITIONS[(self.mode, event)]
        state = self.states[self.mode]
        state.enter(s)
        self.headway.restart(s.pose, s.time)  # each state gets its time to get somewhere
        return state

    def __call__(self, obs: Observation) -> tuple[float, float]:
        dt = 0.0 if self._last_t is None else obs.time - self._last_t
        self._last_t = obs.time
        s = self.sense(obs, dt)
        margin = self.spec.avoid_margin * (self.spec.gains.attend_margin_share if self.mode in ATTENDING else 1.0)
        too_close = self.mode != "avoid" and s.clearance < margin
        if too_close:
            state = self._switch("too close", s)
        elif self.headway.stalled(s.pose, s.time):
            if self.mode == "avoid":
                assert isinstance(self.states["avoid"], Avoid)
                self.states["avoid"].failed_at = s.pos.copy()
            state = self._switch("stuck", s)
        else:
            state = self.states[self.mode]
        command, event = state.step(s)
        while command is None:  # handed over at once: the next state acts in this tick
            state = self._switch(event, s)
            command, event = state.step(s)
        if event:
            self._switch(event, s)
        return self._out(*command, dt, obs.pose)

    def _out(self, v: float, w: float, dt: float, pose: np.ndarray) -> tuple[float, float]:
        """Rate-limited command; one that would swing the head or drive the body into an
        obstacle within the guard's horizon is replaced by the first safe one of: backing off
        while turning, backing off straight, not turning, turning the other way round,
        creeping forward (at the backing-off speed), standing still (always safe). Without
        the last two ways out a robot in a corner where its state's turn and backing off are
        both refused stood there for the rest of its run (a state keeps asking for the same
        turn until it is done)."""
        back = -self.spec.gains.back_off_speed
        ways_out = [(back, w), (back, 0.0), (v, 0.0), (0.0, -w), (-back, 0.0)]
        candidates = [(v, w, 0.0)] + [(a, b, 0.0) for a, b in ways_out if (a, b) != (0.0, 0.0)]  # not standing yet
        v, w, _ = self._guard.first_safe(pose, candidates)
        return self._limit(v, w, dt=dt)
