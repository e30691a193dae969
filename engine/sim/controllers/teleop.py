"""Teleoperation (``teleop``, `TeleopDriver`): ViTa-SLAM's keyboard teleoperation emulated -
one key at a time from its key set, stop-and-go, along the run's own jittered copy of the
environment's loop from a random start, exploring the tactile landmarks it passes.

Its modes are `Drive`, `Approach`, `Hold`, `Leave` (`TeleopMode`), like the foraging states.
At each decision the driver asks its mode for a key; the mode returns the key to press
(None: hand over at once, the next mode decides in this same decision) and an event ("" for
none) that `TELEOP_TRANSITIONS` maps to the next mode:

    drive --landmark--> approach --reached--> hold --done--> leave --clear--> drive
                        approach --gave up--> leave

The modes keep their state on the driver (``target_landmark``, ``until``,
``approach_from``, ``contacts_left``), which its tests and the simulation loop read."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np

from vitaplace.engine.data.dataset import TOUCH_THRESHOLD
from vitaplace.engine.sim.clearance import (
    HEAD_CENTRE,
    HEAD_RADIUS,
    ROUTE_LOOKAHEAD,
    ROUTE_MIN_CLEARANCE,
    Route,
    footprint_clearance,
    loop_clearance,
)
from vitaplace.engine.sim.controllers.common import Limiter as _Limiter
from vitaplace.engine.sim.controllers.common import Observation
from vitaplace.engine.sim.controllers.common import wrap as _wrap
from vitaplace.engine.sim.controllers.safety import Headway, SafetyGuard
from vitaplace.engine.sim.controllers.settings import StationsRun, TeleopRun
from vitaplace.engine.sim.environment import EnvironmentSpec

Press = tuple[str, float]  #: a key and how long it is pressed [s] (inf: until the next decision)
STOP: Press = ("k", math.inf)

LEAVE_TIME = 6.0  #: the longest the driver backs off from a landmark before driving on [s]
_HOLD_PATIENCE = 3  #: a hold waiting for its contacts ends after this many whisk cycles per contact
_LEAVE_GAP = 0.15  #: after a hold, back off until the head is this far from the landmark [m]
_APPROACH_TIMEOUT = 12.0  #: an exploration that has not reached its landmark by then is given up [s]
_MAKE_ROOM = 0.3  #: where the head cannot swing round to face a landmark, back away up to this far first [m]


class TeleopMode(ABC):
    """One mode of the teleoperator; `decide` returns (key or None, event)."""

    name = ""

    def __init__(self, driver: TeleopDriver) -> None:
        self.driver = driver

    def enter(self, t: float, pose: np.ndarray) -> None:
        """Called when the driver switches to this mode; a mode without set-up keeps this no-op."""
        return None

    @abstractmethod
    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        """The key to press (None: hand over at once) and the event for `TELEOP_TRANSITIONS`."""


class Drive(TeleopMode):
    """Along the path (the loop or, in a detour window, the offset loop): translation keys
    towards the path ahead, turning when the heading is off by more than the tolerance; a
    tactile landmark being passed is explored (`TeleopDriver._start_visit`); blocked, the
    driver makes its way round (`TeleopDriver._way_round`)."""

    name = "drive"

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        path = d.detour if d.detour is not None and d.in_detour(t) else d.loop
        if path is not d.path:
            d._switch_path(path)
        d._progress(pose[:2])
        if path is d.loop and d._start_visit(t, pose):
            return None, "landmark"
        ranked = self._ranked(pose)
        stalled = d.headway.stalled(pose, t)
        key, duration = d._pick(pose, ranked)
        if (key == "k" and d._standing()) or stalled:
            return d._way_round(pose), ""
        return (key, duration), ""

    def _ranked(self, pose: np.ndarray) -> list[str]:
        """The keys to try, best first: towards the path ahead, turning first when the heading
        is off (forward and turn at once where the error is small and forward is best)."""
        d = self.driver
        direction = d._path_direction(pose)
        err = _wrap(d._facing(pose[:2]) - float(pose[2]))
        d.turning = abs(err) > (0.5 if d.turning else 1.0) * d.tolerance
        translation = d._translation_keys(direction)
        if not d.turning:
            return translation
        if d.outward is None and abs(err) < 3 * d.tolerance and translation[:1] == ["i"]:
            return ["u" if err > 0 else "o", d._turn_key(err), *translation]  # forward and turn
        return [d._turn_key(err), *translation]


class Approach(TeleopMode):
    """Turn to face the landmark (as far as the head can swing round; backing away first up to
    `_MAKE_ROOM` where it cannot), then drive up until the whiskers touch it with the head
    within ``touch_gap``: reached. Given up after `_APPROACH_TIMEOUT`, or when it can get no
    closer and the whiskers do not reach it."""

    name = "approach"
    #: the translation keys towards the landmark it tries, best first (the rest: a tap, or stop)
    ranked_keys = 3

    def enter(self, t: float, pose: np.ndarray) -> None:
        d = self.driver
        d.until, d.approach_from = t + _APPROACH_TIMEOUT, pose[:2].copy()

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        if t >= d.until:  # could not get there: give up
            return STOP, "gave up"
        i = d.target_landmark
        bearing = d._bearing(pose, i)
        whisking = d.touched and d._landmark_gaps(pose)[i] <= d.spec.touch_gap
        if abs(bearing) > 0.5 * d.tolerance and not whisking:  # face it
            press = self._face(pose, bearing)
            if press is not None:
                return press, ""
        if whisking:
            return STOP, "reached"
        # then drive up to it until the whiskers touch it, and as close as touch_gap
        key, duration = d._pick(pose, d._translation_keys(bearing)[: self.ranked_keys])
        if key != "k":
            return (key, duration), ""
        if not d._standing():  # stop first: from standstill, taps may still be safe
            return STOP, ""
        return STOP, "reached" if d.touched else "gave up"  # no closer: hold if the whiskers reach it

    def _face(self, pose: np.ndarray, bearing: float) -> Press | None:
        """A key turning towards ``bearing`` (or backing away to make room first), else None."""
        d = self.driver
        room = d._room_to_turn(pose, bearing)
        cramped = abs(room) < abs(bearing) - 0.5 * d.tolerance
        if cramped and np.linalg.norm(pose[:2] - d.approach_from) < _MAKE_ROOM:  # back away first
            key, duration = d._pick(pose, d._translation_keys(bearing + math.pi)[:3])
            if key != "k":
                return key, duration
        if abs(room) > 0.5 * d.tolerance:  # as far as the head can swing round here
            key, duration = d._pick(pose, [d._turn_key(room)])
            if key != "k":
                return key, duration
        return None


class Hold(TeleopMode):
    """Stand at the landmark until ``hold_cycles`` samples with contact are recorded (tapping
    back onto it when the whiskers lose it), or `_HOLD_PATIENCE` whisk cycles per contact."""

    name = "hold"

    def enter(self, t: float, pose: np.ndarray) -> None:
        d = self.driver
        lo, hi = d.spec.hold_cycles
        d.contacts_left = int(d.rng.integers(lo, hi + 1)) - int(d.touched)
        d.until = t + _HOLD_PATIENCE * d.contacts_left * d.sample_period

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        d.contacts_left -= int(d.touched)
        if d.contacts_left > 0 and t < d.until:
            if d.touched:
                return STOP, ""
            bearing = d._bearing(pose, d.target_landmark)
            return d._pick(pose, d._translation_keys(bearing)[:3], hold=False), ""  # tap back onto it
        return None, "done"


class Leave(TeleopMode):
    """Back away from the landmark until the head is `_LEAVE_GAP` from it, for at most
    `LEAVE_TIME`; then drive on."""

    name = "leave"

    def enter(self, t: float, pose: np.ndarray) -> None:
        self.driver.until = t + LEAVE_TIME

    def decide(self, t: float, pose: np.ndarray) -> tuple[Press | None, str]:
        d = self.driver
        if d._landmark_gaps(pose)[d.target_landmark] < _LEAVE_GAP and t < d.until:
            away = d._bearing(pose, d.target_landmark) + math.pi
            return d._pick(pose, d._translation_keys(away)), ""
        return None, "clear"


#: (mode, event) -> next mode of the teleoperator
TELEOP_TRANSITIONS: dict[tuple[str, str], str] = {
    ("drive", "landmark"): "approach",  # a tactile landmark being passed
    ("approach", "reached"): "hold",  # the whiskers on it, the head within touch_gap
    ("approach", "gave up"): "leave",  # timed out, or no closer and the whiskers do not reach it
    ("hold", "done"): "leave",  # its contacts recorded, or out of patience
    ("leave", "clear"): "drive",  # far enough from it, or out of time
}

#: ViTa-SLAM's keyboard teleoperation (whiskeye_controller/src/teleop.py): each key sets the
#: multipliers of the forward speed, the leftward (strafe) speed and the turn rate; "k", like
#: any key not bound, stops the robot.
TELEOP_KEYS: dict[str, tuple[int, int, int]] = {
    "i": (1, 0, 0), "o": (1, 0, -1), "j": (0, 0, 1), "l": (0, 0, -1), "u": (1, 0, 1),
    ",": (-1, 0, 0), ".": (-1, 0, 1), "m": (-1, 0, -1),
    "O": (1, -1, 0), "J": (0, 1, 0), "L": (0, -1, 0), "U": (1, 1, 0), ">": (-1, -1, 0), "M": (-1, 1, 0),
    "k": (0, 0, 0),
}  # (I and < repeat i and ,)
#: teleop.launch's ``turn``: the turn keys' rate [rad/s] (kept when the operator lowers only the
#: linear speed with the x key to `settings.TELEOP_SPEED`)
TELEOP_TURN = 0.25

#: directions [deg] of the translation keys in the robot frame (0: forward, 90: left)
_TRANSLATION_KEYS = {"i": 0.0, "U": 45.0, "J": 90.0, "M": 135.0, ",": 180.0, ">": -135.0, "L": -90.0, "O": -45.0}
_TAP = 0.2  #: a key tapped where holding it would be unsafe: pressed this long [s]
_STANDING = 0.02  #: the base counts as standing below this speed [m/s]
_TURN_CLEARANCE = 0.02  #: the driver turns towards a landmark only as far as the head stays this clear [m]
_SKIP_AHEAD = 0.1  #: blocked on its path, the driver looks this much further along it per decision [m]


class TeleopDriver:
    """An emulated keyboard teleoperator (ViTa-SLAM's ``teleop.py``, see docs/SIMULATION.md).

    Every ``decision_interval`` it looks at the robot and picks one key of `TELEOP_KEYS`:
    the key's speeds are the run's speed (the nominal speed after a few q/z presses) and
    `TELEOP_TURN` times the same speed steps as the turn rate. A new key is pressed
    ``reaction_delay`` after the decision; the old one is released at once, so the robot
    stops in between (the Gazebo plugin zeroes every command after one update: no key, no
    motion). The driver follows its own copy of the environment's loop (waypoints moved
    by smooth random offsets, ``path_jitter``), from a random start point, facing as the
    environment's ``route_facing`` says, with a constant heading bias and a heading
    tolerance before it turns. A tactile landmark it passes (``visit_range``,
    ``visit_bearing_deg``; once per lap) is explored: turn to face it, drive up until the
    whiskers bend at full protraction with the head within ``touch_gap``, hold still for
    ``hold_cycles`` whisk cycles, back off, go on (at once where it cannot get the whiskers
    onto it). With
    ``off_route_fraction`` the run makes ``detour_count`` detours at random times, together
    that share of the run, along the loop moved ``off_route_offset`` to the left of travel
    (less where that would not be clear). A key that would bring the body or the head
    closer than the `SafetyGuard` allows is not pressed (a tap is tried), or released.
    Blocked on its path (no key towards it is safe, or no `Headway` for 3 s), the driver
    looks further along the path and makes its way round (`_way_round`).
    """

    #: (mode, event) -> next mode; a driver with other modes (`StationDriver`) has its own table
    transitions = TELEOP_TRANSITIONS
    spec: TeleopRun | StationsRun  #: a StationsRun for `StationDriver`

    def __init__(
        self, spec: TeleopRun | StationsRun, env: EnvironmentSpec, rng: np.random.Generator, sample_period: float
    ) -> None:
        self.spec, self.rng, self.obstacles = spec, rng, env.obstacles
        self.guard = SafetyGuard(env.obstacles, 0.25 * spec.avoid_margin, braking=spec.max_accel)
        self.centre = np.mean(env.route, axis=0)
        self.outward = self.centre if env.route_facing == "outward" else None
        k = int(rng.integers(-spec.speed_steps, spec.speed_steps + 1))
        steps = 1.1**k if k >= 0 else 0.9**-k  # q/z scale speed and turn alike
        self.speed, self.turn = spec.speed * steps, TELEOP_TURN * steps
        self.bias = math.radians(spec.heading_bias_deg) * float(np.clip(rng.normal(), -2.0, 2.0))
        self.tolerance = math.radians(spec.turn_threshold_deg)
        base = Route(env.route)
        jitter = self._smooth_offsets(base)
        self.loop = self._clear_offset_route(base, jitter)
        self.detour = (self._clear_offset_route(base, jitter + spec.off_route_offset) if spec.off_route_fraction
                       else None)
        self.detours = self._plan_detours(sample_period)
        self.path = self.loop
        self.s = float(rng.uniform(0.0, self.loop.length))
        self.tactile = [i for i, lm in enumerate(env.landmarks) if lm.tactile]
        self.visited: dict[int, float] = {}  #: landmark -> lap count when it was explored
        self.mode, self.turning = "drive", False  #: the current mode's name (`TeleopMode`); turning while driving
        self.modes: dict[str, TeleopMode] = {mode.name: mode(self) for mode in (Drive, Approach, Hold, Leave)}
        self.target_landmark, self.until, self.approach_from = -1, 0.0, np.zeros(2)
        self.headway = Headway()  #: is the drive getting anywhere?
        self.contacts_left = 0  #: samples with contact still to record in the current hold
        self.touched = False  #: whisker deflection at full protraction seen since the last decision
        self.released = ""  #: the key the guard released since the last decision
        self.sample_period = sample_period
        self.key, self.press_from, self.press_until, self.next_decision = "k", 0.0, 0.0, 0.0
        self._limit = _Limiter(spec.max_accel, 4.0, spec.max_accel)
        self._last_t: float | None = None

    # ------------------------------------------------------------------ the run's own loop
    def _smooth_offsets(self, base: Route) -> np.ndarray:
        """Offsets (n,) of the waypoints across the loop: white noise smoothed along the loop
        (Gaussian, 0.5 m), scaled to std ``path_jitter``."""
        raw = self.rng.normal(size=len(base.points))
        along = np.abs(base.cum[:-1, None] - base.cum[None, :-1])
        along = np.minimum(along, base.length - along)
        smooth = np.exp(-0.5 * (along / 0.5) ** 2) @ raw
        return self.spec.path_jitter * smooth / max(float(np.std(smooth)), 1e-9)

    def _clear_offset_route(self, base: Route, offsets: np.ndarray) -> Route:
        """``base`` with its waypoints moved ``offsets`` to the left; where the robot would come
        closer than `ROUTE_MIN_CLEARANCE` to something, the offsets of the segment's waypoints
        shrink (the base loop itself is clear: `route_collision`)."""
        normals = base.waypoint_normals()
        offsets = np.array(offsets, dtype=float)
        for _ in range(30):
            route = Route(base.points + offsets[:, None] * normals)
            s, clearance = loop_clearance(self.obstacles, route, self.outward)
            bad = np.unique(route.segment_of(s[clearance < ROUTE_MIN_CLEARANCE]))
            if not len(bad):
                return route
            offsets[np.concatenate([bad, (bad + 1) % len(offsets)])] *= 0.7
        return base

    def _plan_detours(self, sample_period: float) -> list[tuple[float, float]]:
        """``detour_count`` windows [t0, t1) of simulation time, together ``off_route_fraction``
        of the recorded run, at random places (uniform gaps between them)."""
        spec = self.spec
        if not spec.off_route_fraction:
            return []
        duration = spec.n_samples * sample_period
        piece = spec.off_route_fraction * duration / spec.detour_count
        gaps = self.rng.dirichlet(np.ones(spec.detour_count + 1)) * (duration - piece * spec.detour_count)
        starts = spec.warmup_cycles * sample_period + np.cumsum(gaps[:-1]) + piece * np.arange(spec.detour_count)
        return [(float(t0), float(t0 + piece)) for t0 in starts]

    def in_detour(self, t: float) -> bool:
        return any(t0 <= t < t1 for t0, t1 in self.detours)

    def start_pose(self) -> tuple[float, float, float]:
        if self.spec.start is not None:
            x, y, yaw = self.spec.start
            self.s, _ = self.loop.project(np.array([x, y]))
            return (x, y, math.radians(yaw))
        p, _ = self.loop.point(self.s)
        yaw = self._facing(p) + float(self.rng.uniform(-1.0, 1.0)) * self.tolerance
        return (float(p[0]), float(p[1]), yaw)

    def _facing(self, pos: np.ndarray) -> float:
        """The heading the driver wants at ``pos`` on its path: away from the loop's centre, or
        towards the path ahead; plus the run's bias."""
        if self.outward is not None:
            rel = pos - self.outward
        else:
            rel = self.path.point(self.s + self.spec.lookahead)[0] - pos
        return math.atan2(rel[1], rel[0]) + self.bias

    # ------------------------------------------------------------------ keys
    def _command(self, key: str) -> tuple[float, float, float]:
        x, y, th = TELEOP_KEYS[key]
        return (x * self.speed, th * self.turn, y * self.speed)

    def _translation_keys(self, direction: float) -> list[str]:
        """Translation keys moving within 90 deg of ``direction`` [rad, robot frame], best first."""
        off = {k: abs(_wrap(math.radians(a) - direction)) for k, a in _TRANSLATION_KEYS.items()}
        return [k for k in sorted(off, key=off.__getitem__) if off[k] < math.pi / 2]

    def _turn_key(self, err: float) -> str:
        return "j" if err > 0 else "l"

    def _current(self) -> tuple[float, float]:
        """The base's commanded forward and leftward speed now (after the rate limit)."""
        return (float(self._limit.state[0]), float(self._limit.state[2]))

    def _standing(self) -> bool:
        return max(abs(v) for v in self._current()) < _STANDING

    def _pick(self, pose: np.ndarray, ranked: list[str], hold: bool = True) -> tuple[str, float]:
        """The first of ``ranked`` that is safe to hold (with ``hold``), else the first safe to
        tap, else stop (a key the guard has just released is not pressed again at once). A tap
        from standstill is checked as pressed `_TAP` (the robot stands through the reaction
        delay); otherwise as held from now to its release."""
        delay = self.spec.reaction_delay
        tap = (_TAP if self._standing() else delay + _TAP, _TAP)
        for horizon, duration in ((delay + SafetyGuard.HORIZON, math.inf), tap) if hold else (tap,):
            for key in (k for k in ranked if k != self.released):
                if self.guard.safe(pose, *self._command(key), horizon=horizon, current=self._current()):
                    return key, duration
        return "k", math.inf

    # ------------------------------------------------------------------ decisions
    def _progress(self, pos: np.ndarray) -> None:
        cand = self.s + np.linspace(-0.1, 0.6, 29)
        d = np.linalg.norm(self.path.at(cand) - pos[None], axis=1)
        self.s = max(self.s, float(cand[int(np.argmin(d))]))

    def _switch_path(self, path: Route) -> None:
        """Follow ``path`` from the same place along the loop (same waypoint, same fraction of its segment)."""
        i = int(self.path.segment_of(self.s))
        frac = (self.s % self.path.length - self.path.cum[i]) / self.path.seg_len[i]
        laps = math.floor(self.s / self.path.length)
        self.s = laps * path.length + path.cum[i] + frac * path.seg_len[i]
        self.path = path

    @staticmethod
    def _head(pose: np.ndarray) -> np.ndarray:
        """The centre (2,) of the head's disc at ``pose``."""
        return pose[:2] + HEAD_CENTRE * np.array([math.cos(pose[2]), math.sin(pose[2])])

    def _path_direction(self, pose: np.ndarray) -> float:
        """Direction [rad, robot frame] from the base to the path point ``lookahead`` ahead."""
        rel = self.path.point(self.s + self.spec.lookahead)[0] - pose[:2]
        return _wrap(math.atan2(rel[1], rel[0]) - pose[2])

    def _landmark_gaps(self, pose: np.ndarray) -> np.ndarray:
        """Clearance (L,) of the head from each landmark [m]."""
        head = self._head(pose)
        return self.obstacles.landmark_distance_many(head[None])[0] - HEAD_RADIUS

    def _bearing(self, pose: np.ndarray, i: int) -> float:
        """Direction [rad, robot frame] from the base to the point of landmark ``i`` nearest the head."""
        head = self._head(pose)
        dist, grad = self.obstacles.query(head[None], landmark=i)
        rel = head - dist[0] * grad[0] - pose[:2]
        return _wrap(math.atan2(rel[1], rel[0]) - pose[2])

    def _decide(self, t: float, pose: np.ndarray) -> tuple[str, float]:
        """The key to press next and how long (inf: until the next decision): the current
        mode's, after the transitions (`transitions`) its events call for; a mode that
        hands over lets the next one decide at once. Away from the path the driver's
        `Headway` restarts (it counts only while driving)."""
        while True:
            if self.mode != "drive":
                self.headway.restart(pose, t)
            press, event = self.modes[self.mode].decide(t, pose)
            if event:
                self.mode = self.transitions[(self.mode, event)]
                self.modes[self.mode].enter(t, pose)
            if press is not None:
                return press

    def _way_round(self, pose: np.ndarray) -> tuple[str, float]:
        """Blocked: standing with no key towards the path ahead safe, or dithering without
        headway (the path bends round something the head is up against, or its target lies
        under the head, which reaches 0.58 m ahead). Look `_SKIP_AHEAD` further along the path
        and turn or move towards it, else move away from the obstacle nearest the head; stand
        only when none of these is safe. Without this the driver would stand, or dither, there
        until the run ends: each decision would see the same blocked keys."""
        self.s += _SKIP_AHEAD
        direction = self._path_direction(pose)
        _, grad = self.obstacles.query(self._head(pose)[None])
        away = _wrap(math.atan2(grad[0, 1], grad[0, 0]) - pose[2])
        turn = [self._turn_key(direction)] if self.outward is None else []
        return self._pick(pose, [*turn, *self._translation_keys(direction), *self._translation_keys(away)])

    def _room_to_turn(self, pose: np.ndarray, bearing: float) -> float:
        """How far [rad] the robot can turn in place towards ``bearing`` (robot frame) with the
        body and the head `_TURN_CLEARANCE` clear all the way."""
        steps = np.arange(1, int(abs(bearing) / math.radians(5.0)) + 1) * math.radians(5.0) * np.sign(bearing)
        if not len(steps):
            return 0.0
        clear = footprint_clearance(self.obstacles, np.repeat(pose[None, :2], len(steps), axis=0), pose[2] + steps)
        blocked = np.flatnonzero(clear < _TURN_CLEARANCE)
        return float(steps[blocked[0] - 1]) if len(blocked) and blocked[0] > 0 else (0.0 if len(blocked) else bearing)

    def _start_visit(self, t: float, pose: np.ndarray) -> bool:
        """Explore the tactile landmark that the robot is passing: the head is within
        ``visit_range`` of it, as close as the path ahead will bring it (0.3 m further on the
        head would be no closer), and it lies ahead or to the side (``visit_bearing_deg``);
        not again within half a lap."""
        if not self.tactile:
            return False
        assert isinstance(self.spec, TeleopRun)  # a StationDriver visits its stations instead
        gaps = self._landmark_gaps(pose)
        ahead = self.path.point(self.s + ROUTE_LOOKAHEAD)[0]
        gaps_ahead = self._landmark_gaps(np.array([*ahead, self._facing(ahead)]))
        laps = self.s / self.path.length
        for i in sorted(self.tactile, key=lambda j: gaps[j]):
            if gaps[i] > self.spec.visit_range:
                break
            passing = gaps_ahead[i] >= gaps[i] and laps - self.visited.get(i, -math.inf) >= 0.5
            if passing and abs(self._bearing(pose, i)) <= math.radians(self.spec.visit_bearing_deg):
                self.visited[i], self.target_landmark = laps, i
                return True
        return False

    def __call__(self, obs: Observation) -> tuple[float, float, float]:
        t = obs.time
        dt = 0.0 if self._last_t is None else t - self._last_t
        self._last_t = t
        # what the driver sees between decisions: are the whiskers bent by something at full
        # protraction (the end of a whisk cycle, when a sample is taken)?
        cycles = t / self.sample_period
        if abs(cycles - round(cycles)) < 1e-6:
            self.touched |= float(np.max(obs.deflection, initial=0.0)) > TOUCH_THRESHOLD
        if t >= self.next_decision - 1e-9:
            self.next_decision = t + self.spec.decision_interval
            key, duration = self._decide(t, obs.pose)
            self.touched, self.released = False, ""
            if key != self.key or math.isfinite(duration) or t >= self.press_until:
                # release, then press the new key after the reaction delay (a tap is a new press)
                self.key, self.press_from = key, t + self.spec.reaction_delay
            self.press_until = self.press_from + duration
        command = (0.0, 0.0, 0.0)
        if self.press_from <= t + 1e-9 < self.press_until:
            command = self._command(self.key)
            horizon = min(SafetyGuard.HORIZON, self.press_until - t)
            if not self.guard.safe(obs.pose, *command, horizon=horizon, current=self._current()):
                command, self.press_until, self.released = (0.0, 0.0, 0.0), t, self.key  # it would hit something
        return self._limit(*command, dt=dt)
