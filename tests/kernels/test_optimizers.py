"""The weight optimisers of MuPNet's training (`vitaplace.engine.network.optimizer`):
hand-computed momentum and Adam steps, the numpy backend and the Warp kernels against the
numpy reference, sgd unchanged bit for bit, and training with each optimiser."""

import numpy as np
import pytest
from test_pc import SYNTH, TRAIN, synthetic

from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.optimizer import make_weight_optimizer
from vitaplace.engine.network.pc import Network
from vitaplace.engine.network.structure import Edge
from vitaplace.kernels import reference

W0 = np.array([[1.0, -2.0], [0.5, 0.0]], np.float32)
#: a fixed step direction g = 2 Y^T G, from Y = [[1, 0], [0, 1]] and G = g / 2
G_FIXED = np.array([[0.2, -0.4], [0.1, 0.3]], np.float32)
Y_EYE = np.eye(2, dtype=np.float32)


def _edge(eta: float) -> Edge:
    return Edge("e", "u", "d", "visual", eta, 1e-3)


def _two_steps(backend, name: str, eta: float, **settings) -> tuple[np.ndarray, np.ndarray]:
    """Two optimiser steps on the 2 x 2 weight W0 with the fixed direction G_FIXED; W and Wt."""
    edge = _edge(eta)
    handle = backend.weights(W0)
    Y = backend.to_device(Y_EYE)
    G = backend.to_device(G_FIXED / 2)
    opt = make_weight_optimizer(backend, name, [edge], {"e": (2, 2)}, **settings)
    assert opt is not None
    for _ in range(2):
        opt.step({"e": handle}, {"u": Y}, {"e": G}, [edge])
    assert opt.steps == 2
    return backend.download(handle.W), backend.download(handle.Wt)


def test_momentum_two_steps_by_hand():
    # v1 = g, W1 = W0 + eta g; v2 = beta g + g, W2 = W1 + eta (1 + beta) g = W0 + eta (2 + beta) g
    eta, beta = 0.1, 0.5
    W, Wt = _two_steps(NumpyBackend(), "momentum", eta, momentum=beta)
    np.testing.assert_allclose(W, W0 + eta * (2 + beta) * G_FIXED, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(Wt, W.T)


def test_adam_two_steps_by_hand():
    # a constant g: m_t / (1 - b1^t) = g and s_t / (1 - b2^t) = g^2 at every t, so each step is
    # eta g / (|g| + eps): W2 = W0 + 2 eta sign(g) |g| / (|g| + eps)
    eta, eps = 0.01, 1e-3
    W, Wt = _two_steps(NumpyBackend(), "adam", eta, beta1=0.9, beta2=0.999, eps=eps)
    g = G_FIXED.astype(np.float64)
    np.testing.assert_allclose(W, W0 + 2 * eta * g / (np.abs(g) + eps), rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(Wt, W.T)
    # and written out in full, step by step (b1 0.5, b2 0.75: the bias corrections matter)
    b1, b2 = 0.5, 0.75
    W, _ = _two_steps(NumpyBackend(), "adam", eta, beta1=b1, beta2=b2, eps=eps)
    m1, s1 = (1 - b1) * g, (1 - b2) * g * g
    w1 = W0 + eta * (m1 / (1 - b1)) / (np.sqrt(s1 / (1 - b2)) + eps)
    m2, s2 = b1 * m1 + (1 - b1) * g, b2 * s1 + (1 - b2) * g * g
    w2 = w1 + eta * (m2 / (1 - b1**2)) / (np.sqrt(s2 / (1 - b2**2)) + eps)
    np.testing.assert_allclose(W, w2, rtol=1e-5, atol=1e-7)


def test_an_unknown_optimiser_is_refused():
    with pytest.raises(ValueError, match="unknown weight optimiser 'rmsprop'"):
        make_weight_optimizer(NumpyBackend(), "rmsprop", [_edge(0.1)], {"e": (2, 2)})


@pytest.mark.parametrize("shape", [(3, 5), (37, 70)], ids=["3x5", "37x70"])
def test_numpy_optimizer_steps_match_the_reference(shape, seed):
    rng = np.random.default_rng(seed)
    be = NumpyBackend()
    W = rng.normal(size=shape).astype(np.float32)
    Y = rng.normal(size=(9, shape[0])).astype(np.float32)
    G = rng.normal(size=(9, shape[1])).astype(np.float32)
    D = be.empty(shape)
    be.weight_gradient(D, Y, G)
    np.testing.assert_allclose(D, 2 * Y.T.astype(np.float64) @ G, rtol=1e-5, atol=1e-5)
    handle, V = be.weights(W), rng.normal(size=shape).astype(np.float32)
    w_ref, v_ref = reference.momentum_weight_step(W, V, D, 0.01, 0.9)
    be.momentum_weight_step(handle, V, D, 0.01, 0.9)
    np.testing.assert_allclose(handle.W, w_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(V, v_ref, rtol=1e-6)
    np.testing.assert_array_equal(handle.Wt, handle.W.T)
    handle = be.weights(W)
    M, S = rng.normal(size=shape).astype(np.float32), rng.random(shape).astype(np.float32)
    w_ref, m_ref, s_ref = reference.adam_weight_step(W, M, S, D, 3, 0.01, 0.9, 0.999, 1e-8)
    t = np.array([3], np.int32)
    be.adam_weight_step(handle, M, S, D, t, 0.01, 0.9, 0.999, 1e-8)
    np.testing.assert_allclose(handle.W, w_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(M, m_ref, rtol=1e-6)
    np.testing.assert_allclose(S, s_ref, rtol=1e-6)
    np.testing.assert_array_equal(handle.Wt, handle.W.T)


@pytest.mark.parametrize("shape", [(3, 5), (37, 70)], ids=["3x5", "37x70"])
def test_warp_optimizer_kernels_match_the_reference(device, shape, seed):
    wp = pytest.importorskip("warp")
    from vitaplace.kernels import warp_kernels as k

    rng = np.random.default_rng(seed)
    W = rng.normal(size=shape).astype(np.float32)
    D = rng.normal(size=shape).astype(np.float32)
    V = rng.normal(size=shape).astype(np.float32)
    M, S = rng.normal(size=shape).astype(np.float32), rng.random(shape).astype(np.float32)
    arr = lambda x: wp.array(x, dtype=wp.float32, device=device)  # noqa: E731

    w, wt, v = arr(W), arr(np.ascontiguousarray(W.T)), arr(V)
    k.momentum_weight_step(w, v, arr(D), 0.01, 0.9, Wt=wt)
    w_ref, v_ref = reference.momentum_weight_step(W, V, D, 0.01, 0.9)
    np.testing.assert_allclose(w.numpy(), w_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(v.numpy(), v_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(wt.numpy(), w.numpy().T)

    t = wp.array(np.array([2], np.int32), dtype=wp.int32, device=device)
    k.count_step(t)
    assert t.numpy()[0] == 3
    w, wt, m, s = arr(W), arr(np.ascontiguousarray(W.T)), arr(M), arr(S)
    k.adam_weight_step(w, m, s, arr(D), t, 0.01, 0.9, 0.999, 1e-8, Wt=wt)
    w_ref, m_ref, s_ref = reference.adam_weight_step(W, M, S, D, 3, 0.01, 0.9, 0.999, 1e-8)
    np.testing.assert_allclose(w.numpy(), w_ref, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(m.numpy(), m_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(s.numpy(), s_ref, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(wt.numpy(), w.numpy().T)
    w = arr(W)  # without Wt: W alone
    k.momentum_weight_step(w, arr(V), arr(D), 0.01, 0.9)
    np.testing.assert_allclose(w.numpy(), reference.momentum_weight_step(W, V, D, 0.01, 0.9)[0], rtol=1e-6, atol=1e-7)


def _backend(name: str):
    if name == "numpy":
        return "numpy"
    pytest.importorskip("warp")
    from vitaplace.engine.network.backends import WarpBackend

    return WarpBackend("cpu")


@pytest.mark.parametrize("name", ["numpy", "warp-cpu"])
def test_sgd_is_the_fused_step_bit_for_bit(name):
    """``weight_optimizer: sgd`` (whatever the other optimisers' settings) trains exactly as
    a configuration written before the option existed."""
    inputs, _ = synthetic(n=60)
    runs = []
    for extra in ({}, {"weight_optimizer": "sgd", "weight_momentum": 0.5, "adam_beta1": 0.5, "adam_eps": 1.0}):
        net = Network(SYNTH, seed=1, backend=_backend(name))
        net.train(inputs, {**TRAIN, "epochs": 3, "batch_size": 25, "inference_steps": 5, **extra})
        runs.append(net.weights)
    for edge, w in runs[0].items():
        np.testing.assert_array_equal(runs[1][edge], w, err_msg=edge)


@pytest.mark.parametrize("optimizer", ["momentum", "adam"])
def test_numpy_and_warp_cpu_agree_on_optimised_training(optimizer):
    pytest.importorskip("warp")
    inputs, _ = synthetic(n=60)
    cfg = {**TRAIN, "epochs": 3, "batch_size": 25, "inference_steps": 5, "weight_optimizer": optimizer}
    weights, energies = {}, {}
    for name in ("numpy", "warp-cpu"):
        net = Network(SYNTH, seed=1, backend=_backend(name))
        history = net.train(inputs, cfg)
        weights[name], energies[name] = net.weights, history.total()
    for edge, w in weights["numpy"].items():
        rel = np.abs(weights["warp-cpu"][edge] - w).max() / np.abs(w).max()
        assert rel <= 1e-5, (edge, rel)
    np.testing.assert_allclose(energies["warp-cpu"], energies["numpy"], rtol=1e-5)


@pytest.mark.parametrize("name", ["numpy", "warp-cpu"])
@pytest.mark.parametrize("optimizer", ["momentum", "adam"])
def test_training_with_an_optimiser_lowers_the_training_energy(name, optimizer):
    """On the synthetic two-modality case of the training tests, at its step sizes (for
    Adam: its learning rates, eta_w 0.005)."""
    inputs, _ = synthetic(n=200)
    net = Network(SYNTH, seed=0, backend=_backend(name))
    history = net.train(inputs, {**TRAIN, "epochs": 10, "weight_optimizer": optimizer})
    total = history.total()
    assert np.all(np.isfinite(total))
    assert total[-1] < 0.5 * total[0], total


def test_optimiser_state_starts_fresh_every_run():
    """The state is the training run's: a second `train` starts from zero moments and count,
    so it repeats the first run's steps from the same weights and latents."""
    inputs, _ = synthetic(n=50)
    cfg = {**TRAIN, "epochs": 2, "batch_size": 25, "inference_steps": 3, "weight_optimizer": "adam"}
    a = Network(SYNTH, seed=2, backend="numpy")
    start = {k: w.copy() for k, w in a.weights.items()}
    a.train(inputs, cfg)
    b = Network(SYNTH, seed=2, backend="numpy")
    b.train(inputs, cfg)
    b.set_weights(start)
    b.train(inputs, cfg)
    for edge, w in a.weights.items():
        np.testing.assert_array_equal(b.weights[edge], w, err_msg=edge)


@pytest.mark.parametrize("name", ["numpy", "warp-cpu"])
def test_one_adam_step_of_training_moves_each_weight_by_its_learning_rate(name):
    """Training runs the chosen optimiser: Adam's first step is eta_w g / (|g| + eps), so one
    minibatch moves every weight whose |g| is well above eps by eta_w (the paper's SGD would
    move each by 2 eta_w |Y^T G|, mostly far less)."""
    inputs, _ = synthetic(n=40)
    net = Network(SYNTH, seed=0, backend=_backend(name))
    start = {k: w.copy() for k, w in net.weights.items()}
    net.train(inputs, {**TRAIN, "epochs": 1, "batch_size": 40, "inference_steps": 3, "weight_optimizer": "adam"})
    for edge, w in net.weights.items():
        moved = np.abs(w.astype(np.float64) - start[edge])
        assert np.mean(np.abs(moved - 0.005) < 1e-4) > 0.95, edge
