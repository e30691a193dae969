"""Warp kernels vs the numpy reference on every device, and the reference vs closed forms.

Expected values come from ``kernels/reference.py`` evaluated in float64 on the same float32
inputs, or from hand computation / finite differences; never from the kernels themselves.
Kernel tests take the ``device`` fixture (tests/conftest.py): ``cpu`` always, ``cuda``
where a CUDA device exists.
"""

import numpy as np
import pytest

from vitaplace.kernels import reference as ref

wp = pytest.importorskip("warp")
wk = pytest.importorskip("vitaplace.kernels.warp_kernels")

TOL = 1e-5  # max relative error, float32 kernels vs float64 reference

# (B, n_l, n_below): batch of one, shapes that are not tile multiples, several tiles.
SHAPES = [(1, 7, 5), (3, 33, 17), (150, 100, 72), (17, 65, 129)]
SHAPE_IDS = ["x".join(map(str, s)) for s in SHAPES]
# Wider layers (the paper's 1000 and 300 units, one past a tile): few shapes, big GEMMs.
WIDE = [(150, 129, 300), (40, 1000, 300), (20, 300, 1000)]
WIDE_IDS = ["x".join(map(str, s)) for s in WIDE]


def rel_err(a, b) -> float:
    """max|a - b| / max(max|b|, tiny)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), np.finfo(np.float64).tiny))


def f64(*arrays):
    return tuple(np.asarray(a, dtype=np.float64) for a in arrays)


def to_wp(a, device, dtype=wp.float32):
    return wp.array(np.ascontiguousarray(a, dtype=wp.dtype_to_numpy(dtype)), dtype=dtype, device=device)


def poisoned(shape, device, dtype=wp.float32):
    """An output buffer full of NaN (or -1 for integers): every element must be written."""
    fill = -1 if dtype == wp.int32 else np.nan
    return to_wp(np.full(shape, fill), device, dtype)


def layer(shape, seed=0):
    """Float32 Y, W, X for one layer, scaled so that A = Y @ W is O(1) (Glorot-like W)."""
    b, n_l, n_below = shape
    rng = np.random.default_rng(seed)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W = (rng.standard_normal((n_l, n_below)) / np.sqrt(n_l)).astype(np.float32)
    X = rng.random((b, n_below)).astype(np.float32)
    return Y, W, X


def run_predict(Y, W, X, device, activation="leaky_relu", slope=0.2, tiles=None, store_prediction=True, slot=1):
    """Returns (A, P, E, G, row energies) from the kernel; A, P None unless stored."""
    b, n_below = X.shape
    dev = wp.get_device(device)
    cfg = tiles or wk.tile_config(dev, "predict", b)
    outs = [poisoned((b, n_below), device) for _ in range(4)]
    R = poisoned((3, b), device, wp.float64)
    partial = poisoned(wk.row_partial_shape(b, n_below, cfg), device)
    A, P = (outs[0], outs[1]) if store_prediction else (None, None)
    wk.predict(to_wp(Y, device), to_wp(W, device), to_wp(X, device), outs[2], outs[3], partial, R, slot,
               activation=activation, slope=slope, A=A, P=P, tiles=cfg)
    got = [o.numpy() for o in outs]
    rows = R.numpy()
    assert np.isnan(rows[[s for s in range(3) if s != slot]]).all(), "only the given slot is written"
    return (*(got[:2] if store_prediction else (None, None)), got[2], got[3], rows[slot])


def latent_scratch(b, n_l, n_below, device, splits=None):
    """The split-K scratch (poisoned): the device's own choice, or ``splits`` slices;
    ``None`` for the single fused kernel."""
    count = wk.latent_scratch_shape(b, n_l, n_below, device)[0] if splits is None else splits
    return poisoned((count, b, n_l), device) if count > 1 else None


# --------------------------------------------------------------------------------------
# Warp kernels vs reference
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("activation", ref.ACTIVATIONS)
@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_predict_matches_reference(shape, activation, device):
    Y, W, X = layer(shape)
    *got, rows = run_predict(Y, W, X, device, activation)
    expected = ref.predict(*f64(Y, W, X), activation)
    for name, g, e in zip("APEG", got, expected, strict=True):
        assert g.dtype == np.float32
        assert rel_err(g, e) <= TOL, (name, rel_err(g, e))
    assert rel_err(rows, np.sum(expected[2] ** 2, axis=1)) <= TOL


@pytest.mark.parametrize("shape", WIDE, ids=WIDE_IDS)
def test_wide_layers_match_reference(shape, device):
    """All three kernels at the paper's layer widths (every tile, every K step)."""
    b, n_l, n_below = shape
    Y, W, X = layer(shape, seed=12)
    _, _, E, G, rows = run_predict(Y, W, X, device, "leaky_relu", store_prediction=False)
    _, _, e, g = ref.predict(*f64(Y, W, X))
    assert rel_err(E, e) <= TOL and rel_err(G, g) <= TOL
    assert rel_err(rows, np.sum(e**2, axis=1)) <= TOL
    wY = to_wp(Y, device)
    wk.latent_update(wY, to_wp(G, device), to_wp(W.T, device), 0.01, latent_scratch(b, n_l, n_below, device))
    assert rel_err(wY.numpy(), ref.latent_step(*f64(Y, G, W), 0.01)) <= TOL
    wW = to_wp(W, device)
    wk.weight_update(wW, to_wp(Y, device), to_wp(G, device), 0.01)
    assert rel_err(wW.numpy(), ref.weight_step(*f64(W, Y, G), 0.01)) <= TOL


def test_predict_without_prediction_outputs(device):
    Y, W, X = layer((17, 65, 129), seed=13)
    A, P, E, G, rows = run_predict(Y, W, X, device, "sigmoid", store_prediction=False)
    _, _, e, g = ref.predict(*f64(Y, W, X), "sigmoid")
    assert A is None and P is None
    assert rel_err(E, e) <= TOL and rel_err(G, g) <= TOL
    # sigmoid(0) = 0.5: padded columns must not leak into the row energies
    assert rel_err(rows, np.sum(e**2, axis=1)) <= TOL


def test_predict_leaky_relu_slope_is_runtime_parameter(device):
    Y, W, X = layer((3, 33, 17), seed=1)
    for slope in (0.01, 0.5):
        *got, _ = run_predict(Y, W, X, device, "leaky_relu", slope)
        expected = ref.predict(*f64(Y, W, X), "leaky_relu", slope)
        for g, e in zip(got, expected, strict=True):
            assert rel_err(g, e) <= TOL


@pytest.mark.parametrize("splits", [None, 1, 3], ids=["auto", "fused", "split3"])
@pytest.mark.parametrize("with_above", [True, False], ids=["E_above", "top"])
@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_latent_update_matches_reference(shape, with_above, splits, device, seed):
    b, n_l, n_below = shape
    Y, W, _ = layer(shape, seed=2)
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32) if with_above else None
    eta = 0.05
    wY = to_wp(Y, device)
    tiles = wk.TileConfig(4, 8, 4, 32) if splits == 3 else None  # several K steps to split
    scratch = latent_scratch(b, n_l, n_below, device, splits)
    wk.latent_update(wY, to_wp(G, device), to_wp(W.T, device), eta, scratch,
                     E_above=to_wp(E_above, device) if with_above else None, tiles=tiles)
    expected = ref.latent_step(*f64(Y, G, W), eta, None if E_above is None else f64(E_above)[0])
    assert rel_err(wY.numpy(), expected) <= TOL


@pytest.mark.parametrize("splits", [1, 3], ids=["fused", "split3"])
def test_latent_update_mask_leaves_inactive_rows_alone(splits, device, seed):
    b, n_l, n_below = 9, 33, 17
    Y, W, _ = layer((b, n_l, n_below), seed=14)
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    mask = np.array([1, 0, 1, 1, 0, 0, 1, 0, 1], dtype=np.int32)
    wY = to_wp(Y, device)
    tiles = wk.TileConfig(4, 8, 4, 32 if device == "cuda" else 1)  # several K steps to split
    wk.latent_update(wY, to_wp(G, device), to_wp(W.T, device), 0.05, latent_scratch(b, n_l, n_below, device, splits),
                     E_above=to_wp(E_above, device), mask=to_wp(mask, device, wp.int32), tiles=tiles)
    stepped = ref.latent_step(*f64(Y, G, W), 0.05, f64(E_above)[0])
    got = wY.numpy()
    on = mask == 1
    assert rel_err(got[on], stepped[on]) <= TOL
    np.testing.assert_array_equal(got[~on], Y[~on])


@pytest.mark.parametrize("first_above", [True, False], ids=["E_above_first", "no_E_above"])
def test_latent_update_accumulates_modalities(first_above, device, seed):
    """Joint layer: two (G, W) pairs (different n_below) accumulated into one Y."""
    b, n_l = 17, 65
    rng = np.random.default_rng(seed)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W1 = (rng.standard_normal((n_l, 129)) / 8).astype(np.float32)
    G1 = rng.standard_normal((b, 129)).astype(np.float32)
    W2 = (rng.standard_normal((n_l, 5)) / 8).astype(np.float32)
    G2 = rng.standard_normal((b, 5)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    eta = 0.01
    wY = to_wp(Y, device)
    wk.latent_update(wY, to_wp(G1, device), to_wp(W1.T, device), eta, latent_scratch(b, n_l, 129, device),
                     E_above=to_wp(E_above, device) if first_above else None)
    wk.latent_update(wY, to_wp(G2, device), to_wp(W2.T, device), eta, latent_scratch(b, n_l, 5, device))
    y, g1, w1, g2, w2, ea = f64(Y, G1, W1, G2, W2, E_above)
    expected = y + 2 * eta * (g1 @ w1.T + g2 @ w2.T)
    if first_above:
        expected -= 2 * eta * ea
    assert rel_err(wY.numpy(), expected) <= TOL


@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_weight_update_matches_reference(shape, device, seed):
    b, n_l, n_below = shape
    Y, W, _ = layer(shape, seed=5)
    G = np.random.default_rng(seed).standard_normal((b, n_below)).astype(np.float32)
    eta = 0.05
    wW = to_wp(W, device)
    wk.weight_update(wW, to_wp(Y, device), to_wp(G, device), eta)
    assert rel_err(wW.numpy(), ref.weight_step(*f64(W, Y, G), eta)) <= TOL


@pytest.mark.parametrize("shape", SHAPES, ids=SHAPE_IDS)
def test_weight_update_keeps_the_transpose(shape, device, seed):
    b, n_l, n_below = shape
    Y, W, _ = layer(shape, seed=16)
    G = np.random.default_rng(seed).standard_normal((b, n_below)).astype(np.float32)
    wW, wWt = to_wp(W, device), poisoned((n_below, n_l), device)
    wk.weight_update(wW, to_wp(Y, device), to_wp(G, device), 0.05, Wt=wWt)
    expected = ref.weight_step(*f64(W, Y, G), 0.05)
    assert rel_err(wW.numpy(), expected) <= TOL
    np.testing.assert_array_equal(wWt.numpy(), wW.numpy().T)


def test_gather_and_scatter_rows(device):
    src = np.arange(7 * 5, dtype=np.float32).reshape(7, 5)
    index = np.array([6, 0, 3], dtype=np.int32)
    dst = poisoned((3, 5), device)
    wk.gather_rows(to_wp(src, device), to_wp(index, device, wp.int32), dst)
    np.testing.assert_array_equal(dst.numpy(), src[[6, 0, 3]])
    store = to_wp(np.zeros((7, 5)), device)
    wk.scatter_rows(dst, to_wp(index, device, wp.int32), store)
    expected = np.zeros((7, 5), np.float32)
    expected[[6, 0, 3]] = src[[6, 0, 3]]
    np.testing.assert_array_equal(store.numpy(), expected)


def test_stop_converged_hand_case(device):
    """Two edges, four samples; limits 1 and 2: sample 0 is under both, 1 only under one,
    2 was already stopped, 3 is exactly on a limit (not under it)."""
    R = np.array([[0.5, 0.5, 9.0, 1.0], [1.9, 2.5, 9.0, 0.1]])
    active = to_wp(np.array([1, 1, 0, 1]), device, wp.int32)
    steps = to_wp(np.array([4, 4, 2, 4]), device, wp.int32)
    wk.stop_converged(to_wp(R, device, wp.float64), to_wp(np.array([1.0, 2.0]), device, wp.float64), active, steps)
    np.testing.assert_array_equal(active.numpy(), [0, 1, 0, 1])
    np.testing.assert_array_equal(steps.numpy(), [4, 5, 2, 5])


def _all_kernels_vs_reference(shape, device, tiles, activation="tanh"):
    b, n_l, n_below = shape
    Y, W, X = layer(shape, seed=8)
    *got, rows = run_predict(Y, W, X, device, activation, tiles=tiles)
    expected = ref.predict(*f64(Y, W, X), activation)
    for g, e in zip(got, expected, strict=True):
        assert rel_err(g, e) <= TOL
    assert rel_err(rows, np.sum(expected[2] ** 2, axis=1)) <= TOL
    rng = np.random.default_rng(9)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    wY = to_wp(Y, device)
    wk.latent_update(wY, to_wp(G, device), to_wp(W.T, device), 0.03, latent_scratch(b, n_l, n_below, device, 2),
                     E_above=to_wp(E_above, device), tiles=tiles)
    assert rel_err(wY.numpy(), ref.latent_step(*f64(Y, G, W), 0.03, f64(E_above)[0])) <= TOL
    wW = to_wp(W, device)
    wk.weight_update(wW, to_wp(Y, device), to_wp(G, device), 0.03, tiles=tiles)
    assert rel_err(wW.numpy(), ref.weight_step(*f64(W, Y, G), 0.03)) <= TOL


def test_small_tiles_many_partial_edges(device):
    """Tiny tiles: several tiles with ragged edges along M, N and K in every kernel."""
    tiles = wk.TileConfig(4, 8, 4, 32 if device == "cuda" else 1)
    _all_kernels_vs_reference((17, 65, 29), device, tiles)
    _all_kernels_vs_reference((1, 7, 5), device, tiles)


@pytest.mark.parametrize("block_dim", [7, 64, 256])
def test_results_do_not_depend_on_block_dim(block_dim, device, monkeypatch):
    """Any block_dim gives the same results (on CPU: cooperative fibres; on CUDA whole warps,
    which cuBLASDx requires: 7 becomes 32 there)."""
    if device == "cpu":
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    else:
        block_dim = max(32, block_dim)
    _all_kernels_vs_reference((17, 65, 29), device, wk.TileConfig(8, 16, 8, block_dim), "sigmoid")


def test_planned_kernels_records_instead_of_launching(device):
    """Inside planned_kernels nothing runs (outputs stay poisoned); preload compiles what
    was recorded, and the operations then run as usual."""
    Y, W, X = layer((3, 33, 17), seed=18)
    E, G = poisoned((3, 17), device), poisoned((3, 17), device)
    R = poisoned((1, 3), device, wp.float64)
    part = poisoned(wk.row_partial_shape(3, 17, wk.tile_config(device, "predict", 3)), device)
    args = (to_wp(Y, device), to_wp(W, device), to_wp(X, device), E, G, part, R, 0)
    with wk.planned_kernels() as plan:
        wk.predict(*args)
    assert np.isnan(E.numpy()).all() and np.isnan(R.numpy()).all()
    assert len(plan) == 2 and all(isinstance(k, wp.Kernel) for k, _ in plan)
    wk.preload(device, plan, workers=2)
    wk.predict(*args)
    _, _, e, _ = ref.predict(*f64(Y, W, X))
    assert rel_err(E.numpy(), e) <= TOL and rel_err(R.numpy()[0], np.sum(e**2, axis=1)) <= TOL


def test_tile_config_shrinks_rows_for_small_batches(device):
    big = wk.tile_config(device, "predict", 10_000)
    assert wk.tile_config(device, "predict", 1).tm == 1
    assert wk.tile_config(device, "predict", 5).tm == min(8, big.tm)
    assert wk.tile_config(device, "weight", 3).tk == min(4, wk.tile_config(device, "weight", 10_000).tk)


def test_warp_api_validation(device):
    Y, W, X = layer((3, 33, 17))
    b, n_below = X.shape
    E, G = (wp.zeros((b, n_below), dtype=wp.float32, device=device) for _ in range(2))
    R = wp.zeros((1, b), dtype=wp.float64, device=device)
    cfg = wk.tile_config(device, "predict", b)
    part = wp.zeros(wk.row_partial_shape(b, n_below, cfg), dtype=wp.float32, device=device)
    with pytest.raises(ValueError, match="leaky_relu"):
        wk.predict(to_wp(Y, device), to_wp(W, device), to_wp(X, device), E, G, part, R, 0, activation="relu6")
    with pytest.raises(ValueError, match="shape"):
        wk.predict(to_wp(Y, device), to_wp(W.T, device), to_wp(X, device), E, G, part, R, 0)
    with pytest.raises(ValueError, match="slot"):
        wk.predict(to_wp(Y, device), to_wp(W, device), to_wp(X, device), E, G, part, R, 1)
    with pytest.raises(ValueError, match="shape"):
        wk.latent_update(to_wp(Y, device), to_wp(X, device), to_wp(W, device), 0.1,
                         latent_scratch(b, 33, 17, device), E_above=to_wp(X, device))
    with pytest.raises(ValueError, match="shape"):
        wk.weight_update(to_wp(W, device), to_wp(Y, device), to_wp(X[:, :3], device), 0.1)
    with pytest.raises(TypeError):
        wk.weight_update(to_wp(W, device, wp.float64), to_wp(Y, device), to_wp(X, device), 0.1)


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
def test_reference_derivative_vs_central_differences(name, seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(-3, 3, size=200)
    a = a[np.abs(a) > 1e-3]  # away from the leaky ReLU kink
    h = 1e-6
    fd = (ref.activation(a + h, name, 0.3) - ref.activation(a - h, name, 0.3)) / (2 * h)
    np.testing.assert_allclose(ref.activation_derivative(a, name, 0.3), fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("name", ref.ACTIVATIONS)
def test_reference_steps_are_gradient_steps_of_the_energy(name, seed):
    """latent_step / weight_step are Y - eta dF/dY and W - eta dF/dW for
    F = ||X - phi(Y W)||^2 + ||Y - P_above||^2 (E_above = Y - P_above), by finite differences."""
    rng = np.random.default_rng(seed)
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
