"""Precision-weighted prediction errors (``precision_weighting``): kernels, network, estimation, bounds.

Expected values come from a hand-computed two-modality network (closed forms below), from
``kernels/reference.py`` in float64, from the estimate's closed form on errors of known
variance, or from the plain (unweighted) code path; never from the weighted code itself.
"""

import numpy as np
import pydantic
import pytest

from conftest import cuda_present
from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.pc import Network, NetworkError
from vitaplace.engine.network.precision import PrecisionEstimator, estimate_precisions
from vitaplace.engine.network.selection import get_backend
from vitaplace.engine.network.solver import curvature_preconditioners, curvature_steps
from vitaplace.kernels import reference as ref
from vitaplace.plugins.mupnet.extractor import MupnetParams

wp = pytest.importorskip("warp")
wk = pytest.importorskip("vitaplace.kernels.warp_kernels")


def _cublas_cpu():
    from test_tensorcores import HostBlas

    from vitaplace.engine.network.tensorcores import CublasBackend

    return CublasBackend("float32", "cpu", blas=HostBlas())


#: every backend: numpy, Warp CPU and CUDA (skipped without), and the tensor-core backend's path
#: (its epilogue kernels, the GEMMs by a host cuBLAS stand-in at float32)
BACKENDS = {
    "numpy": lambda: NumpyBackend(),
    "fixed": lambda: get_backend("fixed"),
    "warp-cpu": lambda: get_backend("warp", "cpu"),
    "warp-cuda": lambda: get_backend("warp", "cuda"),
    "cublas-host": _cublas_cpu,
}


@pytest.fixture(params=list(BACKENDS))
def backend(request):
    if request.param == "warp-cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    return BACKENDS[request.param]


def rel_err(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), np.finfo(np.float64).tiny))


def to_wp(a, device, dtype=wp.float32):
    return wp.array(np.ascontiguousarray(a, dtype=wp.dtype_to_numpy(dtype)), dtype=dtype, device=device)


# --------------------------------------------------------------------------------------
# A hand-computed two-modality network (linear activation, one sample)
# --------------------------------------------------------------------------------------

HAND = {
    "modalities": {
        "visual": {"input_size": 2, "layers": [1], "eta_y": 0.1, "eta_w": 0.1, "threshold": 1e-3},
        "tactile": {"input_size": 1, "layers": [1], "eta_y": 0.1, "eta_w": 0.1, "threshold": 1e-3},
    },
    "joint": {"size": 1, "eta_y": 0.1, "eta_w": 0.1, "threshold": 1e-3},
    "activation": "linear",
    "slope": 0.2,
}
HAND_WEIGHTS = {"visual.1": [[1.0, 2.0]], "tactile.1": [[2.0]], "joint.visual": [[0.5]], "joint.tactile": [[1.0]]}
HAND_PI = {"visual.1": [2.0, 0.5], "tactile.1": [4.0], "joint.visual": [3.0], "joint.tactile": [0.25]}
HAND_INPUTS = {"visual": [[1.0, 2.0]], "tactile": [[3.0]]}
HAND_LATENTS = {"visual.1": [[0.5]], "tactile.1": [[1.0]], "joint": [[2.0]]}
# E = lower - upper W: visual.1 [1 - 0.5, 2 - 1] = [0.5, 1]; tactile.1 3 - 2 = 1;
# joint.visual 0.5 - 1 = -0.5; joint.tactile 1 - 2 = -1.
# F per edge = sum_c pi_c E_c^2: 2 * 0.25 + 0.5 * 1 = 1; 4 * 1 = 4; 3 * 0.25 = 0.75; 0.25 * 1 = 0.25
HAND_ENERGY = {"visual.1": 1.0, "tactile.1": 4.0, "joint.visual": 0.75, "joint.tactile": 0.25}
# dF/dY_u = -2 sum_below (pi E) W^T + 2 pi_above E_above:
#   joint    -2 (3 (-0.5) 0.5 + 0.25 (-1) 1) = 2
#   visual.1 -2 (2 0.5 1 + 0.5 1 2) + 2 3 (-0.5) = -4 - 3 = -7
#   tactile.1 -2 (4 1 2) + 2 0.25 (-1) = -16 - 0.5 = -16.5
HAND_DY = {"joint": 2.0, "visual.1": -7.0, "tactile.1": -16.5}
# dF/dW = -2 Y_u^T (pi E): visual.1 -2 0.5 [1, 0.5] = [-1, -0.5]; tactile.1 -2 1 4 = -8;
# joint.visual -2 2 (-1.5) = 6; joint.tactile -2 2 (-0.25) = 1
HAND_DW = {"visual.1": [[-1.0, -0.5]], "tactile.1": [[-8.0]], "joint.visual": [[6.0]], "joint.tactile": [[1.0]]}


def hand_network(make_backend) -> Network:
    net = Network(HAND, seed=0, backend=make_backend())
    net.set_weights({k: np.array(v, np.float32) for k, v in HAND_WEIGHTS.items()})
    net.set_precisions({k: np.array(v, np.float32) for k, v in HAND_PI.items()})
    return net


def test_hand_computed_energy_gradient_and_weight_step(backend):
    net = hand_network(backend)
    state = net.batch_state(1)
    state.load({m: np.array(v) for m, v in HAND_INPUTS.items()}, {k: np.array(v) for k, v in HAND_LATENTS.items()})
    state.predict_all()
    assert state.energies() == pytest.approx(HAND_ENERGY, rel=1e-6)
    state.latent_step()  # eta_y 0.1: Y' = Y - 0.1 dF/dY
    for node, y in HAND_LATENTS.items():
        assert net.backend.download(state.Y[node])[0, 0] == pytest.approx(y[0][0] - 0.1 * HAND_DY[node], rel=1e-6)
    state.load({m: np.array(v) for m, v in HAND_INPUTS.items()}, {k: np.array(v) for k, v in HAND_LATENTS.items()})
    state.predict_all()
    state.weight_step()  # eta_w 0.1: W' = W - 0.1 dF/dW
    weights = net.host_weights()
    for name, w in HAND_WEIGHTS.items():
        np.testing.assert_allclose(weights[name], np.array(w) - 0.1 * np.array(HAND_DW[name]), rtol=1e-6,
                                   err_msg=name)


def test_hand_computed_gradients_are_the_weighted_energy_s_derivatives():
    """The closed forms above are the derivatives of F = sum pi E^2 (central differences, float64)."""

    def energy(latents, weights):
        e = {"visual.1": np.array(HAND_INPUTS["visual"][0]) - latents["visual.1"] * np.array(weights["visual.1"][0]),
             "tactile.1": HAND_INPUTS["tactile"][0][0] - latents["tactile.1"] * weights["tactile.1"][0][0],
             "joint.visual": latents["visual.1"] - latents["joint"] * weights["joint.visual"][0][0],
             "joint.tactile": latents["tactile.1"] - latents["joint"] * weights["joint.tactile"][0][0]}
        return sum(float(np.sum(np.array(HAND_PI[k]) * np.square(v))) for k, v in e.items())

    latents = {k: v[0][0] for k, v in HAND_LATENTS.items()}
    weights = {k: [list(row) for row in v] for k, v in HAND_WEIGHTS.items()}
    assert energy(latents, weights) == pytest.approx(sum(HAND_ENERGY.values()))
    h = 1e-6
    for node in latents:
        plus, minus = dict(latents), dict(latents)
        plus[node] += h
        minus[node] -= h
        assert (energy(plus, weights) - energy(minus, weights)) / (2 * h) == pytest.approx(HAND_DY[node], rel=1e-6)
    for name, w in weights.items():
        for j in range(len(w[0])):
            plus = {k: [list(r) for r in v] for k, v in weights.items()}
            minus = {k: [list(r) for r in v] for k, v in weights.items()}
            plus[name][0][j] += h
            minus[name][0][j] -= h
            numeric = (energy(latents, plus) - energy(latents, minus)) / (2 * h)
            assert numeric == pytest.approx(HAND_DW[name][0][j], rel=1e-6)


# --------------------------------------------------------------------------------------
# Kernels against the reference, random precisions, every device
# --------------------------------------------------------------------------------------

SHAPES = [(1, 7, 5), (3, 33, 17), (17, 65, 129)]


def layer(shape, seed):
    b, n_l, n_below = shape
    rng = np.random.default_rng(seed)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W = (rng.standard_normal((n_l, n_below)) / np.sqrt(n_l)).astype(np.float32)
    X = rng.random((b, n_below)).astype(np.float32)
    pi = rng.uniform(0.1, 5.0, n_below).astype(np.float32)
    return Y, W, X, pi


@pytest.mark.parametrize("activation", ref.ACTIVATIONS)
@pytest.mark.parametrize("shape", SHAPES, ids=str)
@pytest.mark.parametrize("epilogue", [False, True], ids=["predict", "epilogue"])
def test_weighted_predict_matches_reference(shape, activation, epilogue, device, seed):
    Y, W, X, pi = layer(shape, seed)
    b, n_below = X.shape
    cfg = wk.tile_config(wp.get_device(device), "predict", b)
    E, G = (to_wp(np.full((b, n_below), np.nan), device) for _ in range(2))
    R = to_wp(np.full((2, b), np.nan), device, wp.float64)
    partial = wp.zeros(wk.row_partial_shape(b, n_below, cfg), dtype=wp.float32, device=device)
    if epilogue:
        wk.predict_epilogue(to_wp(Y.astype(np.float64) @ W, device), to_wp(X, device), E, G, partial, R, 1,
                            activation=activation, precision=to_wp(pi, device))
    else:
        wk.predict(to_wp(Y, device), to_wp(W, device), to_wp(X, device), E, G, partial, R, 1, activation=activation,
                   precision=to_wp(pi, device))
    _, _, E_ref, G_ref = ref.predict(Y.astype(np.float64), W.astype(np.float64), X.astype(np.float64), activation,
                                     precision=pi.astype(np.float64))
    assert rel_err(E.numpy(), E_ref) <= 1e-5
    assert rel_err(G.numpy(), G_ref) <= 1e-5
    assert rel_err(R.numpy()[1], ref.energy(E_ref, pi)) <= 1e-5


@pytest.mark.parametrize("splits", [1, 3], ids=["fused", "split3"])
@pytest.mark.parametrize("shape", SHAPES, ids=str)
def test_weighted_latent_update_matches_reference(shape, splits, device, seed):
    b, n_l, n_below = shape
    Y, W, _, _ = layer(shape, seed)
    rng = np.random.default_rng(seed + 1)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    pi_above = rng.uniform(0.1, 5.0, n_l).astype(np.float32)
    expected = ref.latent_step(*(a.astype(np.float64) for a in (Y, G, W)), 0.05, E_above.astype(np.float64),
                               pi_above.astype(np.float64))
    wY = to_wp(Y, device)
    scratch = wp.zeros((splits, b, n_l), dtype=wp.float32, device=device) if splits > 1 else None
    tiles = wk.TileConfig(4, 8, 4, 32) if splits == 3 else None
    wk.latent_update(wY, to_wp(G, device), to_wp(W.T, device), 0.05, scratch, E_above=to_wp(E_above, device),
                     tiles=tiles, precision_above=to_wp(pi_above, device))
    assert rel_err(wY.numpy(), expected) <= 1e-5
    applied = to_wp(Y, device)
    wk.latent_apply(applied, to_wp(G.astype(np.float64) @ W.T, device), 0.05, E_above=to_wp(E_above, device),
                    precision_above=to_wp(pi_above, device))
    assert rel_err(applied.numpy(), expected) <= 1e-5


def test_numpy_backend_weighted_steps_match_reference(seed):
    Y, W, X, pi = layer((9, 6, 11), seed)
    be = NumpyBackend()
    handle = be.weights(W)
    E, G, R = np.zeros_like(X), np.zeros_like(X), np.zeros((1, 9))
    be.predict(Y, handle, X, E, G, R, 0, "tanh", 0.2, pi)
    _, _, E_ref, G_ref = ref.predict(*(a.astype(np.float64) for a in (Y, W, X)), "tanh", precision=pi)
    assert rel_err(G, G_ref) <= 1e-5
    assert rel_err(R[0], ref.energy(E_ref, pi)) <= 1e-5
    pi_above = pi[:6] * 2
    Y2 = Y.copy()
    be.latent_update(Y2, G, handle, 0.05, X[:, :6], None, pi_above)
    expected = ref.latent_step(*(a.astype(np.float64) for a in (Y, G, W)), 0.05, X[:, :6].astype(np.float64),
                               pi_above)
    assert rel_err(Y2, expected) <= 1e-5


@pytest.mark.parametrize("epilogue", [False, True], ids=["predict", "epilogue"])
def test_precisions_of_one_give_the_unweighted_kernels_bit_for_bit(epilogue, device, seed):
    Y, W, X, _ = layer((17, 65, 129), seed)
    ones = to_wp(np.ones(129), device)
    runs = []
    for pi in (None, ones):
        cfg = wk.tile_config(wp.get_device(device), "predict", 17)
        E, G = wp.zeros((17, 129), dtype=wp.float32, device=device), wp.zeros((17, 129), dtype=wp.float32,
                                                                               device=device)
        R = wp.zeros((1, 17), dtype=wp.float64, device=device)
        partial = wp.zeros(wk.row_partial_shape(17, 129, cfg), dtype=wp.float32, device=device)
        if epilogue:
            wk.predict_epilogue(to_wp(Y @ W, device), to_wp(X, device), E, G, partial, R, 0, precision=pi)
        else:
            wk.predict(to_wp(Y, device), to_wp(W, device), to_wp(X, device), E, G, partial, R, 0, precision=pi)
        above = to_wp(Y, device)
        wk.latent_update(above, G, to_wp(W.T, device), 0.1, E_above=to_wp(Y * 0.5, device),
                         precision_above=None if pi is None else to_wp(np.ones(65), device))
        runs.append([a.numpy() for a in (E, G, R, above)])
    for plain, weighted in zip(*runs, strict=True):
        np.testing.assert_array_equal(weighted, plain)


# --------------------------------------------------------------------------------------
# The network: precisions of 1, estimation, persistence
# --------------------------------------------------------------------------------------

SYNTH = {
    "modalities": {
        "visual": {"input_size": 12, "layers": [6], "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
        "tactile": {"input_size": 5, "layers": [4], "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
    },
    "joint": {"size": 3, "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
    "activation": "leaky_relu",
    "slope": 0.2,
}
TRAIN = {"epochs": 3, "batch_size": 16, "inference_steps": 5, "seed": 0, "converge_window": 0, "converge_tol": 0.01}
NO_STOP = dict.fromkeys(["visual.1", "tactile.1", "joint.visual", "joint.tactile"], 0.0)


def synthetic(n=40, seed=0):
    rng = np.random.default_rng(seed)
    z = rng.random((n, 3))
    return {"visual": (1 / (1 + np.exp(-z @ rng.normal(size=(3, 12))))).astype(np.float32),
            "tactile": (0.5 + 0.5 * np.tanh(z @ rng.normal(size=(3, 5)))).astype(np.float32)}


@pytest.mark.parametrize("name", ["numpy", "warp-cpu"])
def test_precisions_of_one_reproduce_training_and_inference_bit_for_bit(name):
    inputs = synthetic()
    runs = []
    for weighted in (False, True):
        net = Network(SYNTH, seed=2, backend=BACKENDS[name]())
        if weighted:
            net.set_precisions({e.name: np.ones(net.sizes[e.lower]) for e in net.edges})
            assert net.device_precisions() is not None  # the weighted kernels run, with pi = 1
        history = net.train(inputs, TRAIN)
        result = net.infer(inputs, max_steps=50, thresholds=NO_STOP)
        runs.append((net.host_weights(), history.energy, result.latents, result.mse))
    (w0, h0, y0, m0), (w1, h1, y1, m1) = runs
    for k in w0:
        np.testing.assert_array_equal(w1[k], w0[k])
    assert h1 == h0
    for k in y0:
        np.testing.assert_array_equal(y1[k], y0[k])
    assert m1 == m0


def test_none_is_the_default_and_leaves_the_network_unweighted():
    inputs = synthetic()
    plain, explicit = Network(SYNTH, seed=2, backend="numpy"), Network(SYNTH, seed=2, backend="numpy")
    plain.train(inputs, TRAIN)
    explicit.train(inputs, {**TRAIN, "precision_weighting": "none"})
    assert not explicit.weighted and explicit.device_precisions() is None
    for k, w in plain.host_weights().items():
        np.testing.assert_array_equal(explicit.host_weights()[k], w)
    assert MupnetParams().precision_weighting == "none"
    assert MupnetParams().training_config().precision_weighting == "none"


def test_estimate_closed_form_channel_layer_and_normalisation():
    # mean squares over 4 samples: a = [1, 4], b = [0.25]
    squares = {"a": np.array([4.0, 16.0]), "b": np.array([1.0])}
    channel = estimate_precisions(squares, 4, "channel", floor=1e-3)
    # raw 1 / var = [1, 0.25], [4]; mean over the 3 channels 1.75
    np.testing.assert_allclose(channel["a"], [1 / 1.75, 0.25 / 1.75], rtol=1e-6)
    np.testing.assert_allclose(channel["b"], [4 / 1.75], rtol=1e-6)
    layer_ = estimate_precisions(squares, 4, "layer", floor=1e-3)
    # pooled var a = 2.5 -> 0.4 per channel, b 4; mean (0.4 + 0.4 + 4) / 3 = 1.6
    np.testing.assert_allclose(layer_["a"], [0.25, 0.25], rtol=1e-6)
    np.testing.assert_allclose(layer_["b"], [2.5], rtol=1e-6)
    for pi in (channel, layer_):
        assert np.concatenate(list(pi.values())).mean() == pytest.approx(1.0)
    # a channel predicted exactly: its variance is floored at 0.5, raw pi 2 against 1 for var 1
    floored = estimate_precisions({"a": np.array([0.0, 4.0])}, 4, "channel", floor=0.5)
    np.testing.assert_allclose(floored["a"], [2 / 1.5, 1 / 1.5], rtol=1e-6)


def test_estimator_sums_the_epoch_s_errors_on_the_backend(backend):
    from vitaplace.engine.network.structure import Edge

    be = backend()
    edges = [Edge("a", "u", "a0", "m", 0.1, 0.0), Edge("b", "u", "b0", "m", 0.1, 0.0)]
    estimator = PrecisionEstimator(be, edges, {"a0": 2, "b0": 1}, "channel", 1e-3)
    # two minibatches of 2; channel variances over the 4 samples: [1, 4], [0.25]
    for rows_a, rows_b in (([[1, 2], [-1, -2]], [[0.5], [-0.5]]), ([[1, -2], [-1, 2]], [[0.5], [0.5]])):
        estimator.accumulate({"a": be.to_device(np.array(rows_a, np.float32)),
                              "b": be.to_device(np.array(rows_b, np.float32))})
    pi = estimator.end_epoch(4)
    np.testing.assert_allclose(pi["a"], [1 / 1.75, 0.25 / 1.75], rtol=1e-6)
    np.testing.assert_allclose(pi["b"], [4 / 1.75], rtol=1e-6)
    estimator.accumulate({"a": be.to_device(np.array([[2, 2]], np.float32)),
                          "b": be.to_device(np.array([[1]], np.float32))})
    # the sums restarted: var [4, 4], [1]; raw [0.25, 0.25], [1], mean 0.5
    np.testing.assert_allclose(estimator.end_epoch(1)["a"], [0.5, 0.5], rtol=1e-6)


@pytest.mark.parametrize("mode", ["layer", "channel"])
def test_training_sets_the_precisions_from_the_epoch_s_final_errors(mode):
    """One epoch, one minibatch, no latent steps: the final errors are those of the initial
    weights at latents 0.1 (reference), the precisions their closed-form estimate."""
    inputs = synthetic()
    net = Network(SYNTH, seed=3, backend="numpy")
    w0 = {k: w.astype(np.float64) for k, w in net.weights.items()}
    net.train(inputs, {**TRAIN, "epochs": 1, "batch_size": 40, "inference_steps": 0, "precision_weighting": mode,
                       "precision_floor": 1e-4})
    var = {}
    for e in net.edges:
        lower = inputs[e.modality] if e.lower.endswith(".0") else np.full((40, net.sizes[e.lower]), 0.1)
        _, _, E, _ = ref.predict(np.full((40, net.sizes[e.upper]), 0.1), w0[e.name], lower.astype(np.float64),
                                 "leaky_relu", 0.2)
        v = np.mean(E**2, axis=0)
        var[e.name] = np.full_like(v, v.mean()) if mode == "layer" else v
    raw = {k: 1 / np.maximum(v, 1e-4) for k, v in var.items()}
    mean = np.concatenate(list(raw.values())).mean()
    for k, r in raw.items():
        np.testing.assert_allclose(net.precisions[k], r / mean, rtol=1e-4, err_msg=k)
    assert net.weighted
    if mode == "layer":
        assert all(np.ptp(p) == 0 for p in net.precisions.values())


def test_first_epoch_runs_at_one_then_the_estimate_is_used():
    inputs = synthetic()
    runs = {}
    for mode in ("none", "channel"):
        net = Network(SYNTH, seed=2, backend="numpy")
        one = net.train(inputs, {**TRAIN, "epochs": 1, "precision_weighting": mode})
        runs[mode] = (net, one)
    np.testing.assert_array_equal(runs["channel"][0].host_weights()["visual.1"],
                                  runs["none"][0].host_weights()["visual.1"])
    assert runs["channel"][1].energy == runs["none"][1].energy
    assert not np.allclose(runs["channel"][0].precisions["visual.1"], 1.0)


def test_precisions_are_fixed_at_test_time_and_saved_with_the_model(tmp_path):
    inputs = synthetic()
    net = Network(SYNTH, seed=2, backend="numpy")
    net.train(inputs, {**TRAIN, "precision_weighting": "channel"})
    before = {k: p.copy() for k, p in net.precisions.items()}
    result = net.infer(inputs, max_steps=30, thresholds=NO_STOP)
    for k, p in before.items():
        np.testing.assert_array_equal(net.precisions[k], p)
    net.save(tmp_path / "net")
    loaded = Network.load(tmp_path / "net", backend="numpy")
    assert loaded.weighted
    for k, p in before.items():
        np.testing.assert_array_equal(loaded.precisions[k], p)
    again = loaded.infer(inputs, max_steps=30, thresholds=NO_STOP)
    np.testing.assert_array_equal(again.latents["joint"], result.latents["joint"])
    # a model saved before precision weighting (no precisions.npz) loads with every precision 1
    (tmp_path / "net" / "precisions.npz").unlink()
    old = Network.load(tmp_path / "net", backend="numpy")
    assert not old.weighted and all(np.all(p == 1) for p in old.precisions.values())
    # and an unweighted network writes none (a stale file would be read back)
    plain = Network(SYNTH, seed=2, backend="numpy")
    plain.save(tmp_path / "net")
    assert not (tmp_path / "net" / "precisions.npz").exists()


def test_weighting_changes_what_inference_settles_at():
    """The estimate is used by infer: a model with other precisions settles elsewhere."""
    inputs = synthetic()
    net = Network(SYNTH, seed=2, backend="numpy")
    net.train(inputs, {**TRAIN, "precision_weighting": "channel"})
    weighted = net.infer(inputs, max_steps=30, thresholds=NO_STOP).latents["joint"]
    net.set_precisions({e.name: np.ones(net.sizes[e.lower]) for e in net.edges})
    plain = net.infer(inputs, max_steps=30, thresholds=NO_STOP).latents["joint"]
    assert not np.allclose(weighted, plain)


def test_bad_mode_and_bad_precisions_are_refused():
    with pytest.raises(pydantic.ValidationError, match="precision_weighting"):
        MupnetParams(precision_weighting="diagonal")
    with pytest.raises(pydantic.ValidationError, match="precision_floor"):
        MupnetParams(precision_floor=0)
    net = Network(SYNTH, seed=0, backend="numpy")
    with pytest.raises(NetworkError, match="precision_weighting"):
        net.train(synthetic(), {**TRAIN, "precision_weighting": "diagonal"})
    with pytest.raises(NetworkError, match="visual.1"):
        net.set_precisions({"visual.1": np.ones(3)})
    with pytest.raises(NetworkError, match="> 0"):
        net.set_precisions({"visual.1": np.zeros(12)})


# --------------------------------------------------------------------------------------
# The test-time solvers' curvature bounds
# --------------------------------------------------------------------------------------


def test_curvature_bounds_take_the_precisions_into_account(seed):
    """Linear activation: the Hessian block of a latent node is exactly
    B = 2 sum_below W diag(pi) W^T + 2 diag(pi_above) + prior I; the preconditioner is its
    inverse, the scalar step's L bounds its largest eigenvalue (equal with one edge below)."""
    net = Network({**SYNTH, "activation": "linear"}, seed=seed % 1000, backend="numpy")
    rng = np.random.default_rng(seed)
    pi = {e.name: rng.uniform(0.2, 4.0, net.sizes[e.lower]) for e in net.edges}
    edges, nodes = net.edges, net.latent_nodes(net.modalities)
    w = {k: v.astype(np.float64) for k, v in net.weights.items()}
    prior = 0.3
    P = curvature_preconditioners(w, edges, nodes, "linear", 0.2, prior, pi)
    L = curvature_steps(w, edges, nodes, "linear", 0.2, prior, pi)
    for node in nodes:
        block = prior * np.eye(net.sizes[node])
        for e in edges:
            if e.upper == node:
                block += 2 * w[e.name] @ np.diag(pi[e.name]) @ w[e.name].T
            if e.lower == node:
                block += 2 * np.diag(pi[e.name])
        np.testing.assert_allclose(P[node] @ block, np.eye(net.sizes[node]), atol=1e-9, err_msg=node)
        largest = np.linalg.eigvalsh(block)[-1]
        assert 1 / L[node] >= largest * (1 - 1e-9), node
        if node != "joint":  # one edge below and one above: each term's own norm
            below = next(e for e in edges if e.upper == node)
            above = next(e for e in edges if e.lower == node)
            exact = (2 * np.linalg.eigvalsh(w[below.name] @ np.diag(pi[below.name]) @ w[below.name].T)[-1]
                     * (1 + 1e-6) + 2 * pi[above.name].max() + prior)
            assert 1 / L[node] == pytest.approx(exact, rel=1e-12)
    # without precisions: the unweighted bounds, unchanged
    ones = {k: np.ones_like(v) for k, v in pi.items()}
    for node, step in curvature_steps(w, edges, nodes, "linear", 0.2, prior).items():
        assert step == pytest.approx(curvature_steps(w, edges, nodes, "linear", 0.2, prior, ones)[node], rel=1e-12)
