"""Kernels (b) and (c), the gradient steps of a layer's latent and weights, on CPU or CUDA.

(b) :func:`latent_update`  ``Y <- Y + 2 eta m * (G @ W.T - pi_above * E_above)`` in place
                           (``m`` the per-sample 0/1 mask of samples still being updated;
                           ``pi_above`` the error precisions of the edge above, 1 when not
                           given; reads the transposed copy ``Wt`` of ``W``);
                           :func:`latent_apply` the same step from a product computed
                           elsewhere (cuBLAS)
(c) :func:`weight_update`  ``W <- W + 2 eta Y.T @ G`` and ``Wt <- W.T`` (in place)
(d) :func:`momentum_weight_step`, :func:`adam_weight_step`, :func:`count_step`
                           the element-wise weight steps of the momentum and Adam optimisers
                           from a step direction ``D = 2 Y.T @ G`` (:func:`weight_update` on
                           zeroed ``D`` with eta 1), keeping ``Wt <- W.T``; the step count
(e) :func:`column_squares` ``out[c] += sum_r E[r, c]^2`` (float64): a minibatch's squared
                           errors per channel, summed over an epoch for the error precisions
(f) :func:`project_rows`   each row of ``W`` rescaled to a given norm (``weight_norm: rows``),
                           keeping ``Wt <- W.T``

The latent update's GEMM has few output tiles (batch x n_l) and a long K (n_below), so on
CUDA it is split along K: each split writes its partial product to a scratch buffer and a
fused element-wise kernel sums the splits in a fixed order and applies the step. Small
layers (and the CPU) use one kernel for GEMM and step. It reads ``Wt``, the transpose of
``W`` that the weight update keeps, so both GEMM operands are read along rows (a transposed
tile load of ``W`` ran at a third of the speed on an H100). No atomics anywhere: results are
bitwise reproducible run to run on one device.
"""

import functools
from typing import no_type_check

import warp as wp

from vitaplace.kernels.launch import (
    F32,
    F32_2D,
    F32_3D,
    F64,
    I32,
    check,
    check_type,
    ensure_init,
    placeholder,
    simt_launch,
    tiled_kernel,
    tiled_launch,
)
from vitaplace.kernels.tiles import TileConfig, cdiv, latent_splits, tile_config

__all__ = [
    "adam_weight_step", "column_squares", "count_step", "latent_apply", "latent_scratch_shape", "latent_update",
    "momentum_weight_step", "project_rows", "weight_update",
]

# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------


@wp.func
@no_type_check
def _row_gate(active: wp.int32) -> wp.float32:
    return wp.where(active != 0, wp.float32(1.0), wp.float32(0.0))


@wp.func
@no_type_check
def _times(x: wp.float32, y: wp.float32) -> wp.float32:
    return x * y


@functools.cache
def _latent_fused_kernel(tiles: TileConfig, has_above: bool, has_mask: bool, weighted: bool = False) -> wp.Kernel:
    """(b) in one kernel: ``Y += 2 eta * mask * (G @ Wt - E_above)``, GEMM M=B, N=n_l,
    K=n_below (``Wt`` = W transposed, n_below x n_l); with ``weighted``, ``pi_above[c] *
    E_above`` in place of ``E_above``.

    Output tile (i, j) reads only Y's tile (i, j), after its GEMM, so Y is updated in place.
    """
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    @no_type_check
    def latent_kernel(
        Y: F32_2D, G: F32_2D, Wt: F32_2D, E_above: F32_2D, mask: I32, two_eta: wp.float32, pi_above: F32
    ):
        i, j = wp.tid()
        row, col = i * tm, j * tn
        d = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        for k in range((G.shape[1] + tk - 1) // tk):
            g = wp.tile_load(G, shape=(tm, tk), offset=(row, k * tk))
            w = wp.tile_load(Wt, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(g, w, d)
        if wp.static(has_above):
            e = wp.tile_load(E_above, shape=(tm, tn), offset=(row, col))
            if wp.static(weighted):
                pi = wp.tile_broadcast(wp.tile_load(pi_above, shape=(tn,), offset=(col,)), shape=(tm, tn))
                e = wp.tile_map(_times, e, pi)
            d = d - e
        d = d * two_eta
        if wp.static(has_mask):
            gate = wp.tile_map(_row_gate, wp.tile_load(mask, shape=(tm,), offset=(row,)))
            d = d * wp.tile_broadcast(wp.tile_reshape(gate, shape=(tm, 1)), shape=(tm, tn))
        wp.tile_store(Y, wp.tile_load(Y, shape=(tm, tn), offset=(row, col)) + d, offset=(row, col))

    above = ("above_pi" if weighted else "above") if has_above else "top"
    name = f"pc_latent_{above}_{'masked' if has_mask else 'all'}_{tm}x{tn}x{tk}"
    return tiled_kernel(latent_kernel, name, tiles)


@functools.cache
def _latent_gemm_kernel(tiles: TileConfig) -> wp.Kernel:
    """(b, split along K) ``D[s] = G[:, Ks] @ Wt[Ks, :]`` for K-slice ``s`` of ``steps`` K-steps."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    @no_type_check
    def latent_gemm_kernel(G: F32_2D, Wt: F32_2D, steps: int, D: F32_3D):
        i, j, s = wp.tid()
        row, col = i * tm, j * tn
        d = wp.tile_zeros(shape=(tm, tn), dtype=wp.float32)
        end = wp.min((s + 1) * steps, (G.shape[1] + tk - 1) // tk)
        for k in range(s * steps, end):
            g = wp.tile_load(G, shape=(tm, tk), offset=(row, k * tk))
            w = wp.tile_load(Wt, shape=(tk, tn), offset=(k * tk, col))
            wp.tile_matmul(g, w, d)
        wp.tile_store(D[s], d, offset=(row, col))

    return tiled_kernel(latent_gemm_kernel, f"pc_latent_gemm_{tm}x{tn}x{tk}", tiles)


@functools.cache
def _latent_step_kernel(has_above: bool, has_mask: bool, weighted: bool = False) -> wp.Kernel:
    """(b, split along K: epilogue) ``Y += 2 eta * mask * (sum_s D[s] - E_above)``, the
    splits summed in order; with ``weighted``, ``pi_above[c] * E_above``."""

    @no_type_check
    def latent_step_kernel(
        Y: F32_2D, D: F32_3D, E_above: F32_2D, mask: I32, two_eta: wp.float32, pi_above: F32
    ):
        r, c = wp.tid()
        if wp.static(has_mask):
            if mask[r] == 0:
                return
        d = D[0, r, c]
        for s in range(1, D.shape[0]):
            d += D[s, r, c]
        if wp.static(has_above):
            if wp.static(weighted):
                d -= pi_above[c] * E_above[r, c]
            else:
                d -= E_above[r, c]
        Y[r, c] = Y[r, c] + two_eta * d

    above = ("above_pi" if weighted else "above") if has_above else "top"
    name = f"pc_latent_step_{above}_{'masked' if has_mask else 'all'}"
    return tiled_kernel(latent_step_kernel, name)


@functools.cache
def _weight_kernel(tiles: TileConfig, with_transpose: bool) -> wp.Kernel:
    """(c) W += 2 eta Y.T @ G (in place), and Wt = W.T of the result when asked.
    GEMM M=n_l, N=n_below, K=B."""
    tm, tn, tk = tiles.tm, tiles.tn, tiles.tk

    @no_type_check
    def weight_kernel(W: F32_2D, Y: F32_2D, G: F32_2D, two_eta: wp.float32, Wt: F32_2D):
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

    return tiled_kernel(weight_kernel, f"pc_weight_{'WWt' if with_transpose else 'W'}_{tm}x{tn}x{tk}", tiles)


@functools.cache
def _momentum_weight_kernel(with_transpose: bool) -> wp.Kernel:
    """(d) heavy ball: ``V <- beta V + D``, ``W <- W + eta V``, and ``Wt = W.T`` when asked."""

    @no_type_check
    def momentum_weight_kernel(W: F32_2D, V: F32_2D, D: F32_2D, eta: wp.float32, beta: wp.float32, Wt: F32_2D):
        r, c = wp.tid()
        v = beta * V[r, c] + D[r, c]
        V[r, c] = v
        w = W[r, c] + eta * v
        W[r, c] = w
        if wp.static(with_transpose):
            Wt[c, r] = w

    return tiled_kernel(momentum_weight_kernel, f"pc_momentum_weight_{'WWt' if with_transpose else 'W'}")


@functools.cache
def _adam_weight_kernel(with_transpose: bool) -> wp.Kernel:
    """(d) Adam: ``M <- b1 M + (1 - b1) D``, ``S <- b2 S + (1 - b2) D^2``, ``W <- W + eta
    (M / c1) / (sqrt(S / c2) + eps)`` with the bias corrections ``c = 1 - b^t`` (float64) of
    the step count ``t[0]``, and ``Wt = W.T`` when asked."""

    @no_type_check
    def adam_weight_kernel(
        W: F32_2D, M: F32_2D, S: F32_2D, D: F32_2D, t: I32, eta: wp.float32, beta1: wp.float32,
        one_minus_beta1: wp.float32, beta2: wp.float32, one_minus_beta2: wp.float32, eps: wp.float32,
        b1: wp.float64, b2: wp.float64, Wt: F32_2D,
    ):
        r, c = wp.tid()
        g = D[r, c]
        m = beta1 * M[r, c] + one_minus_beta1 * g
        s = beta2 * S[r, c] + one_minus_beta2 * (g * g)
        M[r, c] = m
        S[r, c] = s
        n = wp.float64(t[0])
        c1 = wp.float32(wp.float64(1.0) - wp.pow(b1, n))
        c2 = wp.float32(wp.float64(1.0) - wp.pow(b2, n))
        w = W[r, c] + eta * (m / c1) / (wp.sqrt(s / c2) + eps)
        W[r, c] = w
        if wp.static(with_transpose):
            Wt[c, r] = w

    return tiled_kernel(adam_weight_kernel, f"pc_adam_weight_{'WWt' if with_transpose else 'W'}")


@functools.cache
def _project_rows_kernel(with_transpose: bool) -> wp.Kernel:
    """(f) ``W[r] <- W[r] * float32(norms[r] / |W[r]|)`` (``|W[r]|`` summed in float64 in
    column order; a zero row kept), and ``Wt = W.T`` when asked. One thread per row."""

    @no_type_check
    def project_rows_kernel(W: F32_2D, norms: F64, Wt: F32_2D):
        r = wp.tid()
        s = wp.float64(0.0)
        for c in range(W.shape[1]):
            w64 = wp.float64(W[r, c])
            s += w64 * w64
        f = wp.float32(1.0)
        if s > wp.float64(0.0):
            f = wp.float32(norms[r] / wp.sqrt(s))
        for c in range(W.shape[1]):
            w = W[r, c] * f
            W[r, c] = w
            if wp.static(with_transpose):
                Wt[c, r] = w

    return tiled_kernel(project_rows_kernel, f"pc_project_rows_{'WWt' if with_transpose else 'W'}")


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _count_kernel(t: I32):
    t[0] = t[0] + 1


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _column_squares_kernel(E: F32_2D, out: F64):
    """(e) out[c] += sum over rows of E[r, c]^2, in float64, in row order."""
    c = wp.tid()
    s = wp.float64(0.0)
    for r in range(E.shape[0]):
        e = wp.float64(E[r, c])
        s += e * e
    out[c] = out[c] + s


# --------------------------------------------------------------------------------------
# Operations
# --------------------------------------------------------------------------------------


def latent_scratch_shape(
    batch: int, n_l: int, n_below: int, device: wp.DeviceLike, tiles: TileConfig | None = None
) -> tuple[int, int, int]:
    """Shape of the split-K scratch :func:`latent_update` needs (splits x B x n_l); with a
    single split the update is one fused kernel and needs none (shape (0, B, n_l))."""
    cfg = tiles or tile_config(device, "latent", batch)
    splits = latent_splits(device, cfg, batch, n_l, n_below)
    return (splits if splits > 1 else 0, batch, n_l)


def latent_update(
    Y: wp.array, G: wp.array, Wt: wp.array, eta: float, scratch: wp.array | None = None,
    E_above: wp.array | None = None, mask: wp.array | None = None, tiles: TileConfig | None = None,
    precision_above: wp.array | None = None,
) -> None:
    """Kernel (b), in place: ``Y <- Y + 2 eta * mask * (G @ Wt - pi_above * E_above)``.

    The gradient step ``Y - eta dF/dY`` with ``dF/dY = -2 G @ W.T + 2 pi_above E_above``
    (``precision_above``: the error precisions of the edge above, n_l float32; None: 1;
    ``G`` already carries this edge's own, `predict`); it takes
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
    ensure_init()
    check_type("Y", Y)
    check_type("Wt", Wt)
    b, n_l = Y.shape
    device = Y.device
    n_below = Wt.shape[0]
    check("Wt", Wt, (n_below, n_l), device)
    check("G", G, (b, n_below), device)
    if E_above is not None:
        check("E_above", E_above, (b, n_l), device)
    if mask is not None:
        check("mask", mask, (b,), device, wp.int32)
    pi_arg, weighted = _precision_above(precision_above, E_above, n_l, device)
    cfg = tiles or tile_config(device, "latent", b)
    has_above, has_mask = E_above is not None, mask is not None
    above_arg = E_above if has_above else Y
    mask_arg = mask if has_mask else placeholder(device, wp.int32, 1)
    if scratch is None or scratch.shape[0] <= 1:
        tiled_launch(
            _latent_fused_kernel(cfg, has_above, has_mask, weighted),
            (cdiv(b, cfg.tm), cdiv(n_l, cfg.tn)),
            [Y, G, Wt, above_arg, mask_arg, wp.float32(2.0 * eta), pi_arg],
            cfg.block_dim,
            device,
        )
        return
    splits = scratch.shape[0]
    check("scratch", scratch, (splits, b, n_l), device)
    steps = cdiv(cdiv(n_below, cfg.tk), splits)
    tiled_launch(
        _latent_gemm_kernel(cfg),
        (cdiv(b, cfg.tm), cdiv(n_l, cfg.tn), splits),
        [G, Wt, steps, scratch],
        cfg.block_dim,
        device,
    )
    _launch_latent_step(Y, scratch, eta, E_above, mask, pi_arg, weighted)


def _precision_above(precision_above: wp.array | None, E_above: wp.array | None, n_l: int,
                     device: wp.DeviceLike) -> tuple[wp.array, bool]:
    """The kernels' argument for ``precision_above`` (checked; a placeholder when None) and
    whether the top-down term is weighted (only where there is an edge above)."""
    if precision_above is None or E_above is None:
        return placeholder(device, wp.float32, 1), False
    check("precision_above", precision_above, (n_l,), device)
    return precision_above, True


def latent_apply(
    Y: wp.array, D: wp.array, eta: float, E_above: wp.array | None = None, mask: wp.array | None = None,
    precision_above: wp.array | None = None,
) -> None:
    """The step of kernel (b) from a product ``D = G @ W.T`` computed elsewhere (cuBLAS),
    in place: ``Y <- Y + 2 eta * mask * (D - pi_above * E_above)``; ``D`` (B x n_l) float32, the
    rest as in :func:`latent_update`."""
    ensure_init()
    check_type("Y", Y)
    b, n_l = Y.shape
    device = Y.device
    check("D", D, (b, n_l), device)
    if E_above is not None:
        check("E_above", E_above, (b, n_l), device)
    if mask is not None:
        check("mask", mask, (b,), device, wp.int32)
    pi_arg, weighted = _precision_above(precision_above, E_above, n_l, device)
    _launch_latent_step(Y, D.reshape((1, b, n_l)), eta, E_above, mask, pi_arg, weighted)


def _launch_latent_step(Y: wp.array, D: wp.array, eta: float, E_above: wp.array | None, mask: wp.array | None,
                        pi_above: wp.array, weighted: bool) -> None:
    """``Y += 2 eta * mask * (sum_s D[s] - pi_above * E_above)`` (D: splits x B x n_l; ``pi_above``
    read only when ``weighted``)."""
    device = Y.device
    has_above, has_mask = E_above is not None, mask is not None
    simt_launch(
        _latent_step_kernel(has_above, has_mask, weighted),
        tuple(Y.shape),
        [Y, D, E_above if has_above else Y, mask if has_mask else placeholder(device, wp.int32, 1),
         wp.float32(2.0 * eta), pi_above],
        device,
    )


def weight_update(
    W: wp.array, Y: wp.array, G: wp.array, eta: float, Wt: wp.array | None = None, tiles: TileConfig | None = None
) -> None:
    """Kernel (c), in place: ``W <- W + 2 eta Y.T @ G`` (``W - eta dF/dW``,
    ``dF/dW = -2 Y.T @ G``), and ``Wt <- W.T`` of the result when ``Wt`` is given.

    ``W`` (n_l x n_below), ``Y`` (B x n_l), ``G`` (B x n_below), ``Wt`` (n_below x n_l).
    """
    ensure_init()
    check_type("W", W)
    check_type("Y", Y)
    n_l, n_below = W.shape
    device = W.device
    check("W", W, (n_l, n_below), device)
    b = Y.shape[0]
    check("Y", Y, (b, n_l), device)
    check("G", G, (b, n_below), device)
    if Wt is not None:
        check("Wt", Wt, (n_below, n_l), device)
    cfg = tiles or tile_config(device, "weight", b)
    tiled_launch(
        _weight_kernel(cfg, Wt is not None),
        (cdiv(n_l, cfg.tm), cdiv(n_below, cfg.tn)),
        [W, Y, G, wp.float32(2.0 * eta), Wt if Wt is not None else W],
        cfg.block_dim,
        device,
    )


def _check_optimizer_arrays(W: wp.array, Wt: wp.array | None, **same: wp.array) -> None:
    ensure_init()
    check_type("W", W)
    device, shape = W.device, tuple(W.shape)
    for name, arr in same.items():
        check(name, arr, shape, device)
    if Wt is not None:
        check("Wt", Wt, (shape[1], shape[0]), device)


def momentum_weight_step(
    W: wp.array, V: wp.array, D: wp.array, eta: float, beta: float, Wt: wp.array | None = None
) -> None:
    """(d) Heavy-ball weight step, in place: ``V <- beta V + D``, ``W <- W + eta V`` and
    ``Wt <- W.T`` of the result when ``Wt`` is given. ``D`` is the step direction
    ``2 Y.T @ G`` (= -dF/dW); ``W``, ``V``, ``D`` (n_l x n_below) float32."""
    _check_optimizer_arrays(W, Wt, V=V, D=D)
    simt_launch(
        _momentum_weight_kernel(Wt is not None), tuple(W.shape),
        [W, V, D, wp.float32(eta), wp.float32(beta), Wt if Wt is not None else W], W.device,
    )


def adam_weight_step(
    W: wp.array, M: wp.array, S: wp.array, D: wp.array, t: wp.array, eta: float, beta1: float, beta2: float,
    eps: float, Wt: wp.array | None = None,
) -> None:
    """(d) Adam weight step, in place (float32 moments, float64 bias corrections):
    ``M <- b1 M + (1 - b1) D``, ``S <- b2 S + (1 - b2) D^2``,
    ``W <- W + eta (M / (1 - b1^t)) / (sqrt(S / (1 - b2^t)) + eps)`` with ``t = t[0]`` (the
    step count, already counted by :func:`count_step`), and ``Wt <- W.T`` when given.
    ``D`` is the step direction ``2 Y.T @ G`` (= -dF/dW)."""
    _check_optimizer_arrays(W, Wt, M=M, S=S, D=D)
    check("t", t, (1,), W.device, wp.int32)
    simt_launch(
        _adam_weight_kernel(Wt is not None), tuple(W.shape),
        [W, M, S, D, t, wp.float32(eta), wp.float32(beta1), wp.float32(1.0 - beta1), wp.float32(beta2),
         wp.float32(1.0 - beta2), wp.float32(eps), wp.float64(beta1), wp.float64(beta2),
         Wt if Wt is not None else W],
        W.device,
    )


def count_step(t: wp.array) -> None:
    """``t[0] <- t[0] + 1``: the optimiser's step count, on the device (so that a captured
    minibatch counts each replay)."""
    ensure_init()
    check_type("t", t, wp.int32, 1)
    check("t", t, (1,), t.device, wp.int32)
    simt_launch(_count_kernel, 1, [t], t.device)


def column_squares(E: wp.array, out: wp.array) -> None:
    """(e) ``out[c] <- out[c] + sum_r E[r, c]**2`` (the sum in float64, in row order; no
    atomics); ``E`` (B x n) float32, ``out`` (n,) float64."""
    ensure_init()
    check_type("E", E)
    check("out", out, (E.shape[1],), E.device, wp.float64)
    simt_launch(_column_squares_kernel, E.shape[1], [E, out], E.device)


def project_rows(W: wp.array, norms: wp.array, Wt: wp.array | None = None) -> None:
    """(f) Each row of ``W`` (n_l x n_below, float32) rescaled in place to ``norms`` (n_l,
    float64): ``W[r] <- W[r] * float32(norms[r] / |W[r]|)``, its norm summed in float64; a
    zero row is kept. ``Wt <- W.T`` of the result when ``Wt`` is given."""
    _check_optimizer_arrays(W, Wt)
    check("norms", norms, (W.shape[0],), W.device, wp.float64)
    simt_launch(_project_rows_kernel(Wt is not None), W.shape[0], [W, norms, Wt if Wt is not None else W], W.device)
