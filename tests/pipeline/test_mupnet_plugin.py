"""The built-in MuPNet feature plugin on a small synthetic looped path.

The sensors are smooth functions of the position along a closed loop, so nearby poses give
similar readings. Run B follows the same loop as run A, sampled in between A's samples, with
pose and sensor noise. What counts as a correct match comes from the poses alone (ground
truth): a query's best feature match must be a true revisit, i.e. lie within ``TAU`` metres.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension.features import ExtractorParamsError
from vitaplace.engine.extension.registry import discover
from vitaplace.plugins.mupnet.extractor import PAPER_ALGORITHM

N = 80  # samples per run
H, W = 8, 10  # image size
N_WHISKERS = 24
RADIUS = 1.0  # [m], the loop is a circle
SPACING = 2 * np.pi * RADIUS / N  # arc length between consecutive samples [m]
TAU = 2 * SPACING  # revisit tolerance [m]

PARAMS = {
    **PAPER_ALGORITHM,  # the paper's training and test-time rule (the defaults' are tested in test_training_options)
    "image_size": (H, W),
    "visual_layers": [20],
    "tactile_layers": [10],
    "joint_size": 8,
    "epochs": 20,
    "batch_size": 10,
    "eta_y_visual": 0.05,
    "eta_y_tactile": 0.05,
    "eta_y_joint": 0.05,
    "eta_w_visual": 0.005,
    "eta_w_tactile": 0.005,
    "eta_w_joint": 0.005,
    "backend": "numpy",
    "max_steps": 200,
    "seed": 0,
}


def sensor_readings(phi: np.ndarray, rng: np.random.Generator, image_noise: float, tactile_noise: float, size=(H, W)):
    """Images, theta and xy as smooth, 2pi-periodic functions of the loop angle ``phi`` plus noise."""
    n = len(phi)
    h, w = size
    rows = np.arange(h)[:, None] * (H / h)
    cols = np.arange(w)[None, :] * (W / w)
    images = np.empty((n, h, w, 3))
    for channel, (k, a, b) in enumerate([(1, 0.5, 0.0), (1, 0.0, 0.4), (2, 0.3, 0.3)]):
        images[..., channel] = 128 + 100 * np.cos(k * phi[:, None, None] + a * rows + b * cols + channel)
    images += rng.normal(0, image_noise, images.shape)
    whisker = np.arange(N_WHISKERS)
    theta = 0.4 * np.sin(phi[:, None] + 2 * np.pi * whisker / N_WHISKERS)
    xy = np.stack([0.05 * np.cos(phi[:, None] + whisker), 0.05 * np.sin(2 * phi[:, None] + whisker)], axis=-1)
    theta = theta + rng.normal(0, tactile_noise, theta.shape)
    xy = xy + rng.normal(0, tactile_noise / 10, xy.shape)
    return np.clip(np.rint(images), 0, 255).astype(np.uint8), theta, xy


def loop_run(offset: float, seed: int, size=(H, W), name="run") -> Run:
    """N samples around the loop, starting ``offset`` sample spacings in, with pose and sensor noise."""
    rng = np.random.default_rng(seed)
    phi = 2 * np.pi * (np.arange(N) + offset) / N + rng.normal(0, 0.02, N)
    poses = np.stack([RADIUS * np.cos(phi), RADIUS * np.sin(phi), phi + np.pi / 2], axis=1)
    images, theta, xy = sensor_readings(phi, rng, image_noise=12, tactile_noise=0.04, size=size)
    return Run.from_arrays(images=images, theta=theta, xy=xy, poses=poses, name=name)


@pytest.fixture(scope="module")
def runs() -> tuple[Run, Run]:
    return loop_run(0.0, seed=1, name="A"), loop_run(0.5, seed=2, name="B")


@pytest.fixture(scope="module")
def mupnet_class():
    return discover(only="mupnet").get("mupnet")


def make(mupnet_class, **overrides):
    extractor = mupnet_class({**PARAMS, **overrides})
    extractor.progress = False
    return extractor


@pytest.fixture(scope="module")
def fitted(mupnet_class, runs):
    extractor = make(mupnet_class)
    extractor.fit(runs[0])
    return extractor


def revisit_rate(extractor, query: Run, reference: Run, permute: bool = False) -> float:
    """Fraction of queries whose best feature match (lowest TME) is within TAU of the query pose."""
    fq, fr = extractor.transform(query), extractor.transform(reference)
    if permute:  # break the link between features and poses
        fq = {k: v[np.random.default_rng(0).permutation(len(v))] for k, v in fq.items()}
    tme = extractor.distance(fq, fr)
    assert tme.shape == (len(query), len(reference))
    gtm = cdist(query.poses[:, :2], reference.poses[:, :2])
    best = tme.argmin(axis=1)
    return float(np.mean(gtm[np.arange(len(query)), best] <= TAU))


def chance_rate(query: Run, reference: Run) -> float:
    """Expected revisit rate of a uniformly random match, from the poses alone."""
    gtm = cdist(query.poses[:, :2], reference.poses[:, :2])
    return float(np.mean(gtm <= TAU))


def test_ground_truth_of_the_synthetic_loop(runs):
    a, b = runs
    gtm = cdist(b.poses[:, :2], a.poses[:, :2])
    # Every query of B has a true revisit in A; about 4-5 of 80 reference samples lie within TAU.
    assert np.all(gtm.min(axis=1) <= TAU)
    assert 0.03 < chance_rate(b, a) < 0.08


def test_network_shape_follows_the_inputs(fitted):
    assert fitted.network.modalities == ["visual", "tactile"]
    assert fitted.network.sizes["visual.0"] == H * W * 3
    assert fitted.network.sizes["tactile.0"] == N_WHISKERS * 3  # theta (24) + xy (24 x 2)
    assert fitted.network.sizes["joint"] == 8


def test_training_lowers_every_prediction_error(fitted):
    history_by_edge = fitted.training_history()
    assert set(history_by_edge) == {"visual.1", "tactile.1", "joint.visual", "joint.tactile"}
    for edge, history in history_by_edge.items():
        assert len(history) == PARAMS["epochs"]
        assert history[-1] < 0.5 * history[0], edge


def test_joint_latents_recognise_revisits(fitted, runs):
    a, b = runs
    features = fitted.transform(b)
    range_measure = {"tactile_inside", "tactile_beyond", "tactile_measured"}  # the tactile range measure
    drive = {"drive_visual_share", "drive_measured"}  # vision's share of the joint drive (test_drive_share.py)
    assert set(features) == {"latent", "diverged", "inference_steps", "inference_stopped", "inference_settled",
                             *range_measure, *drive}
    assert not features["diverged"].any()
    steps, stopped = features["inference_steps"], features["inference_stopped"]
    assert np.array_equal(features["inference_settled"], stopped)  # the paper's rule: the thresholds alone
    assert steps.shape == stopped.shape == (N,) and steps.min() >= 1
    assert np.all(stopped | (steps == fitted.params.max_steps))  # unstopped samples ran to the cap
    assert features["latent"].shape == (N, 8)
    assert np.all(np.isfinite(features["latent"]))
    assert features["latent"].std(axis=0).min() > 1e-3  # not a constant code

    chance = chance_rate(b, a)
    rate = revisit_rate(fitted, b, a)
    assert rate >= 0.8, rate
    assert rate >= 8 * chance
    # Control: with the query features shuffled against their poses, matching drops to chance level.
    assert revisit_rate(fitted, b, a, permute=True) <= 0.25


@pytest.mark.parametrize("modalities", [["visual"], ["tactile"]], ids=["visual-only", "tactile-only"])
def test_single_modality_ablations(mupnet_class, runs, modalities):
    a, b = runs
    extractor = make(mupnet_class, modalities=modalities)
    extractor.fit(a)
    assert extractor.network.modalities == modalities
    assert set(extractor.training_history()) == {f"{modalities[0]}.1", f"joint.{modalities[0]}"}
    latent = extractor.transform(b)["latent"]
    assert latent.shape == (N, 8)
    assert np.all(np.isfinite(latent))
    assert latent.std(axis=0).min() > 1e-3
    assert revisit_rate(extractor, b, a) >= 0.6


def test_images_are_resampled_to_the_network_size(mupnet_class):
    big = loop_run(0.0, seed=3, size=(2 * H, 2 * W))
    extractor = make(mupnet_class, modalities=["visual"], epochs=2)
    extractor.fit(big)
    assert extractor.network.sizes["visual.0"] == H * W * 3
    assert extractor.transform(big)["latent"].shape == (N, 8)


def test_save_load_gives_identical_features(fitted, mupnet_class, runs, tmp_path):
    a, b = runs
    fitted.save(tmp_path / "mupnet")
    loaded = mupnet_class.load(tmp_path / "mupnet")
    assert loaded.params == fitted.params
    assert loaded.training_history() == fitted.training_history()  # JSON round-trips floats exactly
    for run in runs:
        np.testing.assert_array_equal(loaded.transform(run)["latent"], fitted.transform(run)["latent"])
    np.testing.assert_array_equal(
        loaded.distance(loaded.transform(b), loaded.transform(a)),
        fitted.distance(fitted.transform(b), fitted.transform(a))
    )


def test_transform_before_fit_is_an_error(mupnet_class, runs):
    with pytest.raises(RuntimeError, match="fit"):
        make(mupnet_class).transform(runs[0])


@pytest.mark.parametrize(
    "params, key",
    [
        ({"modalities": ["visual", "visual"]}, "modalities"),
        ({"modalities": []}, "modalities"),
        ({"modalities": ["smell"]}, "modalities"),
        ({"hidden_layers": [5]}, "hidden_layers"),
        ({"epochs": 0}, "epochs"),
        ({"eta_y_joint": "fast"}, "eta_y_joint"),
        ({"backend": "tpu"}, "backend"),
        ({"image_size": (8,)}, "image_size"),
        ({"inference_rtol": 1.0}, "inference_rtol"),  # >= 1 would stop every sample before its first step
        ({"inference_rtol": 0.0}, "inference_rtol"),
        ({"weight_optimizer": "lion"}, "weight_optimizer"),
        ({"precision_weighting": "sample"}, "precision_weighting"),
        ({"eta_w_joint": 0.0}, "eta_w_joint"),
        ({"held_out": 1.0}, "held_out"),
        ({"training_inference": "solver", "inference_solver": "gd"}, "training_inference"),
    ],
    ids=["duplicate-modalities", "no-modality", "unknown-modality", "unknown-key", "zero-epochs", "wrong-type",
         "unknown-backend", "bad-image-size", "rtol-one", "rtol-zero", "unknown-optimiser", "unknown-precision",
         "zero-rate", "all-held-out", "solver-training-with-gd"],
)
def test_params_errors_name_extractor_and_key(mupnet_class, params, key):
    with pytest.raises(ExtractorParamsError) as info:
        mupnet_class(params)
    assert "'mupnet'" in str(info.value)
    assert key in str(info.value)


def with_flat_channel(run: Run, value: float) -> Run:
    """``run`` with whisker 0's x deflection replaced by a constant (a channel that never moves)."""
    xy = run.xy.copy()
    xy[:, 0, 0] = value
    return Run.from_arrays(images=run.images, theta=run.theta, xy=xy, poses=run.poses, name=run.name)


def test_a_channel_flat_in_training_is_not_blown_up(mupnet_class, runs):
    """A tactile channel that did not move in training (range 1e-9) is scaled by the floor
    (0.05), not by 1/1e-9: a test reading 0.1 away from it becomes 2 scaled units, the joint
    latents stay within the training range, and nothing is flagged as diverged."""
    a, b = runs
    train = with_flat_channel(a, 0.0)
    xy = train.xy.copy()
    xy[1, 0, 0] = 1e-9
    train = Run.from_arrays(images=train.images, theta=train.theta, xy=xy, poses=train.poses, name="A")
    extractor = make(mupnet_class)
    extractor.fit(train)
    offset, scale = extractor.network.scalers["tactile"]
    channel = N_WHISKERS + 0  # theta first (24 values), then x, y of whisker 0
    assert scale[channel] == pytest.approx(1 / 0.05)
    test = with_flat_channel(b, 0.1)
    scaled = extractor.scaled_inputs(test)["tactile"][:, channel]
    np.testing.assert_allclose(scaled, 0.1 / 0.05, rtol=1e-5)
    features = extractor.transform(test)
    assert not features["diverged"].any()
    assert np.linalg.norm(features["latent"], axis=1).max() < 10 * extractor.train_norm_max


def test_diverging_latents_are_flagged_per_sample(mupnet_class, runs, caplog):
    """Without the floor the same channel gets a 1e9 scale factor; test samples whose reading
    is off by 0.1 then have inputs of 1e8 and their latents explode: each is flagged and the
    run is named in one warning."""
    a, b = runs
    xy = a.xy.copy()
    xy[:, 0, 0] = 0.0
    xy[1, 0, 0] = 1e-9
    train = Run.from_arrays(images=a.images, theta=a.theta, xy=xy, poses=a.poses, name="A")
    extractor = make(mupnet_class, tactile_min_range=0.0, max_steps=5)
    extractor.fit(train)
    test_xy = b.xy.copy()
    test_xy[:, 0, 0] = 0.0
    test_xy[[3, 7], 0, 0] = 0.1
    test = Run.from_arrays(images=b.images, theta=b.theta, xy=test_xy, poses=b.poses, name="B")
    with caplog.at_level("WARNING", logger="vitaplace.mupnet"):
        features = extractor.transform(test)
    assert list(np.flatnonzero(features["diverged"])) == [3, 7]
    assert "2 of 80 samples of run 'B'" in caplog.text and "first: 3, 7" in caplog.text


# --------------------------------------------------------------------------- one schema


#: TrainingConfig's fields added after the others, with the plugin's defaults (old code builds the same)
LATER_TRAINING_FIELDS = ("latent_prior", "weight_optimizer", "weight_momentum", "adam_beta1", "adam_beta2",
                         "adam_eps", "precision_weighting", "precision_floor", "weight_norm")


def test_the_engine_configs_hold_no_defaults_of_their_own():
    """MuPNet's settings and defaults are MupnetParams alone: the engine's containers, the
    network's seed and the inference step cap have none, but for the latent prior and the
    weight optimiser's and the error precisions' settings, added after the others: their defaults
    are the paper's (the paper's energy, 0, every precision 1, and plain SGD, so that code
    written before them builds the same configuration), which the plugin's are too except
    where the plugin's defaults depart from the paper (`PAPER_ALGORITHM`)."""
    import dataclasses
    import inspect

    from vitaplace.engine.network.pc import JointConfig, ModalityConfig, Network, NetworkConfig, TrainingConfig
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    for container in (ModalityConfig, JointConfig, NetworkConfig, TrainingConfig):
        for field in dataclasses.fields(container):
            if container is not TrainingConfig or field.name not in LATER_TRAINING_FIELDS:
                assert field.default is dataclasses.MISSING, (container, field.name)
            else:
                paper = PAPER_ALGORITHM.get(field.name, MupnetParams.model_fields[field.name].default)
                assert field.default == paper, field.name
            assert field.default_factory is dataclasses.MISSING, (container, field.name)
    assert inspect.signature(Network).parameters["seed"].default is inspect.Parameter.empty
    assert inspect.signature(Network.infer).parameters["max_steps"].default is inspect.Parameter.empty
    prior = PAPER_ALGORITHM["latent_prior"]
    assert prior == 0.0
    assert TrainingConfig(1, 1, 1, 0, 0, 0.01).latent_prior == prior
    assert inspect.signature(Network.infer).parameters["latent_prior"].default == prior


def test_a_changed_schema_default_reaches_the_engine_configs():
    """A schema whose defaults differ in every setting the engine uses: the network and
    training configurations built from its defaults carry each changed value to its place."""
    import pydantic

    from vitaplace.engine.network.pc import JointConfig, ModalityConfig, NetworkConfig, TrainingConfig
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    changed = {
        "image_size": (tuple[int, int], (3, 4)), "visual_layers": (list[int], [7, 5]),
        "tactile_layers": (list[int], [6]),
        "joint_size": (int, 9), "eta_y_visual": (float, 0.11), "eta_y_tactile": (float, 0.12),
        "eta_y_joint": (float, 0.13), "eta_w_visual": (float, 0.21), "eta_w_tactile": (float, 0.22),
        "eta_w_joint": (float, 0.23), "threshold_visual": (float, 0.31), "threshold_tactile": (float, 0.32),
        "threshold_joint": (float, 0.33), "activation": (str, "tanh"), "slope": (float, 0.4), "epochs": (int, 17),
        "batch_size": (int, 19), "inference_steps": (int, 23), "seed": (int, 29), "converge_window": (int, 3),
        "converge_tol": (float, 0.05), "latent_prior": (float, 0.07), "weight_optimizer": (str, "adam"),
        "weight_momentum": (float, 0.41), "adam_beta1": (float, 0.42), "adam_beta2": (float, 0.43),
        "adam_eps": (float, 0.44),
    }
    params = pydantic.create_model("Changed", __base__=MupnetParams, **changed)()
    assert params.network_config(tactile_size=72) == NetworkConfig(
        modalities={"visual": ModalityConfig(3 * 4 * 3, [7, 5], 0.11, 0.21, 0.31),
                    "tactile": ModalityConfig(72, [6], 0.12, 0.22, 0.32)},
        joint=JointConfig(9, 0.13, 0.23, 0.33),
        activation="tanh",
        slope=0.4,
    )
    assert params.training_config() == TrainingConfig(17, 19, 23, 29, 3, 0.05, 0.07, "adam", 0.41, 0.42, 0.43, 0.44,
                                                      weight_norm="rows")  # the plugin's default, not the engine's
    only_touch = pydantic.create_model("OnlyTouch", __base__=MupnetParams, modalities=(list[str], ["tactile"]))()
    assert list(only_touch.network_config(tactile_size=72).modalities) == ["tactile"]


def test_the_solver_is_built_from_the_params():
    from vitaplace.engine.network.solver import GradientDescent, Nesterov, Preconditioned
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    assert MupnetParams(**PAPER_ALGORITHM).solver() == GradientDescent()  # the paper's loop
    assert MupnetParams().solver() == Preconditioned(momentum=0.9, rtol=3e-6)  # the default: settling
    params = MupnetParams(inference_solver="nesterov", inference_momentum=0.8, inference_rtol=1e-5)
    assert params.solver() == Nesterov(momentum=0.8, rtol=1e-5)


def test_the_fitted_network_is_built_from_the_params(fitted):
    assert fitted.network.config == fitted.params.network_config(N_WHISKERS * 3)


@pytest.mark.parametrize("key, value, message", [
    ("eta_y_visual", "-1", "Input should be greater than 0"),
    ("converge_tol", "1.5", "Input should be less than 1"),
    ("activation", "relu", "Input should be 'leaky_relu', 'tanh', 'sigmoid' or 'linear'"),
    ("tactile_input", "sweep", "Input should be 'instant' or 'cycle'"),
    ("cycle_points", "0", "Input should be greater than 0"),
    ("weight_optimizer", "rmsprop", "Input should be 'sgd', 'momentum' or 'adam'"),
    ("weight_momentum", "0", "Input should be greater than 0"),
    ("adam_eps", "0", "Input should be greater than 0"),
    ("adam_beta2", "1", "Input should be less than 1"),
    ("eta_w_joint", "-0.1", "Input should be greater than 0"),
    ("seed", "-1", "Input should be greater than or equal to 0"),  # numpy's generator takes none below 0
    ("cycle_points", "100000", "100000 phase points: expected at most 1000, the most samples a simulated run's "
     "deflection series holds per whisk cycle (robot.deflection_samples)"),
])
def test_an_invalid_mupnet_setting_is_one_line_naming_its_key_path(capsys, key, value, message):
    from vitaplace.engine.cli.main import main

    assert main(["validate", "quickstart", "--set", f"methods.0.params.{key}={value}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("vitaplace: error: ")
    assert "quickstart.yaml: methods.0.params: extractor 'mupnet': " in lines[0]
    assert f"{key}: {message}" in lines[0], lines[0]


@pytest.mark.parametrize("solver", [["--set", "methods.0.params.inference_solver=preconditioned"], []])
def test_the_preconditioned_solver_without_a_prior_is_one_line(capsys, solver):
    """Without the prior the joint layer's curvature bound can be singular: refused at
    validation, whether the solver is set or is the default (preconditioned)."""
    from vitaplace.engine.cli.main import main

    assert main(["validate", "quickstart", *solver, "--set", "methods.0.params.latent_prior=0"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].endswith("methods.0.params: extractor 'mupnet': inference_solver preconditioned needs "
                             "latent_prior > 0, got 0 (without the prior a layer's curvature bound can be singular)")


@pytest.mark.parametrize("key, value, setting, choice, reading", [
    ("inference_momentum", 0.5, "inference_solver", "gd", "nesterov or preconditioned"),
    ("weight_momentum", 0.5, "weight_optimizer", "sgd", "momentum"),
    ("adam_beta1", 0.5, "weight_optimizer", "momentum", "adam"),
    ("adam_beta2", 0.5, "weight_optimizer", "sgd", "adam"),
    ("adam_eps", 0.001, "weight_optimizer", "momentum", "adam"),
    ("precision_floor", 0.1, "precision_weighting", "none", "layer or channel"),
    ("cycle_points", 9, "tactile_input", "instant", "cycle"),
    ("slope", 0.3, "activation", "tanh", "leaky_relu"),
])
def test_a_setting_its_choice_ignores_is_one_line(capsys, key, value, setting, choice, reading):
    """gd takes no momentum, sgd no beta, a tanh no slope...: the value would be ignored."""
    from vitaplace.engine.cli.main import main

    given = [f"{key}={value}", f"{setting}={choice}"] + (["training_inference=plain"] if choice == "gd" else [])
    assert main(["validate", "quickstart", *[a for g in given for a in ("--set", f"methods.0.params.{g}")]]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "methods.0.params: extractor 'mupnet': " in lines[0], lines
    assert f"{key} {value} is ignored by {setting} {choice} (only {reading} reads it)" in lines[0], lines[0]


@pytest.mark.parametrize("solver", ["nesterov", "preconditioned"])
@pytest.mark.parametrize("key", ["eta_y_visual", "eta_y_tactile", "eta_y_joint"])
def test_an_eta_y_no_plain_step_reads_is_one_line(capsys, key, solver):
    """Training's steps from the settling solver and a settling test-time solver take each
    layer's step from its curvature bound (`node_steps`), never at eta_y: a value of its own
    would be ignored, and listed in the report as if used."""
    from vitaplace.engine.cli.main import main

    given = [f"{key}=0.002", "training_inference=solver", f"inference_solver={solver}"]
    assert main(["validate", "quickstart", *[a for g in given for a in ("--set", f"methods.0.params.{g}")]]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "methods.0.params: extractor 'mupnet': " in lines[0], lines
    assert lines[0].endswith(
        f"{key} 0.002 is ignored by training_inference solver and inference_solver {solver} (only training_inference "
        f"plain or inference_solver gd reads it); leave {key} out or choose training_inference plain or "
        "inference_solver gd"), lines[0]


def test_an_eta_y_either_plain_step_reads_is_valid():
    """eta_y sets the plain steps of training (training_inference plain) and of test-time gd:
    either reads it; at its default it reads back from any saved model's params.json."""
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    assert MupnetParams(training_inference="plain", eta_y_visual=1e-3).eta_y_visual == 1e-3  # test time: settling
    assert MupnetParams(**{**PAPER_ALGORITHM, "eta_y_joint": 1e-3}).eta_y_joint == 1e-3  # gd at test time too
    assert MupnetParams(eta_y_tactile=4e-3).eta_y_tactile == 4e-3  # the default, with no plain step at all


def test_a_setting_at_its_default_or_with_a_choice_that_reads_it_is_valid():
    """A saved model's params.json holds every setting at its value: the paper's algorithm
    (gd, sgd) with the default momenta reads back."""
    from vitaplace.plugins.mupnet.extractor import MupnetParams

    paper = MupnetParams(**PAPER_ALGORITHM)
    assert MupnetParams.model_validate(paper.model_dump()) == paper
    MupnetParams(inference_solver="nesterov", inference_momentum=0.5, weight_optimizer="adam", adam_beta1=0.5,
                 precision_weighting="layer", precision_floor=0.1, tactile_input="cycle", cycle_points=1000, slope=0.3)


@pytest.mark.parametrize("modalities, key, bound", [
    (["visual", "tactile"], "eta_y_tactile", 500), (["visual"], "eta_y_visual", 5000),
])
def test_plain_latent_steps_need_eta_y_times_the_prior_below_2(modalities, key, bound):
    """The default eta_y: 4e-3 tactile, 4e-4 visual and joint; 2 / 4e-3 = 500, 2 / 4e-4 = 5000.
    At the bound a plain step multiplies the prior's part of a latent by 1 - 2 = -1."""
    import pydantic

    from vitaplace.plugins.mupnet.extractor import MupnetParams

    plain = {"modalities": modalities, "training_inference": "plain"}
    MupnetParams(**plain, latent_prior=bound * 0.999)
    for rule in (plain, {**plain, "training_inference": "plain", "inference_solver": "gd"}):
        with pytest.raises(pydantic.ValidationError, match=rf"latent_prior {bound} with {key} .* = -1 and diverge; "
                                                           rf"expected latent_prior < 2 / {key} = {bound} "):
            MupnetParams(**rule, latent_prior=bound)
    MupnetParams(modalities=modalities, latent_prior=1e30)  # the settling solver's steps shrink with the prior


def test_diverging_training_is_its_one_error_line_without_numpys_warnings(capsys):
    """Plain latent steps at eta_y 1000 blow up in the first minibatches: one line naming the
    layer, not numpy's overflow warnings before it."""
    from vitaplace.engine.cli.main import main

    tiny = ["train.run.n_samples=40", "evaluations.0.run.n_samples=10", "methods=[{name: L, plugin: mupnet, params: "
            "{image_size: [9, 16], visual_layers: [12], tactile_layers: [8], joint_size: 6, epochs: 2, batch_size: 6, "
            "eta_y_visual: 1000, training_inference: plain, inference_solver: gd, latent_prior: 0}}]"]
    argv = ["-q", "run", "quickstart", "--out", "OUT", "--no-progress", *[a for t in tiny for a in ("--set", t)]]
    import tempfile

    with tempfile.TemporaryDirectory() as out:
        assert main([out if a == "OUT" else a for a in argv]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and re.search(r"error of layer 'visual.1' became (nan|inf) at epoch 1", lines[0]), lines


@pytest.mark.parametrize("plugin", ["mupnet", "autoencoder"])
def test_a_tolerance_without_its_criterion_is_refused(capsys, plugin):
    """converge_window 0 runs every epoch (the paper's): a converge_tol beside it would be
    silently ignored, so it is refused in one line; the default tolerance is left alone."""
    from vitaplace.engine.cli.main import main

    base = ["validate", "quickstart", "--set", f"methods.0.plugin={plugin}", "--set",
            "methods.0.params={converge_window: 0"]
    assert main([*base[:-1], base[-1] + "}"]) == 0
    capsys.readouterr()
    assert main([*base[:-1], base[-1] + ", converge_tol: 0.5}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(
        f"methods.0.params: extractor '{plugin}': converge_tol 0.5 is ignored by converge_window 0 (only a window > 0 "
        "reads it); leave converge_tol out or set converge_window"), lines


def test_memory_counts_every_layer_the_latents_and_the_optimisers_moments():
    """2 x 3 images (18 inputs), visual [4], instant touch (24 x 3 = 72), tactile [5], joint 6,
    10 samples, float32. Training inputs 10 x 18 x 4 = 720 (images) and 10 x 72 x 4 = 2880;
    latents 10 x 4 x 4 = 160, 10 x 5 x 4 = 200, 10 x 6 x 4 = 240; weights x 4 B x 2 copies (W,
    its transposed copy), each to the larger side it joins: 18 x 4 (images) 576, 4 x 6 (joint)
    192, 72 x 5 (tactile) 2880, 5 x 6 (joint) 240. Shares: images 1296, visual 160, tactile
    5960, joint 672 (plain SGD); Adam's two moments double the weights' 3888 to 7776."""
    from vitaplace.plugins.mupnet.extractor import MupnetExtractor, MupnetParams

    sizes = dict(image_size=(2, 3), visual_layers=[4], tactile_layers=[5], joint_size=6, tactile_input="instant",
                 weight_optimizer="sgd")
    assert MupnetExtractor.memory_bytes(MupnetParams(**sizes), 10) == (8088, "tactile_layers", "tactile layers [5]")
    adam = MupnetParams(**{**sizes, "weight_optimizer": "adam"})
    assert MupnetExtractor.memory_bytes(adam, 10)[0] == 8088 + 3888
    wide = MupnetParams(**{**sizes, "joint_size": 1000})  # 4 x 1000 + 5 x 1000 weights, 10 x 1000 latents
    assert MupnetExtractor.memory_bytes(wide, 10)[1:] == ("joint_size", "joint latents of 1000")
