"""Warp kernels (CPU) vs the numpy reference, and the reference vs closed forms (DESIGN §6-7).

Expected values come from ``kernels/reference.py`` evaluated in float64 on the same float32
inputs, or from hand computation / finite differences; never from the kernels themselves.
"""

import numpy as np
import pytest

from vitaplace.kernels import reference as ref

wp = pytest.importorskip("warp")
wk = pytest.importorskip("vitaplace.kernels.warp_kernels")

DEVICE = "cpu"
TOL = 1e-5  # max relative error, float32 kernels vs float64 reference

# (B, n_l, n_below): batch of one, shapes that are not tile multiples, several tiles.
SHAPES = [(1, 7, 5), (3, 33, 17), (150, 100, 72), (17, 65, 129)]
SHAPE_IDS = ["x".join(map(str, s)) for s in SHAPES]


def rel_err(a, b) -> float:
    """max|a - b| / max(max|b|, tiny)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), np.finfo(np.float64).tiny))


def f64(*arrays):
    return tuple(np.asarray(a, dtype=np.float64) for a in arrays)


def to_wp(a):
    return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.float32, device=DEVICE)


def layer(shape, seed=0):
    """Float32 Y, W, X for one layer, scaled so that A = Y @ W is O(1) (Glorot-like W)."""
    b, n_l, n_below = shape
    rng = np.random.default_rng(seed)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W = (rng.standard_normal((n_l, n_below)) / np.sqrt(n_l)).astype(np.float32)
    X = rng.random((b, n_below)).astype(np.float32)
    return Y, W, X


def run_predict(Y, W, X, activation="leaky_relu", slope=0.2):
    b, n_below = X.shape
    outs = [wp.zeros((b, n_below), dtype=wp.float32, device=DEVICE) for _ in range(4)]
    wk.predict(to_wp(Y), to_wp(W), to_wp(X), *outs, activation=activation, slope=slope)
    return [o.numpy() for o in outs]


# --------------------------------------------------------------------------------------
# Warp kernels vs reference
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("activation", ref.ACTIVATIONS)
@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_predict_matches_reference(shape, activation):
    Y, W, X = layer(shape)
    got = run_predict(Y, W, X, activation)
    expected = ref.predict(*f64(Y, W, X), activation)
    for name, g, e in zip("APEG", got, expected):
        assert g.dtype == np.float32
        assert rel_err(g, e) <= TOL, (name, rel_err(g, e))


def test_predict_leaky_relu_slope_is_runtime_parameter():
    Y, W, X = layer((3, 33, 17), seed=1)
    for slope in (0.01, 0.5):
        got = run_predict(Y, W, X, "leaky_relu", slope)
        expected = ref.predict(*f64(Y, W, X), "leaky_relu", slope)
        for g, e in zip(got, expected):
            assert rel_err(g, e) <= TOL


@pytest.mark.parametrize("with_above", [True, False], ids=["E_above", "top"])
@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_latent_update_matches_reference(shape, with_above):
    b, n_l, n_below = shape
    Y, W, _ = layer(shape, seed=2)
    rng = np.random.default_rng(3)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32) if with_above else None
    eta = 0.05
    wY = to_wp(Y)
    wk.latent_update(wY, to_wp(G), to_wp(W), eta, to_wp(E_above) if with_above else None)
    expected = ref.latent_step(*f64(Y, G, W), eta, None if E_above is None else f64(E_above)[0])
    assert rel_err(wY.numpy(), expected) <= TOL


@pytest.mark.parametrize("first_above", [True, False], ids=["E_above_first", "no_E_above"])
def test_latent_update_accumulates_modalities(first_above):
    """Joint layer: two (G, W) pairs (different n_below) accumulated into one Y."""
    b, n_l = 17, 65
    rng = np.random.default_rng(4)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W1 = (rng.standard_normal((n_l, 129)) / 8).astype(np.float32)
    G1 = rng.standard_normal((b, 129)).astype(np.float32)
    W2 = (rng.standard_normal((n_l, 5)) / 8).astype(np.float32)
    G2 = rng.standard_normal((b, 5)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    eta = 0.01
    wY = to_wp(Y)
    wk.latent_update(wY, to_wp(G1), to_wp(W1), eta, to_wp(E_above) if first_above else None)
    wk.latent_update(wY, to_wp(G2), to_wp(W2), eta, None)
    y, g1, w1, g2, w2, ea = f64(Y, G1, W1, G2, W2, E_above)
    expected = y + 2 * eta * (g1 @ w1.T + g2 @ w2.T)
    if first_above:
        expected -= 2 * eta * ea
    assert rel_err(wY.numpy(), expected) <= TOL


@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_weight_update_matches_reference(shape):
    b, n_l, n_below = shape
    Y, W, _ = layer(shape, seed=5)
    G = np.random.default_rng(6).standard_normal((b, n_below)).astype(np.float32)
    eta = 0.05
    wW = to_wp(W)
    wk.weight_update(wW, to_wp(Y), to_wp(G), eta)
    assert rel_err(wW.numpy(), ref.weight_step(*f64(W, Y, G), eta)) <= TOL


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (3, 17), (150, 300), (65, 129)])
def test_squared_norm(shape):
    E = np.random.default_rng(7).standard_normal(shape).astype(np.float32)
    got = wk.squared_norm(to_wp(E))
    assert isinstance(got, float)
    expected = float(np.sum(E.astype(np.float64) ** 2))
    assert abs(got - expected) <= 1e-6 * expected


def test_squared_norm_empty():
    assert wk.squared_norm(wp.zeros((0, 4), dtype=wp.float32, device=DEVICE)) == 0.0


def _all_kernels_vs_reference(shape, activation="tanh"):
    b, n_l, n_below = shape
    Y, W, X = layer(shape, seed=8)
    for g, e in zip(run_predict(Y, W, X, activation), ref.predict(*f64(Y, W, X), activation)):
        assert rel_err(g, e) <= TOL
    rng = np.random.default_rng(9)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    wY = to_wp(Y)
    wk.latent_update(wY, to_wp(G), to_wp(W), 0.03, to_wp(E_above))
    assert rel_err(wY.numpy(), ref.latent_step(*f64(Y, G, W), 0.03, f64(E_above)[0])) <= TOL
    wW = to_wp(W)
    wk.weight_update(wW, to_wp(Y), to_wp(G), 0.03)
    assert rel_err(wW.numpy(), ref.weight_step(*f64(W, Y, G), 0.03)) <= TOL
    E = X - Y[:, :1]
    assert abs(wk.squared_norm(to_wp(E)) - np.sum(f64(E)[0] ** 2)) <= 1e-6 * np.sum(f64(E)[0] ** 2)


def test_small_tiles_many_partial_edges(monkeypatch):
    """Tiny tiles: several tiles with ragged edges along M, N and K in every kernel."""
    monkeypatch.setattr(wk, "_CPU_TILES", (4, 8, 4, 1))
    _all_kernels_vs_reference((17, 65, 29))
    _all_kernels_vs_reference((1, 7, 5))


def test_results_do_not_depend_on_block_dim(monkeypatch):
    """Cooperative CPU blocks (fibers) with an odd block_dim give the same results."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setattr(wk, "_CPU_TILES", (8, 16, 8, 7))
    _all_kernels_vs_reference((17, 65, 29), "sigmoid")


def test_warp_api_validation():
    Y, W, X = layer((3, 33, 17))
    b, n_below = X.shape
    outs = [wp.zeros((b, n_below), dtype=wp.float32, device=DEVICE) for _ in range(4)]
    with pytest.raises(ValueError, match="leaky_relu"):
        wk.predict(to_wp(Y), to_wp(W), to_wp(X), *outs, activation="relu6")
    with pytest.raises(ValueError, match="shape"):
        wk.predict(to_wp(Y), to_wp(W.T), to_wp(X), *outs)
    with pytest.raises(ValueError, match="shape"):
        wk.latent_update(to_wp(Y), to_wp(X), to_wp(W), 0.1, to_wp(X))
    with pytest.raises(ValueError, match="shape"):
        wk.weight_update(to_wp(W), to_wp(Y), to_wp(X[:, :3]), 0.1)
    with pytest.raises(TypeError):
        wk.weight_update(wp.array(W.astype(np.float64), dtype=wp.float64, device=DEVICE), to_wp(Y), to_wp(X), 0.1)


# --------------------------------------------------------------------------------------
# Reference vs hand computation / closed forms
# --------------------------------------------------------------------------------------


def test_reference_hand_computed_1x2x2():
    Y = np.array([[1.0, -2.0]])
    W = np.array([[1.0, 2.0], [3.0, -1.0]])
    X = np.array([[0.5, 1.0]])
    A, P, E, G = ref.predict(Y, W, X, "leaky_relu", 0.2)
    # A = [1*1 + (-2)*3, 1*2 + (-2)*(-1)] = [-5, 4]
    np.testing.assert_allclose(A, [[-5.0, 4.0]])
    np.testing.assert_allclose(P, [[-1.0, 4.0]])  # 0.2 * -5, 4
    np.testing.assert_allclose(E, [[1.5, -3.0]])  # 0.5 - (-1), 1 - 4
    np.testing.assert_allclose(G, [[0.3, -3.0]])  # 0.2 * 1.5, 1 * -3
    # G @ W.T = [0.3*1 - 3*2, 0.3*3 - 3*(-1)] = [-5.7, 3.9]; eta = 0.1 -> 2 eta = 0.2
    np.testing.assert_allclose(ref.latent_step(Y, G, W, 0.1), [[1 - 1.14, -2 + 0.78]])
    np.testing.assert_allclose(ref.latent_step(Y, G, W, 0.1, np.array([[1.0, -1.0]])), [[-0.34, -1.02]])
    # Y.T @ G = [[0.3, -3], [-0.6, 6]]
    np.testing.assert_allclose(ref.weight_step(W, Y, G, 0.1), [[1.06, 1.4], [2.88, 0.2]])


def test_reference_activation_closed_forms():
    a = np.array([-2.0, 0.0, 3.0])
    np.testing.assert_allclose(ref.activation(a, "leaky_relu"), [-0.4, 0.0, 3.0])
    np.testing.assert_allclose(ref.activation(a, "leaky_relu", slope=0.5), [-1.0, 0.0, 3.0])
    np.testing.assert_allclose(ref.activation_derivative(a, "leaky_relu"), [0.2, 0.2, 1.0])
    np.testing.assert_allclose(ref.activation(a, "sigmoid"), 1 / (1 + np.exp(-a)))
    np.testing.assert_allclose(ref.activation(np.array([0.0]), "sigmoid"), [0.5])
    np.testing.assert_allclose(ref.activation_derivative(np.array([0.0]), "sigmoid"), [0.25])
    np.testing.assert_allclose(ref.activation(a, "tanh"), np.tanh(a))
    np.testing.assert_allclose(ref.activation_derivative(np.array([0.0]), "tanh"), [1.0])
    np.testing.assert_allclose(ref.activation(a, "linear"), a)
    np.testing.assert_allclose(ref.activation_derivative(a, "linear"), [1.0, 1.0, 1.0])
    # no overflow for large |a|
    big = np.array([-1000.0, 1000.0])
    np.testing.assert_allclose(ref.activation(big, "sigmoid"), [0.0, 1.0])
    np.testing.assert_allclose(ref.activation_derivative(big, "sigmoid"), [0.0, 0.0])


@pytest.mark.parametrize("name", ref.ACTIVATIONS)
def test_reference_derivative_vs_central_differences(name):
    rng = np.random.default_rng(10)
    a = rng.uniform(-3, 3, size=200)
    a = a[np.abs(a) > 1e-3]  # away from the leaky ReLU kink
    h = 1e-6
    fd = (ref.activation(a + h, name, 0.3) - ref.activation(a - h, name, 0.3)) / (2 * h)
    np.testing.assert_allclose(ref.activation_derivative(a, name, 0.3), fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("name", ref.ACTIVATIONS)
def test_reference_steps_are_gradient_steps_of_the_energy(name):
    """latent_step / weight_step are Y - eta dF/dY and W - eta dF/dW for
    F = ||X - phi(Y W)||^2 + ||Y - P_above||^2 (E_above = Y - P_above), by finite differences."""
    rng = np.random.default_rng(11)
    Y = rng.standard_normal((2, 3))
    W = rng.standard_normal((3, 4)) / 2
    X = rng.random((2, 4))
    P_above = rng.standard_normal((2, 3))
    eta, h = 0.1, 1e-6

    def energy(Y, W):
        return np.sum((X - ref.activation(Y @ W, name)) ** 2) + np.sum((Y - P_above) ** 2)

    def num_grad(f, x):
        g = np.zeros_like(x)
        for idx in np.ndindex(x.shape):
            d = np.zeros_like(x)
            d[idx] = h
            g[idx] = (f(x + d) - f(x - d)) / (2 * h)
        return g

    _, _, _, G = ref.predict(Y, W, X, name)
    dY = num_grad(lambda y: energy(y, W), Y)
    dW = num_grad(lambda w: energy(Y, w), W)
    np.testing.assert_allclose(ref.latent_step(Y, G, W, eta, Y - P_above), Y - eta * dY, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(ref.weight_step(W, Y, G, eta), W - eta * dW, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", ref.ACTIVATIONS)
def test_reference_preserves_dtype(dtype, name):
    Y, W, X = (a.astype(dtype) for a in layer((3, 5, 4)))
    outs = ref.predict(Y, W, X, name)
    assert all(o.dtype == dtype for o in outs)
    assert ref.activation_derivative(Y, name).dtype == dtype
    G = outs[3]
    assert ref.latent_step(Y, G, W, 0.1).dtype == dtype
    assert ref.latent_step(Y, G, W, 0.1, Y).dtype == dtype
    assert ref.weight_step(W, Y, G, 0.1).dtype == dtype


def test_reference_unknown_activation():
    a = np.zeros(3)
    for fn in (ref.activation, ref.activation_derivative):
        with pytest.raises(ValueError, match="leaky_relu.*tanh.*sigmoid.*linear"):
            fn(a, "relu")
    with pytest.raises(ValueError):
        ref.predict(np.zeros((1, 2)), np.zeros((2, 2)), np.zeros((1, 2)), "softplus")
