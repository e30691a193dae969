"""Warp kernels of the test-time solvers (`vitaplace.engine.network.solver`), on CPU or CUDA.

Small element-wise and per-row kernels, launched between the layer steps of
``warp_kernels`` (so a chunk of solver steps is still one captured CUDA graph):

* :func:`scale_add`      ``dst += alpha * mask * src``  (mask per row, 0 / 1)
* :func:`row_dot`        ``out[r] += weight * sum_c A[r, c] B[r, c]``, float64, in order
* :func:`restart_control` per row: restart when the momentum points uphill, and halve
                         the step when that follows a step without momentum
* :func:`momentum_step`  Nesterov momentum with restart, per row: ``V <- b V + m D``,
                         ``Y <- Y + m D + beta V``, ``m`` the row's step scale (0 when
                         inactive), ``b = beta`` (0 on a restart or when inactive)
* :func:`stop_settled`   per-sample stopping by the per-edge thresholds (as
                         ``warp_kernels.stop_converged``) or by the relative rule
                         ``scale[r]^2 gnorm[r] < rtol2 * g0[r]``

The numpy backend computes the same; ``tests/kernels/test_solver_kernels.py`` checks them
against plain numpy. No atomics: results are reproducible run to run on one device.
"""

import functools

import warp as wp

from vitaplace.kernels.warp_kernels import (
    _F32_2D, _F64_2D, _check, _check_type, _ensure_init, _placeholder, _simt_launch, _tiled_kernel, _under_limits,
)

__all__ = ["scale_add", "row_dot", "restart_control", "momentum_step", "stop_settled"]

_I32 = wp.array(dtype=wp.int32)
_F64 = wp.array(dtype=wp.float64)


@functools.cache
def _scale_add_kernel(has_mask: bool):
    def scale_add_kernel(dst: _F32_2D, src: _F32_2D, mask: _I32, alpha: wp.float32):
        r, c = wp.tid()
        if wp.static(has_mask):
            if mask[r] == 0:
                return
        dst[r, c] = dst[r, c] + alpha * src[r, c]

    return _tiled_kernel(scale_add_kernel, f"pc_scale_add_{'masked' if has_mask else 'all'}")


@wp.kernel(enable_backward=False, module="unique")
def _row_dot_kernel(A: _F32_2D, B: _F32_2D, out: _F64, weight: wp.float64):
    r = wp.tid()
    s = wp.float64(0.0)
    for c in range(A.shape[1]):
        s += wp.float64(A[r, c]) * wp.float64(B[r, c])
    out[r] = out[r] + weight * s


@wp.kernel(enable_backward=False, module="unique")
def _control_kernel(scale: _F64, plain: _I32, uphill: _F64, active: _I32):
    r = wp.tid()
    if active[r] == 0:
        return
    restart = uphill[r] > wp.float64(0.0)
    if restart and plain[r] != 0:
        scale[r] = scale[r] * wp.float64(0.5)
    uphill[r] = wp.where(restart, wp.float64(1.0), wp.float64(0.0))
    plain[r] = wp.where(restart, 1, 0)


@wp.kernel(enable_backward=False, module="unique")
def _momentum_kernel(Y: _F32_2D, V: _F32_2D, D: _F32_2D, restart: _F64, scale: _F64, active: _I32, beta: wp.float32):
    r, c = wp.tid()
    m = wp.where(active[r] != 0, wp.float32(scale[r]), wp.float32(0.0))
    keep = wp.where(restart[r] > wp.float64(0.0) or active[r] == 0, wp.float32(0.0), beta)
    d = m * D[r, c]
    v = keep * V[r, c] + d
    V[r, c] = v
    Y[r, c] = Y[r, c] + d + beta * v


@wp.kernel(enable_backward=False, module="unique")
def _stop_settled_kernel(
    row_energy: _F64_2D, limits: _F64, gnorm: _F64, scale: _F64, g0: _F64, rtol2: wp.float64, active: _I32,
    steps: _I32,
):
    r = wp.tid()
    if active[r] == 0:
        return
    if _under_limits(row_energy, limits, r) or scale[r] * scale[r] * gnorm[r] < rtol2 * g0[r]:
        active[r] = 0
    else:
        steps[r] = steps[r] + 1


def scale_add(dst, src, alpha: float, mask=None) -> None:
    """``dst <- dst + alpha * mask * src`` in place (rows where ``mask`` is 0 left alone;
    ``mask`` (B,) int32 or ``None``); ``src`` may be ``dst`` itself."""
    _ensure_init()
    _check_type("dst", dst)
    device = dst.device
    _check("src", src, tuple(dst.shape), device)
    if mask is not None:
        _check("mask", mask, (dst.shape[0],), device, wp.int32)
    mask_arg = mask if mask is not None else _placeholder(device, wp.int32, 1)
    _simt_launch(_scale_add_kernel(mask is not None), tuple(dst.shape), [dst, src, mask_arg, wp.float32(alpha)], device)


def row_dot(A, B, weight: float, out) -> None:
    """``out[r] <- out[r] + weight * sum_c A[r, c] * B[r, c]`` (the sum in float64, in
    column order); ``A``, ``B`` (B x n) float32, ``out`` (B,) float64."""
    _ensure_init()
    _check_type("A", A)
    device = A.device
    _check("B", B, tuple(A.shape), device)
    _check("out", out, (A.shape[0],), device, wp.float64)
    _simt_launch(_row_dot_kernel, A.shape[0], [A, B, out, wp.float64(weight)], device)


def restart_control(scale, plain, uphill, active) -> None:
    """The restart and step control of the Nesterov solver, per active row ``r``: the
    momentum points uphill when ``uphill[r] > 0`` (dF/dY . V); that is a restart, written
    to ``uphill[r]`` (1 / 0) and to ``plain[r]`` (the next step is without momentum), and
    when the step just taken had no momentum (``plain[r]``: it overshot the minimum along
    its own direction, as across a kink) it also halves ``scale[r]``. ``scale``, ``uphill``
    (B,) float64, ``plain`` and ``active`` int32."""
    _ensure_init()
    _check_type("scale", scale, wp.float64, 1)
    b = scale.shape[0]
    device = scale.device
    _check("uphill", uphill, (b,), device, wp.float64)
    for name, arr in (("plain", plain), ("active", active)):
        _check(name, arr, (b,), device, wp.int32)
    _simt_launch(_control_kernel, b, [scale, plain, uphill, active], device)


def momentum_step(Y, V, D, beta: float, restart, scale, active) -> None:
    """One Nesterov step per row from the step ``D`` (= -eta dF/dY): ``V <- b V + m D``,
    ``Y <- Y + m D + beta V`` with ``m = scale[r]`` on an active row (0 otherwise) and
    ``b = beta`` unless ``restart[r] > 0`` or the row is inactive (``b = 0``). ``V`` of an
    inactive row becomes 0, so the row stays where it is."""
    _ensure_init()
    _check_type("Y", Y)
    device, shape = Y.device, tuple(Y.shape)
    _check("V", V, shape, device)
    _check("D", D, shape, device)
    for name, arr in (("restart", restart), ("scale", scale)):
        _check(name, arr, (shape[0],), device, wp.float64)
    _check("active", active, (shape[0],), device, wp.int32)
    _simt_launch(_momentum_kernel, shape, [Y, V, D, restart, scale, active, wp.float32(beta)], device)


def stop_settled(row_energy, limits, gnorm, scale, g0, rtol2: float, active, steps) -> None:
    """Per-sample stopping: a row still ``active`` stops when every edge's energy is under
    its limit (as :func:`warp_kernels.stop_converged`) or when its step is short,
    ``scale[r]^2 gnorm[r] < rtol2 g0[r]``; otherwise the step about to be taken is counted
    in ``steps[r]``."""
    _ensure_init()
    _check_type("row_energy", row_energy, wp.float64)
    n_edges, b = row_energy.shape
    device = row_energy.device
    _check("limits", limits, (n_edges,), device, wp.float64)
    for name, arr in (("gnorm", gnorm), ("scale", scale), ("g0", g0)):
        _check(name, arr, (b,), device, wp.float64)
    _check("active", active, (b,), device, wp.int32)
    _check("steps", steps, (b,), device, wp.int32)
    _simt_launch(_stop_settled_kernel, b, [row_energy, limits, gnorm, scale, g0, wp.float64(rtol2), active, steps],
                 device)
