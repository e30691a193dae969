"""Warp kernels for the predictive-coding layer steps, on CPU or CUDA.

Fused tile GEMMs with their element-wise epilogues, and the small kernels that keep a
whole training or inference run on the device:

(a) :func:`predict`        ``A = Y @ W``, ``P = phi(A)``, ``E = X - P``, ``G = phi'(A) * E``
                           and each row's ``sum(E**2)`` (the per-sample energy of the edge)
(b) :func:`latent_update`  ``Y <- Y + 2 eta m * (G @ W.T - E_above)``  (in place; ``m`` the
                           per-sample 0/1 mask of samples still being updated; reads the
                           transposed copy ``Wt`` of ``W``)
(c) :func:`weight_update`  ``W <- W + 2 eta Y.T @ G`` and ``Wt <- W.T`` (in place)
(d) :func:`gather_rows` / :func:`scatter_rows`   minibatch rows of a device-resident store
(e) :func:`stop_converged` per-sample stopping of test-time inference

``kernels/reference.py`` is the numpy specification these are tested against.

Design notes
------------
* Kernels are built by factories over the static tile sizes (and the activation / flags)
  and cached, so each configuration compiles once per process (and is cached on disk by
  Warp).
* Shapes need not be multiples of the tile sizes: ``wp.tile_load`` reads elements past the
  array's extent as zero and ``wp.tile_store`` skips writes past it. The zero padding along
  K keeps the edge tiles exact; padded output rows / columns are computed, never stored.
* No code depends on ``block_dim`` or the lane index: only cooperative tile operations.
  On CPU Warp runs a tile with one thread.
* The latent update's GEMM has few output tiles (batch x n_l) and a long K (n_below), so
  on CUDA it is split along K: each split writes its partial product to a scratch buffer
  and a fused element-wise kernel sums the splits in a fixed order and applies the step.
  Small layers (and the CPU) use one kernel for GEMM and step. It reads ``Wt``, the
  transpose of ``W`` that the weight update keeps, so both GEMM operands are read along
  rows (a transposed tile load of ``W`` ran at a third of the speed on an H100).
  No atomics anywhere: results are bitwise reproducible run to run on one device.
* Per-row energies are written per column tile and summed by a second small kernel in a
  fixed order, for the same reason.
* Every operation only launches kernels (no host synchronisation, no allocation once its
  scratch exists), so a sequence of them can be captured as a CUDA graph.
"""

import contextlib
import functools
import threading
from collections.abc import Iterator
from typing import NamedTuple

import warp as wp

from vitaplace.engine.base.cpus import usable_cpus
from vitaplace.kernels.reference import ACTIVATIONS

__all__ = [
    "ACTIVATIONS",
    "TileConfig",
    "tile_config",
    "latent_splits",
    "set_tile_config",
    "planned_kernels",
    "preload",
    "predict",
    "predict_epilogue",
    "latent_update",
    "latent_apply",
    "weight_update",
    "to_bfloat16",
    "planning",
    "gather_rows",
    "scatter_rows",
    "stop_converged",
]


def _quiet_warp() -> None:
    """Silence Warp's greeting and per-module load messages (warnings still shown)."""
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
def _square(x: wp.float32) -> wp.float32:
    return x * x


@wp.func
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
# Tile configuration
# --------------------------------------------------------------------------------------


class TileConfig(NamedTuple):
    """Static tile sizes of one GEMM (output tile tm x tn, K step tk), the launch
    ``block_dim``, and whether ``tile_matmul`` goes through libmathdx (cuBLASDx) on CUDA
    (``False``: Warp's own tile GEMM, which compiles in seconds rather than tens of
    seconds)."""

    tm: int
    tn: int
    tk: int
    block_dim: int
    mathdx: bool = True


# CPU: Warp runs each tile serially with one thread through its scalar register-blocked
# GEMM, so the tile sizes only trade padding waste against per-tile load / loop overhead.
# Measured at B=150, n_l=1000, n_below=10800 (predict): 16^3 ~0.68 s, 32^3 ~0.39 s,
# 64x64x32 ~0.33 s, 64x128x32 ~0.28 s.
_CPU_TILES = {
    "predict": TileConfig(64, 128, 32, 1),
    "latent": TileConfig(64, 128, 32, 1),
    "weight": TileConfig(64, 128, 32, 1),
}
# CUDA: chosen by bench/tile_sweep.py on an H100 at the paper's largest edge (B=150,
# n_l=1000, n_below=10800; docs/PERFORMANCE.md). 64x64 output tiles with a 32-deep K step and
# 128 threads beat 64x128, 128x64 and 128x128 in every kernel, and Warp's own tile GEMM
# matched or beat cuBLASDx there (predict 270 vs 281 us, latent 218 vs 226 us, weight 195 vs
# 300 us) while compiling in seconds instead of ~35 s per kernel.
_CUDA_TILES = {
    "predict": TileConfig(64, 64, 32, 128, mathdx=False),
    "latent": TileConfig(64, 64, 32, 128, mathdx=False),
    "weight": TileConfig(64, 64, 32, 128, mathdx=False),
}
#: Element-wise / per-row kernels: threads per block on CUDA.
_SIMT_BLOCK = 256


def set_tile_config(kernel: str, tiles: TileConfig, cuda: bool = True) -> None:
    """Use ``tiles`` for ``kernel`` (``predict``, ``latent``, ``weight``) from now on, on
    CUDA devices (or on the CPU with ``cuda=False``): e.g. the winner of a tile sweep on
    another GPU model."""
    table = _CUDA_TILES if cuda else _CPU_TILES
    if kernel not in table:
        raise ValueError(f"unknown kernel {kernel!r}; valid: {', '.join(table)}")
    table[kernel] = TileConfig(*tiles)


def _round_rows(m: int, cap: int) -> int:
    """Smallest power of two >= m (at least 1), capped: avoids computing 31 padded rows
    for a single-sample batch."""
    t = 1
    while t < m and t < cap:
        t *= 2
    return t


def tile_config(device, kernel: str, rows: int) -> TileConfig:
    """Tile sizes of ``kernel`` (``predict``, ``latent``, ``weight``) on ``device``.

    ``rows`` is the batch: the output rows of predict / latent (the row tile shrinks to
    the next power of two >= batch) and the K of the weight update (so is its K step).
    """
    cfg = (_CUDA_TILES if wp.get_device(device).is_cuda else _CPU_TILES)[kernel]
    if kernel == "weight":
        return cfg._replace(tk=_round_rows(rows, cfg.tk))
    return cfg._replace(tm=_round_rows(rows, cfg.tm))


def _cdiv(a: int, b: int) -> int:
    return (a + b - 1) // b


def latent_splits(device, tiles: TileConfig, batch: int, n_l: int, n_below: int) -> int:
    """How many K-slices the latent GEMM is split into: 1 on CPU; on CUDA enough blocks for
    two waves over the multiprocessors, each slice at least 16 K-steps long."""
    dev = wp.get_device(device)
    if not dev.is_cuda:
        return 1
    blocks = _cdiv(batch, tiles.tm) * _cdiv(n_l, tiles.tn)
    want = _cdiv(2 * dev.sm_count, blocks)
    return max(1, min(want, _cdiv(n_below, 16 * tiles.tk)))


# --------------------------------------------------------------------------------------
# Kernel factories
# --------------------------------------------------------------------------------------

_F32_2D = wp.array2d(dtype=wp.float32)
_F32_3D = wp.array3d(dtype=wp.float32)
_F64_2D = wp.array2d(dtype=wp.float64)
_BF16_2D = wp.array2d(dtype=wp.bfloat16)


def _tiled_kernel(fn, name: str, tiles: TileConfig | None = None):
    """Compile ``fn`` as a forward-only kernel in its own module, named ``name`` (and the
    tile GEMM's options)."""
    mathdx = tiles is None or tiles.mathdx
    if tiles is not None:
        name += "" if mathdx else "_nomathdx"
    fn.__name__ = fn.__qualname__ = name
    return wp.kernel(fn, enable_backward=False, module="unique", module_options={"enable_mathdx_gemm": mathdx})



@functools.cache
def _predict_kernel(
    tiles: TileConfig, activation: str, store_prediction: bool, with_energy: bool, gemm: bool = True, low_gain: bool = False
):
    """(a) GEMM M=B, N=n_below, K=n_l, then the epilogue; ``row_partial[j, r]`` receives
    row r's sum of squared errors over column tile j (when ``with_energy``).

    Without ``gemm`` only the epilogue runs, on the product read from ``A`` (computed
    elsewhere, e.g. by cuBLAS); with ``low_gain`` G is also written in bfloat16 to ``G_low``
    (an operand of the next GEMMs)."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk
    phi, gain = _PHI[activation]
    assert gemm or not store_prediction, "without the GEMM, A is the input"

    def predict_kernel(
        Y: _F32_2D,
        W: _F32_2D,
        X: _F32_2D,
        slope: wp.float32,
        A: _F32_2D,
        P: _F32_2D,
        E: _F32_2D,
        G: _F32_2D,
        row_partial: _F32_2D,
        G_low: _BF16_2D,
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
            wp.tile_store(row_partial[j], wp.tile_sum(wp.tile_map(_square, e), axis=1), offset=row)

    tag = ("AP" if store_prediction else "EG") + ("R" if with_energy else "")
    kind = "predict" if gemm else "epilogue"
    tag += "_Glow" if low_gain else ""
    return _tiled_kernel(predict_kernel, f"pc_{kind}_{activation}_{tag}_{tm}x{tn}x{tk}", tiles)


@wp.func
def _row_gate(active: wp.int32) -> wp.float32:
    return wp.where(active != 0, wp.float32(1.0), wp.float32(0.0))


@functools.cache
def _latent_fused_kernel(tiles: TileConfig, has_above: bool, has_mask: bool):
    """(b) in one kernel: ``Y += 2 eta * mask * (G @ Wt - E_above)``, GEMM M=B, N=n_l,
    K=n_below (``Wt`` = W transposed, n_below x n_l).

    Output tile (i, j) reads only Y's tile (i, j), after its GEMM, so Y is updated in place.
    """
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    def latent_kernel(
        Y: _F32_2D, G: _F32_2D, Wt: _F32_2D, E_above: _F32_2D, mask: wp.array(dtype=wp.int32), two_eta: wp.float32
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        d = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((G.shape[1] + tk - 1) // tk):
            g = wp.tile_load(G, shape=(tm, tk), offset=(row, k * tk))
            w = wp.tile_load(Wt, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(g, w, d)
        if wp.static(has_above):
            d = d - wp.tile_load(E_above, shape=(tm, tn), offset=(row, col))
        d = d * two_eta
        if wp.static(has_mask):
            gate = wp.tile_map(_row_gate, wp.tile_load(mask, shape=(tm,), offset=(row,)))
            d = d * wp.tile_broadcast(wp.tile_reshape(gate, shape=(tm, 1)), shape=(tm, tn))
        wp.tile_store(Y, wp.tile_load(Y, shape=(tm, tn), offset=(row, col)) + d, offset=(row, col))

    name = f"pc_latent_{'above' if has_above else 'top'}_{'masked' if has_mask else 'all'}_{tm}x{tn}x{tk}"
    return _tiled_kernel(latent_kernel, name, tiles)


@functools.cache
def _latent_gemm_kernel(tiles: TileConfig):
    """(b, split along K) ``D[s] = G[:, Ks] @ Wt[Ks, :]`` for K-slice ``s`` of ``steps`` K-steps."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    def latent_gemm_kernel(G: _F32_2D, Wt: _F32_2D, steps: int, D: _F32_3D):
        i, j, s = wp.tid()
        row, col = i * tm, j * tn
        d = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        end = wp.min((s + 1) * steps, (G.shape[1] + tk - 1) // tk)
        for k in range(s * steps, end):
            g = wp.tile_load(G, shape=(tm, tk), offset=(row, k * tk))
            w = wp.tile_load(Wt, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(g, w, d)
        wp.tile_store(D[s], d, offset=(row, col))

    return _tiled_kernel(latent_gemm_kernel, f"pc_latent_gemm_{tm}x{tn}x{tk}", tiles)


@functools.cache
def _latent_step_kernel(has_above: bool, has_mask: bool):
    """(b, split along K: epilogue) ``Y += 2 eta * mask * (sum_s D[s] - E_above)``, the
    splits summed in order."""

    def latent_step_kernel(
        Y: _F32_2D, D: _F32_3D, E_above: _F32_2D, mask: wp.array(dtype=wp.int32), two_eta: wp.float32
    ):
        r, c = wp.tid()
        if wp.static(has_mask):
            if mask[r] == 0:
                return
        d = D[0, r, c]
        for s in range(1, D.shape[0]):
            d += D[s, r, c]
        if wp.static(has_above):
            d -= E_above[r, c]
        Y[r, c] = Y[r, c] + two_eta * d

    name = f"pc_latent_step_{'above' if has_above else 'top'}_{'masked' if has_mask else 'all'}"
    return _tiled_kernel(latent_step_kernel, name)


@functools.cache
def _weight_kernel(tiles: TileConfig, with_transpose: bool):
    """(c) W += 2 eta Y.T @ G (in place), and Wt = W.T of the result when asked.
    GEMM M=n_l, N=n_below, K=B."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    def weight_kernel(W: _F32_2D, Y: _F32_2D, G: _F32_2D, two_eta: wp.float32, Wt: _F32_2D):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        d = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((Y.shape[0] + tk - 1) // tk):
            y = wp.tile_load(Y, shape=(tk, tm), offset=(k * tk, row))
            g = wp.tile_load(G, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(wp.tile_transpose(y), g, d)
        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col)) + d * two_eta
        wp.tile_store(W, w, offset=(row, col))
        if wp.static(with_transpose):
            wp.tile_store(Wt, wp.tile_transpose(w), offset=(col, row))

    return _tiled_kernel(weight_kernel, f"pc_weight_{'WWt' if with_transpose else 'W'}_{tm}x{tn}x{tk}", tiles)


@wp.kernel(enable_backward=False, module="unique")
def _row_energy_kernel(row_partial: _F32_2D, out: _F64_2D, slot: int):
    """out[slot, r] = sum over column tiles of row_partial[:, r], in float64, in order."""
    r = wp.tid()
    s = wp.float64(0.0)
    for j in range(row_partial.shape[0]):
        s += wp.float64(row_partial[j, r])
    out[slot, r] = s


@wp.kernel(enable_backward=False, module="unique")
def _gather_kernel(src: _F32_2D, index: wp.array(dtype=wp.int32), dst: _F32_2D):
    r, c = wp.tid()
    dst[r, c] = src[index[r], c]


@wp.kernel(enable_backward=False, module="unique")
def _scatter_kernel(src: _F32_2D, index: wp.array(dtype=wp.int32), dst: _F32_2D):
    r, c = wp.tid()
    dst[index[r], c] = src[r, c]


@wp.func
def _under_limits(row_energy: _F64_2D, limits: wp.array(dtype=wp.float64), r: int) -> bool:
    """Row ``r``'s energy under its limit on every edge."""
    done = bool(True)
    for e in range(row_energy.shape[0]):
        if not (row_energy[e, r] < limits[e]):
            done = False
    return done


@wp.kernel(enable_backward=False, module="unique")
def _stop_kernel(
    row_energy: _F64_2D,
    limits: wp.array(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    steps: wp.array(dtype=wp.int32),
):
    r = wp.tid()
    if active[r] == 0:
        return
    if _under_limits(row_energy, limits, r):
        active[r] = 0
    else:
        steps[r] = steps[r] + 1


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------


def _check_type(name: str, arr, dtype=wp.float32, ndim: int = 2) -> None:
    if not isinstance(arr, wp.array) or arr.ndim != ndim or arr.dtype != dtype:
        raise TypeError(f"{name} must be a wp.array{ndim}d(dtype={dtype.__name__}), got {arr!r}")


def _check(name: str, arr, shape: tuple[int, ...], device, dtype=wp.float32) -> None:
    _check_type(name, arr, dtype, len(shape))
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} has shape {tuple(arr.shape)}, expected {tuple(shape)}")
    if arr.device != device:
        raise ValueError(f"{name} is on {arr.device}, expected {device}")
    if not arr.is_contiguous:
        raise ValueError(f"{name} must be contiguous")


# While a plan is being recorded (see `planned_kernels`), launches are recorded, not run.
_plan: list[tuple[wp.Kernel, int]] | None = None


def _launch_tiled(kernel, dim, inputs, block_dim: int, device) -> None:
    if _plan is not None:
        _plan.append((kernel, block_dim))
        return
    wp.launch_tiled(kernel, dim=dim, inputs=inputs, block_dim=block_dim, device=device)


def _simt_launch(kernel, dim, inputs, device) -> None:
    block_dim = _SIMT_BLOCK if device.is_cuda else 1
    if _plan is not None:
        _plan.append((kernel, block_dim))
        return
    wp.launch(kernel, dim=dim, inputs=inputs, device=device, block_dim=block_dim)


@contextlib.contextmanager
def planned_kernels() -> Iterator[list[tuple[wp.Kernel, int]]]:
    """Record, instead of launching, the kernels the operations called inside the block
    would launch (checks and scratch allocation still happen): the list of
    ``(kernel, block_dim)`` to hand to :func:`preload`."""
    global _plan
    outer, _plan = _plan, []
    try:
        yield _plan
    finally:
        _plan = outer


def preload(device, kernels: list[tuple[wp.Kernel, int]], workers: int | None = None) -> None:
    """Compile and load ``kernels`` on ``device`` in parallel threads (one per usable CPU by
    default). A cuBLASDx tile GEMM takes tens of seconds to compile on CUDA; compiled
    modules are cached on disk by Warp, so this costs nothing the second time."""
    _ensure_init()
    by_block: dict[int, list] = {}
    for kernel, block_dim in kernels:
        modules = by_block.setdefault(block_dim, [])
        if kernel.module not in modules:
            modules.append(kernel.module)
    for block_dim, modules in by_block.items():
        wp.force_load(device=device, modules=modules, block_dim=block_dim, max_workers=workers or usable_cpus())


def row_partial_shape(batch: int, n_below: int, tiles: TileConfig) -> tuple[int, int]:
    """Shape of the scratch :func:`predict` writes per-row partial energies to."""
    return (_cdiv(n_below, tiles.tn), batch)


def predict(
    Y,
    W,
    X,
    E,
    G,
    row_partial=None,
    row_energy=None,
    slot: int = 0,
    activation: str = "leaky_relu",
    slope: float = 0.2,
    A=None,
    P=None,
    tiles: TileConfig | None = None,
) -> None:
    """Kernel (a): ``E = X - phi(Y @ W)``, ``G = phi'(Y @ W) * E``; with ``row_energy``,
    also ``row_energy[slot, r] = sum_c E[r, c]**2`` (float64); with ``A`` and ``P``, also
    ``A = Y @ W`` and ``P = phi(A)``.

    Shapes: ``Y`` (B x n_l), ``W`` (n_l x n_below); ``X``, ``E``, ``G`` (and ``A``, ``P``)
    (B x n_below), float32; ``row_energy`` (slots x B) float64 with ``row_partial`` the
    float32 scratch of :func:`row_partial_shape`. All on one device.
    """
    _check_activation(activation)
    _ensure_init()
    _check_type("Y", Y)
    _check_type("W", W)
    b, n_l = Y.shape
    device = Y.device
    n_below = W.shape[1]
    _check("W", W, (n_l, n_below), device)
    store = A is not None or P is not None
    if store and (A is None or P is None):
        raise ValueError("give both A and P, or neither")
    for name, arr in (("X", X), ("E", E), ("G", G)) + ((("A", A), ("P", P)) if store else ()):
        _check(name, arr, (b, n_below), device)
    cfg = tiles or tile_config(device, "predict", b)
    with_energy = row_energy is not None
    _check_energy_buffers(row_partial, row_energy, slot, b, n_below, cfg, device)
    _launch_predict(
        _predict_kernel(cfg, activation, store, with_energy), cfg, b, n_below, row_partial, row_energy, slot,
        [Y, W, X, wp.float32(slope), A if store else E, P if store else E, E, G, row_partial if with_energy else E,
         _placeholder(device, wp.bfloat16)],
        device,
    )


def predict_epilogue(
    A,
    X,
    E,
    G,
    row_partial=None,
    row_energy=None,
    slot: int = 0,
    activation: str = "leaky_relu",
    slope: float = 0.2,
    G_low=None,
    tiles: TileConfig | None = None,
) -> None:
    """Kernel (a) without its GEMM: ``E = X - phi(A)``, ``G = phi'(A) * E`` from a product
    ``A = Y @ W`` computed elsewhere (cuBLAS), the row energies as in :func:`predict`, and
    with ``G_low`` (bfloat16, B x n_below) G rounded to bfloat16 as well."""
    _check_activation(activation)
    _ensure_init()
    _check_type("A", A)
    b, n_below = A.shape
    device = A.device
    for name, arr in (("X", X), ("E", E), ("G", G)):
        _check(name, arr, (b, n_below), device)
    if G_low is not None:
        _check("G_low", G_low, (b, n_below), device, wp.bfloat16)
    cfg = tiles or tile_config(device, "predict", b)
    with_energy = row_energy is not None
    _check_energy_buffers(row_partial, row_energy, slot, b, n_below, cfg, device)
    low = G_low is not None
    _launch_predict(
        _predict_kernel(cfg, activation, False, with_energy, gemm=False, low_gain=low), cfg, b, n_below, row_partial,
        row_energy, slot,
        [E, E, X, wp.float32(slope), A, E, E, G, row_partial if with_energy else E,
         G_low if low else _placeholder(device, wp.bfloat16)],
        device,
    )


def _launch_predict(kernel, cfg: TileConfig, b: int, n_below: int, row_partial, row_energy, slot: int, inputs,
                    device) -> None:
    """One configuration of kernel (a) over the (B x n_below) output tiles, then the
    in-order sum of the per-row energies when asked."""
    _launch_tiled(kernel, (_cdiv(b, cfg.tm), _cdiv(n_below, cfg.tn)), inputs, cfg.block_dim, device)
    if row_energy is not None:
        _simt_launch(_row_energy_kernel, b, [row_partial, row_energy, slot], device)


def _check_energy_buffers(row_partial, row_energy, slot: int, b: int, n_below: int, cfg: TileConfig, device) -> None:
    if row_energy is None:
        return
    _check("row_partial", row_partial, row_partial_shape(b, n_below, cfg), device)
    _check_type("row_energy", row_energy, wp.float64)
    _check("row_energy", row_energy, (row_energy.shape[0], b), device, wp.float64)
    if not 0 <= slot < row_energy.shape[0]:
        raise ValueError(f"slot {slot} outside row_energy's {row_energy.shape[0]} rows")


_placeholders: dict[tuple[str, type, int], wp.array] = {}


def _placeholder(device, dtype, ndim: int = 2):
    """An empty array standing in for an argument a kernel configuration never reads (one
    per device, made once: nothing is allocated while a CUDA graph is captured)."""
    key = (str(device), dtype, ndim)
    if key not in _placeholders:
        _placeholders[key] = wp.empty((0,) * ndim, dtype=dtype, device=device)
    return _placeholders[key]


def latent_scratch_shape(batch: int, n_l: int, n_below: int, device, tiles: TileConfig | None = None) -> tuple[int, int, int]:
    """Shape of the split-K scratch :func:`latent_update` needs (splits x B x n_l); with a
    single split the update is one fused kernel and needs none (shape (0, B, n_l))."""
    cfg = tiles or tile_config(device, "latent", batch)
    splits = latent_splits(device, cfg, batch, n_l, n_below)
    return (splits if splits > 1 else 0, batch, n_l)


def latent_update(Y, G, Wt, eta: float, scratch=None, E_above=None, mask=None, tiles: TileConfig | None = None) -> None:
    """Kernel (b), in place: ``Y <- Y + 2 eta * mask * (G @ Wt - E_above)``.

    The gradient step ``Y - eta dF/dY`` with ``dF/dY = -2 G @ W.T + 2 E_above``; it takes
    ``Wt`` = W transposed (n_below x n_l, kept by :func:`weight_update`) so that the long
    K runs down the rows of both operands. ``Y`` (B x n_l), ``G`` (B x n_below),
    ``E_above`` (B x n_l) or ``None`` (top / joint layer), ``mask`` (B,) int32 (0: leave
    that row alone) or ``None``. ``scratch``: float32 (splits x B x n_l) of
    :func:`latent_scratch_shape`; ``None`` or zero splits run the single fused kernel,
    more split the GEMM along K (each split's partial product into the scratch, then a
    fused element-wise kernel sums them in order and applies the step).

    Calls accumulate into ``Y``: the joint layer, which predicts several modalities, calls
    this once per modality (``E_above=None``). Run :func:`predict` for every layer first:
    this reads only ``G``, ``Wt`` and ``E_above`` besides ``Y``, which no other layer's
    latent update writes, so all layers step from the same state.
    """
    _ensure_init()
    _check_type("Y", Y)
    _check_type("Wt", Wt)
    b, n_l = Y.shape
    device = Y.device
    n_below = Wt.shape[0]
    _check("Wt", Wt, (n_below, n_l), device)
    _check("G", G, (b, n_below), device)
    if E_above is not None:
        _check("E_above", E_above, (b, n_l), device)
    if mask is not None:
        _check("mask", mask, (b,), device, wp.int32)
    cfg = tiles or tile_config(device, "latent", b)
    has_above, has_mask = E_above is not None, mask is not None
    placeholder = E_above if has_above else Y
    mask_arg = mask if has_mask else _placeholder(device, wp.int32, 1)
    splits = 0 if scratch is None else scratch.shape[0]
    if splits <= 1:
        _launch_tiled(
            _latent_fused_kernel(cfg, has_above, has_mask),
            (_cdiv(b, cfg.tm), _cdiv(n_l, cfg.tn)),
            [Y, G, Wt, placeholder, mask_arg, wp.float32(2.0 * eta)],
            cfg.block_dim,
            device,
        )
        return
    _check("scratch", scratch, (splits, b, n_l), device)
    steps = _cdiv(_cdiv(n_below, cfg.tk), splits)
    _launch_tiled(
        _latent_gemm_kernel(cfg),
        (_cdiv(b, cfg.tm), _cdiv(n_l, cfg.tn), splits),
        [G, Wt, steps, scratch],
        cfg.block_dim,
        device,
    )
    _launch_latent_step(Y, scratch, eta, E_above, mask)


def latent_apply(Y, D, eta: float, E_above=None, mask=None) -> None:
    """The step of kernel (b) from a product ``D = G @ W.T`` computed elsewhere (cuBLAS),
    in place: ``Y <- Y + 2 eta * mask * (D - E_above)``; ``D`` (B x n_l) float32, the
    rest as in :func:`latent_update`."""
    _ensure_init()
    _check_type("Y", Y)
    b, n_l = Y.shape
    device = Y.device
    _check("D", D, (b, n_l), device)
    if E_above is not None:
        _check("E_above", E_above, (b, n_l), device)
    if mask is not None:
        _check("mask", mask, (b,), device, wp.int32)
    _launch_latent_step(Y, D.reshape((1, b, n_l)), eta, E_above, mask)


def _launch_latent_step(Y, D, eta: float, E_above, mask) -> None:
    """``Y += 2 eta * mask * (sum_s D[s] - E_above)`` (D: splits x B x n_l)."""
    device = Y.device
    has_above, has_mask = E_above is not None, mask is not None
    _simt_launch(
        _latent_step_kernel(has_above, has_mask),
        tuple(Y.shape),
        [Y, D, E_above if has_above else Y, mask if has_mask else _placeholder(device, wp.int32, 1), wp.float32(2.0 * eta)],
        device,
    )


@wp.kernel(enable_backward=False, module="unique")
def _bfloat16_kernel(src: _F32_2D, dst: _BF16_2D):
    r, c = wp.tid()
    dst[r, c] = wp.bfloat16(src[r, c])


def to_bfloat16(src, dst) -> None:
    """``dst = src`` rounded to bfloat16 (to nearest, ties to even); both 2-d, one shape."""
    _ensure_init()
    _check_type("src", src)
    _check("dst", dst, tuple(src.shape), src.device, wp.bfloat16)
    _simt_launch(_bfloat16_kernel, tuple(src.shape), [src, dst], src.device)


def planning() -> bool:
    """True while :func:`planned_kernels` records launches instead of running them: work
    that is not a Warp kernel (a cuBLAS call) must then be skipped as well."""
    return _plan is not None


def weight_update(W, Y, G, eta: float, Wt=None, tiles: TileConfig | None = None) -> None:
    """Kernel (c), in place: ``W <- W + 2 eta Y.T @ G`` (``W - eta dF/dW``,
    ``dF/dW = -2 Y.T @ G``), and ``Wt <- W.T`` of the result when ``Wt`` is given.

    ``W`` (n_l x n_below), ``Y`` (B x n_l), ``G`` (B x n_below), ``Wt`` (n_below x n_l).
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
    if Wt is not None:
        _check("Wt", Wt, (n_below, n_l), device)
    cfg = tiles or tile_config(device, "weight", b)
    _launch_tiled(
        _weight_kernel(cfg, Wt is not None),
        (_cdiv(n_l, cfg.tm), _cdiv(n_below, cfg.tn)),
        [W, Y, G, wp.float32(2.0 * eta), Wt if Wt is not None else W],
        cfg.block_dim,
        device,
    )


def _move_rows(kernel, src, index, dst, small) -> None:
    """Launch ``kernel`` over the rows of ``small`` (the side ``index`` runs along)."""
    _ensure_init()
    _check_type("src", src)
    _check_type("dst", dst)
    _check("index", index, (small.shape[0],), src.device, wp.int32)
    if dst.shape[1] != src.shape[1]:
        raise ValueError(f"dst has {dst.shape[1]} columns, src {src.shape[1]}")
    _simt_launch(kernel, tuple(small.shape), [src, index, dst], src.device)


def gather_rows(src, index, dst) -> None:
    """``dst[r] = src[index[r]]`` (``index`` int32 of length ``dst.shape[0]``)."""
    _move_rows(_gather_kernel, src, index, dst, dst)


def scatter_rows(src, index, dst) -> None:
    """``dst[index[r]] = src[r]`` (``index`` int32 of length ``src.shape[0]``, no repeats)."""
    _move_rows(_scatter_kernel, src, index, dst, src)


def stop_converged(row_energy, limits, active, steps) -> None:
    """Per-sample stopping: for every row ``r`` still ``active``, if
    ``row_energy[e, r] < limits[e]`` for every edge ``e`` set ``active[r] = 0``, otherwise
    count the step about to be taken in ``steps[r]``.

    ``row_energy`` (edges x B) float64, ``limits`` (edges,) float64 (threshold x layer
    width: a per-sample sum of squares against a mean-squared-error threshold),
    ``active`` and ``steps`` (B,) int32.
    """
    _ensure_init()
    _check_type("row_energy", row_energy, wp.float64)
    n_edges, b = row_energy.shape
    device = row_energy.device
    _check("limits", limits, (n_edges,), device, wp.float64)
    _check("active", active, (b,), device, wp.int32)
    _check("steps", steps, (b,), device, wp.int32)
    _simt_launch(_stop_kernel, b, [row_energy, limits, active, steps], device)
