"""Tests of the station drives (``kind: stations``, `StationDriver`): the stations derived
from named landmarks, two drives visiting and whisking the same stations from their own
starts, collision-free; the settings refused at validate; the four touch worlds."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import ScenarioError
from vitaplace.engine.sim import simulate as simulate_module
from vitaplace.engine.sim.controllers import STATION_TRANSITIONS, make_controller, stations_of
from vitaplace.engine.sim.controllers.stations import AT_STATION, approach_clearance
from vitaplace.engine.sim.environment import load_environment
from vitaplace.engine.sim.robot import RobotSpec
from vitaplace.engine.sim.simulate import run_spec, simulate_run

#: images are not looked at here: a tiny camera saves rendering time
ROBOT = RobotSpec(camera_width=16, camera_height=12)
N = 240  #: samples per drive (120 s): one lap, every station of a touch world once
WORLD = "touch-alike-shapes"
TOUCH_WORLDS = ("touch-alike-boxes", "touch-alike-shapes", "touch-distinct-boxes", "touch-distinct-shapes")
TAU, HEADING_DEG = 0.3, 30.0  #: the default ground truth (scoring.tau, heading_tolerance_deg)


@pytest.fixture(scope="module")
def drives():
    """Two station drives in one touch world (seeds 1 and 2, as an evaluation's query and
    reference), each with the driver that drove it."""
    out = []
    make = simulate_module.make_controller
    env = load_environment(WORLD)
    for seed in (1, 2):
        drivers = []

        def capture(*args, _drivers=drivers, **kwargs):
            controller, start = make(*args, **kwargs)
            _drivers.append(controller)
            return controller, start

        simulate_module.make_controller = capture
        try:
            run = simulate_run(env, run_spec(kind="stations", n_samples=N), seed, ROBOT, progress=False)
        finally:
            simulate_module.make_controller = make
        out.append((run, drivers[0]))
    return env, out


# ---------------------------------------------------------------------- the stations
def test_stations_are_the_loop_points_towards_their_landmarks_facing_their_nearest_points():
    """touch-alike-boxes: four 1 x 1 boxes centred 2.138 m east, north, west and south of the
    centre, their near faces at 1.638 m; its loop (symmetric: centroid at the origin) has the
    waypoints (0.87, 0), (0, 0.87), (-0.87, 0), (0, -0.87) on those axes. So each station is
    that waypoint, facing the face's midpoint straight ahead: 0, 90, 180, -90 deg."""
    env = load_environment("touch-alike-boxes")
    stations = stations_of(env, run_spec(kind="stations", n_samples=5))
    assert [st.name for st in stations] == ["east", "north", "west", "south"]
    expected = [((0.87, 0.0), 0.0), ((0.0, 0.87), 90.0), ((-0.87, 0.0), 180.0), ((0.0, -0.87), -90.0)]
    for st, (point, facing) in zip(stations, expected, strict=True):
        assert st.point == pytest.approx(point, abs=0.006)  # the loop is searched every 1 cm
        assert math.degrees(st.facing) % 360 == pytest.approx(facing % 360, abs=0.5)


def test_stations_and_station_count_choose_the_landmarks_in_the_order_given():
    env = load_environment("e1")
    chosen = stations_of(env, run_spec(kind="stations", n_samples=5, station_landmarks=["cyl_south", "box_east"]))
    assert [st.name for st in chosen] == ["cyl_south", "box_east"]
    first = stations_of(env,
                        run_spec(kind="stations", n_samples=5, station_landmarks=["cyl_south", "box_east"],
                                 station_count=1))
    assert [st.name for st in first] == ["cyl_south"]
    every = stations_of(env, run_spec(kind="stations", n_samples=5, station_count=2))
    assert [st.name for st in every] == ["box_east", "box_west"]  # the tactile landmarks, in the file's order


@pytest.mark.parametrize("name", TOUCH_WORLDS)
def test_every_station_of_a_touch_world_is_reachable_without_body_collision(name):
    """Facing its landmark, the robot moves straight from each station's point until the head
    is touch_gap (0.06 m) from the landmark: the body and head keep at least the safety
    guard's floor (0.015 m) from everything on the way; and the head gets there (the
    clearance at the end is the head's touch_gap)."""
    env = load_environment(name)
    stations = stations_of(env, run_spec(kind="stations", n_samples=5))
    assert len(stations) >= 4
    for st in stations:
        clearance = approach_clearance(env, st, 0.06)
        assert 0.015 <= clearance <= 0.06 + 1e-9, (st.name, clearance)


# ---------------------------------------------------------------------- two drives
def test_both_drives_visit_every_station_within_its_jitter_from_different_starts(drives):
    env, runs = drives
    (a, driver_a), (b, driver_b) = runs
    assert np.linalg.norm(a.poses[0, :2] - b.poses[0, :2]) > 0.5  # each drive its own start
    assert driver_a.stations == driver_b.stations  # the same stations, whatever the seed
    spec = run_spec(kind="stations", n_samples=N)
    for driver in (driver_a, driver_b):
        assert {k for _, k, _ in driver.arrivals} == set(range(len(driver.stations)))
        for _, k, pose in driver.arrivals:
            offset = np.linalg.norm(pose[:2] - np.asarray(driver.stations[k].point))
            assert offset <= spec.station_jitter + AT_STATION + 0.01, (k, offset)


@pytest.mark.parametrize("side", [0, 1])
def test_station_drives_never_drive_the_body_into_anything(drives, side):
    assert drives[1][side][0].attrs["body_collision_instants"] == 0


def test_each_station_is_whisked_at_the_sampling_instant_and_a_touched_query_there_has_a_touched_match(drives):
    """Each drive has samples whose whiskers bend (touch_mask: |xy| > 0.01 at the sampling
    instant) with contact points on each station's landmark while the robot is within
    0.4 m of the station; every such query sample has a touched reference sample within
    tau and the heading tolerance."""
    env, runs = drives
    (query, driver), (reference, _) = runs
    ref_touched = reference.touch_mask()
    for st in driver.stations:
        at_station = []
        for run in (query, reference):
            touched = run.touch_mask()
            on_it = np.zeros(len(run), bool)
            for k in np.flatnonzero(touched):
                points = run.contacts(int(k))[0][:, :2]
                gaps = env.obstacles.landmark_distance_many(points)[:, st.landmark]
                near = np.linalg.norm(run.poses[k, :2] - np.asarray(st.point)) < 0.4
                on_it[k] = near and len(points) > 0 and gaps.min() < 0.02
            assert on_it.any(), (st.name, run.name)
            at_station.append(np.flatnonzero(on_it))
        for k in at_station[0]:
            dist = np.linalg.norm(reference.poses[:, :2] - query.poses[k, :2], axis=1)
            turn = np.abs((reference.poses[:, 2] - query.poses[k, 2] + math.pi) % (2 * math.pi) - math.pi)
            match = (dist <= TAU) & (turn <= math.radians(HEADING_DEG))
            assert (match & ref_touched).any(), (st.name, k)


def test_the_station_drivers_modes_switch_by_their_transition_table():
    """drive --landmark--> to_station --arrived--> approach: a driver whose progress along its
    loop has just passed a station (0.2 m, less than the 0.5 m it looks back) goes there, to
    a point within station_jitter of it, and arrives within AT_STATION of that point."""
    env = load_environment(WORLD)
    driver, _ = make_controller(env, run_spec(kind="stations", n_samples=N), np.random.default_rng(3), 0.5)
    assert STATION_TRANSITIONS[("drive", "landmark")] == "to_station"
    driver.s = driver.station_s[2] + 0.2  # just past the west station
    point = np.asarray(driver.stations[2].point)
    driver._decide(1.0, np.array([*point, math.pi]))
    assert driver.mode == "to_station" and driver.station.name == "west"
    assert np.linalg.norm(driver.station_target - point) <= driver.spec.station_jitter
    at_target = np.array([*driver.station_target, math.pi])
    driver._decide(1.5, at_target)
    assert driver.mode == "approach" and driver.arrivals[-1][1] == 2


def test_the_approach_faces_the_landmark_off_by_the_visits_heading_offset():
    """At touch-alike-boxes' east station (0.87, 0) facing east, the east box's nearest point
    (1.638, 0) lies straight ahead of the head: bearing 0. With this visit's heading offset
    0.05 rad the driver's bearing is 0.05 rad, so its approach turns until the box lies
    0.05 rad to the right."""
    env = load_environment("touch-alike-boxes")
    driver, _ = make_controller(env, run_spec(kind="stations", n_samples=N), np.random.default_rng(0), 0.5)
    pose = np.array([0.87, 0.0, 0.0])
    driver.heading_offset = 0.0
    assert driver._bearing(pose, 0) == pytest.approx(0.0, abs=1e-3)
    driver.heading_offset = 0.05
    assert driver._bearing(pose, 0) == pytest.approx(0.05, abs=1e-3)


# ---------------------------------------------------------------------- bad settings
def _scenario(tmp_path: Path, run: dict, environment: str = "e1", scoring: dict | None = None) -> Path:
    path = tmp_path / "stations.yaml"
    data = {
        "name": "stations",
        "train": {"environment": "e1", "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E", "environment": environment, "run": {"kind": "stations", "n_samples": 8, **run}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
    }
    if scoring:
        data["scoring"] = scoring
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("run, scoring, message", [
    ({"station_landmarks": ["box_east", "nope"]}, None,
     r"evaluations\.0\.run\.station_landmarks: 'nope' names no landmark of 'e1'"),
    ({"station_count": 4}, None, r"evaluations\.0\.run\.station_count: 4 stations asked for, but 'e1' has only 3"),
    ({"station_count": 0}, None, r"evaluations\.0\.run\.station_count: .*greater than or equal to 1"),
    ({"station_landmarks": ["box_east"], "station_count": 2}, None,
     r"evaluations\.0\.run.*station_count 2 is more than the 1 landmarks named"),
    ({"station_landmarks": ["box_east", "box_east"]}, None, r"evaluations\.0\.run.*must name each landmark once"),
    ({"station_jitter": 0.6}, None, r"evaluations\.0\.run\.station_jitter: .*less than or equal to 0\.5"),
    ({"station_heading_jitter_deg": -1}, None, r"evaluations\.0\.run\.station_heading_jitter_deg: .*greater than"),
    ({"station_jitter": 0.2}, None, r"evaluations\.0\.run\.station_jitter: 0\.2 m .* more than scoring\.tau = 0\.3 m"),
    ({"station_jitter": 0.1}, {"tau": 0.15}, r"evaluations\.0\.run\.station_jitter: .*scoring\.tau = 0\.15 m"),
    ({"station_heading_jitter_deg": 20}, None,
     r"evaluations\.0\.run\.station_heading_jitter_deg: 20 deg .* scoring\.heading_tolerance_deg = 30"),
], ids=["unknown landmark", "more stations than landmarks", "no station", "more stations than named", "named twice",
        "jitter out of range", "heading jitter out of range", "jitter over half tau", "jitter over half a smaller tau",
        "heading jitter over half the tolerance"])
def test_bad_station_settings_are_refused_naming_the_key(tmp_path, run, scoring, message):
    with pytest.raises(ScenarioError, match=message):
        load_scenario(_scenario(tmp_path, run, scoring=scoring))


def test_a_station_heading_jitter_is_not_bounded_without_a_heading_tolerance(tmp_path):
    load_scenario(_scenario(tmp_path, {"station_heading_jitter_deg": 20}, scoring={"heading_tolerance_deg": None}))


@pytest.mark.parametrize("environment, message", [
    ({"name": "bare", "extends": "base.yaml"},
     r"evaluations\.0\.run\.kind: a stations run needs the environment's route"),
    ({"name": "hidden", "extends": "e1.yaml", "landmarks": [
        {"name": "ghost", "type": "box", "pos": [2.138, 0.0], "size": [1.0, 1.0, 0.3], "tactile": False}]},
     r"evaluations\.0\.run\.kind: .* 0 tactile landmarks"),
])
def test_a_stations_run_needs_a_route_and_tactile_landmarks(tmp_path, environment, message):
    shipped = Path(vitaplace.engine.sim.__file__).resolve().parents[2] / "scenarios" / "environments"
    environment = {**environment, "extends": str(shipped / environment["extends"])}
    env_file = tmp_path / "env.yaml"
    env_file.write_text(yaml.safe_dump(environment))
    with pytest.raises(ScenarioError, match=message):
        load_scenario(_scenario(tmp_path, {}, environment=str(env_file)))


def test_validate_says_it_in_one_line_with_exit_status_2(tmp_path):
    path = _scenario(tmp_path, {"station_landmarks": ["nope"]})
    done = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "validate", str(path)],
                          capture_output=True, text=True)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "evaluations.0.run.station_landmarks: 'nope' names no landmark" in lines[0], done.stderr


# ---------------------------------------------------------------------- sampling at stations only


def test_sampling_at_stations_records_only_the_cycles_held_whisking_a_station():
    """``sample_at: stations``: the drive between stations is simulated, not recorded, so the
    run's samples are the held cycles only: each within reach of a station (the hold is
    0.06 m from the landmark, the station's point within 0.5 m of its approach), each whisk
    cycle of it in the 'hold' mode, and the samples' whiskers touch at the sampling instant
    (hold waits for contact) far more often than a plain drive's (about 1 in 5 here)."""
    env = load_environment(WORLD)
    n = 40
    run = simulate_run(env, run_spec(kind="stations", n_samples=n, sample_at="stations"), 1, ROBOT, progress=False)
    points = np.array([st.point for st in stations_of(env, run_spec(kind="stations", n_samples=n))])
    nearest = np.linalg.norm(run.poses[:, None, :2] - points[None], axis=2).min(axis=1)
    assert len(run) == n and nearest.max() < 0.5
    assert run.touch_mask().mean() >= 0.8
    assert run.attrs["controller_modes"]["hold"] >= n  # ticks in hold: at least one per sample
    plain = simulate_run(env, run_spec(kind="stations", n_samples=n), 1, ROBOT, progress=False)
    assert np.linalg.norm(plain.poses[:, None, :2] - points[None], axis=2).min(axis=1).max() > 0.5  # it drives between


def test_a_controller_that_stops_recording_is_an_error_not_a_hang(monkeypatch):
    env = load_environment(WORLD)
    monkeypatch.setattr(simulate_module, "MAX_UNRECORDED_CYCLES", 5)
    monkeypatch.setattr("vitaplace.engine.sim.controllers.stations.StationDriver.records_sample", lambda self: False)
    with pytest.raises(simulate_module.SimulationError, match="no sample in 5 whisk cycles after sample 0"):
        simulate_run(env, run_spec(kind="stations", n_samples=4), 1, ROBOT, progress=False)
