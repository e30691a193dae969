"""The settings of a run (`RunSpec`)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer, model_validator

#: the teleop keys' nominal speed [m/s] for the WhiskEye (see docs/SIMULATION.md)
TELEOP_SPEED = 0.3

#: marks the `RunSpec` fields that are gains or thresholds of the foraging states
FORAGING_GAIN = object()
ForagingGain = Annotated[float, FORAGING_GAIN]


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
