"""Tests of the emulated keyboard teleoperator (``kind: teleop``), the shared safety guard and
the route-clearance check that environments pass before any compute."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import math
import re
import subprocess
import sys
import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)
from vitaplace.engine.evaluation.difficulty import longest_stay
from vitaplace.engine.sim.clearance import ROUTE_MIN_CLEARANCE, Route, loop_clearance
from vitaplace.engine.sim.controllers import TELEOP_TURN, SafetyGuard, make_controller
from vitaplace.engine.sim.environment import EnvironmentSpec, environment_files, load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import run_spec, simulate_run  # noqa: E402

ENVS = sorted(environment_files())
#: images are not looked at here: a tiny camera saves rendering time
ROBOT = RobotSpec(camera_width=16, camera_height=12)
N = 200  #: samples per simulated run (100 s)


@pytest.fixture(scope="module")
def drives() -> dict[str, object]:
    """One teleop run per shipped world (seed 1), physical whiskers (the default touch model)."""
    return {name: simulate_run(load_environment(name), run_spec(kind="teleop", n_samples=N), 1, ROBOT, progress=False)
            for name in ENVS}


def _nearest_m(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return cKDTree(reference[:, :2]).query(query[:, :2])[0]


# ---------------------------------------------------------------------- the shared guard
def test_safety_guard_hand_cases():
    """In a bare 6 m arena (east wall's face at x = 3), the robot at (2.2, 0) facing east has
    its head disc (centre 0.5 m ahead, radius hypot(0.08, 0.08) = 0.113 m) 0.187 m from the
    wall. Driving 0.4 m/s for the 0.5 s horizon brings it to -0.013 m (refused: the floor is
    0.015 m); 0.3 m/s to 0.037 m (allowed); strafing or backing away is allowed; the first
    safe of a list wins and standing still is the last resort."""
    env = EnvironmentSpec.model_validate({"name": "bare", "arena": {"size": 6.0}})
    guard = SafetyGuard(env.obstacles, 0.015)
    pose = np.array([2.2, 0.0, 0.0])
    head_radius = math.hypot(0.08, 0.08)
    assert guard.clearance(pose, 0.0, 0.0) == pytest.approx(0.3 - head_radius, abs=1e-9)
    assert guard.clearance(pose, 0.4, 0.0) == pytest.approx(0.1 - head_radius, abs=1e-9)
    assert not guard.safe(pose, 0.4, 0.0)
    assert guard.safe(pose, 0.3, 0.0)
    assert guard.safe(pose, 0.0, 0.0, 0.4) and guard.safe(pose, -0.4, 0.0)
    assert guard.first_safe(pose, [(0.4, 0.0, 0.0), (0.0, 0.0, 0.4)]) == (0.0, 0.0, 0.4)
    assert guard.first_safe(pose, [(0.4, 0.0, 0.0), (0.5, 0.0, 0.0)]) == (0.0, 0.0, 0.0)


def test_safety_guard_with_braking_follows_the_base_to_a_stop():
    """With braking 0.5 m/s^2 from rest, 0.3 m/s forward over 0.5 s: the base ramps to 0.25 m/s
    (0.0625 m), then brakes to a stop (0.25^2 / 1 = 0.0625 m): 0.125 m in all, so the head
    ends 0.3 - 0.125 m from the wall minus its radius. Already moving at 0.3 m/s, the same
    command goes 0.15 m + 0.09 m of braking."""
    env = EnvironmentSpec.model_validate({"name": "bare", "arena": {"size": 6.0}})
    guard = SafetyGuard(env.obstacles, 0.015, braking=0.5)
    pose = np.array([2.2, 0.0, 0.0])
    head_radius = math.hypot(0.08, 0.08)
    assert guard.clearance(pose, 0.3, 0.0) == pytest.approx(0.3 - 0.125 - head_radius, abs=1e-9)
    assert guard.clearance(pose, 0.3, 0.0, current=(0.3, 0.0)) == pytest.approx(0.3 - 0.24 - head_radius, abs=1e-9)
    assert guard.clearance(pose, 0.0, 0.0, 0.3) == pytest.approx(0.3 - head_radius, abs=1e-9)  # sideways


def test_both_controllers_use_the_one_guard():
    e1 = load_environment("e1")
    foraging, _ = make_controller(e1, run_spec(kind="foraging", n_samples=2), np.random.default_rng(0))
    driver, _ = make_controller(e1, run_spec(kind="teleop", n_samples=2), np.random.default_rng(0))
    assert type(foraging._guard) is SafetyGuard and type(driver.guard) is SafetyGuard


# ---------------------------------------------------------------------- each run its own drive
def test_each_seed_draws_its_own_start_speed_loop_and_bias():
    """Start points spread along the loop, speeds are the keys' speed after -2..2 presses of q
    (x1.1) or z (x0.9), the turn rate keeps teleop.launch's 0.25 rad/s per m/s, and every
    jittered loop differs from the shipped one yet keeps the footprint clear."""
    e1 = load_environment("e1")
    spec = run_spec(kind="teleop", n_samples=2)
    allowed = {round(0.3 * f, 9) for f in (0.81, 0.9, 1.0, 1.1, 1.21)}
    base = Route(e1.route)
    starts, speeds = [], set()
    for seed in range(8):
        driver, start = make_controller(e1, spec, np.random.default_rng(seed))
        starts.append(base.project(np.array(start[:2]))[0])
        speeds.add(round(driver.speed, 9))
        assert driver.turn == pytest.approx(0.25 * driver.speed / 0.3)  # q/z steps scale 0.3 m/s and 0.25 rad/s alike
        moved = np.linalg.norm(driver.loop.points - base.points, axis=1)
        assert 0.02 < moved.max() < 0.4
        _, clearance = loop_clearance(e1.obstacles, driver.loop, np.mean(e1.route, axis=0))
        assert clearance.min() >= ROUTE_MIN_CLEARANCE
    assert speeds <= allowed and len(speeds) >= 3
    gaps = np.diff(np.sort(starts))
    assert np.ptp(starts) > 0.5 * base.length and gaps.min() > 0.01  # spread, all different


def test_two_teleop_seeds_are_independent_drives_unlike_two_route_runs():
    """Query -> nearest reference pose: two route runs (same start, loop, speed) are ~2 cm
    apart; two teleop drives are clearly further apart (each its own start, loop and speed)."""
    e1 = load_environment("e1")
    medians = {}
    for kind in ("route", "teleop"):
        ref, query = (simulate_run(e1, run_spec(kind=kind, n_samples=150), seed, ROBOT, progress=False)
                      for seed in (1, 2))
        medians[kind] = float(np.median(_nearest_m(query.poses, ref.poses)))
        if kind == "teleop":
            assert np.linalg.norm(ref.poses[0, :2] - query.poses[0, :2]) > 0.5
    assert medians["route"] < 0.04
    assert medians["teleop"] > max(0.06, 2.5 * medians["route"]), medians


# ---------------------------------------------------------------------- collisions, touch
@pytest.mark.parametrize("name", ENVS)
def test_teleop_never_drives_the_body_into_anything(drives, name):
    assert drives[name].attrs["body_collision_instants"] == 0


def test_touch_share_follows_the_paper_e3_above_e2_above_e1(drives):
    """The paper: E3 had the most tactile data, E2 more landmarks than E1. The teleoperator,
    whisking each landmark it passes, touches in at least 5 % of E1's samples, 15 % of E2's
    and 20 % of E3's (ten times the route kind's 1-2 % there). touch_share is
    Run.touch_mask's mean."""
    share = {name: drives[name].attrs["touch_share"] for name in ("e1", "e2", "e3")}
    for name in share:
        assert share[name] == pytest.approx(float(drives[name].touch_mask().mean()))
    assert share["e3"] > share["e2"] > share["e1"], share
    assert share["e1"] >= 0.05 and share["e2"] >= 0.15 and share["e3"] >= 0.20, share
    for name in ("e1", "e2", "e3"):
        assert drives[name].attrs["controller_modes"].get("hold", 0) > 0  # it stopped to whisk


def test_a_hold_lasts_until_its_contacts_are_recorded_and_nudges_back_onto_the_landmark():
    """Holding at E1's east box (face at x = 1.638) with the head 0.05 m from it: a sample with
    contact counts and the driver stands ("k"); a sample without is not counted and the driver
    taps the key towards the box ("i", facing it); once the hold's contacts are in, it leaves."""
    e1 = load_environment("e1")
    driver, _ = make_controller(e1, run_spec(kind="teleop", n_samples=N), np.random.default_rng(0), 0.5)
    east = [lm.name for lm in e1.landmarks].index("box_east")
    pose = np.array([1.638 - 0.05 - math.hypot(0.08, 0.08) - 0.5, 0.0, 0.0])  # head disc 0.05 m from the face
    driver.mode, driver.target_landmark, driver.until, driver.contacts_left = "hold", east, 100.0, 2
    driver.touched = True
    assert driver._decide(1.0, pose) == ("k", math.inf) and driver.contacts_left == 1
    driver.touched = False
    key, duration = driver._decide(1.5, pose)
    assert (key, duration) == ("i", 0.2) and driver.contacts_left == 1
    driver.touched = True
    driver._decide(2.0, pose)
    assert driver.mode == "leave" and driver.contacts_left == 0


# ---------------------------------------------------------------------- blocked on its path
#: where one E3 drive of the first study stood still from sample 212 to its end (seed
#: 1384528246, the study's seed 3 query, penetration whiskers): heading east between the
#: central rock and the south-east cylinder, where its jittered loop bends north-east; the
#: lookahead point lies under the head (it reaches 0.58 m ahead), every key towards it was
#: refused by the guard, and the driver stopped at each decision
STUCK_SEED, STUCK_POSE, STUCK_S = 1384528246, np.array([0.332, -0.709, -0.036]), 5.004


def test_a_driver_blocked_on_its_path_presses_a_safe_key_instead_of_standing():
    """At the pose where that drive froze, standing, with no landmark to explore: the driver
    presses a key (not "k") that the guard lets it press, and looks further along its path."""
    e3 = load_environment("e3")
    driver, _ = make_controller(e3, run_spec(kind="teleop", n_samples=600), np.random.default_rng(STUCK_SEED), 0.5)
    driver.s, driver.tactile = STUCK_S, ()
    key, duration = driver._decide(150.0, STUCK_POSE)
    assert key != "k"
    horizon = driver.spec.reaction_delay + (SafetyGuard.HORIZON if math.isinf(duration) else duration)
    assert driver.guard.safe(STUCK_POSE, *driver._command(key), horizon=horizon)
    assert driver.s > STUCK_S


def test_a_driver_without_headway_for_3_s_looks_further_along_its_path():
    """On its loop, facing along it, in the open: a driver that made headway just now keeps
    its place along the loop; one that has neither moved 0.1 m nor turned 0.3 rad for 3 s
    (dithering between keys) looks 0.1 m further along it, as when blocked."""
    e3 = load_environment("e3")
    s0 = {}
    for stalled_for in (0.0, 3.0):
        driver, _ = make_controller(e3, run_spec(kind="teleop", n_samples=600), np.random.default_rng(STUCK_SEED), 0.5)
        point, tangent = driver.loop.point(1.0)
        pose = np.array([*point, math.atan2(tangent[1], tangent[0])])
        driver.s, driver.tactile = 1.0, ()
        driver.headway.restart(pose, 100.0 - stalled_for)
        key, _ = driver._decide(100.0, pose)
        assert key != "k"
        s0[stalled_for] = driver.s
    assert s0[0.0] == pytest.approx(1.0, abs=0.03)
    assert s0[3.0] == pytest.approx(s0[0.0] + 0.1)


def test_a_drive_started_where_one_froze_moves_on():
    """Simulated from that pose (same seed, so the same jittered loop; exploring switched off
    by a tiny ``visit_range``, or the driver whisks the rock beside it first), the drive
    creeps through the bend (taps: the corridor is narrow) and goes on: within 20 s it has
    left the 0.25 m disc around the pose for good, and it ends more than 0.5 m away. The old
    driver never moved: the simulation failed its plausibility check."""
    start = (*STUCK_POSE[:2], math.degrees(STUCK_POSE[2]))
    run = simulate_run(load_environment("e3"), run_spec(kind="teleop", n_samples=60, visit_range=0.01, start=start),
                       STUCK_SEED, RobotSpec(camera_width=16, camera_height=12, tactile_model="penetration"),
                       progress=False)
    length, first = longest_stay(run.poses[:, :2], 0.25)
    assert length < 40, (length, first)
    assert np.hypot(*(run.poses[-1, :2] - STUCK_POSE[:2])) > 0.5


# ---------------------------------------------------------------------- detours
def test_detours_are_spread_along_the_run_with_the_requested_share():
    """off_route_fraction 0.3 in 3 detours: three disjoint windows of equal length whose
    samples are 30 % of the run (to one sample per window), not all at its end; in them the
    robot drives the loop moved up to 0.6 m inward, clearly further from the shipped loop than
    elsewhere."""
    e1 = load_environment("e1")
    spec = run_spec(kind="teleop", n_samples=N, off_route_fraction=0.3, detour_count=3)
    driver, _ = make_controller(e1, spec, np.random.default_rng(3), 0.5)
    windows = driver.detours
    assert len(windows) == 3
    lengths = [t1 - t0 for t0, t1 in windows]
    assert lengths == pytest.approx([0.3 * N * 0.5 / 3] * 3)
    assert all(b[0] >= a[1] for a, b in zip(windows, windows[1:], strict=False))  # consecutive pairs
    times = (spec.warmup_cycles + 1 + np.arange(N)) * 0.5
    inside = np.array([driver.in_detour(t) for t in times])
    assert abs(inside.mean() - 0.3) <= 3 / N
    assert windows[0][0] < 0.6 * times[-1]  # not only the final part
    _, clearance = loop_clearance(e1.obstacles, driver.detour, np.mean(e1.route, axis=0))
    assert clearance.min() >= ROUTE_MIN_CLEARANCE

    run = simulate_run(e1, spec, 3, ROBOT, progress=False)
    off = Route(e1.route).distance(run.poses[:, :2])
    settled = np.zeros(N, dtype=bool)
    for t0, t1 in windows:
        settled |= (times >= 0.5 * (t0 + t1)) & (times < t1)  # second half: the robot got there
    assert np.median(off[settled]) > 0.3
    assert np.median(off[settled]) > np.median(off[~inside]) + 0.1  # (outside: explorations, returns)


# ---------------------------------------------------------------------- routes checked before compute
def test_a_route_the_whiskeye_cannot_drive_clear_is_refused_by_validate(tmp_path):
    path = tmp_path / "narrow.yaml"
    path.write_text("extends: e1\nroute: [[2.1, 0], [0, 1.5], [-2.1, 0], [0, -1.5]]\n")
    result = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "validate", str(path)],
                            capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-500:]
    assert str(path) in lines[0] and "route.0" in lines[0] and "(2.1, 0)" in lines[0], lines[0]


@pytest.mark.parametrize(("route", "named"), [
    pytest.param([[0.5, 0.5], [0.5, 0.5], [1, 1.5], [-1, 1]], "route.1: waypoint 1 (0.5, 0.5) is where waypoint 0 is",
                 id="first two"),
    pytest.param([[0, 0], [0, 0], [0, 0]], "route.1: waypoint 1 (0, 0) is where waypoint 0 is", id="all one point"),
    pytest.param([[0.5, 0.5], [1, 1.5], [-1, 1], [0.5, 0.5], [0.5, 0.5]],
                 "route.4: waypoint 4 (0.5, 0.5) is where waypoint 3 is", id="the closing waypoint twice"),
])
def test_a_route_with_a_segment_of_no_length_is_refused_before_any_arithmetic(route, named):
    """Two consecutive waypoints at one point leave a segment with no length and no direction
    (a drive along it divided by its zero length): refused naming the second one, before
    numpy warns of the division. The first waypoint repeated at the end, closing the loop, is
    no segment (`Route` drops it) and passes."""
    data = {"name": "t", "route": route}  # the default 6 m arena: no landmark in the way
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=re.escape(named) + "; expected consecutive waypoints at different points"):
            EnvironmentSpec.model_validate(data)
        closed = [[0.5, 0.5], [1, 1.5], [-1, 1], [0.5, 0.5]]
        assert EnvironmentSpec.model_validate({"name": "t", "route": closed}).route == [tuple(p) for p in closed]


def test_a_route_with_a_segment_of_no_length_is_one_line_from_validate(tmp_path):
    path = tmp_path / "still.yaml"
    path.write_text("extends: e1\nroute: [[0, 0], [0, 0], [0, 0]]\n")
    result = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "validate", str(path)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and result.stderr.splitlines() == [
        f"vitaplace: error: {path}: route.1: waypoint 1 (0, 0) is where waypoint 0 is; expected consecutive waypoints "
        "at different points (the segment between them has no length)"], result.stderr[-500:]


def test_route_check_names_the_waypoint_near_the_obstacle():
    """A triangle in E1 driven facing the direction of travel whose third corner, (0, -1.75),
    lies inside the cylinder (radius 0.5 at (0, -2.138)). On the way there (2.6 m from
    (-0.5, 0.8)) the head disc (0.5 m ahead, radius 0.113) first comes within 0.03 m of the
    cylinder 0.76 m before that corner - the segment's second half: waypoint 2 is named."""
    data = load_environment("e1").model_dump()
    data["route"] = [[0.5, 0.8], [-0.5, 0.8], [0.0, -1.75]]
    data["route_facing"] = "travel"
    with pytest.raises(ValueError, match=r"route\.2: .*near waypoint 2 \(0, -1\.75\)"):
        EnvironmentSpec.model_validate(data)


def test_waypoint_normals_where_the_route_turns_back_are_the_incoming_segments_normal():
    """Left of travel, by hand. [[0, 0], [1, 0]] is driven out along +x and back along -x:
    at (1, 0) the incoming +x has its left at (0, 1), at (0, 0) the incoming -x at (0, -1).
    [[0, 0], [2, 0], [2, 2], [2, 1]]: the corner (2, 0) turns left from +x to +y, the bisector
    of (0, 1) and (-1, 0) is (-1, 1) / sqrt 2; the tip (2, 2) turns back from +y to -y, its
    normal is +y's left (-1, 0). [[0, 0], [0.3, 0.1], [0.9, 0.3]] is a line driven out and
    back: a reversal at both ends (the incoming (0.9, 0.3) -> (0, 0) has its left at
    (1, -3) / sqrt 10) and the straight middle's normal (-1, 3) / sqrt 10."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no division by the zero bisector
        np.testing.assert_allclose(Route([[0, 0], [1, 0]]).waypoint_normals(), [[0, -1], [0, 1]], atol=1e-12)
        np.testing.assert_allclose(Route([[0, 0], [2, 0], [2, 2], [2, 1]]).waypoint_normals()[1:3],
                                   [[-math.sqrt(0.5), math.sqrt(0.5)], [-1, 0]], atol=1e-12)
        line = np.array([[1, -3], [-1, 3], [-1, 3]]) / math.sqrt(10)
        np.testing.assert_allclose(Route([[0, 0], [0.3, 0.1], [0.9, 0.3]]).waypoint_normals(), line, atol=1e-12)


#: routes that turn back on themselves, valid in E1 both ways of facing: docs/SIMULATION.md's
#: two-waypoint loop, the line out and back (the first waypoint repeated closes the loop), a spike
REVERSING = {
    "two waypoints": [[-1, -1], [1, 1]],
    "out and back": [[0, 0], [0.8, 0], [0, 0]],
    "spike": [[-0.9, -0.9], [0.9, -0.9], [0, 0.3], [0, 1.0], [0, 0.3]],
}


@pytest.mark.parametrize("kind", ["teleop", "stations", "visits"])
@pytest.mark.parametrize("route", list(REVERSING), ids=list(REVERSING))
def test_a_route_that_turns_back_on_itself_is_driven_by_every_kind(route, kind):
    """A route that validate accepts is driven: the teleoperator's own loop and detour loop
    move a reversal's waypoint across the incoming segment (`Route.waypoint_normals`), where
    a zero bisector once made every waypoint NaN and the run end in numpy's "arange: cannot
    compute length". The teleoperator's loops keep their waypoint count and stay finite, its
    own loop within 0.4 m of the route (the jitter), and a short run of every kind records a
    finite pose per sample (the detours: 30 % of the teleop run)."""
    data = load_environment("e1").model_dump()
    data["route"] = REVERSING[route]
    env = EnvironmentSpec.model_validate(data)
    base = Route(env.route)
    settings = {"off_route_fraction": 0.3} if kind == "teleop" else {}
    spec = run_spec(kind=kind, n_samples=12, **settings)
    driver, start = make_controller(env, spec, np.random.default_rng(3))
    assert np.isfinite(start).all()
    if kind == "teleop":
        assert len(driver.loop.points) == len(base.points) and len(driver.detour.points) == len(base.points)
        assert np.isfinite(driver.loop.points).all() and np.isfinite(driver.detour.points).all()
        assert 0.0 < np.linalg.norm(driver.loop.points - base.points, axis=1).max() < 0.4
    run = simulate_run(env, spec, 1, ROBOT, progress=False)
    assert run.poses.shape == (12, 3) and np.isfinite(run.poses).all()


@pytest.mark.parametrize("name", ENVS)
def test_shipped_routes_pass_the_route_check(name):
    from vitaplace.engine.sim.clearance import route_collision

    env = load_environment(name)
    assert route_collision(env.route, env.route_facing, env.obstacles) is None


def test_first_key_waits_for_the_reaction_delay_and_is_one_of_the_keys():
    """The driver decides at its first tick and presses the key 0.25 s later (the robot
    stands until then); the command is then one key's: forward/strafe components of 0 or the
    run's speed, a turn rate of 0 or 0.25 rad/s per m/s of it."""
    from vitaplace.engine.sim.controllers import Observation

    e1 = load_environment("e1")
    driver, start = make_controller(e1, run_spec(kind="teleop", n_samples=2, max_accel=100.0), np.random.default_rng(5))
    seen = []
    for k in range(5):  # ticks at 0.5 (decision), 0.6, 0.7 (waiting), 0.8, 0.9 (pressed)
        obs = Observation(time=0.5 + 0.1 * k, pose=np.array(start), contacts=np.zeros((0, 3)), deflection=np.zeros(24))
        seen.append(driver(obs))
    assert seen[1] == seen[2] == (0.0, 0.0, 0.0)
    v, w, lateral = seen[4]
    assert driver.key != "k" and (v, w, lateral) != (0.0, 0.0, 0.0)
    assert {round(abs(v), 9), round(abs(lateral), 9)} <= {0.0, round(driver.speed, 9)}
    assert abs(w) == pytest.approx(0.0) or abs(w) == pytest.approx(TELEOP_TURN * driver.speed / 0.3)


def test_the_teleoperators_modes_switch_by_their_transition_table():
    """Like the foraging states: every mode is reachable from ``drive`` and leads back to it,
    and a mode entered through the table sets its own clock (leave: `LEAVE_TIME`)."""
    from vitaplace.engine.sim.controllers.teleop import LEAVE_TIME, TELEOP_TRANSITIONS

    driver, _ = make_controller(load_environment("e1"), run_spec(kind="teleop", n_samples=2), np.random.default_rng(0))
    assert set(driver.modes) == {"drive", "approach", "hold", "leave"} == {m for _, m in TELEOP_TRANSITIONS.items()}
    reached, todo = {"drive"}, ["drive"]
    while todo:
        mode = todo.pop()
        for (src, _), dst in TELEOP_TRANSITIONS.items():
            if src == mode and dst not in reached:
                reached.add(dst)
                todo.append(dst)
    assert reached == set(driver.modes)
    driver.modes["leave"].enter(10.0, np.zeros(3))
    assert driver.until == 10.0 + LEAVE_TIME == 16.0


# ---------------------------------------------------------------------- plausible drives
@pytest.mark.parametrize("kind, settings, message", [
    # issue 32's reproduction: a 60-sample query held at one landmark for its whole run
    ("teleop", {"hold_cycles": [100000, 100000]}, r"hold_cycles: every hold \(100000 whisk cycles at least\) is "
     "longer than the run's 60 samples"),
    ("stations", {"hold_cycles": [61, 80]}, r"hold_cycles: every hold \(61"),
    ("teleop", {"detour_count": 41, "off_route_fraction": 0.3}, "detour_count: 41 detours in a run of 40 samples"),
])
def test_holds_and_detours_no_longer_than_the_run(kind, settings, message):
    samples = 40 if "detour_count" in settings else 60
    with pytest.raises(ValueError, match=message):
        run_spec(kind=kind, n_samples=samples, **settings)
    longest = {"hold_cycles": [60, 100000]} if "hold_cycles" in settings else {"detour_count": 40}
    run_spec(kind=kind, n_samples=samples, **{**settings, **longest})  # the run's length is allowed


@pytest.mark.parametrize("stay, samples, stuck", [
    (48, 60, True),  # issue 32: 48 of 60 samples at one landmark (the old floor of 50 let it pass)
    (12, 200, False),  # a station drive's longest hold
    (49, 200, False), (50, 200, True),  # a quarter of the run
    (9, 20, False), (10, 20, True),  # at least 10 samples, however short the run
])
def test_a_stuck_drive_is_a_quarter_of_its_run_and_ten_samples(stay, samples, stuck):
    from vitaplace.engine.pipeline.stages.simulate import is_stuck

    assert is_stuck(stay, samples) is stuck
