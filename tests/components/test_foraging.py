"""Tests of the foraging controller's states (``kind: foraging``): each state's command for a
hand-made situation, the transitions between them, and their gains as run-schema fields."""

from __future__ import annotations

import math
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import numpy as np
import pytest
import yaml

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)
from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.evaluation.difficulty import longest_stay  # noqa: E402
from vitaplace.engine.sim.clearance import HEAD_CENTRE, HEAD_RADIUS, footprint_clearance
from vitaplace.engine.sim.controllers import (
    HEAD_REACH,
    TRANSITIONS,
    Attention,
    Avoid,
    Explore,
    ForagingController,
    ForagingGains,
    Leave,
    Observation,
    Orient,
    Surroundings,
    Wander,
    key_form,
)
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import run_hash, run_spec, simulate_run  # noqa: E402

E1 = str(Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml")
#: defaults used below: speed 0.15 m/s, turn-rate limit 90 deg/s, avoid_margin 0.06 m
SPEC = run_spec(kind="foraging", n_samples=1)
W_MAX = math.pi / 2
NO_CONTACTS = np.zeros((0, 3))


def around(time: float = 1.0, yaw_deg: float = 0.0, contacts: np.ndarray = NO_CONTACTS, body_gap: float = 1.0,
           head_gap: float = 1.0, ahead_distance: float = 1.0, escape_deg: float = 180.0,
           wander_turn: float = 0.2) -> Surroundings:
    """The robot at the origin heading ``yaw_deg``, far from everything unless told."""
    e = math.radians(escape_deg)
    return Surroundings(time=time, pose=np.array([0.0, 0.0, math.radians(yaw_deg)]), contacts=contacts,
                        body_gap=body_gap, head_gap=head_gap, ahead_distance=ahead_distance,
                        ahead_escape=np.array([math.cos(e), math.sin(e)]), wander_turn=wander_turn)


def at(bearing_deg: float, distance: float) -> np.ndarray:
    b = math.radians(bearing_deg)
    return np.array([distance * math.cos(b), distance * math.sin(b)])


def attending(target: np.ndarray, side: float = 1.0, refractory_until: float = 0.0) -> Attention:
    return Attention(target=np.array(target, dtype=float), side=side, refractory_until=refractory_until)


# ---------------------------------------------------------------------- wander
def test_wander_drives_at_speed_with_its_random_turn_rate_clipped_to_the_limit():
    assert Wander(SPEC, Attention()).step(around(wander_turn=0.2)) == ((0.15, 0.2), "")
    assert Wander(SPEC, Attention()).step(around(wander_turn=-3.0)) == ((0.15, -W_MAX), "")


def test_wander_steers_towards_the_escape_direction_of_an_obstacle_ahead():
    # obstacle 0.03 m from the probe (< 0.05), escape direction 30 deg left: 0.2 + 1.5 * pi/6
    command, event = Wander(SPEC, Attention()).step(around(ahead_distance=0.03, escape_deg=30.0))
    assert command == pytest.approx((0.15, 0.2 + 1.5 * math.pi / 6)) and event == ""
    # 0.06 m away: beyond wander_steer_range, no steering
    assert Wander(SPEC, Attention()).step(around(ahead_distance=0.06, escape_deg=30.0))[0] == (0.15, 0.2)


def test_wander_is_touched_by_heeded_contacts_only():
    touch = np.array([[0.7, 0.0, 0.1]])
    assert Wander(SPEC, Attention()).step(around(time=5.0, contacts=touch)) == (None, "touch")
    # during the refractory period contacts are ignored - and an obstacle ahead that touches the
    # whiskers is no reason to steer (only a visual-only one is)
    ignored = Wander(SPEC, Attention(refractory_until=6.0)).step(
        around(time=5.0, contacts=touch, ahead_distance=0.03, escape_deg=30.0))
    assert ignored == ((0.15, 0.2), "")


# ---------------------------------------------------------------------- orient
def test_orient_turns_toward_a_distant_point_at_three_times_its_bearing():
    # 20 deg off, 2 m away (beyond the turning reach): no backing, full turn 3 * 20 deg
    command, event = Orient(SPEC, attending(at(20.0, 2.0))).step(around())
    assert command == pytest.approx((0.0, 3.0 * math.radians(20.0))) and event == ""
    # 10 deg off: facing it (< 15 deg), explore next
    assert Orient(SPEC, attending(at(10.0, 2.0))).step(around())[1] == "facing"


def test_orient_backs_off_and_turns_slowly_from_a_point_at_the_snout():
    reach = HEAD_CENTRE + HEAD_RADIUS + 0.06  # the head's turning reach plus avoid_margin
    command, _ = Orient(SPEC, attending(at(20.0, HEAD_REACH))).step(around())
    # backing 1.5 x the shortfall, at most 0.08 m/s (0.09 m short here); turn slowed to its floor share 0.15
    assert command == pytest.approx((-0.08, 0.15 * 3.0 * math.radians(20.0)))
    # 0.02 m inside the reach: backing at 0.03 m/s, the turn slowed in proportion to the way from the snout
    command, _ = Orient(SPEC, attending(at(20.0, reach - 0.02))).step(around())
    slow = (reach - 0.02 - HEAD_REACH) / (reach - HEAD_REACH)
    assert command == pytest.approx((-0.03, slow * 3.0 * math.radians(20.0)))


def test_orient_attends_to_the_first_contacts_then_follows_the_newest():
    attention = Attention(target=np.array([9.0, 9.0]))
    orient = Orient(SPEC, attention)
    touch = np.array([[0.6, 0.2, 0.1], [0.8, 0.4, 0.0]])
    orient.enter(around(contacts=touch))
    orient.step(around(contacts=touch))
    np.testing.assert_allclose(attention.target, [0.7, 0.3])  # the centroid: a new object
    orient.step(around(contacts=np.array([[1.7, 1.3, 0.0]])))
    np.testing.assert_allclose(attention.target, [0.7 * 0.7 + 0.3 * 1.7, 0.7 * 0.3 + 0.3 * 1.3])


# ---------------------------------------------------------------------- explore
def explore(attention: Attention, until: float = 10.0) -> Explore:
    state = Explore(SPEC, attention, np.random.default_rng(0))
    state.until = until
    return state


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_explore_keeps_the_point_25_deg_to_its_side_at_the_whiskers_reach(side):
    # the point 35 deg to the side and 0.1 m beyond where it belongs (0.12 m beyond the head's centre):
    # 2.5 x 10 deg + 1.5 x 0.1 m, towards the side; half speed with the head clear
    target = at(side * 35.0, HEAD_CENTRE + 0.12 + 0.1)
    command, event = explore(attending(target, side)).step(around())
    assert command == pytest.approx((0.075, side * (2.5 * math.radians(10.0) + 0.15))) and event == ""


def test_explore_steers_the_snout_away_and_slows_near_the_object():
    # head 0.03 m clear (< avoid_margin 0.06): 8 x 0.03 rad/s away from the side; speed ramps from
    # 0 at 0.015 m to full at 0.075 m: a quarter of 0.075 m/s
    target = at(35.0, HEAD_CENTRE + 0.22)
    command, _ = explore(attending(target)).step(around(head_gap=0.03))
    assert command == pytest.approx((0.075 * 0.25, 2.5 * math.radians(10.0) + 0.15 - 8.0 * 0.03))


def test_explore_bout_ends_at_its_time_and_leave_acts_at_once():
    assert explore(attending(at(35.0, 1.0)), until=1.0).step(around(time=1.0)) == (None, "bout over")


def test_explore_bouts_last_3_to_8_s_on_either_side():
    sides, lengths = set(), []
    for seed in range(40):
        attention = Attention()
        state = Explore(SPEC, attention, np.random.default_rng(seed))
        state.enter(around(time=2.0))
        sides.add(attention.side)
        lengths.append(state.until - 2.0)
    assert sides == {-1.0, 1.0} and 3.0 <= min(lengths) and max(lengths) <= 8.0 and max(lengths) - min(lengths) > 3


# ---------------------------------------------------------------------- leave
def leave(heading_deg: float, until: float = 10.0) -> Leave:
    state = Leave(SPEC, Attention(), np.random.default_rng(0))
    state.heading, state.until = math.radians(heading_deg), until
    return state


def test_leave_turns_away_and_drives_once_within_45_deg():
    command, event = leave(20.0).step(around())
    assert command == pytest.approx((0.15, 3.0 * math.radians(20.0))) and event == ""
    assert leave(60.0).step(around()) == ((0.0, W_MAX), "")  # 3 x 60 deg/s clipped to 90 deg/s
    assert leave(20.0).step(around(head_gap=0.05))[0][0] == -0.05  # head within the margin: back off


def test_leave_hands_over_to_wander_after_its_time_within_20_deg():
    assert leave(10.0, until=1.0).step(around(time=1.0))[1] == "turned away"
    assert leave(25.0, until=1.0).step(around(time=1.0))[1] == ""
    assert leave(10.0, until=1.5).step(around(time=1.0))[1] == ""


def test_leave_heads_away_from_the_object_and_ignores_contacts_for_the_refractory_time():
    attention = attending([1.0, 0.0])
    state = Leave(SPEC, attention, np.random.default_rng(3))
    state.enter(around(time=2.0))
    assert state.until == 3.5 and attention.refractory_until == 6.0
    assert abs(math.remainder(state.heading - math.pi, 2 * math.pi)) <= 0.8


# ---------------------------------------------------------------------- avoid
def avoid(heading_deg: float) -> Avoid:
    state = Avoid(SPEC, Attention(), EnvironmentSpec(name="open").obstacles)
    state.heading = math.radians(heading_deg)
    return state


def test_avoid_drives_off_along_an_escape_heading_it_faces():
    # head exactly at the margin: speed ramps from 0 at 0.03 m to 0.075 m/s at 0.09 m - half of it
    command, event = avoid(10.0).step(around(head_gap=0.06))
    assert command == pytest.approx((0.0375, 3.0 * math.radians(10.0))) and event == ""


def test_avoid_turns_in_place_and_backs_off_when_cramped():
    assert avoid(90.0).step(around(head_gap=0.05, body_gap=0.05)) == ((0.0, W_MAX), "")
    assert avoid(-90.0).step(around(head_gap=0.5, body_gap=0.02)) == ((-0.05, -W_MAX), "")


def test_avoid_is_clear_at_the_margin_plus_004_with_nothing_ahead():
    assert avoid(90.0).step(around(head_gap=0.11, body_gap=0.2, ahead_distance=0.2)) == (None, "clear")
    assert avoid(90.0).step(around(head_gap=0.09, body_gap=0.2, ahead_distance=0.2))[1] == ""
    assert avoid(90.0).step(around(head_gap=0.11, body_gap=0.2, ahead_distance=0.08))[1] == ""


# ---------------------------------------------------------------------- the controller
def open_arena(size: float) -> EnvironmentSpec:
    return EnvironmentSpec.model_validate({"name": "open", "arena": {"size": size}})


def test_transition_table_covers_every_state_and_only_avoid_is_entered_when_too_close():
    states = {"wander", "orient", "explore", "leave", "avoid"}
    assert {a for a, _ in TRANSITIONS} == states and set(TRANSITIONS.values()) == states
    assert {a for (a, event), b in TRANSITIONS.items() if event == "too close"} == states - {"avoid"}
    assert all(b == "avoid" for (_, event), b in TRANSITIONS.items() if event == "too close")


def test_a_touch_ahead_is_oriented_to_and_explored_in_one_tick():
    ctrl = ForagingController(SPEC, open_arena(20.0).obstacles, np.random.default_rng(0))
    touch = np.array([[0.7, 0.05, 0.1], [0.7, -0.05, 0.1]])
    ctrl(Observation(time=0.0, pose=np.zeros(3), contacts=touch, deflection=np.zeros(24)))
    # wander hands over to orient at once, which faces the point (0 deg) and hands over to explore
    assert ctrl.mode == "explore" and 3.0 <= ctrl.states["explore"].until <= 8.0
    np.testing.assert_array_equal(ctrl.attention.target, [0.7, 0.0])


def test_a_touch_to_the_side_is_oriented_to():
    ctrl = ForagingController(SPEC, open_arena(20.0).obstacles, np.random.default_rng(0))
    ctrl(Observation(time=0.0, pose=np.zeros(3), contacts=np.array([[0.5, 0.5, 0.1]]), deflection=np.zeros(24)))
    assert ctrl.mode == "orient"


def test_too_close_to_a_wall_enters_avoid_with_the_free_most_smallest_turn():
    # east wall at x = 2; the head 0.02 m from it, the body 0.40 m
    x = 2.0 - HEAD_CENTRE - HEAD_RADIUS - 0.02
    ctrl = ForagingController(SPEC, open_arena(4.0).obstacles, np.random.default_rng(0))
    ctrl(Observation(time=0.0, pose=np.array([x, 0.0, 0.0]), contacts=NO_CONTACTS, deflection=np.zeros(24)))
    assert ctrl.mode == "avoid"
    # probes 0.5 m out at 0, +-30, +-60, ... deg: those at +-60 deg are 0.38 m from the wall, free enough
    # (capped at HEAD_RADIUS + 0.25 = 0.36 m); +-30 deg only 0.20 m; of the two smallest free turns, the
    # first probed (counter-clockwise) wins
    assert ctrl.states["avoid"].heading == pytest.approx(math.radians(60.0))


def test_while_attending_avoid_waits_for_half_the_margin():
    x = 2.0 - HEAD_CENTRE - HEAD_RADIUS - 0.04  # head 0.04 m clear: inside the margin, outside its half
    for mode, expected in (("wander", "avoid"), ("leave", "leave")):
        ctrl = ForagingController(SPEC, open_arena(4.0).obstacles, np.random.default_rng(0))
        ctrl.mode, ctrl.states["leave"].until, ctrl.states["leave"].heading = mode, 10.0, 1.0
        ctrl(Observation(time=0.0, pose=np.array([x, 0.0, 0.0]), contacts=NO_CONTACTS, deflection=np.zeros(24)))
        assert ctrl.mode == expected


def flank_stuck() -> tuple[Avoid, np.ndarray]:
    """Where the touch benchmark's training drive (touch-alike-shapes, seed 2968811710) dithered from
    sample 42 to the end of its run: the north landmark's west corner at the body's right flank, 0.03 m
    from it, the head far from everything."""
    env = load_environment("touch-alike-shapes")
    return Avoid(SPEC, Attention(), env.obstacles), np.array([-0.728, 2.0, 1.958])


def step_clearance(state: Avoid, pose: np.ndarray, heading: float) -> float:
    ahead = pose[:2] + 0.1 * np.array([math.cos(heading), math.sin(heading)])
    return float(footprint_clearance(state.obstacles, ahead[None], np.array([heading]))[0])


def test_an_escape_judged_at_the_head_alone_drives_the_flank_into_the_obstacle():
    state, pose = flank_stuck()
    state.enter(Surroundings(**{**vars(around()), "pose": pose}))
    # every head probe ahead is free enough, so the heading stays the one faced; 0.1 m along it the
    # body would touch the box (the guard refuses the drive: the dithering)
    assert state.heading == pytest.approx(pose[2])
    assert step_clearance(state, pose, state.heading) < 0.0


def test_an_avoid_that_starts_where_the_last_got_nowhere_judges_the_whole_footprint():
    state, pose = flank_stuck()
    here = Surroundings(**{**vars(around()), "pose": pose})
    now = float(footprint_clearance(state.obstacles, pose[None, :2], pose[2:])[0])
    state.failed_at = pose[:2] + 0.05  # within Headway's 0.1 m
    state.enter(here)
    assert step_clearance(state, pose, state.heading) > now > 0.0  # a step along it moves away
    assert state.failed_at is None  # used once
    state.failed_at = pose[:2] + 0.2  # another place: the head alone, as before
    state.enter(here)
    assert state.heading == pytest.approx(pose[2])


def test_a_stall_in_avoid_marks_the_place_and_the_next_avoid_there_gets_away():
    ctrl = ForagingController(SPEC, load_environment("touch-alike-shapes").obstacles, np.random.default_rng(0))
    pose = flank_stuck()[1]
    for t in np.arange(0.0, 3.2, 0.1):  # the robot does not move: Headway stalls after 3 s
        ctrl(Observation(time=float(t), pose=pose, contacts=NO_CONTACTS, deflection=np.zeros(24)))
    assert ctrl.mode == "avoid"  # stuck -> wander, too close -> avoid again in the same tick
    assert step_clearance(ctrl.states["avoid"], pose, ctrl.states["avoid"].heading) > 0.03


def test_the_touch_benchmark_training_drive_no_longer_stays_at_the_corner():
    # it stayed within 0.25 m from sample 42 to the end of its run (958 of 1000 samples)
    run = simulate_run(load_environment("touch-alike-shapes"), run_spec(kind="foraging", n_samples=100),
                       seed=2968811710, robot=RobotSpec(camera_width=16, camera_height=12))
    length, start = longest_stay(run.poses[:, :2])
    assert start + length < len(run.poses)


# ---------------------------------------------------------------------- the gains in the schema
GAINS = sorted(ForagingGains.model_fields)


def test_every_gain_is_documented_and_bounded():
    assert len(GAINS) >= 20
    for name in GAINS:
        field = ForagingGains.model_fields[name]
        bounds = {type(m).__name__ for m in field.metadata}
        assert field.description and {"Gt", "Ge"} & bounds and "Le" in bounds, name


def test_the_dump_holds_every_gain_and_gains_at_their_defaults_leave_the_run_hash_as_it_was():
    """The dump is exact (``gains`` with all of them); the key form, like the dump of simulator
    version 6, leaves out the gains at their defaults, so the run hash is as it was."""
    assert set(SPEC.model_dump(mode="json")["gains"]) == set(GAINS)
    assert not set(GAINS) & set(key_form(SPEC))
    env, robot = open_arena(4.0), RobotSpec()
    explicit = run_spec(kind="foraging", n_samples=1, gains={"avoid_turn_gain": 3.0, "leave_jitter": 0.8})
    assert run_hash(env, explicit, robot, 0) == run_hash(env, SPEC, robot, 0)


@pytest.mark.parametrize("name", GAINS)
def test_a_changed_gain_is_in_the_dump_round_trips_and_changes_the_hash(name):
    half = 0.5 * ForagingGains.model_fields[name].default
    spec = run_spec(kind="foraging", n_samples=1, gains={name: half})
    dumped = spec.model_dump(mode="json")
    assert dumped["gains"][name] == half and run_spec(dumped) == spec
    assert key_form(spec)[name] == half  # at the top level, as simulator version 6 dumped it
    env, robot = open_arena(4.0), RobotSpec()
    assert run_hash(env, spec, robot, 0) != run_hash(env, SPEC, robot, 0)


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("avoid_turn_gain", 0.0, "greater than 0"),
        ("contact_weight", 1.5, "less than or equal to 1"),
        ("leave_jitter", -0.1, "greater than or equal to 0"),
        ("orient_done_deg", 120.0, "less than or equal to 90"),
    ],
)
def test_a_gain_out_of_range_is_refused_in_one_line_naming_its_key_path(tmp_path, capsys, key, value, message):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({
        "name": "t",
        "train": {"environment": E1, "run": {"kind": "foraging", "n_samples": 5, "gains": {key: value}}},
        "evaluations": [{"name": "E1", "environment": E1, "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
    }))
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vitaplace: error: {path}: train.run.gains.{key}: ")
    assert message in lines[0]
