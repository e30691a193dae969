"""Tests of the landmark-visits training run (``kind: visits``, `VisitsController`): its
approach poses worked by hand on a cylinder, the share of time it spends visiting, that its
visits whisk the landmarks (more samples with contact than foraging's at the same seed), that
a seed reproduces it, and its settings refused at validate naming the key."""

from __future__ import annotations

import math
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import numpy as np
import pytest
import yaml

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)
from vitaplace.engine.cli.main import main
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import ScenarioError
from vitaplace.engine.sim.clearance import HEAD_CENTRE, HEAD_RADIUS
from vitaplace.engine.sim.controllers import VisitsController, make_controller
from vitaplace.engine.sim.environment import load_environment
from vitaplace.engine.sim.robot import RobotSpec
from vitaplace.engine.sim.simulate import run_spec, simulate_run

#: images are not looked at here: a tiny camera saves rendering time
ROBOT = RobotSpec(camera_width=16, camera_height=12)
WORLD = "touch-alike-shapes"


def visits(env_name: str = "e1", **settings: object) -> VisitsController:
    controller, _ = make_controller(load_environment(env_name), run_spec(kind="visits", n_samples=10, **settings),
                                    np.random.default_rng(0))
    assert isinstance(controller, VisitsController)
    return controller


def test_an_approach_pose_faces_a_cylinder_from_behind_the_robot_with_the_head_at_the_drawn_gap():
    # e1's cyl_south: centre (0, -2.138), radius 0.5. The robot faces south (-90 deg); with no
    # spread the base lies north of the centre (-90 + 180 deg), facing south, its centre at
    # radius + gap + head centre + head radius from the cylinder's centre, the head's disc
    # `gap` from the outline: 0.5 + 0.2 + 0.5 + 0.113 = 1.313 north, at (0, -0.825).
    controller = visits(visit_spread_deg=0, visit_distance=(0.2, 0.2))
    controller.tactile = [controller.env.landmark_names().index("cyl_south")]
    station = controller.draw_station(np.array([0.0, 0.0, -math.pi / 2]))
    assert station is not None and station.name == "cyl_south"
    np.testing.assert_allclose(station.point, (0.0, -2.138 + 0.5 + 0.2 + HEAD_CENTRE + HEAD_RADIUS), atol=1e-3)
    assert abs(math.remainder(station.facing + math.pi / 2, 2 * math.pi)) < 1e-3


def test_the_landmark_visited_is_the_nearest_other_than_the_last_and_its_pose_within_the_spread():
    controller = visits(WORLD, visit_spread_deg=20)
    names = controller.env.landmark_names()
    pose = np.array([-1.0, 0.3, math.pi])  # facing west, nearest to the west landmark
    for last, expected in ((-1, "west"), (names.index("west"), None)):
        controller.last = last
        station = controller.draw_station(pose)
        assert station is not None and (expected is None or station.name == expected)
        assert station.name != names[last] if last >= 0 else True
        centre = np.asarray(controller.env.landmarks[station.landmark].pos[:2])
        direction = math.atan2(station.point[1] - centre[1], station.point[0] - centre[0])
        assert abs(math.remainder(direction - (pose[2] + math.pi), 2 * math.pi)) <= math.radians(20) + 1e-9


@pytest.fixture(scope="module")
def runs():
    """A visits run and a foraging run of 300 samples in the benchmark's training world, seed 0."""
    env = load_environment(WORLD)
    return {kind: simulate_run(env, run_spec(kind=kind, n_samples=300), 0, ROBOT, progress=False)
            for kind in ("visits", "foraging")}


def test_visits_take_their_share_of_the_time_and_whisk_more_than_foraging(runs):
    modes = runs["visits"].attrs["controller_modes"]
    visiting = sum(n for mode, n in modes.items() if mode.startswith("visit "))
    # a visit starts while the share so far is below visit_share (0.5) and runs to its end
    assert abs(visiting / sum(modes.values()) - 0.5) <= 0.1
    assert modes["visit hold"] >= 4 * 5  # several visits held with contact (>= 4 cycles of 5 ticks each)
    assert runs["visits"].touch_mask().mean() > runs["foraging"].touch_mask().mean()
    assert runs["visits"].attrs["body_collision_instants"] == 0


def test_a_seed_reproduces_a_visits_run():
    env = load_environment(WORLD)
    a, b = (simulate_run(env, run_spec(kind="visits", n_samples=30), 3, ROBOT, progress=False) for _ in range(2))
    np.testing.assert_array_equal(a.poses, b.poses)
    c = simulate_run(env, run_spec(kind="visits", n_samples=30), 4, ROBOT, progress=False)
    assert not np.array_equal(a.poses, c.poses)


def _scenario(tmp_path: Path, run: dict, environment: str = WORLD) -> Path:
    path = tmp_path / "visits.yaml"
    path.write_text(yaml.safe_dump({
        "name": "visits", "train": {"environment": environment, "run": {"kind": "visits", "n_samples": 8, **run}},
        "evaluations": [{"name": "E", "environment": WORLD, "run": {"kind": "teleop", "n_samples": 8}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
    }))
    return path


@pytest.mark.parametrize("run, message", [
    ({"visit_share": 0}, r"train\.run\.visit_share: .*greater than 0"),
    ({"visit_share": 1.5}, r"train\.run\.visit_share: .*less than or equal to 1"),
    ({"visit_distance": [0.3, 0.1]}, r"train\.run.*visit_distance must be \[min, max\] with 0 < min <= max <= 2"),
    ({"visit_spread_deg": 200}, r"train\.run\.visit_spread_deg: .*less than or equal to 180"),
    ({"hold_cycles": [3, 2]}, r"train\.run.*hold_cycles must be \[min, max\] with 1 <= min <= max"),
    ({"hold_cycles": [9, 12]}, r"train\.run.*every hold \(9 whisk cycles at least\) is longer than the run's 8"),
    ({"station_count": 2}, r"train\.run\.station_count"),
], ids=["no visits", "share over 1", "distance reversed", "spread over 180", "hold reversed", "hold over the run",
        "a stations key"])
def test_bad_visit_settings_are_refused_naming_the_key(tmp_path, run, message):
    with pytest.raises(ScenarioError, match=message):
        load_scenario(_scenario(tmp_path, run))


@pytest.mark.parametrize("environment, message", [
    ({"name": "routeless", "extends": "e1.yaml", "route": []}, r"'routeless' has 0 route waypoints and 3 tactile"),
    ({"name": "hidden", "extends": "e1.yaml", "landmarks": [
        {"name": "ghost", "type": "box", "pos": [2.138, 0.0], "size": [1.0, 1.0, 0.3], "tactile": False}]},
     r"'hidden' has \d+ route waypoints and 0 tactile landmarks"),
], ids=["no route", "no tactile landmark"])
def test_a_visits_run_needs_a_route_and_tactile_landmarks(tmp_path, environment, message):
    shipped = Path(vitaplace.engine.sim.__file__).resolve().parents[2] / "scenarios" / "environments"
    env_file = tmp_path / "env.yaml"
    env_file.write_text(yaml.safe_dump({**environment, "extends": str(shipped / environment["extends"])}))
    with pytest.raises(ScenarioError, match=r"train\.run\.kind: a visits run needs the environment's route and "
                       r"tactile landmarks; " + message):
        load_scenario(_scenario(tmp_path, {}, environment=str(env_file)))


def test_validate_says_it_in_one_line_with_exit_status_2(tmp_path, capsys):
    assert main(["validate", str(_scenario(tmp_path, {"visit_share": 0}))]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "train.run.visit_share" in lines[0], lines
