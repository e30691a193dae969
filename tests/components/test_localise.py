"""The place-recognition task (engine/tasks/localise.py, ``WhiskEye-Localise-v0``): Gymnasium's
checker, the reward by the benchmark's rule, the true pose kept out of the observation, the
vector entry point sharing one reference map."""

from __future__ import annotations

import inspect
import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import vitaplace.engine.tasks  # noqa: E402,F401  (registers the task)
from vitaplace.engine.base.errors import UserError  # noqa: E402
from vitaplace.engine.data.dataset import Run, write_run  # noqa: E402
from vitaplace.engine.sim.environment import environment_files, load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.tasks.localise import ENV_ID, LocaliseEnv, build_map  # noqa: E402

SMALL = {"camera_width": 32, "camera_height": 24}  # small frames: fast tests
SAMPLES = 30  # a short reference drive: 30 whisk cycles along E1's route


@pytest.fixture(scope="module")
def reference_map():
    return build_map(load_environment("e1"), RobotSpec(**SMALL), reference_samples=SAMPLES)


def placed(run: Run, k: int, pose) -> Run:
    """Reference sample ``k`` as a one-sample run taken at the hand-placed ``pose``."""
    one = run.subset([k])
    return Run.from_arrays(images=one.images, theta=one.theta, xy=one.xy, poses=np.array([pose], dtype=np.float64),
                           times=one.times, deflection=one.deflection, contact_points=one.contacts(0)[0],
                           contact_normals=one.contacts(0)[1], contact_offsets=one.contact_offsets, name="placed")


def test_gymnasiums_checker_passes(reference_map):
    env = gymnasium.make(ENV_ID, robot=SMALL, reference_map=reference_map, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    assert env.spec.max_episode_steps == 200 and env.spec.vector_entry_point is not None
    env.close()


@pytest.mark.parametrize(("offset", "turn_deg", "reward"), [
    ((0.2, 0.0), 0.0, 1.0),     # 0.2 m <= tau 0.3 m, same heading
    ((0.18, 0.2), 0.0, 1.0),    # 0.269 m <= tau
    ((0.35, 0.0), 0.0, 0.0),    # 0.35 m > tau
    ((0.0, 0.0), 25.0, 1.0),    # 25 deg <= 30 deg
    ((0.0, 0.0), 40.0, 0.0),    # 40 deg > 30 deg, on the spot
    ((0.0, 0.0), -355.0, 1.0),  # -355 deg wraps to 5 deg
])
def test_the_reward_is_the_benchmarks_rule_at_a_hand_placed_pose(reference_map, offset, turn_deg, reward):
    """A sample identical to reference sample k is best matched to k (distance 0); placed
    ``offset`` metres and ``turn_deg`` degrees from k's pose, it is right by the benchmark's
    rule (within tau = 0.3 m and 30 deg) exactly when the hand-worked
    distance and heading difference are within them."""
    env = LocaliseEnv(robot=SMALL, reference_map=reference_map)
    k = SAMPLES // 2
    x, y, yaw = reference_map.run.poses[k]
    step = env.localise(placed(reference_map.run, k, (x + offset[0], y + offset[1], yaw + math.radians(turn_deg))))
    assert step.best_match == k and step.match_distance == 0.0
    assert step.reward == reward and step.correct is (reward == 1.0)
    if turn_deg == 40.0:
        assert step.match_error_m == math.inf  # facing elsewhere: no match at any distance
    else:
        assert step.match_error_m == pytest.approx(math.hypot(*offset), abs=1e-12)
    np.testing.assert_array_equal(step.match_pose, reference_map.run.poses[k])


def test_a_step_is_scored_at_the_true_pose_that_only_info_holds(reference_map, caplog):
    """The observation is the robot's senses (image, theta, xy); the true pose is in info,
    where it equals the pose of the sample's run, and the step's reward is the rule's verdict
    worked here from info's poses. The plugin's warning about samples without whisker
    contact is logged once, not at every such step."""
    env = gymnasium.make(ENV_ID, robot=SMALL, reference_map=reference_map)
    assert set(env.observation_space) == {"image", "theta", "xy"}
    obs, info = env.reset(seed=1)
    assert set(obs) == {"image", "theta", "xy"} and info["true_pose"].shape == (3,)
    start = info["true_pose"]
    assert np.min(np.hypot(*(reference_map.run.poses[:, :2] - start[:2]).T)) < 1e-6  # a reference pose (float32)
    rewards, untouched = [], 0
    for _ in range(6):
        obs, reward, terminated, truncated, info = env.step(np.array([0.15, 0.0, 0.1, 1.0], dtype=np.float32))
        assert set(obs) == {"image", "theta", "xy"} and not terminated
        inner = env.unwrapped._inner
        np.testing.assert_allclose(info["true_pose"], inner.last_sample().poses[0], atol=0)
        dyaw = (info["true_pose"][2] - info["match_pose"][2] + math.pi) % (2 * math.pi) - math.pi
        right = (math.hypot(*(info["true_pose"][:2] - info["match_pose"][:2])) <= 0.3
                 and abs(math.degrees(dyaw)) <= 30.0)
        assert reward == float(right) == info["reward"]
        rewards.append(reward)
        untouched += info["whisker_contacts"] == 0
    assert untouched >= 2 and sum("has no contacts" in r.getMessage() for r in caplog.records) == 1
    assert env.unwrapped.last_step.true_pose is not None
    assert sum(rewards) >= 1  # started on the reference drive: some place is recognised
    env.close()
    with pytest.raises(RuntimeError, match=rf"^step\(\): this {ENV_ID} environment is closed"):
        env.unwrapped.step(np.zeros(4, dtype=np.float32))


def test_the_vector_entry_point_shares_one_map_and_steps_two_envs(monkeypatch):
    """``make_vec`` uses the task's vector entry point: two environments in this process, one
    reference drive simulated and one plugin fitted for both, each truncated by the spec's
    limit; the map is built when the environments are made there, not at the first step."""
    import vitaplace.engine.tasks.localise as localise

    built = []
    real = localise.build_map
    monkeypatch.setattr(localise, "build_map", lambda *a, **k: built.append(1) or real(*a, **k))
    env = gymnasium.make_vec(ENV_ID, num_envs=2, robot=SMALL, reference_samples=12)
    assert len(built) == 1
    first, second = (e.unwrapped for e in env.envs)
    assert first.reference_map() is second.reference_map()
    assert [e._max_episode_steps for e in env.envs] == [200, 200]
    obs, info = env.reset(seed=0)
    assert obs["image"].shape == (2, 24, 32, 3) and "pose" not in obs and info["true_pose"].shape == (2, 3)
    obs, reward, terminated, truncated, info = env.step(np.array([[0.1, 0.0, 0.0, 1.0]] * 2, dtype=np.float32))
    assert reward.shape == (2,) and set(np.unique(reward)) <= {0.0, 1.0}
    np.testing.assert_array_equal(reward, info["correct"].astype(float))
    env.close()
    assert len(built) == 1


def test_the_map_is_built_at_the_first_reset_in_the_process_that_steps(reference_map, monkeypatch):
    import vitaplace.engine.tasks.localise as localise

    built = []
    monkeypatch.setattr(localise, "build_map", lambda *a, **k: built.append(k) or reference_map)
    env = LocaliseEnv(robot=SMALL, reference_samples=7, reference_seed=3)
    assert not built  # made, not yet reset: no drive, no GL context
    env.reset(seed=0)
    env.reset(seed=1)
    assert built == [{"reference": None, "reference_samples": 7, "reference_seed": 3, "plugin": "handcrafted",
                      "params": None}]


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"tau": -0.1}, r"^WhiskEye-Localise-v0: tau: Input should be greater than 0"),
    ({"heading_tolerance_deg": 200}, r"^WhiskEye-Localise-v0: heading_tolerance_deg: Input should be less than or"),
    ({"reference_samples": 0}, r"^WhiskEye-Localise-v0: reference_samples 0: expected a whole number >= 1$"),
    # E1's arena is 6.05 m square: its diagonal 6.05 * sqrt(2) = 8.556 m; at tau 100 every step would score 1
    ({"tau": 100}, r"^WhiskEye-Localise-v0: tau: 100\.0 m is not below the 8\.56 m diagonal of e1: every pair"),
    ({"tau": 8.557}, r"^WhiskEye-Localise-v0: tau: 8\.557 m is not below the 8\.56 m diagonal of e1"),
])
def test_bad_settings_are_one_line_naming_the_setting(kwargs, message):
    with pytest.raises(UserError, match=message) as err:
        LocaliseEnv(robot=SMALL, **kwargs)
    assert "\n" not in str(err.value)


def test_a_tau_below_the_arenas_diagonal_is_kept():
    assert LocaliseEnv(robot=SMALL, tau=8.55).tau == 8.55  # just below E1's 8.556 m diagonal


def test_a_misspelt_keyword_is_one_line_with_a_did_you_mean():
    """``make`` hands every keyword to the environment: a misspelt one is a bad setting named
    in one line, and the signature still lists every keyword by name."""
    with pytest.raises(UserError, match=r"^WhiskEye-Localise-v0: unknown keyword 'tua'; did you mean 'tau'\? "
                                        r"\(keywords: environment, robot, .*tau, heading_tolerance_deg") as err:
        gymnasium.make(ENV_ID, robot=SMALL, tua=0.3)
    assert "\n" not in str(err.value)
    assert {"tau", "reference", "reference_map"} <= set(inspect.signature(LocaliseEnv).parameters)


@pytest.fixture(scope="module")
def e1_file(reference_map, tmp_path_factory):
    """The reference drive (E1, 24x32 images) as a run file."""
    return write_run(tmp_path_factory.mktemp("runs") / "e1route.h5", reference_map.run)


def test_a_reference_of_another_environment_is_refused_naming_it(e1_file):
    """The run file records the environment it was driven in (E1): a task in E2 refuses it
    at make(), where it would score E2's poses against E1's drive."""
    with pytest.raises(UserError, match=r"^WhiskEye-Localise-v0: reference: .*e1route\.h5 was recorded in environment "
                                        r"'e1', this task's is 'e2'") as err:
        gymnasium.make(ENV_ID, environment="e2", robot=SMALL, reference=e1_file)
    assert "\n" not in str(err.value)


def test_a_reference_of_another_image_size_is_refused_naming_it(e1_file, reference_map):
    """A drive with 24x32 images cannot be matched by a robot whose camera is 120x160 (the
    plugin fitted on one cannot read the other), as a scenario's runs."""
    with pytest.raises(UserError, match=r"^WhiskEye-Localise-v0: reference: .*e1route\.h5 has 24x32x3 images, "
                                        r"the task's robot 120x160x3$"):
        LocaliseEnv(environment="e1", reference=e1_file)
    with pytest.raises(UserError, match=r"^WhiskEye-Localise-v0: reference: 'reference' has 24x32x3 images"):
        LocaliseEnv(environment="e1", robot={"camera_width": 48, "camera_height": 24}, reference=reference_map.run)


def test_a_reference_of_the_same_environment_and_robot_is_kept(e1_file):
    """E1 named by its shipped name or by its file's path is the environment the file records."""
    for environment in ("e1", environment_files()["e1"]):
        env = LocaliseEnv(environment=environment, robot=SMALL, reference=e1_file)
        assert env.environment.name == "e1" and len(env.reference_map().run) == SAMPLES


def test_a_wrong_shaped_action_names_the_expected_shape(reference_map):
    env = gymnasium.make(ENV_ID, robot=SMALL, reference_map=reference_map)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"^action \[0\.0, 0\.0, 0\.0\] has shape \(3,\): expected an array of shape "
                                         r"\(4,\), float32 \(forward, strafe, turn, whisk amplitude\)$"):
        env.step(np.zeros(3))
    env.close()


def test_the_plugins_distances_are_checked_as_the_pipelines(reference_map, monkeypatch):
    """Each step's distances pass the pipeline's checks (`check_methods`): a plugin returning
    NaN is one line naming the method and plugin, not a reward read from a NaN best match."""
    extractor_class = type(reference_map.extractor)
    monkeypatch.setattr(extractor_class, "distance", lambda self, q, r: np.full((1, len(reference_map.run)), np.nan))
    env = gymnasium.make(ENV_ID, robot=SMALL, reference_map=reference_map)
    env.reset(seed=0)
    with pytest.raises(UserError, match=r"^distance \(plugin 'handcrafted'\): feature 'distance' has NaN or infinite "
                                        r"values in 1 samples"):
        env.step(np.array([0.1, 0.0, 0.0, 1.0], dtype=np.float32))
    env.close()
