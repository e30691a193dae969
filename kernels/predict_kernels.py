"""Kernel (a), the prediction of the layer below and its error, on CPU or CUDA.

:func:`predict` runs the fused tile GEMM ``A = Y @ W`` with its element-wise epilogue
``P = phi(A)``, ``E = X - P``, ``G = phi'(A) * E`` and each row's ``sum(E**2)`` (the
per-sample energy of the edge); given the edge's error precisions ``pi`` (one per column),
``G = pi * phi'(A) * E`` and the row energies ``sum(pi * E**2)``, in the same kernel;
:func:`predict_epilogue` runs the epilogue alone on a product computed elsewhere(cuBLAS).
``kernels/reference.py`` is the numpy specification.

Per-row energies are written per column tile and summed by a second small kernel in a fixed
order: no atomics, so results are bitwise reproducible run to run on one device.
"""

import functools
from typing import Any, no_type_check

import warp as wp

from vitaplace.kernels.launch import (
    BF16_2D,
    F32,
    F32_2D,
    F64_2D,
    check,
    check_type,
    ensure_init,
    placeholder,
    simt_launch,
    tiled_kernel,
    tiled_launch,
)
from vitaplace.kernels.reference import ACTIVATIONS
from vitaplace.kernels.tiles import TileConfig, cdiv, tile_config

__all__ = ["predict", "predict_epilogue", "row_partial_shape"]

# --------------------------------------------------------------------------------------
# Activations (element-wise Warp functions; slope is a runtime scalar)
# --------------------------------------------------------------------------------------


@wp.func
@no_type_check
def _phi_leaky_relu(a: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.where(a > wp.float32(0.0), a, slope * a)


@wp.func
@no_type_check
def _gain_leaky_relu(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.where(a > wp.float32(0.0), e, slope * e)


@wp.func
@no_type_check
def _phi_tanh(a: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.tanh(a)


@wp.func
@no_type_check
def _gain_tanh(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    t = wp.tanh(a)
    return (wp.float32(1.0) - t * t) * e


@wp.func
@no_type_check
def _sigmoid(a: wp.float32) -> wp.float32:
    # stable for large |a|: exp of a non-positive number only
    z = wp.exp(-wp.abs(a))
    return wp.where(a >= wp.float32(0.0), wp.float32(1.0) / (wp.float32(1.0) + z), z / (wp.float32(1.0) + z))


@wp.func
@no_type_check
def _phi_sigmoid(a: wp.float32, slope: wp.float32) -> wp.float32:
    return _sigmoid(a)


@wp.func
@no_type_check
def _gain_sigmoid(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    s = _sigmoid(a)
    return s * (wp.float32(1.0) - s) * e


@wp.func
@no_type_check
def _phi_linear(a: wp.float32, slope: wp.float32) -> wp.float32:
    return a


@wp.func
@no_type_check
def _gain_linear(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    return e


@wp.func
@no_type_check
def _square(x: wp.float32) -> wp.float32:
    return x * x


@wp.func
@no_type_check
def _times(x: wp.float32, y: wp.float32) -> wp.float32:
    return x * y


@wp.func
@no_type_check
def _below(c: wp.int32, n: wp.int32) -> wp.float32:
    return wp.where(c < n, wp.float32(1.0), wp.float32(0.0))


_PHI = {
    "leaky_relu": (_phi_leaky_relu, _gain_leaky_relu),
    "tanh": (_phi_tanh, _gain_tanh),
    "sigmoid": (_phi_sigmoid, _gain_sigmoid),
    "linear": (_phi_linear, _gain_linear),
}
assert tuple(_PHI) == ACTIVATIONS


def _check_activation(name: str) -> None:
    if name not in _PHI:
        raise ValueError(f"unknown activation {name!r}; valid activations: {', '.join(ACTIVATIONS)}")


# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------


@functools.cache
def _predict_kernel(
    tiles: TileConfig, activation: str, store_prediction: bool, with_energy: bool, gemm: bool = True,
    low_gain: bool = False, weighted: bool = False,
) -> wp.Kernel:
    """(a) GEMM M=B, N=n_below, K=n_l, then the epilogue; ``row_partial[j, r]`` receives
    row r's sum of squared errors over column tile j (when ``with_energy``). With
    ``weighted`` the gain and the squared errors are multiplied by the column's precision
    ``pi[c]``.

    Without ``gemm`` only the epilogue runs, on the product read from ``A`` (computed
    elsewhere, e.g. by cuBLAS); with ``low_gain`` G is also written in bfloat16 to ``G_low``
    (an operand of the next GEMMs)."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk
    phi, gain = _PHI[activation]
    assert gemm or not store_prediction, "without the GEMM, A is the input"

    @no_type_check
    def predict_kernel(
        Y: F32_2D,
        W: F32_2D,
        X: F32_2D,
        slope: wp.float32,
        A: F32_2D,
        P: F32_2D,
        E: F32_2D,
        G: F32_2D,
        row_partial: F32_2D,
        G_low: BF16_2D,
        pi: F32,
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        if wp.static(gemm):
            a = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
            for k in range((Y.shape[1] + tk - 1) // tk):
                y = wp.tile_load(Y, shape=(tm, tk), offset=(row, k * tk))
                w = wp.tile_load(W, shape=(tk, tn), offset=(k * tk, col))
                wp.tile_matmul(y, w, a)
        else:
            a = wp.tile_load(A, shape=(tm, tn), offset=(row, col))
        p = wp.tile_map(phi, a, slope)
        e = wp.tile_load(X, shape=(tm, tn), offset=(row, col)) - p
        g = wp.tile_map(gain, a, e, slope)
        if wp.static(weighted):
            weight = wp.tile_broadcast(wp.tile_load(pi, shape=(tn,), offset=(col,)), shape=(tm, tn))
            g = wp.tile_map(_times, g, weight)
        if wp.static(store_prediction):
            wp.tile_store(A, a, offset=(row, col))
            wp.tile_store(P, p, offset=(row, col))
        wp.tile_store(E, e, offset=(row, col))
        wp.tile_store(G, g, offset=(row, col))
        if wp.static(low_gain):
            wp.tile_store(G_low, wp.tile_astype(g, wp.bfloat16), offset=(row, col))
        if wp.static(with_energy):
            if wp.static(activation == "sigmoid"):
                # padded columns read X = A = 0, so e = -phi(0) there: zero them for the sums
                cols = wp.tile_arange(tn, dtype=wp.int32)
                left = wp.tile_ones(shape=(tn,), dtype=wp.int32) * (X.shape[1] - col)
                e = e * wp.tile_broadcast(wp.tile_map(_below, cols, left), shape=(tm, tn))
            if wp.static(weighted):
                squares = wp.tile_map(_times, wp.tile_map(_square, e), weight)
            else:
                squares = wp.tile_map(_square, e)
            wp.tile_store(row_partial[j], wp.tile_sum(squares, axis=1), offset=row)

    tag = ("AP" if store_prediction else "EG") + ("R" if with_energy else "") + ("_pi" if weighted else "")
    kind = "predict" if gemm else "epilogue"
    tag += "_Glow" if low_gain else ""
    return tiled_kernel(predict_kernel, f"pc_{kind}_{activation}_{tag}_{tm}x{tn}x{tk}", tiles)


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _row_energy_kernel(row_partial: F32_2D, out: F64_2D, slot: int):
    """out[slot, r] = sum over column tiles of row_partial[:, r], in float64, in order."""
    r = wp.tid()
    s = wp.float64(0.0)
    for j in range(row_partial.shape[0]):
        s += wp.float64(row_partial[j, r])
    out[slot, r] = s


# --------------------------------------------------------------------------------------
# Operations
# --------------------------------------------------------------------------------------


def row_partial_shape(batch: int, n_below: int, tiles: TileConfig) -> tuple[int, int]:
    """Shape of the scratch :func:`predict` writes per-row partial energies to."""
    return (cdiv(n_below, tiles.tn), batch)


def predict(
    Y: wp.array,
    W: wp.array,
    X: wp.array,
    E: wp.array,
    G: wp.array,
    row_partial: wp.array | None = None,
    row_energy: wp.array | None = None,
    slot: int = 0,
    activation: str = "leaky_relu",
    slope: float = 0.2,
    A: wp.array | None = None,
    P: wp.array | None = None,
    tiles: TileConfig | None = None,
    precision: wp.array | None = None,
) -> None:
    """Kernel (a): ``E = X - phi(Y @ W)``, ``G = phi'(Y @ W) * E``; with ``row_energy``,
    also ``row_energy[slot, r] = sum_c E[r, c]**2`` (float64); with ``A`` and ``P``, also
    ``A = Y @ W`` and ``P = phi(A)``. With ``precision`` (``pi``, n_below float32, the
    edge's error precisions) ``G = pi * phi'(Y @ W) * E`` and ``row_energy[slot, r] =
    sum_c pi[c] E[r, c]**2``.

    Shapes: ``Y`` (B x n_l), ``W`` (n_l x n_below); ``X``, ``E``, ``G`` (and ``A``, ``P``)
    (B x n_below), float32; ``row_energy`` (slots x B) float64 with ``row_partial`` the
    float32 scratch of :func:`row_partial_shape`. All on one device.
    """
    _check_activation(activation)
    ensure_init()
    check_type("Y", Y)
    check_type("W", W)
    b, n_l = Y.shape
    device = Y.device
    n_below = W.shape[1]
    check("W", W, (n_l, n_below), device)
    store = A is not None or P is not None
    if store and (A is None or P is None):
        raise ValueError("give both A and P, or neither")
    for name, arr in (("X", X), ("E", E), ("G", G)) + ((("A", A), ("P", P)) if store else ()):
        check(name, arr, (b, n_below), device)
    cfg = tiles or tile_config(device, "predict", b)
    with_energy = row_energy is not None
    _check_energy_buffers(row_partial, row_energy, slot, b, n_below, cfg, device)
    _launch_predict(
        _predict_kernel(cfg, activation, store, with_energy, weighted=precision is not None), cfg, b, n_below,
        row_partial, row_energy, slot,
        [Y, W, X, wp.float32(slope), A if store else E, P if store else E, E, G, row_partial if with_energy else E,
         placeholder(device, wp.bfloat16), _precision_arg(precision, n_below, device)],
        device,
    )


def predict_epilogue(
    A: wp.array,
    X: wp.array,
    E: wp.array,
    G: wp.array,
    row_partial: wp.array | None = None,
    row_energy: wp.array | None = None,
    slot: int = 0,
    activation: str = "leaky_relu",
    slope: float = 0.2,
    G_low: wp.array | None = None,
    tiles: TileConfig | None = None,
    precision: wp.array | None = None,
) -> None:
    """Kernel (a) without its GEMM: ``E = X - phi(A)``, ``G = phi'(A) * E`` from a product
    ``A = Y @ W`` computed elsewhere (cuBLAS), the row energies and ``precision`` as in
    :func:`predict`, and with ``G_low`` (bfloat16, B x n_below) G rounded to bfloat16 as well."""
    _check_activation(activation)
    ensure_init()
    check_type("A", A)
    b, n_below = A.shape
    device = A.device
    for name, arr in (("X", X), ("E", E), ("G", G)):
        check(name, arr, (b, n_below), device)
    if G_low is not None:
        check("G_low", G_low, (b, n_below), device, wp.bfloat16)
    cfg = tiles or tile_config(device, "predict", b)
    with_energy = row_energy is not None
    _check_energy_buffers(row_partial, row_energy, slot, b, n_below, cfg, device)
    low = G_low is not None
    _launch_predict(
        _predict_kernel(cfg, activation, False, with_energy, gemm=False, low_gain=low, weighted=precision is not None),
        cfg, b, n_below, row_partial, row_energy, slot,
        [E, E, X, wp.float32(slope), A, E, E, G, row_partial if with_energy else E,
         G_low if low else placeholder(device, wp.bfloat16), _precision_arg(precision, n_below, device)],
        device,
    )


def _precision_arg(precision: wp.array | None, n_below: int, device: wp.DeviceLike) -> wp.array:
    """The precision vector (checked: n_below float32 on ``device``) or a placeholder."""
    if precision is None:
        return placeholder(device, wp.float32, 1)
    check("precision", precision, (n_below,), device)
    return precision


def _launch_predict(
    kernel: wp.Kernel, cfg: TileConfig, b: int, n_below: int, row_partial: wp.array | None,
    row_energy: wp.array | None, slot: int, inputs: list[Any], device: wp.DeviceLike,
) -> None:
    """One configuration of kernel (a) over the (B x n_below) output tiles, then the
    in-order sum of the per-row energies when asked."""
    tiled_launch(kernel, (cdiv(b, cfg.tm), cdiv(n_below, cfg.tn)), inputs, cfg.block_dim, device)
    if row_energy is not None:
        simt_launch(_row_energy_kernel, b, [row_partial, row_energy, slot], device)


def _check_energy_buffers(
    row_partial: wp.array | None, row_energy: wp.array | None, slot: int, b: int, n_below: int, cfg: TileConfig,
    device: wp.DeviceLike,
) -> None:
    if row_energy is None:
        return
    check("row_partial", row_partial, row_partial_shape(b, n_below, cfg), device)
    check_type("row_energy", row_energy, wp.float64)
    check("row_energy", row_energy, (row_energy.shape[0], b), device, wp.float64)
    if not 0 <= slot < row_energy.shape[0]:
        raise ValueError(f"slot {slot} outside row_energy's {row_energy.shape[0]} rows")
