"""Warp tile kernels for the predictive-coding layer steps (DESIGN §6-7).

Three fused tile GEMMs, each with its element-wise epilogue, plus a reduction:

(a) :func:`predict`        ``A = Y @ W``, ``P = phi(A)``, ``E = X - P``, ``G = phi'(A) * E``
(b) :func:`latent_update`  ``Y <- Y + 2 eta G @ W.T - 2 eta E_above``   (in place)
(c) :func:`weight_update`  ``W <- W + 2 eta Y.T @ G``                     (in place)
(d) :func:`squared_norm`   ``sum(E**2)`` (for the energy ``F = sum_l ||E_l||^2``)

``kernels/reference.py`` is the numpy specification these are tested against.

Design notes
------------
* Kernels are built by factories over the static tile sizes (and the activation / the
  ``E_above`` flag) and cached, so each configuration compiles once per process (and the
  compiled binary is cached on disk by Warp).
* The tiled GEMM accumulation loops live in ``@wp.func`` helpers (:func:`_tile_gemms`, one
  ``gemm_nn`` / ``gemm_nt`` / ``gemm_tn`` set per static tile size); each kernel is tile
  indices -> helper GEMM -> its element-wise epilogue -> stores.
* Shapes need not be multiples of the tile sizes: ``wp.tile_load`` (``bounds_check=True``,
  the default) reads elements past the array's extent as zero, and ``wp.tile_store`` skips
  writes past it. The zero padding along K is what keeps the edge GEMM tiles exact; the
  padded rows / columns of the output tiles are computed but never stored.
* No code depends on ``block_dim`` or the lane index: only cooperative tile operations are
  used. On CPU Warp runs a tile with one thread (``block_dim`` resolves to 1 unless
  ``wp.config.enable_cpu_blocks`` is set).
* In-place updates are safe: every output tile reads only its own tile of the updated
  array (``Y`` or ``W``), after its GEMM and before its store, and the GEMM operands
  (``G``, ``W`` resp. ``Y``, ``G``) never alias the updated array.
"""

import functools
import threading
from typing import NamedTuple

import numpy as np
import warp as wp

from vitaplace.kernels.reference import ACTIVATIONS

__all__ = [
    "ACTIVATIONS",
    "TileConfig",
    "tile_config",
    "predict",
    "latent_update",
    "weight_update",
    "squared_norm",
]


def _quiet_warp() -> None:
    """Silence Warp's greeting and per-module load messages (warnings still shown).

    Warp 1.19 uses ``wp.config.log_level`` (``wp.config.quiet`` is gone); older versions
    use ``wp.config.quiet``.
    """
    wp.config.quiet = True
    level = getattr(wp, "LOG_WARNING", None)
    if level is not None and getattr(wp.config, "log_level", level) < level:
        wp.config.log_level = level


_quiet_warp()

_init_lock = threading.Lock()
_initialised = False


def _ensure_init() -> None:
    """Initialise Warp once, lazily (keeps ``import`` cheap and silent)."""
    global _initialised
    if not _initialised:
        with _init_lock:
            if not _initialised:
                wp.init()
                _initialised = True


# --------------------------------------------------------------------------------------
# Activations (element-wise Warp functions; slope is a runtime scalar)
# --------------------------------------------------------------------------------------


@wp.func
def _phi_leaky_relu(a: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.where(a > wp.float32(0.0), a, slope * a)


@wp.func
def _gain_leaky_relu(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.where(a > wp.float32(0.0), e, slope * e)


@wp.func
def _phi_tanh(a: wp.float32, slope: wp.float32) -> wp.float32:
    return wp.tanh(a)


@wp.func
def _gain_tanh(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    t = wp.tanh(a)
    return (wp.float32(1.0) - t * t) * e


@wp.func
def _sigmoid(a: wp.float32) -> wp.float32:
    # stable for large |a|: exp of a non-positive number only
    z = wp.exp(-wp.abs(a))
    return wp.where(a >= wp.float32(0.0), wp.float32(1.0) / (wp.float32(1.0) + z), z / (wp.float32(1.0) + z))


@wp.func
def _phi_sigmoid(a: wp.float32, slope: wp.float32) -> wp.float32:
    return _sigmoid(a)


@wp.func
def _gain_sigmoid(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    s = _sigmoid(a)
    return s * (wp.float32(1.0) - s) * e


@wp.func
def _phi_linear(a: wp.float32, slope: wp.float32) -> wp.float32:
    return a


@wp.func
def _gain_linear(a: wp.float32, e: wp.float32, slope: wp.float32) -> wp.float32:
    return e


@wp.func
def _square64(x: wp.float32) -> wp.float64:
    y = wp.float64(x)
    return y * y


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
# Tile configuration
# --------------------------------------------------------------------------------------


class TileConfig(NamedTuple):
    """Static tile sizes of one GEMM (output tile tm x tn, K step tk) and the launch
    ``block_dim``."""

    tm: int
    tn: int
    tk: int
    block_dim: int


# CPU: Warp runs each tile serially with one thread through its scalar register-blocked
# GEMM, so the tile sizes only trade padding waste against per-tile load / loop overhead.
# Measured at B=150, n_l=1000, n_below=10800 (predict): 16^3 ~0.68 s, 32^3 ~0.39 s,
# 64x64x32 ~0.33 s, 64x128x32 ~0.28 s.
# CUDA (not measured here, no GPU): 64 threads per block, 32 x 32 output tiles with a
# 32-deep K step (3 x 4 KiB of shared memory per block), enough blocks even for B = 150.
# The row tile (the batch for predict / latent, the K step for the weight update) is
# shrunk to the next power of two >= B for small batches.
_CPU_TILES = (64, 128, 32, 1)
_CUDA_TILES = (32, 32, 32, 64)


def _round_rows(m: int, cap: int) -> int:
    """Smallest power of two >= m (at least 1), capped: avoids computing 31 padded rows
    for a single-sample batch."""
    t = 1
    while t < m and t < cap:
        t *= 2
    return t


def tile_config(device, m: int) -> TileConfig:
    """Tile sizes for a GEMM with ``m`` output rows (the batch for predict / latent)."""
    tm, tn, tk, bd = _CUDA_TILES if device.is_cuda else _CPU_TILES
    return TileConfig(_round_rows(m, tm), tn, tk, bd)


# --------------------------------------------------------------------------------------
# Kernel factories
# --------------------------------------------------------------------------------------

_F32_2D = wp.array2d(dtype=wp.float32)


class _TileGemms(NamedTuple):
    """The tile-GEMM accumulators of one static ``(tm, tn, tk)``; see :func:`_tile_gemms`."""

    gemm_nn: wp.Function
    gemm_nt: wp.Function
    gemm_tn: wp.Function


@functools.cache
def _tile_gemms(tm: int, tn: int, tk: int) -> _TileGemms:
    """``@wp.func`` helpers computing the ``tm x tn`` output tile at ``(row, col)`` of a GEMM,
    stepping through K by ``tk`` (``nk = ceil(K / tk)`` steps):

    * ``gemm_nn(A, B, row, col)``: ``A @ B``,   ``A`` (M x K), ``B`` (K x N)
    * ``gemm_nt(A, B, row, col)``: ``A @ B.T``, ``A`` (M x K), ``B`` (N x K)
    * ``gemm_tn(A, B, row, col)``: ``A.T @ B``, ``A`` (K x M), ``B`` (K x N)

    Loads past an array's extent read zero, so the edge tiles are exact (see the module notes).
    """

    @wp.func
    def gemm_nn(A: _F32_2D, B: _F32_2D, row: int, col: int):
        acc = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((A.shape[1] + tk - 1) // tk):
            a = wp.tile_load(A, shape=(tm, tk), offset=(row, k * tk))
            b = wp.tile_load(B, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(a, b, acc)
        return acc

    @wp.func
    def gemm_nt(A: _F32_2D, B: _F32_2D, row: int, col: int):
        acc = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((A.shape[1] + tk - 1) // tk):
            a = wp.tile_load(A, shape=(tm, tk), offset=(row, k * tk))
            b = wp.tile_load(B, shape=(tn, tk), offset=(col, k * tk))
            wp.tile_matmul(a, wp.tile_transpose(b), acc)
        return acc

    @wp.func
    def gemm_tn(A: _F32_2D, B: _F32_2D, row: int, col: int):
        acc = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((A.shape[0] + tk - 1) // tk):
            a = wp.tile_load(A, shape=(tk, tm), offset=(k * tk, row))
            b = wp.tile_load(B, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(wp.tile_transpose(a), b, acc)
        return acc

    return _TileGemms(gemm_nn, gemm_nt, gemm_tn)


def _tiled_kernel(fn, name: str):
    """Compile ``fn`` as a forward-only kernel in its own module, named ``name``."""
    fn.__name__ = fn.__qualname__ = name
    return wp.kernel(fn, enable_backward=False, module="unique")


@functools.cache
def _predict_kernel(tm: int, tn: int, tk: int, activation: str):
    """(a) A = Y @ W; P = phi(A); E = X - P; G = phi'(A) * E.   GEMM M=B, N=n_below, K=n_l."""
    phi, gain = _PHI[activation]
    gemm = _tile_gemms(tm, tn, tk).gemm_nn

    def predict_kernel(
        Y: _F32_2D,
        W: _F32_2D,
        X: _F32_2D,
        slope: wp.float32,
        A: _F32_2D,
        P: _F32_2D,
        E: _F32_2D,
        G: _F32_2D,
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        a = gemm(Y, W, row, col)
        p = wp.tile_map(phi, a, slope)
        e = wp.tile_load(X, shape=(tm, tn), offset=(row, col)) - p
        g = wp.tile_map(gain, a, e, slope)
        wp.tile_store(A, a, offset=(row, col))
        wp.tile_store(P, p, offset=(row, col))
        wp.tile_store(E, e, offset=(row, col))
        wp.tile_store(G, g, offset=(row, col))

    return _tiled_kernel(predict_kernel, f"pc_predict_{activation}_{tm}x{tn}x{tk}")


@functools.cache
def _latent_kernel(tm: int, tn: int, tk: int, has_above: bool):
    """(b) Y_out = Y + 2 eta G @ W.T [- 2 eta E_above].   GEMM M=B, N=n_l, K=n_below.

    Y_out may alias Y: output tile (i, j) reads only Y's tile (i, j), after its GEMM.
    """
    gemm = _tile_gemms(tm, tn, tk).gemm_nt

    def latent_kernel(
        Y: _F32_2D,
        G: _F32_2D,
        W: _F32_2D,
        E_above: _F32_2D,
        two_eta: wp.float32,
        Y_out: _F32_2D,
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        d = gemm(G, W, row, col)
        y = wp.tile_load(Y, shape=(tm, tn), offset=(row, col))
        if wp.static(has_above):
            d = d - wp.tile_load(E_above, shape=(tm, tn), offset=(row, col))
        wp.tile_store(Y_out, y + d * two_eta, offset=(row, col))

    return _tiled_kernel(latent_kernel, f"pc_latent_{'above' if has_above else 'top'}_{tm}x{tn}x{tk}")


@functools.cache
def _weight_kernel(tm: int, tn: int, tk: int):
    """(c) W += 2 eta Y.T @ G (in place).   GEMM M=n_l, N=n_below, K=B."""
    gemm = _tile_gemms(tm, tn, tk).gemm_tn

    def weight_kernel(
        W: _F32_2D,
        Y: _F32_2D,
        G: _F32_2D,
        two_eta: wp.float32,
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        d = gemm(Y, G, row, col)
        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col))
        wp.tile_store(W, w + d * two_eta, offset=(row, col))

    return _tiled_kernel(weight_kernel, f"pc_weight_{tm}x{tn}x{tk}")


@functools.cache
def _sqnorm_kernel(tm: int, tn: int):
    """(d) per-tile partial sums of squares, accumulated in float64."""

    def sqnorm_kernel(E: _F32_2D, partial: wp.array(dtype=wp.float64)):
        i, j = wp.tid()
        e = wp.tile_load(E, shape=(tm, tn), offset=(i * tm, j * tn))
        s = wp.tile_sum(wp.tile_map(_square64, e))
        wp.tile_store(partial, s, offset=i * ((E.shape[1] + tn - 1) // tn) + j)

    return _tiled_kernel(sqnorm_kernel, f"pc_sqnorm_{tm}x{tn}")


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------


def _cdiv(a: int, b: int) -> int:
    return (a + b - 1) // b


def _check_type(name: str, arr) -> None:
    if not isinstance(arr, wp.array) or arr.ndim != 2 or arr.dtype != wp.float32:
        raise TypeError(f"{name} must be a wp.array2d(dtype=wp.float32), got {arr!r}")


def _check(name: str, arr, shape: tuple[int, int], device) -> None:
    _check_type(name, arr)
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} has shape {tuple(arr.shape)}, expected {tuple(shape)}")
    if arr.device != device:
        raise ValueError(f"{name} is on {arr.device}, expected {device}")
    if not arr.is_contiguous:
        raise ValueError(f"{name} must be contiguous")


def predict(Y, W, X, A, P, E, G, activation: str = "leaky_relu", slope: float = 0.2) -> None:
    """Kernel (a): write ``A = Y @ W``, ``P = phi(A)``, ``E = X - P``, ``G = phi'(A) * E``.

    Shapes: ``Y`` (B x n_l), ``W`` (n_l x n_below); ``X``, ``A``, ``P``, ``E``, ``G``
    (B x n_below). All float32 2-D Warp arrays on one device.
    """
    _check_activation(activation)
    _ensure_init()
    _check_type("Y", Y)
    _check_type("W", W)
    b, n_l = Y.shape
    device = Y.device
    _check("Y", Y, (b, n_l), device)
    n_below = W.shape[1]
    _check("W", W, (n_l, n_below), device)
    for name, arr in (("X", X), ("A", A), ("P", P), ("E", E), ("G", G)):
        _check(name, arr, (b, n_below), device)
    cfg = tile_config(device, b)
    kernel = _predict_kernel(cfg.tm, cfg.tn, cfg.tk, activation)
    wp.launch_tiled(
        kernel,
        dim=(_cdiv(b, cfg.tm), _cdiv(n_below, cfg.tn)),
        inputs=[Y, W, X, wp.float32(slope), A, P, E, G],
        block_dim=cfg.block_dim,
        device=device,
    )


def latent_update(Y, G, W, eta: float, E_above=None) -> None:
    """Kernel (b), in place: ``Y <- Y + 2 eta G @ W.T - 2 eta E_above``.

    The gradient step ``Y - eta dF/dY`` with ``dF/dY = -2 G @ W.T + 2 E_above``.
    ``Y`` (B x n_l), ``G`` (B x n_below), ``W`` (n_l x n_below), ``E_above`` (B x n_l) or
    ``None`` (top / joint layer).

    Calls accumulate into ``Y``: the joint layer, which predicts several modalities, calls
    this once per modality (``E_above=None``), giving ``Y + 2 eta sum_m G_m @ W_m.T``.
    For the parallel update of DESIGN §6 run :func:`predict` for every layer first: this
    kernel reads only ``G``, ``W`` and ``E_above`` besides ``Y``, none of which another
    layer's latent update writes.
    """
    _ensure_init()
    _check_type("Y", Y)
    _check_type("W", W)
    b, n_l = Y.shape
    device = Y.device
    _check("Y", Y, (b, n_l), device)
    n_below = W.shape[1]
    _check("W", W, (n_l, n_below), device)
    _check("G", G, (b, n_below), device)
    has_above = E_above is not None
    if has_above:
        _check("E_above", E_above, (b, n_l), device)
    cfg = tile_config(device, b)
    kernel = _latent_kernel(cfg.tm, cfg.tn, cfg.tk, has_above)
    wp.launch_tiled(
        kernel,
        dim=(_cdiv(b, cfg.tm), _cdiv(n_l, cfg.tn)),
        inputs=[Y, G, W, E_above if has_above else Y, wp.float32(2.0 * eta), Y],
        block_dim=cfg.block_dim,
        device=device,
    )


def weight_update(W, Y, G, eta: float) -> None:
    """Kernel (c), in place: ``W <- W + 2 eta Y.T @ G`` (``W - eta dF/dW``, ``dF/dW = -2 Y.T @ G``).

    ``W`` (n_l x n_below), ``Y`` (B x n_l), ``G`` (B x n_below).
    """
    _ensure_init()
    _check_type("W", W)
    _check_type("Y", Y)
    n_l, n_below = W.shape
    device = W.device
    _check("W", W, (n_l, n_below), device)
    b = Y.shape[0]
    _check("Y", Y, (b, n_l), device)
    _check("G", G, (b, n_below), device)
    tm, tn, tk, bd = _CUDA_TILES if device.is_cuda else _CPU_TILES
    tk = _round_rows(b, tk)  # K = batch: no padded K work for a single sample
    kernel = _weight_kernel(tm, tn, tk)
    wp.launch_tiled(
        kernel,
        dim=(_cdiv(n_l, tm), _cdiv(n_below, tn)),
        inputs=[W, Y, G, wp.float32(2.0 * eta)],
        block_dim=bd,
        device=device,
    )


def squared_norm(E) -> float:
    """``sum(E**2)`` as a Python float (per-tile partial sums in float64, summed on host)."""
    _ensure_init()
    _check_type("E", E)
    m, n = E.shape
    if m == 0 or n == 0:
        return 0.0
    device = E.device
    tm, tn, _, bd = _CUDA_TILES if device.is_cuda else _CPU_TILES
    tm = _round_rows(m, tm)
    gm, gn = _cdiv(m, tm), _cdiv(n, tn)
    partial = wp.empty(gm * gn, dtype=wp.float64, device=device)
    wp.launch_tiled(
        _sqnorm_kernel(tm, tn),
        dim=(gm, gn),
        inputs=[E, partial],
        block_dim=bd,
        device=device,
    )
    return float(np.sum(partial.numpy()))
