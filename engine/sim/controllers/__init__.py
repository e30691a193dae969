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
gains and thresholds are the foraging run's nested ``gains`` (`ForagingGains`,
docs/SCENARIOS.md), defaulting to the values the controller always used.

Teleoperation (``teleop``, `TeleopDriver`): ViTa-SLAM's keyboard teleoperation emulated -
one key at a time from its key set, stop-and-go, along the run's own jittered copy of the
environment's loop from a random start, exploring the tactile landmarks it passes. Its modes
(`Drive`, `Approach`, `Hold`, `Leave`: `TeleopMode`) switch by `TELEOP_TRANSITIONS`, as the
foraging states do. Foraging and teleop share one look-ahead `SafetyGuard` that keeps the
body and the head off obstacles.

Station drives (``stations``, `StationDriver`): the same teleoperator, whisking the same K
tactile stations (each derived from a named landmark: `stations_of`) in every drive, from
jittered approach poses, so that a touched query has a touched true match.

Landmark visits (``visits``, `VisitsController`, training runs): foraging that breaks off,
for ``visit_share`` of the run's time, to whisk the tactile landmark nearest the robot as a
station drive does (`Visitor`, the station driver), from an approach pose drawn per visit.

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

The package, one module per concern: `common` (the `Observation`, noise, the rate limiter),
`safety` (`SafetyGuard`, `Headway`), `settings` (the run settings per kind: `RunSpec`,
`run_spec`, `key_form`), `foraging`, `teleop` (the driver and its modes), `stations` (the station
driver, its stations), `visits` (foraging with landmark visits), `route` (route and orbit),
`factory` (`make_controller`). This module re-exports their public names.
"""

from vitaplace.engine.sim.controllers.common import HEAD_REACH, Observation
from vitaplace.engine.sim.controllers.factory import make_controller
from vitaplace.engine.sim.controllers.foraging import (
    ATTENDING,
    PROBE_AHEAD,
    TRANSITIONS,
    Attention,
    Avoid,
    Explore,
    ForagingController,
    ForagingState,
    Leave,
    Orient,
    Surroundings,
    Wander,
)
from vitaplace.engine.sim.controllers.route import RouteFollower
from vitaplace.engine.sim.controllers.safety import Headway, SafetyGuard
from vitaplace.engine.sim.controllers.settings import (
    RENAMED_RUN_KEYS,
    RUN_KINDS,
    TELEOP_SPEED,
    V6_DEFAULTS,
    ForagingGains,
    ForagingRun,
    OrbitRun,
    RouteRun,
    RunSpec,
    StationsRun,
    TeleopRun,
    VisitsRun,
    key_form,
    legacy_gain_paths,
    nest_legacy_gains,
    recorded_run_spec,
    rename_legacy_run_keys,
    run_spec,
)
from vitaplace.engine.sim.controllers.stations import (
    STATION_TRANSITIONS,
    Station,
    StationDriver,
    ToStation,
    stations_of,
)
from vitaplace.engine.sim.controllers.teleop import (
    TELEOP_KEYS,
    TELEOP_TRANSITIONS,
    TELEOP_TURN,
    Approach,
    Drive,
    Hold,
    TeleopDriver,
    TeleopMode,
)
from vitaplace.engine.sim.controllers.visits import Visitor, VisitsController

__all__ = ["RunSpec", "Observation", "ForagingController", "RouteFollower", "TeleopDriver", "make_controller",
           "SafetyGuard", "Headway", "Surroundings", "Attention", "ForagingState", "Wander", "Orient", "Explore",
           "Leave", "Avoid", "TRANSITIONS", "ATTENDING", "PROBE_AHEAD", "HEAD_REACH", "TELEOP_KEYS", "TELEOP_TURN",
           "TELEOP_SPEED", "ForagingGains", "ForagingRun", "TeleopRun", "RouteRun", "OrbitRun",
           "run_spec", "recorded_run_spec", "key_form", "legacy_gain_paths", "nest_legacy_gains",
           "rename_legacy_run_keys", "RENAMED_RUN_KEYS", "RUN_KINDS", "V6_DEFAULTS",
           "TeleopMode", "Drive", "Approach", "Hold", "TELEOP_TRANSITIONS", "StationsRun", "StationDriver", "Station",
           "ToStation", "STATION_TRANSITIONS", "stations_of", "VisitsRun", "VisitsController", "Visitor"]
