"""The backprop control of MuPNet (`autoencoder`): its gradients against central finite
differences (float64) and against the closed form of a one-layer linear autoencoder, its
initialisation against MuPNet's, its training and features, its parameters."""

from __future__ import annotations

import numpy as np
import pytest

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension.features import ExtractorParamsError
from vitaplace.engine.extension.registry import discover
from vitaplace.engine.network.pc import Network
from vitaplace.plugins.autoencoder.model import Autoencoder, Optimizer
from vitaplace.plugins.mupnet.extractor import MupnetParams

SIZES = {"visual": [5, 4, 3], "tactile": [4, 3]}


def total_loss(model: Autoencoder, inputs) -> float:
    return sum(model.loss_and_gradients(inputs)[0].values())


@pytest.mark.parametrize("encoder", ["learned", "tied"])
@pytest.mark.parametrize("activation", ["leaky_relu", "tanh", "sigmoid", "linear"])
def test_gradients_match_central_finite_differences(encoder, activation, seed):
    rng = np.random.default_rng(seed)
    model = Autoencoder(SIZES, 2, activation=activation, slope=0.2, encoder=encoder, seed=seed, dtype=np.float64)
    inputs = {m: rng.uniform(0, 1, (6, s[0])) for m, s in SIZES.items()}
    _, grads = model.loss_and_gradients(inputs)
    assert set(grads) == set(model.weights)  # tied: no encoder weights of its own
    eps = 1e-6
    for name, w in model.weights.items():
        numeric = np.empty_like(w)
        for index in np.ndindex(w.shape):
            keep = w[index]
            w[index] = keep + eps
            up = total_loss(model, inputs)
            w[index] = keep - eps
            down = total_loss(model, inputs)
            w[index] = keep
            numeric[index] = (up - down) / (2 * eps)
        np.testing.assert_allclose(grads[name], numeric, rtol=1e-5, atol=1e-8, err_msg=name)


def test_gradients_of_a_one_layer_linear_autoencoder_are_the_closed_form(seed):
    """x (B x 4) -> z = x V (V = W^T when tied) -> xhat = z W, L = ||x - x V W||^2 / B:
    dL/dW = -(2/B) (x V)^T R and dL/dV = -(2/B) x^T R W^T with R = x - x V W; tied, the two
    uses of W add: dL/dW = -(2/B) (W x^T R + W R^T x)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(7, 4))
    b = len(x)
    learned = Autoencoder({"tactile": [4]}, 3, activation="linear", slope=0.2, encoder="learned", seed=seed,
                          dtype=np.float64)
    w, v = learned.weights["joint.tactile"], learned.weights["encoder.joint.tactile"]
    assert w.shape == (3, 4) and v.shape == (4, 3)
    r = x - x @ v @ w
    losses, grads = learned.loss_and_gradients({"tactile": x})
    assert losses["tactile"] == pytest.approx(np.sum(r * r) / b, rel=1e-12)
    np.testing.assert_allclose(grads["joint.tactile"], -2 / b * (x @ v).T @ r, rtol=1e-12)
    np.testing.assert_allclose(grads["encoder.joint.tactile"], -2 / b * x.T @ r @ w.T, rtol=1e-12)

    tied = Autoencoder({"tactile": [4]}, 3, activation="linear", slope=0.2, encoder="tied", seed=seed,
                       dtype=np.float64)
    w = tied.weights["joint.tactile"]
    r = x - x @ w.T @ w
    _, grads = tied.loss_and_gradients({"tactile": x})
    np.testing.assert_allclose(grads["joint.tactile"], -2 / b * (w @ x.T @ r + w @ r.T @ x), rtol=1e-10)


def test_the_generative_path_starts_from_mupnets_initial_weights():
    """Same seed, same layer sizes: the decoder's weights are the ones MuPNet's network draws."""
    params = MupnetParams(image_size=(2, 3), visual_layers=[5, 4], tactile_layers=[3], joint_size=2)
    network = Network(params.network_config(tactile_size=6), seed=11, backend="numpy")
    model = Autoencoder({"visual": [18, 5, 4], "tactile": [6, 3]}, 2, activation="leaky_relu", slope=0.2,
                        encoder="learned", seed=11)
    for name, w in network.weights.items():
        np.testing.assert_array_equal(model.weights[name], w)


def test_adam_takes_the_bias_corrected_step_and_sgd_the_plain_one():
    # Adam's first step: m = 0.1 g, v = 0.001 g^2, corrected m / (1 - 0.9) = g, v / (1 - 0.999) = g^2:
    # the step is lr * g / (|g| + 1e-8) = lr * sign(g) (to 1e-8 / |g|, 1e-6 for g = 0.01).
    weights = {"w": np.array([1.0, 1.0, 1.0])}
    Optimizer(weights, 0.01, "adam").step(weights, {"w": np.array([2.0, -0.5, 1e-2])})
    np.testing.assert_allclose(weights["w"], [0.99, 1.01, 0.99], rtol=1e-7)
    weights = {"w": np.array([1.0, 1.0])}
    Optimizer(weights, 0.1, "sgd").step(weights, {"w": np.array([2.0, -0.5])})
    np.testing.assert_allclose(weights["w"], [0.8, 1.05])


# --------------------------------------------------------------------------- the extractor

PLACES = 8
PARAMS = {"image_size": (4, 4), "visual_layers": [16], "tactile_layers": [8], "joint_size": 6, "epochs": 60,
          "batch_size": 8, "learning_rate": 0.01, "seed": 0}


def places_run(seed: int, repeats: int = 4, name: str = "run") -> Run:
    """``repeats`` visits of each of 8 places (the same order each lap); a place is a random
    image and a whisker reading, seen with noise."""
    place_rng, rng = np.random.default_rng(99), np.random.default_rng(seed)
    images = place_rng.uniform(0, 255, (PLACES, 4, 4, 3))
    xy = place_rng.normal(0, 0.1, (PLACES, 24, 2))
    place = np.tile(np.arange(PLACES), repeats)
    n = len(place)
    noisy = np.clip(images[place] + rng.normal(0, 15, (n, 4, 4, 3)), 0, 255).astype(np.uint8)
    poses = np.stack([place, np.zeros(n), np.zeros(n)], axis=1).astype(float)
    return Run.from_arrays(images=noisy, theta=np.zeros((n, 24)), xy=xy[place] + rng.normal(0, 0.01, (n, 24, 2)),
                           poses=poses, name=name)


@pytest.fixture(scope="module")
def autoencoder_class():
    return discover(only="autoencoder").get("autoencoder")


@pytest.mark.parametrize("encoder", ["learned", "tied"])
def test_training_lowers_the_reconstruction_error_and_the_code_finds_the_place(autoencoder_class, encoder):
    train_run, test_run = places_run(1), places_run(2, repeats=2)
    extractor = autoencoder_class({**PARAMS, "encoder": encoder})
    extractor.progress = False
    extractor.fit(train_run)
    history = extractor.training_history()
    assert set(history) == {"visual", "tactile"} and len(history["visual"]) == PARAMS["epochs"]
    for m, curve in history.items():
        assert curve[-1] < 0.5 * curve[0], m
    assert extractor.training_summary() == {"epochs": 60, "max_epochs": 60, "converged": False}
    query, reference = extractor.transform(test_run), extractor.transform(train_run)
    assert query["latent"].shape == (16, 6)
    best = extractor.distance(query, reference).argmin(axis=1)
    same_place = train_run.poses[best, 0] == test_run.poses[:, 0]
    assert same_place.mean() >= 0.9  # chance: 1 in 8


def test_the_fixed_backend_multiplies_in_numpys_loops_after_fit_and_load(autoencoder_class, tmp_path):
    """``backend: fixed`` (the same bits under any BLAS kernel: tests/kernels/test_fixed_order.py)
    trains and encodes with the fixed-order product, also once saved and loaded, and learns
    what the BLAS product learns up to float32 rounding."""
    from vitaplace.engine.network.fixed_order import matmul

    train_run, test_run = places_run(1), places_run(2, repeats=2)
    fitted = {}
    for backend in ("numpy", "fixed"):
        extractor = autoencoder_class({**PARAMS, "epochs": 5, "backend": backend})
        extractor.progress = False
        extractor.fit(train_run)
        fitted[backend] = extractor
    assert fitted["fixed"].model._matmul is matmul and fitted["numpy"].model._matmul is np.matmul
    fitted["fixed"].save_state(tmp_path)
    loaded = autoencoder_class({**PARAMS, "epochs": 5, "backend": "fixed"})
    loaded.load_state(tmp_path)
    assert loaded.model._matmul is matmul
    codes = {name: e.transform(test_run)["latent"] for name, e in {**fitted, "loaded": loaded}.items()}
    np.testing.assert_array_equal(codes["loaded"], codes["fixed"])
    np.testing.assert_allclose(codes["fixed"], codes["numpy"], rtol=1e-3, atol=1e-4)


def test_training_stops_once_converged(autoencoder_class):
    extractor = autoencoder_class({**PARAMS, "epochs": 200, "converge_window": 5, "converge_tol": 0.5})
    extractor.progress = False
    extractor.fit(places_run(1))
    summary = extractor.training_summary()
    assert summary["converged"] and summary["epochs"] < 200


def test_each_epoch_s_losses_reach_on_epoch_as_it_ends(autoencoder_class):
    extractor = autoencoder_class({**PARAMS, "epochs": 4})
    extractor.progress, seen = False, []
    extractor.on_epoch = lambda epoch, numbers: seen.append((epoch, numbers))
    extractor.fit(places_run(1))
    history = extractor.training_history()
    assert [epoch for epoch, _ in seen] == [1, 2, 3, 4]
    for i, (_, numbers) in enumerate(seen):
        assert numbers == {"loss": history["visual"][i] + history["tactile"][i],
                           "loss.visual": history["visual"][i], "loss.tactile": history["tactile"][i]}


@pytest.mark.parametrize("params, key", [
    ({"encoder": "transposed"}, "encoder"), ({"optimizer": "lbfgs"}, "optimizer"),
    ({"learning_rate": 0}, "learning_rate"),
    ({"max_steps": 10}, "max_steps"), ({"tactile_input": "sweep"}, "tactile_input"),
    ({"activation": "tanh", "slope": 0.3}, "slope 0.3 is ignored by activation tanh"),
    ({"cycle_points": 4}, "cycle_points 4 is ignored by tactile_input instant"),
    ({"seed": -1}, "seed"),
])
def test_params_errors_name_extractor_and_key(autoencoder_class, params, key):
    with pytest.raises(ExtractorParamsError) as info:
        autoencoder_class(params)
    assert "'autoencoder'" in str(info.value) and key in str(info.value)


def test_memory_counts_weights_moments_and_training_images(autoencoder_class):
    # 4 x 4 x 3 = 48 inputs x 16 units x 4 bytes x (decoder + encoder) x (weights, gradients, two moments)
    # + 10 samples x 48 x 4 bytes
    need, key, _ = autoencoder_class.memory_bytes(autoencoder_class.Params(**PARAMS), 10)
    assert (need, key) == (48 * 16 * 4 * 2 * 4 + 10 * 48 * 4, "image_size")


def test_the_test_runs_tactile_values_outside_the_training_range_are_reported(autoencoder_class):
    """The training run itself with whisker 5's x raised by 1 rad in samples 0 and 3: two
    values of one of the 72 channels leave the training range (every sample is touched:
    |xy| ~ 0.1 > 0.01)."""
    train_run = places_run(1)
    xy = train_run.xy.copy()
    xy[[0, 3], 5, 0] += 1.0
    test_run = Run.from_arrays(images=train_run.images, theta=train_run.theta, xy=xy, poses=train_run.poses,
                               name="test")
    extractor = autoencoder_class({**PARAMS, "epochs": 1})
    extractor.progress = False
    extractor.fit(train_run)
    extractor.transform(test_run)
    message = test_run.warnings["autoencoder tactile range (instant)"]
    assert "2 of 32 samples of run 'test' (2 of its 32 touched samples)" in message
    assert "(2 values in 1 of 72 channels" in message
    extractor.transform(train_run)
    assert train_run.warnings == {}


def test_a_diverging_training_is_one_error_naming_the_rate_without_numpys_warnings(autoencoder_class):
    """Plain SGD at rate 1e6 overflows in the first minibatches: a NetworkError naming the
    input and the rate at the minibatch it happens, no RuntimeWarning before it."""
    import warnings

    from vitaplace.engine.network.pc import NetworkError

    extractor = autoencoder_class({**PARAMS, "optimizer": "sgd", "learning_rate": 1e6})
    extractor.progress = False
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(NetworkError, match=r"autoencoder: the reconstruction error of the (visual|tactile) input "
                                               r"became (inf|nan) at epoch 1, minibatch \d; lower learning_rate "
                                               r"\(1e\+06, optimizer sgd\)"):
            extractor.fit(places_run(1))
