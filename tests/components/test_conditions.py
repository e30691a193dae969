"""A run's condition (engine/sim/condition.py): the query drive under other lights or a
degraded camera. Each degradation against a hand-computable expectation, the lights in the
rendered frames, the keys unchanged when no condition is set, bad values refused at validate."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.config.loading import load_scenario  # noqa: E402
from vitaplace.engine.sim.condition import (  # noqa: E402
    CameraCondition,
    Condition,
    Fog,
    LightCondition,
    Occlusion,
    degrade,
    kelvin_rgb,
    light_rgb,
    noise_rng,
)
from vitaplace.engine.sim.controllers import key_form, run_spec  # noqa: E402
from vitaplace.engine.sim.environment import load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import Simulator, run_hash  # noqa: E402

ROBOT = RobotSpec(camera_width=32, camera_height=24)
POSE = (0.0, 0.0, 0.3)


def frame(condition: Condition | None, seed: int = 0) -> np.ndarray:
    """The eye camera's frame at `POSE` in E1 under ``condition``."""
    sim = Simulator(load_environment("e1"), ROBOT, condition=condition, seed=seed)
    try:
        sim.reset(POSE)
        mujoco.mj_forward(sim.model, sim.data)
        return sim.render().copy()
    finally:
        sim.close()


# --------------------------------------------------------------------------- colour temperature


def test_kelvin_rgb_by_hand():
    # 1000 K: t = 10 -> R 255; G = 99.4708025861 ln 10 - 161.1195681661 = 67.92042; B: t <= 19 -> 0
    assert kelvin_rgb(1000) == pytest.approx((1.0, 67.92042 / 255, 0.0), abs=1e-6)
    # 2500 K: t = 25 -> G = 99.4708025861 ln 25 - 161.1195681661 = 159.06459;
    #   B = 138.5177312231 ln 15 - 305.0447927307 = 70.06818
    assert kelvin_rgb(2500) == pytest.approx((1.0, 159.06459 / 255, 70.06818 / 255), abs=1e-6)
    # 6600 K: t = 66 -> G = 99.4708 ln 66 - 161.1196 = 255.62 clipped to 255; B 255: white
    assert kelvin_rgb(6600) == (1.0, 1.0, 1.0)
    # 10000 K: t = 100 -> R = 329.698727446 * 40^-0.1332047592 = 329.6987 * exp(-0.491377) = 201.70435;
    #   G = 288.1221695283 * 40^-0.0755148492 = 218.07072; B 255
    assert kelvin_rgb(10000) == pytest.approx((201.70435 / 255, 218.07072 / 255, 1.0), abs=1e-6)


def test_a_light_is_its_level_times_intensity_times_colour():
    assert light_rgb(0.5, None) == [0.5, 0.5, 0.5]
    assert light_rgb(0.5, LightCondition()) == [0.5, 0.5, 0.5]
    r, g, b = kelvin_rgb(2500)
    assert light_rgb(0.4, LightCondition(intensity=2.0, colour_temperature_k=2500)) == pytest.approx(
        [0.8 * r, 0.8 * g, 0.8 * b])


# --------------------------------------------------------------------------- camera degradation


def test_exposure_scales_intensities_and_clips_at_255():
    image = np.array([[[0, 10, 100], [127, 128, 200]]], dtype=np.uint8)
    out = degrade(image, CameraCondition(exposure=2.0), noise_rng(0))
    assert out.tolist() == [[[0, 20, 200], [254, 255, 255]]]
    # 0.5: 10 * 0.5 = 5, 127 * 0.5 = 63.5 -> 64 (round half to even: 64), 201 * 0.5 = 100.5 -> 100
    out = degrade(np.array([[[10, 127, 201]]], dtype=np.uint8), CameraCondition(exposure=0.5), noise_rng(0))
    assert out.tolist() == [[[5, 64, 100]]]


@pytest.mark.parametrize("side, rows, cols", [("top", slice(0, 3), slice(None)), ("bottom", slice(7, 10), slice(None)),
                                              ("left", slice(None), slice(0, 4)), ("right", slice(None), slice(8, 12))])
def test_occlusion_blanks_the_stated_part_and_nothing_else(side, rows, cols):
    # 10 rows x 12 columns, share 0.3: 3 rows (top, bottom) or round(3.6) = 4 columns (left, right)
    image = np.full((10, 12, 3), 77, dtype=np.uint8)
    out = degrade(image, CameraCondition(occlusion=Occlusion(share=0.3, side=side)), noise_rng(0))
    expected = image.copy()
    expected[rows, cols] = 0
    assert np.array_equal(out, expected)
    # share 0.96: round(9.6) = 10 rows, round(11.52) = 12 columns: all of it
    assert np.array_equal(degrade(image, CameraCondition(occlusion=Occlusion(share=0.96, side=side)), noise_rng(0)),
                          np.zeros_like(image))


def test_noise_has_the_stated_std_and_is_reproducible_from_the_seed():
    image = np.full((200, 200, 3), 128, dtype=np.uint8)
    camera = CameraCondition(noise_std=10.0)
    out = degrade(image, camera, noise_rng(5)).astype(np.float64) - 128
    # 120,000 draws: the std's standard error is 10 / sqrt(2 * 120000) = 0.02; rounding adds 1/12 variance
    assert out.mean() == pytest.approx(0.0, abs=0.1)
    assert out.std() == pytest.approx(math.sqrt(100 + 1 / 12), abs=0.1)
    assert np.array_equal(degrade(image, camera, noise_rng(5)), degrade(image, camera, noise_rng(5)))
    assert not np.array_equal(degrade(image, camera, noise_rng(5)), degrade(image, camera, noise_rng(6)))


def test_blur_is_a_gaussian_of_the_stated_sigma():
    """A vertical edge (0 | 200) blurred by sigma = 1.5 px, against a plain convolution with
    the sampled Gaussian (truncated at 4 sigma: radius 6), edges extended."""
    image = np.zeros((8, 20, 3), dtype=np.uint8)
    image[:, 10:] = 200
    out = degrade(image, CameraCondition(blur_sigma_px=1.5), noise_rng(0))
    k = np.arange(-6, 7)
    w = np.exp(-k**2 / (2 * 1.5**2))
    w /= w.sum()
    row = image[0, :, 0].astype(float)
    expected = [sum(w[i] * row[min(max(c + k[i], 0), 19)] for i in range(len(k))) for c in range(20)]
    assert np.abs(out[3, :, 1].astype(float) - np.rint(expected)).max() <= 1
    assert np.all(out == out[:1])  # rows equal: the blur along the edge changes nothing


def test_the_default_camera_leaves_the_frame_as_it_is():
    image = np.random.default_rng(0).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    assert degrade(image, CameraCondition(), noise_rng(0)) is image


# --------------------------------------------------------------------------- rendered frames


def test_the_default_condition_renders_exactly_todays_frame():
    today = frame(None)
    assert np.array_equal(frame(Condition()), today)
    assert np.array_equal(frame(Condition(light=LightCondition(intensity=1.0))), today)


def test_the_query_drive_sees_another_frame_at_the_same_pose(tmp_path):
    """An evaluation's query condition reaches the query run only: rendered at one pose, the
    reference's frame is today's, the query's is darker and warmer."""
    scenario, _ = load_scenario("quickstart", overrides=[
        "evaluations.0.query_condition={light: {intensity: 0.6, colour_temperature_k: 2500}}"])
    pair = scenario.evaluations[0]
    query, reference = pair.run_for("query"), pair.run_for("reference")
    assert reference.condition is None and query.condition.light.intensity == 0.6
    today, dusk = frame(reference.condition), frame(query.condition)
    assert np.array_equal(today, frame(None))
    assert dusk.mean() < today.mean() - 10
    # warmer: blue loses more than red (2500 K: red 1, blue 0.27)
    drop = today.reshape(-1, 3).mean(axis=0) - dusk.reshape(-1, 3).mean(axis=0)
    assert drop[2] > drop[0] + 10


def test_a_sun_along_another_direction_lights_the_scene_otherwise():
    assert not np.array_equal(frame(Condition(light=LightCondition(direction=(1.0, 0.0, -0.1)))), frame(None))


def test_fog_mixes_each_surface_with_its_colour_by_depth():
    """OpenGL's linear fog, by hand: a surface at depth z along the camera's axis is seen as
    f x its clear colour + (1 - f) x the fog's, f = (end - z) / (end - start) clipped to [0, 1];
    the depths from MuJoCo's depth buffer at the same pose, the robot hidden as its camera hides it."""
    fog = Fog(start_m=0.5, end_m=3.0, colour=(0.8, 0.6, 0.4))
    clear, foggy = frame(None), frame(Condition(fog=fog))
    sim = Simulator(load_environment("e1"), ROBOT)
    try:
        sim.reset(POSE)
        mujoco.mj_forward(sim.model, sim.data)
        renderer = mujoco.Renderer(sim.model, ROBOT.camera_height, ROBOT.camera_width)
        renderer.enable_depth_rendering()
        hidden = mujoco.MjvOption()
        hidden.geomgroup[3] = 0  # the robot's own geoms (ROBOT_GROUP)
        renderer.update_scene(sim.data, camera="eye", scene_option=hidden)
        depth = renderer.render().astype(np.float64)
        renderer.close()
    finally:
        sim.close()
    assert depth.min() < 3.0 < depth.max()  # the frame holds fogged, half-fogged and clear surfaces
    f = np.clip((3.0 - depth) / (3.0 - 0.5), 0.0, 1.0)[..., None]
    expected = f * clear + (1 - f) * 255 * np.array([0.8, 0.6, 0.4])
    assert np.abs(foggy - expected).max() <= 1.5  # rounding to 0-255 on both frames


def test_fog_is_clear_air_by_default_and_changes_the_key():
    assert Condition(fog=None) == Condition()
    env = load_environment("e1")
    plain = run_spec(kind="teleop", n_samples=10)
    foggy = run_spec(kind="teleop", n_samples=10, condition={"fog": {"end_m": 4.0}})
    assert key_form(foggy)["condition"]["fog"] == {"start_m": 0.0, "end_m": 4.0, "colour": [0.75, 0.75, 0.75]}
    assert run_hash(env, foggy, RobotSpec(), 0) != run_hash(env, plain, RobotSpec(), 0)


def test_a_noisy_camera_is_reproducible_per_run_seed():
    noisy = Condition(camera=CameraCondition(noise_std=8.0))
    assert np.array_equal(frame(noisy, seed=3), frame(noisy, seed=3))
    assert not np.array_equal(frame(noisy, seed=3), frame(noisy, seed=4))


# --------------------------------------------------------------------------- keys


def test_the_keys_are_unchanged_without_a_condition_and_change_with_one():
    env = load_environment("e1")
    plain = run_spec(kind="teleop", n_samples=10)
    assert "condition" not in key_form(plain)
    assert key_form(run_spec(kind="teleop", n_samples=10, condition={})) == key_form(plain)
    night = run_spec(kind="teleop", n_samples=10, condition={"light": {"intensity": 0.2}})
    assert key_form(night)["condition"]["light"]["intensity"] == 0.2
    assert run_hash(env, night, RobotSpec(), 0) != run_hash(env, plain, RobotSpec(), 0)
    blurred = run_spec(kind="teleop", n_samples=10, condition={"camera": {"blur_sigma_px": 1.0}})
    assert run_hash(env, blurred, RobotSpec(), 0) not in (run_hash(env, night, RobotSpec(), 0),
                                                          run_hash(env, plain, RobotSpec(), 0))


# --------------------------------------------------------------------------- bad input

BAD = {
    "negative intensity": ("evaluations.0.query_condition={light: {intensity: -1}}",
                           "evaluations.0.query_condition.light.intensity: Input should be greater than or equal to 0"),
    "too cold": ("evaluations.0.query_condition={light: {colour_temperature_k: 500}}",
                 "evaluations.0.query_condition.light.colour_temperature_k: "
                 "Input should be greater than or equal to 1000"),
    "too hot": ("evaluations.0.reference_condition={light: {colour_temperature_k: 50000}}",
                "evaluations.0.reference_condition.light.colour_temperature_k: "
                "Input should be less than or equal to 40000"),
    "a zero direction": ("evaluations.0.query_condition={light: {direction: [0, 0, 0]}}",
                         "evaluations.0.query_condition.light.direction: direction must not be zero"),
    "negative noise": ("evaluations.0.query_condition={camera: {noise_std: -1}}",
                       "evaluations.0.query_condition.camera.noise_std: Input should be greater than or equal to 0"),
    "negative blur": ("train.run.condition={camera: {blur_sigma_px: -0.5}}",
                      "train.run.condition.camera.blur_sigma_px: Input should be greater than or equal to 0"),
    "zero exposure": ("evaluations.0.query_condition={camera: {exposure: 0}}",
                      "evaluations.0.query_condition.camera.exposure: Input should be greater than 0"),
    "occlusion over 1": ("evaluations.0.query_condition={camera: {occlusion: {share: 1.5}}}",
                         "evaluations.0.query_condition.camera.occlusion.share: Input should be less than 1"),
    "all occluded": ("evaluations.0.query_condition={camera: {occlusion: {share: 1}}}",
                     "evaluations.0.query_condition.camera.occlusion.share: Input should be less than 1"),
    "negative occlusion": ("evaluations.0.query_condition={camera: {occlusion: {share: -0.1}}}",
                           "evaluations.0.query_condition.camera.occlusion.share: "
                           "Input should be greater than or equal to 0"),
    "an unknown side": ("evaluations.0.query_condition={camera: {occlusion: {share: 0.2, side: middle}}}",
                        "evaluations.0.query_condition.camera.occlusion.side: "
                        "Input should be 'top', 'bottom', 'left' or 'right'"),
    "fog ending before it starts": ("evaluations.0.query_condition={fog: {start_m: 2, end_m: 1}}",
                                    "evaluations.0.query_condition.fog: end_m (1.0) must be greater than start_m "
                                    "(2.0)"),
    "fog without an end": ("evaluations.0.query_condition={fog: {start_m: 2}}",
                           "evaluations.0.query_condition.fog.end_m: required key is missing"),
    "a fog colour over 1": ("evaluations.0.query_condition={fog: {end_m: 3, colour: [1, 2, 0]}}",
                            "evaluations.0.query_condition.fog.colour: colour must be three values in [0, 1]"),
    "an unknown key": ("evaluations.0.query_condition={light: {brightness: 2}}",
                       "evaluations.0.query_condition.light.brightness: unknown key"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_conditions_are_refused_at_validate_in_one_line(capsys, case):
    override, message = BAD[case]
    assert main(["validate", "quickstart", "--set", override]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: ") and message in lines[0], lines


def test_a_condition_of_recorded_runs_is_refused(tmp_path, capsys):
    (tmp_path / "q.h5").write_bytes(b"")
    argv = ["validate", "quickstart", "--set", "evaluations.0.run=null", "--set", "evaluations.0.environment=null",
            "--set", "evaluations.0.query_off_route=0",
            "--set", f"evaluations.0.datasets={{query: {tmp_path / 'q.h5'}, reference: {tmp_path / 'q.h5'}}}",
            "--set", "evaluations.0.query_condition={light: {intensity: 0.5}}"]
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "query_condition needs simulated runs" in lines[0], lines


def test_a_condition_survives_the_simulation_job_and_the_run_file():
    """The simulate stage hands a run's settings to its worker as a dict (`run_spec` reads it
    back) and stores them in the run file's attributes as JSON (`recorded_run_spec`)."""
    import json

    from vitaplace.engine.sim.controllers import recorded_run_spec

    scenario, _ = load_scenario("quickstart", overrides=[
        "evaluations.0.query_condition={light: {direction: [1, 0, -0.5]}, "
        "camera: {occlusion: {share: 0.25, side: left}}}"])
    query = scenario.evaluations[0].run_for("query")
    assert run_spec(query.model_dump()) == query
    assert recorded_run_spec(json.loads(json.dumps(query.model_dump(mode="json")))) == query
    plain, _ = load_scenario("quickstart")
    assert key_form(scenario.evaluations[0].run_for("reference")) == key_form(plain.evaluations[0].run_for("reference"))
    assert key_form(query) != key_form(plain.evaluations[0].run_for("query"))
