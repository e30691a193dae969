"""Trajectories: a tactile-attention foraging controller (training runs), an emulated
keyboard teleoperator (evaluation runs: independent drives), a noisy route follower and a
noisy orbit (near-duplicate evaluation runs, kept for regression).

Every controller is called at each control tick (``control_hz``, rounded to
deflection-series samples) with an `Observation` and returns a command ``(v, w)`` or
``(v, w, lateral)``: forward speed [m/s], yaw rate [rad/s] and sideways (leftward) speed
[m/s] of the holonomic base. All randomness comes from the ``numpy.random.Generator``
they are given, so a seed reproduces the trajectory.

Foraging (inspired by rodent exploration; Mitchinson & Prescott's "orient" behaviour):

* ``wander``  - drive forward with a smoothly random turn rate (Ornstein-Uhlenbeck);
* ``orient``  - on whisker contact, turn toward the contact (the attended point);
* ``explore`` - keep the attended object to one side, at the whiskers' reach, and move slowly along it,
  re-attending to the newest contacts (contour following), for a random 3-8 s;
* ``leave``   - turn away from the explored object, ignore contacts for a refractory period;
* ``avoid``   - whenever the chassis or the head gets close to a wall or landmark (from
  the environment's 2-D obstacle map, a stand-in for a proximity sensor), turn away.

Each mode is a `ForagingState` (`Wander`, `Orient`, `Explore`, `Leave`, `Avoid`) whose step
returns a command and an event; `TRANSITIONS` maps (state, event) to the next state. Their
gains and thresholds are `RunSpec` fields (docs/SCENARIOS.md), defaulting to the values the
controller always used.

Teleoperation (``teleop``, `TeleopDriver`): ViTa-SLAM's keyboard teleoperation emulated -
one key at a time from its key set, stop-and-go, along the run's own jittered copy of the
environment's loop from a random start, exploring the tactile landmarks it passes. Foraging
and teleop share one look-ahead `SafetyGuard` that keeps the body and the head off obstacles.

Route following (``route``): pure pursuit along the environment's closed waypoint loop,
facing the direction of travel.

Orbit (``orbit``, ViTa-SLAM's evaluation trajectory): a circle of ``orbit_radius`` around
``orbit_centre`` driven sideways (counter-clockwise), the camera facing outward, towards
the walls. An environment whose ``route_facing`` is ``outward`` has its route driven the
same way, facing away from the route's centroid.

Both evaluation kinds add three independent Ornstein-Uhlenbeck noise processes - an offset
across the path (``lateral_noise``), a heading offset (``heading_noise_deg``) and a speed
factor (``speed_noise``) - and start from a noisy pose, so two runs with different seeds
follow the same path closely but never see the same frame. With ``off_route_fraction`` > 0
the final fraction of the run leaves the path, ``off_route_offset`` metres across it (to
the left of the direction of travel; for the orbit, towards the centre), so those places are
not revisits and true negatives occur.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer, model_validator

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
from vitaplace.engine.sim.environment import EnvironmentSpec, ObstacleMap
from vitaplace.engine.sim.robot import BODY_RADIUS, HEAD_HALF, HEAD_POS

__all__ = ["RunSpec", "Observation", "ForagingController", "RouteFollower", "make_controller",
           "Surroundings", "Attention", "ForagingState", "Wander", "Orient", "Explore", "Leave", "Avoid", "TRANSITIONS", "Headway"]

HEAD_REACH = HEAD_POS[0] + HEAD_HALF[0]  #: distance from the base centre to the snout [m]

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
#: linear speed with teleop.py's x key to `TELEOP_SPEED`)
TELEOP_TURN = 0.25
#: the keys' nominal speed [m/s] for the WhiskEye (see docs/SIMULATION.md)
TELEOP_SPEED = 0.3


#: marks the `RunSpec` fields that are gains or thresholds of the foraging states
FORAGING_GAIN = object()
ForagingGain = Annotated[float, FORAGING_GAIN]


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
        moved = math.hypot(*(pose[:2] - self.pose[:2])) > self.DISTANCE or abs(_wrap(pose[2] - self.pose[2])) > self.TURN
        if moved:
            self.restart(pose, t)
        return not moved and t - self.since >= self.STALL_TIME


class RunSpec(BaseModel):
    """What one recorded run does. Only ``kind`` and ``n_samples`` are required."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    kind: Literal["foraging", "teleop", "route", "orbit"] = Field(
        description="foraging (tactile-attention exploration, training), teleop (an emulated keyboard "
        "teleoperator driving its own copy of the environment's route and whisking its landmarks), "
        "route (noisy laps of the environment's route) or orbit (noisy laps of a circle, driven "
        "sideways with the camera facing outward); route and orbit runs with different seeds are "
        "near-duplicates (kept for regression), teleop runs are independent drives",
    )
    n_samples: int = Field(gt=0, description="samples (whisk cycles) to record")
    speed: float = Field(
        0.15, gt=0, le=1.0, description=f"nominal forward speed [m/s] (teleop: the keys' speed, default {TELEOP_SPEED})"
    )
    max_turn_rate_deg: float = Field(90.0, gt=0, le=720, description="turn-rate limit [deg/s]")
    max_accel: float = Field(0.5, gt=0, description="linear acceleration limit [m/s^2]")
    warmup_cycles: int = Field(1, ge=0, le=100, description="whisk cycles simulated before the first sample")
    start: tuple[float, float, float] | None = Field(
        None, description="start pose [x, y, yaw_deg]; default: the environment's start (foraging) or the route start"
    )
    # route-following noise (independent per run, seeded)
    lateral_noise: float = Field(0.02, ge=0, le=0.2, description="std of the lateral offset from the route [m]")
    heading_noise_deg: float = Field(3.0, ge=0, le=45, description="std of the heading offset [deg]")
    speed_noise: float = Field(0.1, ge=0, le=0.5, description="std of the relative speed change")
    noise_time_constant: float = Field(3.0, gt=0, description="correlation time of the noise processes [s]")
    start_noise: float = Field(0.03, ge=0, le=0.5, description="std of the start position along/across the route [m]")
    lookahead: float = Field(0.3, gt=0.05, le=2.0, description="pure-pursuit lookahead distance [m]")
    off_route_fraction: float = Field(
        0.0, ge=0, le=0.9, description="final fraction of a route/orbit run driven off the path (not revisits)"
    )
    off_route_offset: float = Field(
        0.6, ge=-3, le=3, description="how far off the path that part runs: left of travel, or towards the orbit's centre [m]"
    )
    # teleoperation (kind teleop, see TeleopDriver)
    decision_interval: float = Field(0.5, gt=0, le=5, description="how often the teleoperator reconsiders its key [s]")
    reaction_delay: float = Field(
        0.25, ge=0, le=2, description="from a decision to the new key's press; the robot stands meanwhile [s]"
    )
    heading_tolerance_deg: float = Field(
        10.0, gt=0, le=90, description="heading error the teleoperator lets pass before it turns [deg]"
    )
    heading_bias_deg: float = Field(5.0, ge=0, le=45, description="std of the run's constant heading bias [deg]")
    path_jitter: float = Field(
        0.08, ge=0, le=0.5, description="std of the smooth offsets of the run's own copy of the route loop [m]"
    )
    speed_steps: int = Field(
        2, ge=0, le=5, description="the run's speed is the keys' speed after k presses of q (x1.1) or z (x0.9), |k| <= this"
    )
    visit_range: float = Field(
        0.5, ge=0, le=2, description="a tactile landmark this close to the head [m] is explored (turn, approach, hold)"
    )
    visit_bearing_deg: float = Field(
        90.0, ge=0, le=180, description="... and its nearest point lies at most this far from the heading [deg]"
    )
    touch_gap: float = Field(
        0.06, gt=0, le=0.2, description="an explored landmark is approached until the whiskers touch it and the head is this close [m]"
    )
    hold_cycles: tuple[int, int] = Field((2, 5), description="whisk cycles held at an explored landmark [min, max]")
    detour_count: int = Field(3, ge=1, le=50, description="detours that the off-route share is split into (teleop)")
    # orbit
    orbit_radius: float = Field(1.0, gt=0.1, le=20, description="orbit radius [m] (ViTa-SLAM: 1 m)")
    orbit_centre: tuple[float, float] = Field((0.0, 0.0), description="orbit centre [x, y] [m]")
    # foraging behaviour
    wander_turn_deg: float = Field(20.0, ge=0, description="std of the wandering turn rate [deg/s]")
    explore_time: tuple[float, float] = Field((3.0, 8.0), description="range of the exploration bout length [s]")
    refractory_time: float = Field(4.0, ge=0, description="contacts ignored after leaving an object [s]")
    avoid_margin: float = Field(0.06, ge=0, description="clearance kept between the body and obstacles [m]")
    control_hz: float = Field(10.0, gt=0, le=500, description="controller update rate (rounded to deflection samples) [Hz]")
    # foraging states (ForagingController): gains and thresholds; left out of the run's
    # dump while at their defaults (see _drop_default_foraging_gains)
    wander_turn_time: ForagingGain = Field(
        2.0, gt=0, le=60, description="wander: correlation time of the random turn rate [s]"
    )
    wander_steer_range: ForagingGain = Field(
        0.05, ge=0, le=1, description="wander: steer away from an obstacle this close to the point 0.15 m beyond the snout [m]"
    )
    wander_steer_gain: ForagingGain = Field(
        1.5, ge=0, le=20, description="wander: turn rate per radian of that obstacle's escape direction [1/s]"
    )
    contact_weight: ForagingGain = Field(
        0.3, gt=0, le=1, description="orient, explore: weight of the newest contacts' centroid in the attended point per tick"
    )
    orient_turn_gain: ForagingGain = Field(
        3.0, gt=0, le=20, description="orient: turn rate per radian of bearing to the attended point [1/s]"
    )
    orient_slow_share: ForagingGain = Field(
        0.15, gt=0, le=1, description="orient: share of that turn rate left when the attended point is at the snout"
    )
    orient_back_gain: ForagingGain = Field(
        1.5, ge=0, le=20, description="orient: backing speed per metre the attended point is inside the head's turning reach [1/s]"
    )
    orient_back_speed: ForagingGain = Field(0.08, ge=0, le=0.5, description="orient: largest backing speed [m/s]")
    orient_done_deg: ForagingGain = Field(
        15.0, gt=0, le=90, description="orient: bearing of the attended point at which exploring starts [deg]"
    )
    explore_bearing_deg: ForagingGain = Field(
        25.0, ge=0, le=90, description="explore: the attended point is kept this far to one side of the heading [deg]"
    )
    explore_reach: ForagingGain = Field(
        0.12, ge=0, le=0.3, description="explore: ... and this far beyond the head's centre, within the whiskers' reach [m]"
    )
    explore_bearing_gain: ForagingGain = Field(
        2.5, ge=0, le=20, description="explore: turn rate per radian of bearing error [1/s]"
    )
    explore_distance_gain: ForagingGain = Field(
        1.5, ge=0, le=50, description="explore: turn rate per metre of distance error [rad/(s m)]"
    )
    explore_snout_gain: ForagingGain = Field(
        8.0, ge=0, le=100, description="explore: turn rate away per metre that the head is inside avoid_margin [rad/(s m)]"
    )
    explore_speed_share: ForagingGain = Field(
        0.5, gt=0, le=1, description="explore: largest forward speed, as a share of speed"
    )
    leave_time: ForagingGain = Field(
        1.5, ge=0, le=30, description="leave: shortest time spent turning away and leaving [s]"
    )
    leave_jitter: ForagingGain = Field(
        0.8, ge=0, le=3.1, description="leave: it heads away from the object plus a uniform angle within +-this [rad]"
    )
    leave_turn_gain: ForagingGain = Field(
        3.0, gt=0, le=20, description="leave: turn rate per radian of heading error [1/s]"
    )
    leave_drive_deg: ForagingGain = Field(
        45.0, gt=0, le=180, description="leave: heading error below which it drives at speed [deg]"
    )
    leave_done_deg: ForagingGain = Field(
        20.0, gt=0, le=180, description="leave: heading error below which wandering resumes [deg]"
    )
    attend_margin_share: ForagingGain = Field(
        0.5, gt=0, le=1, description="share of avoid_margin that triggers avoid while attending (orient, explore, leave)"
    )
    avoid_release_gap: ForagingGain = Field(
        0.04, ge=0, le=0.5, description="avoid: ends when the body and head are avoid_margin + this clear [m] ..."
    )
    avoid_release_ahead: ForagingGain = Field(
        0.1, ge=0, le=1, description="avoid: ... and nothing is this close to the point 0.15 m beyond the snout [m]"
    )
    avoid_turn_gain: ForagingGain = Field(
        3.0, gt=0, le=20, description="avoid: turn rate per radian of error to the escape heading [1/s]"
    )
    avoid_drive_deg: ForagingGain = Field(
        30.0, gt=0, le=180, description="avoid: heading error below which it drives off [deg]"
    )
    avoid_speed_share: ForagingGain = Field(
        0.5, gt=0, le=1, description="avoid: largest escape speed, as a share of speed"
    )
    back_off_speed: ForagingGain = Field(
        0.05, ge=0, le=0.5, description="avoid, leave, safety guard: speed of backing away from an obstacle [m/s]"
    )
    guard_margin_share: ForagingGain = Field(
        0.25, gt=0, le=1, description="safety guard: no command may bring the body or head closer than this share of avoid_margin"
    )

    @model_serializer(mode="wrap")
    def _drop_default_foraging_gains(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """The dump leaves out foraging gains at their defaults, so that run hashes and cache
        keys of runs recorded before the gains were settings stay valid (the defaults are the
        constants those runs used). Changing a gain's default therefore needs a
        SIMULATOR_VERSION bump."""
        data = handler(self)
        for name, field in type(self).model_fields.items():
            if FORAGING_GAIN in field.metadata and getattr(self, name) == field.default:
                del data[name]
        return data

    @model_validator(mode="before")
    @classmethod
    def _teleop_speed(cls, data: Any) -> Any:
        """A teleop run's default speed is the keys' nominal speed."""
        if isinstance(data, dict) and data.get("kind") == "teleop" and "speed" not in data:
            return {**data, "speed": TELEOP_SPEED}
        return data

    @model_validator(mode="after")
    def _check(self) -> RunSpec:
        lo, hi = self.explore_time
        if not 0 < lo <= hi:
            raise ValueError("explore_time must be [min, max] with 0 < min <= max")
        lo, hi = self.hold_cycles
        if not 1 <= lo <= hi:
            raise ValueError("hold_cycles must be [min, max] with 1 <= min <= max")
        return self


@dataclass
class Observation:
    """What a controller sees at a control tick."""

    time: float
    pose: np.ndarray  #: (3,) x, y, yaw
    contacts: np.ndarray  #: (k, 3) whisker contact points (world frame) at this tick
    deflection: np.ndarray  #: (24,) |xy| per whisker [rad]


class _OU:
    """Ornstein-Uhlenbeck process with stationary std ``sigma`` and time constant ``tau``."""

    def __init__(self, rng: np.random.Generator, sigma: float, tau: float, x0: float | None = None) -> None:
        self.rng, self.sigma, self.tau = rng, sigma, tau
        self.x = float(rng.normal(0.0, sigma)) if x0 is None else x0

    def step(self, dt: float) -> float:
        a = math.exp(-dt / self.tau)
        self.x = a * self.x + self.sigma * math.sqrt(1 - a * a) * float(self.rng.normal())
        return self.x


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class _Limiter:
    """Rate-limits each command component (so the base accelerates smoothly and whisker
    inertial noise stays low): ``limits`` are the largest changes per second."""

    def __init__(self, *limits: float) -> None:
        self.limits = np.asarray(limits, dtype=float)
        self.state = np.zeros(len(limits))

    def __call__(self, *command: float, dt: float) -> tuple[float, ...]:
        step = self.limits * dt
        self.state += np.clip(np.asarray(command, dtype=float) - self.state, -step, step)
        return tuple(float(c) for c in self.state)


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

    def __init__(self, spec: RunSpec, attention: Attention) -> None:
        self.spec, self.attention = spec, attention
        self.max_turn = math.radians(spec.max_turn_rate_deg)

    def enter(self, s: Surroundings) -> None:
        """Called when the controller switches to this state."""

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
        if s.ahead_distance < spec.wander_steer_range and not len(s.contacts):
            w += spec.wander_steer_gain * _wrap(math.atan2(s.ahead_escape[1], s.ahead_escape[0]) - s.yaw)
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
        attention.follow(s, spec.contact_weight)
        err = attention.bearing(s)
        reach = HEAD_CENTRE + HEAD_RADIUS + spec.avoid_margin
        dist = attention.distance(s)
        v = float(np.clip(spec.orient_back_gain * (dist - reach), -spec.orient_back_speed, 0.0))
        slow = float(np.clip((dist - HEAD_REACH) / (reach - HEAD_REACH), spec.orient_slow_share, 1.0))
        w = self._turn(spec.orient_turn_gain * err * slow)
        return (v, w), "facing" if abs(err) < math.radians(spec.orient_done_deg) else ""


class Explore(ForagingState):
    """Contour following for a bout of ``explore_time`` (uniform): keep the attended point
    ``explore_bearing_deg`` to one side (chosen at random) and ``explore_reach`` beyond the
    head's centre, turning at ``explore_bearing_gain`` x bearing error + ``explore_distance_gain``
    x distance error (x side), and ``explore_snout_gain`` x intrusion away from the object when
    the head is within ``avoid_margin``; forward speed ``explore_speed_share`` x ``speed``,
    ramped down to 0 as the head's clearance falls to a quarter of ``avoid_margin``."""

    name = "explore"

    def __init__(self, spec: RunSpec, attention: Attention, rng: np.random.Generator) -> None:
        super().__init__(spec, attention)
        self.rng = rng
        self.until = 0.0  #: end of the bout [s]

    def enter(self, s: Surroundings) -> None:
        lo, hi = self.spec.explore_time
        self.until = s.time + float(self.rng.uniform(lo, hi))
        self.attention.side = float(self.rng.choice([-1.0, 1.0]))

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec, attention = self.spec, self.attention
        attention.follow(s, spec.contact_weight)
        if s.time >= self.until:
            return None, "bout over"
        side, margin = attention.side, spec.avoid_margin
        err = _wrap(attention.bearing(s) - side * math.radians(spec.explore_bearing_deg))
        reach_err = attention.distance(s) - (HEAD_CENTRE + spec.explore_reach)
        w = spec.explore_bearing_gain * err + spec.explore_distance_gain * reach_err * side
        if s.head_gap < margin:  # snout too close: steer away from the object's side
            w -= side * spec.explore_snout_gain * (margin - s.head_gap)
        v = spec.explore_speed_share * spec.speed * float(np.clip((s.head_gap - 0.25 * margin) / margin, 0.0, 1.0))
        return (v, self._turn(w)), ""


class Leave(ForagingState):
    """Turn to a heading away from the attended point (plus a uniform angle within
    ``leave_jitter``) at ``leave_turn_gain`` x error, driving at ``speed`` once within
    ``leave_drive_deg`` of it (backing at ``back_off_speed`` while the head is within
    ``avoid_margin``); contacts are ignored for ``refractory_time``. After ``leave_time`` and
    within ``leave_done_deg`` of the heading: wander."""

    name = "leave"

    def __init__(self, spec: RunSpec, attention: Attention, rng: np.random.Generator) -> None:
        super().__init__(spec, attention)
        self.rng = rng
        self.until = 0.0  #: earliest end [s]
        self.heading = 0.0  #: the heading it leaves along [rad]

    def enter(self, s: Surroundings) -> None:
        spec = self.spec
        self.until = s.time + spec.leave_time
        self.attention.refractory_until = s.time + spec.refractory_time
        away = s.pos - self.attention.target
        self.heading = math.atan2(away[1], away[0]) + float(self.rng.uniform(-spec.leave_jitter, spec.leave_jitter))

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec = self.spec
        err = _wrap(self.heading - s.yaw)
        w = self._turn(spec.leave_turn_gain * err)
        v = 0.0 if abs(err) > math.radians(spec.leave_drive_deg) else spec.speed
        if s.head_gap < spec.avoid_margin:
            v = -spec.back_off_speed
        done = s.time >= self.until and abs(err) < math.radians(spec.leave_done_deg)
        return (v, w), "turned away" if done else ""


class Avoid(ForagingState):
    """Entered from any state when the body or head comes closer than ``avoid_margin`` (while
    attending: ``attend_margin_share`` of it). Turn to the free-most escape heading at
    ``avoid_turn_gain`` x error; within ``avoid_drive_deg`` of it drive off at up to
    ``avoid_speed_share`` x ``speed`` (ramped from 0 at half the margin; blocked: pick another
    heading), otherwise back at ``back_off_speed`` when within half the margin. Clear by
    ``avoid_release_gap`` beyond the margin with the probe ahead ``avoid_release_ahead`` free:
    wander."""

    name = "avoid"

    def __init__(self, spec: RunSpec, attention: Attention, obstacles: ObstacleMap) -> None:
        super().__init__(spec, attention)
        self.obstacles = obstacles
        self.heading = 0.0  #: the escape heading [rad]

    def enter(self, s: Surroundings) -> None:
        self.heading = self._escape_heading(s.pos, s.yaw)

    def _escape_heading(self, pos: np.ndarray, yaw: float) -> float:
        """The free-most of 12 headings (probed where the head would be), preferring small turns."""
        cand = yaw + np.radians(np.arange(12) * 30.0)
        probes = pos[None] + HEAD_CENTRE * np.stack([np.cos(cand), np.sin(cand)], axis=1)
        clear = self.obstacles.distance_many(probes)
        turn = np.abs((np.arange(12) * 30.0 + 180.0) % 360.0 - 180.0)
        score = np.minimum(clear, HEAD_RADIUS + 0.25) - 1e-3 * turn  # free enough -> the smallest turn wins
        return float(cand[int(np.argmax(score))])

    def step(self, s: Surroundings) -> tuple[Command | None, str]:
        spec = self.spec
        margin = spec.avoid_margin
        if s.clearance >= margin + spec.avoid_release_gap and s.ahead_distance > spec.avoid_release_ahead:
            return None, "clear"
        err = _wrap(self.heading - s.yaw)
        if abs(err) < math.radians(spec.avoid_drive_deg):
            v = spec.avoid_speed_share * spec.speed * float(np.clip((s.head_gap - 0.5 * margin) / margin, 0.0, 1.0))
            if v == 0.0:  # blocked in this direction too: look for another way out
                self.heading = self._escape_heading(s.pos, s.yaw + math.pi / 6)
        else:
            v = -spec.back_off_speed if s.clearance < 0.5 * margin else 0.0  # make room to turn
        return (v, self._turn(spec.avoid_turn_gain * err)), ""


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

    spec: RunSpec
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
        self._wander = _OU(self.rng, math.radians(spec.wander_turn_deg), spec.wander_turn_time, x0=0.0)
        self._limit = _Limiter(spec.max_accel, 4.0)
        self._guard = SafetyGuard(self.obstacles, spec.guard_margin_share * spec.avoid_margin)
        self.headway = Headway()  #: is the robot getting anywhere?
        self._last_t: float | None = None

    def start_pose(self, default: tuple[float, float, float]) -> tuple[float, float, float]:
        x, y, yaw = self.spec.start if self.spec.start is not None else default
        return (x, y, math.radians(yaw))

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
        margin = self.spec.avoid_margin * (self.spec.attend_margin_share if self.mode in ATTENDING else 1.0)
        too_close = self.mode != "avoid" and s.clearance < margin
        if too_close:
            state = self._switch("too close", s)
        elif self.headway.stalled(s.pose, s.time):
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
        back = -self.spec.back_off_speed
        ways_out = [(back, w), (back, 0.0), (v, 0.0), (0.0, -w), (-back, 0.0)]
        candidates = [(v, w, 0.0)] + [(a, b, 0.0) for a, b in ways_out if (a, b) != (0.0, 0.0)]  # not standing yet
        v, w, _ = self._guard.first_safe(pose, candidates)
        return self._limit(v, w, dt=dt)


@dataclass
class RouteFollower:
    """Pure pursuit along a closed route with seeded pose, heading and speed noise; facing the
    direction of travel, or (``outward`` given) driven sideways with the camera facing away
    from that point."""

    spec: RunSpec
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


#: directions [deg] of the translation keys in the robot frame (0: forward, 90: left)
_TRANSLATION_KEYS = {"i": 0.0, "U": 45.0, "J": 90.0, "M": 135.0, ",": 180.0, ">": -135.0, "L": -90.0, "O": -45.0}
_TAP = 0.2  #: a key tapped where holding it would be unsafe: pressed this long [s]
_STANDING = 0.02  #: the base counts as standing below this speed [m/s]
_HOLD_PATIENCE = 3  #: a hold waiting for its contacts ends after this many whisk cycles per contact
_LEAVE_GAP = 0.15  #: after a hold, back off until the head is this far from the landmark [m]
_APPROACH_TIMEOUT = 12.0  #: an exploration that has not reached its landmark by then is given up [s]
_TURN_CLEARANCE = 0.02  #: the driver turns towards a landmark only as far as the head stays this clear [m]
_MAKE_ROOM = 0.3  #: where the head cannot swing round to face a landmark, back away up to this far first [m]
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

    def __init__(self, spec: RunSpec, env: EnvironmentSpec, rng: np.random.Generator, sample_period: float) -> None:
        self.spec, self.rng, self.obstacles = spec, rng, env.obstacles
        self.guard = SafetyGuard(env.obstacles, 0.25 * spec.avoid_margin, braking=spec.max_accel)
        self.centre = np.mean(env.route, axis=0)
        self.outward = self.centre if env.route_facing == "outward" else None
        k = int(rng.integers(-spec.speed_steps, spec.speed_steps + 1))
        steps = 1.1**k if k >= 0 else 0.9**-k  # q/z scale speed and turn alike
        self.speed, self.turn = spec.speed * steps, TELEOP_TURN * steps
        self.bias = math.radians(spec.heading_bias_deg) * float(np.clip(rng.normal(), -2.0, 2.0))
        self.tolerance = math.radians(spec.heading_tolerance_deg)
        base = Route(env.route)
        jitter = self._smooth_offsets(base)
        self.loop = self._clear_offset_route(base, jitter)
        self.detour = self._clear_offset_route(base, jitter + spec.off_route_offset) if spec.off_route_fraction else None
        self.detours = self._plan_detours(sample_period)
        self.path = self.loop
        self.s = float(rng.uniform(0.0, self.loop.length))
        self.tactile = [i for i, lm in enumerate(env.landmarks) if lm.tactile]
        self.visited: dict[int, float] = {}  #: landmark -> lap count when it was explored
        self.mode, self.turning = "drive", False
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
        return [k for k in sorted(off, key=off.get) if off[k] < math.pi / 2]

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
        """The key to press next and how long (inf: until the next decision)."""
        pos, yaw = pose[:2], float(pose[2])
        if self.mode != "drive":
            self.headway.restart(pose, t)
        if self.mode == "hold":
            self.contacts_left -= int(self.touched)
            if self.contacts_left > 0 and t < self.until:
                if self.touched:
                    return "k", math.inf
                bearing = self._bearing(pose, self.target_landmark)
                return self._pick(pose, self._translation_keys(bearing)[:3], hold=False)  # tap back onto it
            self.mode, self.until = "leave", t + 6.0
        if self.mode == "leave":
            if self._landmark_gaps(pose)[self.target_landmark] < _LEAVE_GAP and t < self.until:
                away = self._bearing(pose, self.target_landmark) + math.pi
                return self._pick(pose, self._translation_keys(away))
            self.mode = "drive"
        if self.mode == "approach":
            i = self.target_landmark
            bearing = self._bearing(pose, i)
            if t >= self.until:  # could not get there: give up
                self.mode, self.until = "leave", t + 6.0
                return "k", math.inf
            gap = self._landmark_gaps(pose)[i]
            whisking = self.touched and gap <= self.spec.touch_gap
            if abs(bearing) > 0.5 * self.tolerance and not whisking:  # face it
                room = self._room_to_turn(pose, bearing)
                cramped = abs(room) < abs(bearing) - 0.5 * self.tolerance
                if cramped and np.linalg.norm(pos - self.approach_from) < _MAKE_ROOM:  # back away first
                    key, duration = self._pick(pose, self._translation_keys(bearing + math.pi)[:3])
                    if key != "k":
                        return key, duration
                if abs(room) > 0.5 * self.tolerance:  # as far as the head can swing round here
                    key, duration = self._pick(pose, [self._turn_key(room)])
                    if key != "k":
                        return key, duration
            if not whisking:
                # then drive up to it until the whiskers touch it, and as close as touch_gap
                key, duration = self._pick(pose, self._translation_keys(bearing)[:3])
                if key != "k":
                    return key, duration
                if not self._standing():  # stop first: from standstill, taps may still be safe
                    return "k", math.inf
                if not self.touched:  # no closer, and the whiskers do not reach it: go on
                    self.mode, self.until = "leave", t + 6.0
                    return "k", math.inf
            lo, hi = self.spec.hold_cycles
            self.contacts_left = int(self.rng.integers(lo, hi + 1)) - int(self.touched)
            self.mode, self.until = "hold", t + _HOLD_PATIENCE * self.contacts_left * self.sample_period
            return "k", math.inf
        # ---- drive along the path (the loop or, in a detour window, the offset loop)
        path = self.detour if self.detour is not None and self.in_detour(t) else self.loop
        if path is not self.path:
            self._switch_path(path)
        self._progress(pos)
        if path is self.loop and self._start_visit(t, pose):
            return self._decide(t, pose)
        direction = self._path_direction(pose)
        err = _wrap(self._facing(pos) - yaw)
        self.turning = abs(err) > (0.5 if self.turning else 1.0) * self.tolerance
        translation = self._translation_keys(direction)
        if not self.turning:
            ranked = translation
        elif self.outward is None and abs(err) < 3 * self.tolerance and translation[:1] == ["i"]:
            ranked = ["u" if err > 0 else "o", self._turn_key(err), *translation]  # forward and turn
        else:
            ranked = [self._turn_key(err), *translation]
        stalled = self.headway.stalled(pose, t)
        key, duration = self._pick(pose, ranked)
        if (key == "k" and self._standing()) or stalled:
            return self._way_round(pose)
        return key, duration

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
        gaps = self._landmark_gaps(pose)
        ahead = self.path.point(self.s + ROUTE_LOOKAHEAD)[0]
        gaps_ahead = self._landmark_gaps(np.array([*ahead, self._facing(ahead)]))
        laps = self.s / self.path.length
        for i in sorted(self.tactile, key=lambda j: gaps[j]):
            if gaps[i] > self.spec.visit_range:
                break
            passing = gaps_ahead[i] >= gaps[i] and laps - self.visited.get(i, -math.inf) >= 0.5
            if passing and abs(self._bearing(pose, i)) <= math.radians(self.spec.visit_bearing_deg):
                self.visited[i] = laps
                self.mode, self.target_landmark, self.until = "approach", i, t + _APPROACH_TIMEOUT
                self.approach_from = pose[:2].copy()
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


def make_controller(
    env: EnvironmentSpec, spec: RunSpec, rng: np.random.Generator, sample_period: float = 0.5
) -> tuple[ForagingController | TeleopDriver | RouteFollower, tuple[float, float, float]]:
    """The controller for ``spec.kind`` and its start pose ``(x, y, yaw_rad)``; ``sample_period``
    [s] (one whisk cycle) places the off-route part (route, orbit: at the end of the run;
    teleop: its detours) and sets the teleoperator's hold times."""
    if spec.kind == "foraging":
        ctrl = ForagingController(spec, env.obstacles, rng)
        return ctrl, ctrl.start_pose(env.start)
    if spec.kind in ("teleop", "route") and not env.route:
        raise ValueError(f"environment {env.name!r} has no route: a {spec.kind!r} run needs route waypoints")
    if spec.kind == "teleop":
        driver = TeleopDriver(spec, env, rng, sample_period)
        return driver, driver.start_pose()
    off_from = (spec.warmup_cycles + (1.0 - spec.off_route_fraction) * spec.n_samples) * sample_period
    off_from = off_from if spec.off_route_fraction > 0 else math.inf
    if spec.kind == "orbit":
        phi = np.radians(np.arange(0.0, 360.0, 5.0))
        centre = np.asarray(spec.orbit_centre, dtype=float)
        circle = centre + spec.orbit_radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)
        ctrl = RouteFollower(spec, Route(circle), env.obstacles, rng, off_from, outward=centre)
        return ctrl, ctrl.start_pose()
    outward = np.mean(env.route, axis=0) if env.route_facing == "outward" else None
    ctrl = RouteFollower(spec, Route(env.route), env.obstacles, rng, off_from, outward)
    return ctrl, ctrl.start_pose()
