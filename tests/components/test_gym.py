"""The Gymnasium environment (engine/sim/gym_env.py, the `gym` extra): Gymnasium's own checker,
seeded resets, the drive and whisking against the robot's physics, recording a run file."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import vitaplace.engine.sim.gym_env  # noqa: E402,F401  (registers the ids)
from vitaplace.engine.data.dataset import open_run  # noqa: E402
from vitaplace.engine.sim.environment import EnvironmentSpecError  # noqa: E402
from vitaplace.engine.sim.gym_env import MAX_SPEED, MAX_TURN, WhiskEyeEnv  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402

SMALL = {"camera_width": 32, "camera_height": 24}  # small frames: fast tests
BARE = {"name": "bare", "arena": {"size": 6.0, "wall_thickness": 0.1}, "landmarks": [], "route": []}


def make(env_id: str = "WhiskEye-E1-v0", **kwargs):
    return gymnasium.make(env_id, robot=SMALL, **kwargs).unwrapped


@pytest.fixture
def bare(tmp_path):
    import yaml

    path = tmp_path / "bare.yaml"
    path.write_text(yaml.safe_dump(BARE))
    env = WhiskEyeEnv(environment=path, robot=SMALL, render_mode="rgb_array", record=True)
    yield env
    env.close()


@pytest.mark.parametrize("env_id", ["WhiskEye-E1-v0", "WhiskEye-E2-v0", "WhiskEye-E3-v0"])
def test_gymnasiums_checker_passes(env_id):
    env = gymnasium.make(env_id, robot=SMALL, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    assert env.spec.max_episode_steps == 1000
    env.close()


def test_any_environment_file_and_the_spaces(bare):
    obs, _ = bare.reset(seed=0)
    assert obs["image"].shape == (24, 32, 3) and obs["image"].dtype == np.uint8
    assert obs["theta"].shape == (24,) and obs["xy"].shape == (24, 2) and obs["pose"].shape == (3,)
    # the robot's own limits: a run's speed is at most 1 m/s
    np.testing.assert_array_equal(bare.action_space.high, [MAX_SPEED, MAX_SPEED, MAX_TURN, 1.0])
    assert MAX_SPEED == 1.0
    np.testing.assert_array_equal(bare.render(), obs["image"])
    # reset puts the whiskers at full protraction, where every sample is taken
    np.testing.assert_allclose(obs["theta"], math.radians(RobotSpec().protraction_max_deg), atol=1e-6)


def test_the_same_seed_gives_the_same_episode_and_another_seed_another_start(seed):
    a, b = make(), make()
    rng = np.random.default_rng(seed)
    first_a, _ = a.reset(seed=seed)
    first_b, _ = b.reset(seed=seed)
    for key in first_a:
        np.testing.assert_array_equal(first_a[key], first_b[key])
    for _ in range(2):
        action = rng.uniform(a.action_space.low, a.action_space.high).astype(np.float32)
        oa, ob = a.step(action)[0], b.step(action)[0]
        for key in oa:
            np.testing.assert_array_equal(oa[key], ob[key])
    other, _ = b.reset(seed=seed + 1)
    assert np.hypot(*(other["pose"][:2] - first_a["pose"][:2])) > 1e-3


def test_pure_forward_motion_covers_speed_times_time_less_the_servo_lag(bare):
    """The base follows its velocity command through a critically damped pose servo of
    bandwidth w = 2 pi base_servo_hz: after a ramp of speed v it trails the reference by
    2 v / w (the ramp's steady-state error of a critically damped second-order loop), so
    n whisk cycles at v cover v n T - 2 v / w (v = 0.2 m/s, T = 0.5 s, 4 cycles: 0.4 m less
    6.4 mm) along the heading, and nothing sideways."""
    v, n, yaw = 0.2, 4, math.radians(30)
    obs, _ = bare.reset(options={"start": [-1.0, -1.0, math.degrees(yaw)]})
    start = obs["pose"].astype(float)
    for _ in range(n):
        obs, _, terminated, truncated, _ = bare.step(np.array([v, 0.0, 0.0, 1.0], dtype=np.float32))
        assert not terminated and not truncated
    moved = obs["pose"][:2] - start[:2]
    along = moved @ [math.cos(yaw), math.sin(yaw)]
    across = moved @ [-math.sin(yaw), math.cos(yaw)]
    robot = RobotSpec()
    expected = v * n * robot.whisk_period - 2 * v / (2 * math.pi * robot.base_servo_hz)
    assert along == pytest.approx(expected, abs=2e-3)
    assert abs(across) < 1e-3 and abs(obs["pose"][2] - yaw) < 1e-3


def test_strafe_and_turn_move_the_base_as_commanded(bare):
    obs, _ = bare.reset(options={"start": [0.0, 0.0, 0.0]})
    for _ in range(2):
        obs = bare.step(np.array([0.0, 0.2, 0.0, 1.0], dtype=np.float32))[0]
    assert obs["pose"][1] > 0.15 and abs(obs["pose"][0]) < 1e-3  # leftward = +y at yaw 0
    obs, _ = bare.reset(options={"start": [0.0, 0.0, 0.0]})
    for _ in range(2):
        obs = bare.step(np.array([0.0, 0.0, 0.5, 1.0], dtype=np.float32))[0]
    # 0.5 rad/s for 1 s less the same servo lag: 0.5 - 2 * 0.5 / (20 pi)
    assert obs["pose"][2] == pytest.approx(0.5 - 1.0 / (20 * math.pi), abs=5e-3)


def test_whisk_amplitude_zero_holds_the_whiskers_and_a_wall_bends_them(bare):
    """Without whisking, in open space nothing moves a whisker off full protraction and its
    base stays undeflected; whisking at full amplitude sweeps them through the full range;
    driving into the east wall brings whisker contact, then the body's (terminated)."""
    hold = np.array([0.0, 0.0, 0.0, 0.0], dtype=np.float32)
    bare.reset(options={"start": [0.0, 0.0, 0.0]})
    for _ in range(2):
        obs, _, _, _, info = bare.step(hold)
    assert np.abs(obs["xy"]).max() < 1e-4 and info["whisker_contacts"] == 0
    np.testing.assert_allclose(obs["theta"], math.radians(60.0), atol=1e-3)
    series = bare._steps[-1]["series"]
    assert np.abs(series).max() < 1e-4  # all cycle long
    obs, _, _, _, info = bare.step(np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32))
    assert info["whisker_contacts"] == 0
    # facing the east wall (inner face at x = 3 m), 2.9 m ahead the whiskers' tips at ~0.75 m
    bare.reset(options={"start": [1.7, 0.0, 0.0]})
    contacts, deflection, terminated, steps = 0, 0.0, False, 0
    while not terminated and steps < 20:
        obs, _, terminated, _, info = bare.step(np.array([0.3, 0.0, 0.0, 1.0], dtype=np.float32))
        contacts += info["whisker_contacts"]
        deflection = max(deflection, float(np.abs(bare._steps[-1]["series"]).max()))
        steps += 1
    assert contacts > 0 and math.degrees(deflection) > 5.0
    # the snout (0.58 m ahead of the base) reaches the wall 3 - 1.7 - 0.58 = 0.72 m on: 5 cycles at 0.3 m/s
    assert terminated and steps in (5, 6), steps
    assert obs["pose"][0] + 0.58 == pytest.approx(3.0, abs=0.1)


def test_a_recorded_drive_is_a_run_file_the_loader_reads(bare, tmp_path):
    obs, _ = bare.reset(seed=3, options={"start": [0.0, 0.0, 0.0]})
    rng = np.random.default_rng(3)
    poses, images = [], []
    for _ in range(5):
        action = rng.uniform([0.1, -0.1, -0.3, 0.5], [0.3, 0.1, 0.3, 1.0]).astype(np.float32)
        obs = bare.step(action)[0]
        poses.append(obs["pose"])
        images.append(obs["image"])
    path = bare.write_run(tmp_path / "drive.h5")
    run = open_run(path)
    assert len(run) == 5
    np.testing.assert_allclose(run.poses, np.array(poses), atol=1e-5)
    np.testing.assert_array_equal(run.images, np.array(images))
    assert run.attrs["run"]["kind"] == "gym" and len(run.attrs["run"]["actions"]) == 5
    assert run.attrs["environment"] == "bare" and run.deflection.shape == (5, 25, 24, 2)


def test_bad_input_is_one_clear_line(bare, tmp_path):
    with pytest.raises(EnvironmentSpecError, match=r"nowhere\.yaml: no such environment file"):
        WhiskEyeEnv(environment=tmp_path / "nowhere.yaml")
    with pytest.raises(ValueError, match=r"render_mode 'human'"):
        WhiskEyeEnv(environment="e1", render_mode="human")
    bare.reset(seed=0)
    for action in ([2.0, 0, 0, 1], [0, 0, 0, 1.5], [0, 0, 0, -0.1], [np.nan, 0, 0, 1]):
        with pytest.raises(ValueError, match=r"^action .* is outside the action space .*"
                                             r"\[-1\.0, -1\.0, -1\.0, 0\.0\]\.\.\[1\.0, 1\.0, 1\.0, 1\.0\]; "
                                             r"gymnasium\.wrappers\.ClipAction clips") as err:
            bare.step(np.array(action, dtype=np.float32))
        assert "\n" not in str(err.value)
    for action in ([0.1, 0, 0], [[0.1, 0, 0, 1]], 0.5):  # the wrong shape: named, not "outside the space"
        with pytest.raises(ValueError, match=r"^action .* has shape \(.*\): expected an array of shape \(4,\), "
                                             r"float32 \(forward, strafe, turn, whisk amplitude\)$"):
            bare.step(np.array(action, dtype=np.float32))
    with pytest.raises(ValueError, match=r"unknown option 'pose' \(options: start\)"):
        bare.reset(options={"pose": [0, 0, 0]})
    with pytest.raises(ValueError, match=r"option 'start' .* is outside the arena"):
        bare.reset(options={"start": [5.0, 0, 0]})
    e1 = make()
    # E1's cylinder (r 0.5 m) at (0, -2.138): the body (r 0.23 m) of a base 0.338 m from its
    # centre overlaps it by 0.5 + 0.23 - 0.338 = 0.392 m
    with pytest.raises(ValueError, match=r"option 'start' .* 0\.39 m into an obstacle"):
        e1.reset(options={"start": [0.0, -1.8, 0.0]})
    fresh = WhiskEyeEnv(environment=BARE_SPEC(), robot=SMALL)
    fresh.reset(seed=0)
    fresh.step(np.zeros(4, dtype=np.float32))
    with pytest.raises(ValueError, match=r"made without record=True"):
        fresh.write_run(tmp_path / "x.h5")
    bare.reset(seed=0)
    with pytest.raises(ValueError, match=r"no steps taken since reset"):
        bare.write_run(tmp_path / "x.h5")
    assert not list(tmp_path.glob("x.h5*"))  # nothing half-written


def BARE_SPEC():
    from vitaplace.engine.sim.environment import EnvironmentSpec

    return EnvironmentSpec.model_validate(BARE)


def test_importing_without_gymnasium_names_the_extra():
    code = ("import sys; sys.modules['gymnasium'] = None\n"
            "import vitaplace.engine.sim.gym_env")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 1
    assert out.stderr.strip().splitlines()[-1] == (
        "ImportError: vitaplace's Gymnasium environment needs the gym extra: pip install 'vitaplace[gym]'")


def test_recorded_drives_are_scored_like_any_other_run(tmp_path):
    """Three drives written by the environment, as a scenario's recorded runs: the pipeline
    scores them (H, hand-crafted features). The query drive is the reference's arc 0.1 m to
    the side, step for step at the same headings, so every query has a revisit within
    tau = 0.3 m."""
    import vitaplace

    env = gymnasium.make("WhiskEye-E1-v0", record=True).unwrapped
    for name, dy, n in (("train", 0.3, 12), ("query", 0.05, 8), ("reference", -0.05, 10)):
        env.reset(seed=0, options={"start": [0.0, dy, 0.0]})
        for _ in range(n):
            assert not env.step(np.array([0.2, 0.0, 0.2, 1.0], dtype=np.float32))[2]
        env.write_run(tmp_path / f"{name}.h5", name=name)
    env.close()
    (tmp_path / "s.yaml").write_text(
        "name: gym-drives\nseed: 0\ntrain: {dataset: train.h5}\n"
        "evaluations:\n  - {name: E1, datasets: {query: query.h5, reference: reference.h5}}\n"
        "methods:\n  - {name: H, plugin: handcrafted}\nscoring: {tau: 0.3}\n")
    rows = vitaplace.run(tmp_path / "s.yaml", out=tmp_path / "out", until="evaluate")
    row = next(r for r in rows if r["direction"] == "query-to-reference")
    assert (row["environment"], row["method"], row["n_queries"], row["n_references"]) == ("E1", "H", 8, 10)
    assert row["n_revisit"] == 8 and 0.0 <= row["max_f1"] <= 1.0


def test_a_closed_environment_refuses_in_one_line(bare):
    bare.reset(seed=0)
    bare.close()
    bare.close()  # a second close does nothing (the fixture's close too)
    with pytest.raises(RuntimeError, match=r"^step\(\): this WhiskEyeEnv is closed; make a new one"):
        bare.step([0.0, 0.0, 0.0, 1.0])
    with pytest.raises(RuntimeError, match=r"^reset\(\): this WhiskEyeEnv is closed"):
        bare.reset(seed=1)


def test_the_camera_is_made_at_the_first_frame_in_the_process_that_renders(bare):
    """Constructing the environment makes no GL context (a vector environment's parent makes
    one to read the spaces); a camera whose process is not this one (inherited over fork) is
    never used: the next frame makes a new one, and the old renderer is not freed here."""
    from vitaplace.engine.sim import render

    assert bare._sim.camera is None
    first, _ = bare.reset(options={"start": [0.0, 0.0, 0.0]})
    camera = bare._sim.camera
    assert camera is not None and camera.pid == os.getpid()
    camera.pid = -1  # as if made by the process this one was forked from
    again, _ = bare.reset(options={"start": [0.0, 0.0, 0.0]})
    assert bare._sim.camera is not camera and bare._sim.camera.pid == os.getpid()
    assert render._INHERITED[-1] is not None and camera._renderer is None
    np.testing.assert_array_equal(again["image"], first["image"])


ASYNC = """
import os, sys
import gymnasium, numpy as np
import vitaplace.engine.sim.gym_env
from vitaplace.engine.sim.glsetup import GLUnavailableError

def drive(context):
    env = gymnasium.make_vec("WhiskEye-E1-v0", num_envs=2, vectorization_mode="async",
                             vector_kwargs={"context": context}, robot={"camera_width": 32, "camera_height": 24})
    obs, _ = env.reset(seed=0)
    for _ in range(2):
        obs = env.step(np.array([[0.2, 0.0, 0.0, 1.0]] * 2, dtype=np.float32))[0]
    env.close()
    print(context, *obs["pose"].ravel().tolist(), obs["image"].shape)

if __name__ == "__main__":
    drive("fork")
    drive("spawn")
    one = gymnasium.make("WhiskEye-E1-v0", robot={"camera_width": 32, "camera_height": 24})
    one.reset(seed=0)  # this process has made an EGL context now: a forked worker cannot
    try:
        drive("fork")
    except GLUnavailableError as exc:
        print("refused", exc)
"""


def test_make_vec_sync_and_async_with_fork_and_spawn(tmp_path):
    """Sync in this process; async in a fresh one (this one has rendered already) with forked
    and spawned workers, which step as the sync environments do; a worker forked after its
    parent made an EGL context refuses in one line instead of hanging."""
    sync = gymnasium.make_vec("WhiskEye-E1-v0", num_envs=2, vectorization_mode="sync", robot=SMALL)
    obs, _ = sync.reset(seed=0)
    for _ in range(2):
        obs = sync.step(np.array([[0.2, 0.0, 0.0, 1.0]] * 2, dtype=np.float32))[0]
    sync.close()
    assert obs["image"].shape == (2, 24, 32, 3)
    script = tmp_path / "drive_async.py"
    script.write_text(ASYNC)
    if os.environ.get("MUJOCO_GL", "egl") != "egl":
        pytest.skip("the fork refusal is for EGL")
    # its own session: a worker that hangs is ended with it
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
    assert proc.returncode == 0, stdout + stderr[-2000:]
    lines = stdout.splitlines()
    assert [line.split()[0] for line in lines] == ["fork", "spawn", "refused"], stdout
    for line in lines[:2]:
        np.testing.assert_allclose([float(v) for v in line.split()[1:7]], obs["pose"].ravel(), atol=1e-5)
    assert "forked from process" in lines[2] and "'spawn'" in lines[2]


@pytest.mark.parametrize("action", ["fast", ["a", "b", "c", "d"], None, {"forward": 1.0}, [0.1, [0.0, 0.0], 0.0]])
def test_an_action_that_is_not_numbers_is_refused_naming_it(bare, action):
    bare.reset(seed=0)
    with pytest.raises(ValueError, match=r"^action .* is not numbers: expected an array of shape \(4,\), float32"
                                         r" \(forward, strafe, turn, whisk amplitude\)$") as err:
        bare.step(action)
    assert "\n" not in str(err.value) and repr(action)[:6] in str(err.value)
