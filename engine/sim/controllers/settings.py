"""The settings of a run: one model per run kind, a discriminated union on ``kind``.

`RunSpec` names "the settings of a run": `ForagingRun`, `VisitsRun`, `TeleopRun`, `StationsRun`,
`RouteRun` or `OrbitRun`, chosen by ``kind``, each with only the fields its controller (and the
simulation loop) uses; the foraging states' gains and thresholds are the nested
`ForagingGains` (``gains:``). A model's dump is exact: every field, gains included.
`run_spec` builds one from a mapping (``run_spec({"kind": "route", "n_samples": 8})``).

Two older forms are still read:

* a scenario's ``run:`` with the foraging gains at its top level (before ``gains:``): the
  scenario loader moves them under ``gains`` with one warning (`legacy_gain_paths`,
  `nest_legacy_gains`);
* the settings stored in run files recorded before the split (one flat dict holding the
  fields of every kind): `recorded_run_spec` nests the gains and leaves out the fields that
  do not belong to the run's kind (they never had an effect on it).

Cache keys and run hashes are computed from `key_form`: the version-6 key format, i.e. the
flat dict the single ``RunSpec`` of simulator version 6 dumped - the run's own fields, the
fields of the other kinds at their `V6_DEFAULTS`, and the foraging gains that differ from
their defaults (those at their defaults were left out, so that keys of runs recorded
before the gains were settings stayed valid) - with the run's ``condition`` added only when
it changes something (`is_default`). So every key computed before the split is
unchanged; changing a default therefore needs a SIMULATOR_VERSION bump.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, TypeAdapter, model_validator

from vitaplace.engine.base.configfile import Degrees, NumbersNotBooleans
from vitaplace.engine.sim.condition import Condition, is_default

__all__ = ["RunSpec", "ForagingGains", "ForagingRun", "VisitsRun", "TeleopRun", "StationsRun", "RouteRun", "OrbitRun",
           "run_spec", "recorded_run_spec", "key_form", "rename_legacy_run_keys", "RENAMED_RUN_KEYS", "V6_DEFAULTS",
           "TELEOP_SPEED", "RUN_KINDS"]

#: the teleop keys' nominal speed [m/s] for the WhiskEye (see docs/SIMULATION.md)
TELEOP_SPEED = 0.3


class _Settings(NumbersNotBooleans):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ForagingGains(_Settings):
    """The gains and thresholds of the foraging states (`ForagingState`); the defaults are
    the constants the controller always used."""

    wander_turn_time: float = Field(
        2.0, gt=0, le=60, description="wander: correlation time of the random turn rate [s]"
    )
    wander_steer_range: float = Field(
        0.05, ge=0, le=1, description="wander: steer away from an obstacle this close to the point 0.15 m beyond the "
        "snout [m]"
    )
    wander_steer_gain: float = Field(
        1.5, ge=0, le=20, description="wander: turn rate per radian of that obstacle's escape direction [1/s]"
    )
    contact_weight: float = Field(
        0.3, gt=0, le=1, description="orient, explore: weight of the newest contacts' centroid in the attended point "
        "per tick"
    )
    orient_turn_gain: float = Field(
        3.0, gt=0, le=20, description="orient: turn rate per radian of bearing to the attended point [1/s]"
    )
    orient_slow_share: float = Field(
        0.15, gt=0, le=1, description="orient: share of that turn rate left when the attended point is at the snout"
    )
    orient_back_gain: float = Field(
        1.5, ge=0, le=20, description="orient: backing speed per metre the attended point is inside the head's "
        "turning reach [1/s]"
    )
    orient_back_speed: float = Field(0.08, ge=0, le=0.5, description="orient: largest backing speed [m/s]")
    orient_done_deg: float = Field(
        15.0, gt=0, le=90, description="orient: bearing of the attended point at which exploring starts [deg]"
    )
    explore_bearing_deg: float = Field(
        25.0, ge=0, le=90, description="explore: the attended point is kept this far to one side of the heading [deg]"
    )
    explore_reach: float = Field(
        0.12, ge=0, le=0.3, description="explore: ... and this far beyond the head's centre, within the whiskers' "
        "reach [m]"
    )
    explore_bearing_gain: float = Field(
        2.5, ge=0, le=20, description="explore: turn rate per radian of bearing error [1/s]"
    )
    explore_distance_gain: float = Field(
        1.5, ge=0, le=50, description="explore: turn rate per metre of distance error [rad/(s m)]"
    )
    explore_snout_gain: float = Field(
        8.0, ge=0, le=100, description="explore: turn rate away per metre that the head is inside avoid_margin "
        "[rad/(s m)]"
    )
    explore_speed_share: float = Field(
        0.5, gt=0, le=1, description="explore: largest forward speed, as a share of speed"
    )
    leave_time: float = Field(
        1.5, ge=0, le=30, description="leave: shortest time spent turning away and leaving [s]"
    )
    leave_jitter: float = Field(
        0.8, ge=0, le=3.1, description="leave: it heads away from the object plus a uniform angle within +-this [rad]"
    )
    leave_turn_gain: float = Field(
        3.0, gt=0, le=20, description="leave: turn rate per radian of heading error [1/s]"
    )
    leave_drive_deg: float = Field(
        45.0, gt=0, le=180, description="leave: heading error below which it drives at speed [deg]"
    )
    leave_done_deg: float = Field(
        20.0, gt=0, le=180, description="leave: heading error below which wandering resumes [deg]"
    )
    attend_margin_share: float = Field(
        0.5, gt=0, le=1, description="share of avoid_margin that triggers avoid while attending (orient, explore, "
        "leave)"
    )
    avoid_release_gap: float = Field(
        0.04, ge=0, le=0.5, description="avoid: ends when the body and head are avoid_margin + this clear [m] ..."
    )
    avoid_release_ahead: float = Field(
        0.1, ge=0, le=1, description="avoid: ... and nothing is this close to the point 0.15 m beyond the snout [m]"
    )
    avoid_turn_gain: float = Field(
        3.0, gt=0, le=20, description="avoid: turn rate per radian of error to the escape heading [1/s]"
    )
    avoid_drive_deg: float = Field(
        30.0, gt=0, le=180, description="avoid: heading error below which it drives off [deg]"
    )
    avoid_speed_share: float = Field(
        0.5, gt=0, le=1, description="avoid: largest escape speed, as a share of speed"
    )
    back_off_speed: float = Field(
        0.05, ge=0, le=0.5, description="avoid, leave, safety guard: speed of backing away from an obstacle [m/s]"
    )
    guard_margin_share: float = Field(
        0.25, gt=0, le=1, description="safety guard: no command may bring the body or head closer than this share of "
        "avoid_margin"
    )


class _Run(_Settings):
    """The settings every kind of run has. Only ``kind`` and ``n_samples`` are required."""

    kind: str = Field(description="the run's kind (each kind's model narrows it to its own name)")
    n_samples: int = Field(gt=0, description="samples (whisk cycles) to record")
    speed: float = Field(0.15, gt=0, le=1.0, description="nominal forward speed [m/s]")
    max_accel: float = Field(0.5, gt=0, description="linear acceleration limit [m/s^2]")
    warmup_cycles: int = Field(1, ge=0, le=100, description="whisk cycles simulated before the first sample")
    start: tuple[float, float, Degrees] | None = Field(
        None, description="start pose [x, y, yaw_deg]; default: the environment's start (foraging) or the route start"
    )
    avoid_margin: float = Field(
        0.06, ge=0, description="clearance kept between the body and obstacles [m] (teleop: its safety guard keeps a "
        "quarter of it)"
    )
    control_hz: float = Field(
        10.0, gt=0, le=500, description="controller update rate (rounded to deflection samples) [Hz]"
    )
    condition: Condition | None = Field(
        None, description="the lighting and camera state the run is recorded under (docs/SIMULATION.md, Conditions); "
        "null: the environment's lights and a clean camera"
    )


class _OffPath(_Run):
    """The fields of the kinds that follow a path (teleop, route, orbit)."""

    lookahead: float = Field(0.3, gt=0.05, le=2.0, description="pure-pursuit lookahead distance [m]")
    off_route_fraction: float = Field(
        0.0, ge=0, le=0.9, description="share of the run driven off the path (not revisits): route and orbit at the "
        "end, teleop in detours"
    )
    off_route_offset: float = Field(
        0.6, ge=-3, le=3, description="how far off the path that part runs: left of travel, or towards the orbit's "
        "centre [m]"
    )


class _Foraging(_Run):
    """The fields of the kinds that forage (foraging, visits): `ForagingController`."""

    max_turn_rate_deg: float = Field(90.0, gt=0, le=720, description="turn-rate limit [deg/s]")
    wander_turn_deg: float = Field(20.0, ge=0, description="std of the wandering turn rate [deg/s]")
    explore_time: tuple[float, float] = Field((3.0, 8.0), description="range of the exploration bout length [s]")
    refractory_time: float = Field(4.0, ge=0, description="contacts ignored after leaving an object [s]")
    gains: ForagingGains = Field(
        ForagingGains(), description="gains and thresholds of the foraging states (wander, orient, explore, leave, "
        "avoid)"
    )

    @model_validator(mode="after")
    def _check(self) -> _Foraging:
        lo, hi = self.explore_time
        if not 0 < lo <= hi:
            raise ValueError("explore_time must be [min, max] with 0 < min <= max")
        return self


class ForagingRun(_Foraging):
    """Tactile-attention foraging (training runs): `ForagingController`."""

    kind: Literal["foraging"] = Field(description="foraging: tactile-attention exploration (training)")


def _check_hold(hold_cycles: tuple[int, int], n_samples: int) -> None:
    """A ValueError naming ``hold_cycles`` unless 1 <= min <= max and min <= ``n_samples``."""
    lo, hi = hold_cycles
    if not 1 <= lo <= hi:
        raise ValueError("hold_cycles must be [min, max] with 1 <= min <= max")
    if lo > n_samples:  # a long maximum shows as the stuck-run warning (a quarter of the run)
        raise ValueError(f"hold_cycles: every hold ({lo} whisk cycles at least) is longer than the run's "
                         f"{n_samples} samples; expected min <= n_samples")


class _Teleoperated(_OffPath):
    """The fields of the kinds an emulated keyboard teleoperator drives (teleop, stations):
    its keys, its own copy of the route, its approaches to landmarks and its detours."""

    speed: float = Field(TELEOP_SPEED, gt=0, le=1.0, description="the keys' nominal speed [m/s]")
    decision_interval: float = Field(0.5, gt=0, le=5, description="how often the teleoperator reconsiders its key [s]")
    reaction_delay: float = Field(
        0.25, ge=0, le=2, description="from a decision to the new key's press; the robot stands meanwhile [s]"
    )
    turn_threshold_deg: float = Field(
        10.0, gt=0, le=90, description="heading error the teleoperator lets pass before it turns [deg] "
        "(before: heading_tolerance_deg, a name the ground truth's gate also had)"
    )
    heading_bias_deg: float = Field(5.0, ge=0, le=45, description="std of the run's constant heading bias [deg]")
    path_jitter: float = Field(
        0.08, ge=0, le=0.5, description="std of the smooth offsets of the run's own copy of the route loop [m]"
    )
    speed_steps: int = Field(
        2, ge=0, le=5, description="the run's speed is the keys' speed after k presses of q (x1.1) or z (x0.9), "
        "|k| <= this"
    )
    touch_gap: float = Field(
        0.06, gt=0, le=0.2, description="an explored landmark is approached until the whiskers touch it and the head "
        "is this close [m]"
    )
    hold_cycles: tuple[int, int] = Field((2, 5), description="whisk cycles held at an explored landmark [min, max]")
    detour_count: int = Field(3, ge=1, le=50, description="detours that the off-route share is split into")

    @model_validator(mode="after")
    def _check(self) -> _Teleoperated:
        _check_hold(self.hold_cycles, self.n_samples)
        if self.off_route_fraction > 0 and self.detour_count > self.n_samples:
            raise ValueError(f"detour_count: {self.detour_count} detours in a run of {self.n_samples} samples; "
                             "expected at most n_samples")
        return self


class TeleopRun(_Teleoperated):
    """An emulated keyboard teleoperator driving its own copy of the environment's route and
    whisking its landmarks (evaluation runs: independent drives): `TeleopDriver`."""

    kind: Literal["teleop"] = Field(description="teleop: an emulated keyboard teleoperator (evaluation)")
    visit_range: float = Field(
        0.5, ge=0, le=2, description="a tactile landmark this close to the head [m] is explored (turn, approach, hold)"
    )
    visit_bearing_deg: float = Field(
        90.0, ge=0, le=180, description="... and its nearest point lies at most this far from the heading [deg]"
    )


class StationsRun(_Teleoperated):
    """The teleoperator of `TeleopRun` whisking K tactile stations, the same for every drive
    in the environment, from jittered approach poses instead of the landmarks it happens to
    pass: `StationDriver` (docs/SIMULATION.md, "Station drives")."""

    kind: Literal["stations"] = Field(description="stations: the teleoperator whisks the same K tactile stations "
                                      "in every drive (evaluation)")
    station_landmarks: list[str] | None = Field(
        None, min_length=1, description="names of the landmarks whose stations are whisked (tactile landmarks of the "
        "environment); null: every tactile landmark, in the environment's order"
    )
    station_count: int | None = Field(
        None, ge=1, description="K: the first K of those stations are whisked; null: all of them"
    )
    station_jitter: float = Field(
        0.05, ge=0, le=0.5, description="each approach starts within this distance of its station's point, uniform "
        "in the disc (drawn per visit) [m]"
    )
    station_heading_jitter_deg: float = Field(
        5.0, ge=0, le=45, description="each approach faces the landmark's nearest point plus a uniform angle within "
        "+-this (drawn per visit) [deg]"
    )
    hold_cycles: tuple[int, int] = Field(
        (4, 6), description="whisk cycles with contact held at each station [min, max]"
    )
    sample_at: Literal["cycle", "stations"] = Field(
        "cycle", description="cycle: a sample at the end of every whisk cycle of the drive; stations: only of the "
        "cycles held whisking a station (the drive between stations is simulated, not recorded): place recognition "
        "where the robot whisks"
    )

    @model_validator(mode="after")
    def _check_stations(self) -> StationsRun:
        if self.station_landmarks is not None and len(set(self.station_landmarks)) != len(self.station_landmarks):
            raise ValueError(f"station_landmarks must name each landmark once, got {self.station_landmarks}")
        if (self.station_landmarks is not None and self.station_count is not None
                and self.station_count > len(self.station_landmarks)):
            raise ValueError(f"station_count {self.station_count} is more than the {len(self.station_landmarks)} "
                             "landmarks named")
        return self


class VisitsRun(_Foraging):
    """Foraging that breaks off to whisk the environment's tactile landmarks as station drives
    do (training runs): `VisitsController` (docs/SIMULATION.md, "Landmark visits")."""

    kind: Literal["visits"] = Field(description="visits: foraging alternating with station-style visits to the "
                                    "environment's tactile landmarks (training)")
    visit_share: float = Field(
        0.5, gt=0, le=1, description="share of the run's time spent visiting landmarks (driving to the approach "
        "pose, approaching, holding, backing off); the rest is foraging"
    )
    visit_distance: tuple[float, float] = Field(
        (0.1, 0.3), description="each approach starts facing the landmark with the head this far from its outline, "
        "uniform in [min, max] (drawn per visit) [m]"
    )
    visit_spread_deg: float = Field(
        30.0, ge=0, le=180, description="... along a heading within +-this of the robot's when the visit starts, "
        "uniform (drawn per visit) [deg]"
    )
    visit_heading_jitter_deg: float = Field(
        5.0, ge=0, le=45, description="each approach faces the landmark's nearest point plus a uniform angle within "
        "+-this (drawn per visit) [deg]"
    )
    hold_cycles: tuple[int, int] = Field(
        (4, 6), description="whisk cycles with contact held at each landmark, uniform in [min, max] (drawn per visit)"
    )
    touch_gap: float = Field(
        0.06, gt=0, le=0.2, description="a landmark is approached until the whiskers touch it and the head is this "
        "close [m]"
    )

    @model_validator(mode="after")
    def _check_visits(self) -> VisitsRun:
        lo, hi = self.visit_distance
        if not 0 < lo <= hi <= 2:
            raise ValueError("visit_distance must be [min, max] with 0 < min <= max <= 2 [m]")
        _check_hold(self.hold_cycles, self.n_samples)
        return self

    def foraging(self) -> ForagingRun:
        """The settings of its foraging: its own foraging fields."""
        fields = {k: getattr(self, k) for k in ForagingRun.model_fields if k != "kind"}
        return ForagingRun(kind="foraging", **fields)

    def stations(self) -> StationsRun:
        """The settings of its visits: a stations run of the teleoperator's defaults with its
        hold, touch gap and heading jitter (the approach pose is drawn by `VisitsController`)."""
        return StationsRun(kind="stations", n_samples=self.n_samples, max_accel=self.max_accel,
                           avoid_margin=self.avoid_margin, control_hz=self.control_hz, hold_cycles=self.hold_cycles,
                           touch_gap=self.touch_gap, station_jitter=0.0,
                           station_heading_jitter_deg=self.visit_heading_jitter_deg)


class _Laps(_OffPath):
    """The fields of the kinds that drive noisy laps of a loop (route, orbit): `RouteFollower`."""

    max_turn_rate_deg: float = Field(90.0, gt=0, le=720, description="turn-rate limit [deg/s]")
    lateral_noise: float = Field(0.02, ge=0, le=0.2, description="std of the lateral offset from the route [m]")
    heading_noise_deg: float = Field(3.0, ge=0, le=45, description="std of the heading offset [deg]")
    speed_noise: float = Field(0.1, ge=0, le=0.5, description="std of the relative speed change")
    noise_time_constant: float = Field(3.0, gt=0, description="correlation time of the noise processes [s]")
    start_noise: float = Field(0.03, ge=0, le=0.5, description="std of the start position along/across the route [m]")


class RouteRun(_Laps):
    """Noisy laps of the environment's route (near-duplicates of each other, kept for
    regression): `RouteFollower`."""

    kind: Literal["route"] = Field(description="route: noisy laps of the environment's route")


class OrbitRun(_Laps):
    """Noisy laps of a circle, driven sideways with the camera facing outward (ViTa-SLAM's
    evaluation trajectory): `RouteFollower` with ``outward``."""

    kind: Literal["orbit"] = Field(description="orbit: noisy laps of a circle, driven sideways facing outward")
    orbit_radius: float = Field(1.0, gt=0.1, le=20, description="orbit radius [m] (ViTa-SLAM: 1 m)")
    orbit_centre: tuple[float, float] = Field((0.0, 0.0), description="orbit centre [x, y] [m]")


#: the settings of a run: one model per ``kind``
AnyRun = ForagingRun | VisitsRun | TeleopRun | StationsRun | RouteRun | OrbitRun
RunSpec = Annotated[AnyRun, Field(discriminator="kind")]
RUN_KINDS: dict[str, type[_Run]] = {"foraging": ForagingRun, "visits": VisitsRun, "teleop": TeleopRun,
                                     "stations": StationsRun, "route": RouteRun, "orbit": OrbitRun}
_ADAPTER: TypeAdapter[AnyRun] = TypeAdapter(RunSpec)


def run_spec(data: Any = None, **fields: Any) -> AnyRun:
    """The settings of a run from a mapping and/or keywords: ``run_spec(kind="route", n_samples=8)``."""
    return _ADAPTER.validate_python({**(data or {}), **fields})


GAIN_NAMES = tuple(ForagingGains.model_fields)

#: the version-6 key format: the flat dict of the single ``RunSpec`` of simulator version 6
#: held these fields (besides ``kind``, ``n_samples`` and the gains) whatever the kind; a
#: kind without a field gets it at this value in `key_form`
V6_DEFAULTS: dict[str, Any] = {
    "speed": 0.15, "max_turn_rate_deg": 90.0, "max_accel": 0.5, "warmup_cycles": 1, "start": None,
    "lateral_noise": 0.02, "heading_noise_deg": 3.0, "speed_noise": 0.1, "noise_time_constant": 3.0,
    "start_noise": 0.03, "lookahead": 0.3, "off_route_fraction": 0.0, "off_route_offset": 0.6,
    "decision_interval": 0.5, "reaction_delay": 0.25, "heading_tolerance_deg": 10.0, "heading_bias_deg": 5.0,
    "path_jitter": 0.08, "speed_steps": 2, "visit_range": 0.5, "visit_bearing_deg": 90.0, "touch_gap": 0.06,
    "hold_cycles": [2, 5], "detour_count": 3, "orbit_radius": 1.0, "orbit_centre": [0.0, 0.0],
    "wander_turn_deg": 20.0, "explore_time": [3.0, 8.0], "refractory_time": 4.0, "avoid_margin": 0.06,
    "control_hz": 10.0,
}


#: run settings renamed since version 6: old name -> new name (read with a warning; `key_form`
#: writes the old name, so keys stay valid)
RENAMED_RUN_KEYS = {"heading_tolerance_deg": "turn_threshold_deg"}


#: condition keys added after the key format, each with the value that leaves it out of a key
#: (so a condition that does not use one keeps the key it had before the key existed)
CONDITION_ADDED: dict[str, Any] = {"fog": None}


def key_form(run: AnyRun) -> dict[str, Any]:
    """The run's settings in the version-6 key format (JSON values): what cache keys and run
    hashes are computed from. Equal to the old flat dump, so keys stay valid."""
    own = run.model_dump(mode="json", exclude={"gains", "condition"})
    if not is_default(run.condition):
        condition = run.condition.model_dump(mode="json")  # type: ignore[union-attr]
        own["condition"] = {k: v for k, v in condition.items()
                            if not (k in CONDITION_ADDED and v == CONDITION_ADDED[k])}
    for old, new in RENAMED_RUN_KEYS.items():
        if new in own:
            own[old] = own.pop(new)
    flat = {**V6_DEFAULTS, **own}
    if isinstance(run, _Foraging):
        default = ForagingGains()
        flat.update({k: v for k, v in run.gains.model_dump(mode="json").items() if v != getattr(default, k)})
    return flat


def legacy_gain_paths(run: Any) -> list[str]:
    """The foraging gains given at the top level of a ``run:`` mapping (the form before ``gains:``)."""
    return [k for k in GAIN_NAMES if k in run] if isinstance(run, dict) else []


def nest_legacy_gains(run: dict[str, Any]) -> dict[str, Any]:
    """``run`` with its top-level foraging gains moved under ``gains`` (given there too: an error)."""
    moved = {k: run[k] for k in legacy_gain_paths(run)}
    if not moved:
        return run
    nested = run.get("gains") or {}
    both = sorted(set(moved) & set(nested)) if isinstance(nested, dict) else []
    if both:
        raise ValueError(f"{', '.join(both)} given both at the top level and under 'gains': keep only 'gains'")
    rest = {k: v for k, v in run.items() if k not in moved}
    return {**rest, "gains": {**nested, **moved} if isinstance(nested, dict) else nested}


def rename_legacy_run_keys(run: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """``run`` with its settings of an old name (`RENAMED_RUN_KEYS`) under the new one, and the
    old names found; both names at once is a ValueError."""
    found = [old for old in RENAMED_RUN_KEYS if old in run]
    both = [old for old in found if RENAMED_RUN_KEYS[old] in run]
    if both:
        raise ValueError(f"both '{both[0]}' and '{RENAMED_RUN_KEYS[both[0]]}' are set; '{both[0]}' is the old name "
                         f"of '{RENAMED_RUN_KEYS[both[0]]}', keep only '{RENAMED_RUN_KEYS[both[0]]}'")
    return {RENAMED_RUN_KEYS.get(k, k): v for k, v in run.items()}, found


def recorded_run_spec(data: dict[str, Any]) -> AnyRun:
    """The settings stored in a run file (``attrs["run"]``), of any version: the flat dict of
    files recorded before the settings were split per kind has its gains nested and the
    fields of other kinds left out (they had no effect on the run)."""
    data, _ = rename_legacy_run_keys(nest_legacy_gains(dict(data)))
    model = RUN_KINDS.get(data.get("kind"))  # type: ignore[arg-type]
    if model is not None:
        data = {k: v for k, v in data.items() if k in model.model_fields}
    return run_spec(data)
