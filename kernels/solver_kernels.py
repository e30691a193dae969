"""Warp kernels of the test-time solvers (`vitaplace.engine.network.solver`), on CPU or CUDA.

Small element-wise and per-row kernels, launched between the layer steps of
``predict_kernels`` and ``update_kernels`` (so a chunk of solver steps is still one
captured CUDA graph):

* :func:`scale_add`      ``dst += alpha * mask * src``  (mask per row, 0 / 1)
* :func:`row_dot`        ``out[r] += weight * sum_c A[r, c] B[r, c]``, float64, in order
* :func:`restart_control` per row: restart when the momentum points uphill, and halve
                         the step when that follows a step without momentum
* :func:`momentum_step`  Nesterov momentum with restart, per row: ``V <- b V + m D``,
                         ``Y <- Y + m D + beta V``, ``m`` the row's step scale (0 when
                         inactive), ``b = beta`` (0 on a restart or when inactive)
* :func:`stop_converged` per-sample stopping of test-time inference by the per-edge
                         thresholds
* :func:`stop_settled`   per-sample stopping by the per-edge thresholds (as
                         :func:`stop_converged`) or by the relative rule
                         ``scale[r]^2 gnorm[r] < rtol2 * g0[r]``

The numpy backend computes the same; ``tests/kernels/test_solver.py`` checks them against
plain numpy (and ``tests/kernels/test_kernels.py`` :func:`stop_converged` by hand). No
atomics: results are reproducible run to run on one device.
"""

import functools
from typing import no_type_check

import warp as wp

from vitaplace.kernels.launch import (
    F32_2D,
    F64,
    F64_2D,
    I32,
    check,
    check_type,
    ensure_init,
    placeholder,
    simt_launch,
    tiled_kernel,
)

__all__ = ["momentum_step", "restart_control", "row_dot", "scale_add", "stop_converged", "stop_settled"]


@functools.cache
def _scale_add_kernel(has_mask: bool) -> wp.Kernel:
    @no_type_check
    def scale_add_kernel(dst: F32_2D, src: F32_2D, mask: I32, alpha: wp.float32):
        r, c = wp.tid()
        if wp.static(has_mask):
            if mask[r] == 0:
                return
        dst[r, c] = dst[r, c] + alpha * src[r, c]

    return tiled_kernel(scale_add_kernel, f"pc_scale_add_{'masked' if has_mask else 'all'}")


@wp.func
@no_type_check
def _under_limits(row_energy: F64_2D, limits: F64, r: int) -> bool:
    """Row ``r``'s energy under its limit on every edge."""
    done = bool(True)  # noqa: UP018 - Warp: a constructor makes the variable mutable in the loop
    for e in range(row_energy.shape[0]):
        if not (row_energy[e, r] < limits[e]):
            done = False
    return done


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _stop_kernel(row_energy: F64_2D, limits: F64, active: I32, steps: I32):
    r = wp.tid()
    if active[r] == 0:
        return
    if _under_limits(row_energy, limits, r):
        active[r] = 0
    else:
        steps[r] = steps[r] + 1


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _row_dot_kernel(A: F32_2D, B: F32_2D, out: F64, weight: wp.float64):
    r = wp.tid()
    s = wp.float64(0.0)
    for c in range(A.shape[1]):
        s += wp.float64(A[r, c]) * wp.float64(B[r, c])
    out[r] = out[r] + weight * s


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _control_kernel(scale: F64, plain: I32, uphill: F64, active: I32):
    r = wp.tid()
    if active[r] == 0:
        return
    restart = uphill[r] > wp.float64(0.0)
    if restart and plain[r] != 0:
        scale[r] = scale[r] * wp.float64(0.5)
    uphill[r] = wp.where(restart, wp.float64(1.0), wp.float64(0.0))
    plain[r] = wp.where(restart, 1, 0)


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _momentum_kernel(Y: F32_2D, V: F32_2D, D: F32_2D, restart: F64, scale: F64, active: I32, beta: wp.float32):
    r, c = wp.tid()
    m = wp.where(active[r] != 0, wp.float32(scale[r]), wp.float32(0.0))
    keep = wp.where(restart[r] > wp.float64(0.0) or active[r] == 0, wp.float32(0.0), beta)
    d = m * D[r, c]
    v = keep * V[r, c] + d
    V[r, c] = v
    Y[r, c] = Y[r, c] + d + beta * v


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _stop_settled_kernel(
    row_energy: F64_2D, limits: F64, gnorm: F64, scale: F64, g0: F64, rtol2: wp.float64, active: I32,
    steps: I32,
):
    r = wp.tid()
    if active[r] == 0:
        return
    if _under_limits(row_energy, limits, r) or scale[r] * scale[r] * gnorm[r] < rtol2 * g0[r]:
        active[r] = 0
    else:
        steps[r] = steps[r] + 1


def scale_add(dst: wp.array, src: wp.array, alpha: float, mask: wp.array | None = None) -> None:
    """``dst <- dst + alpha * mask * src`` in place (rows where ``mask`` is 0 left alone;
    ``mask`` (B,) int32 or ``None``); ``src`` may be ``dst`` itself."""
    ensure_init()
    check_type("dst", dst)
    device = dst.device
    check("src", src, tuple(dst.shape), device)
    if mask is not None:
        check("mask", mask, (dst.shape[0],), device, wp.int32)
    mask_arg = mask if mask is not None else placeholder(device, wp.int32, 1)
    simt_launch(_scale_add_kernel(mask is not None), tuple(dst.shape), [dst, src, mask_arg, wp.float32(alpha)], device)


def row_dot(A: wp.array, B: wp.array, weight: float, out: wp.array) -> None:
    """``out[r] <- out[r] + weight * sum_c A[r, c] * B[r, c]`` (the sum in float64, in
    column order); ``A``, ``B`` (B x n) float32, ``out`` (B,) float64."""
    ensure_init()
    check_type("A", A)
    device = A.device
    check("B", B, tuple(A.shape), device)
    check("out", out, (A.shape[0],), device, wp.float64)
    simt_launch(_row_dot_kernel, A.shape[0], [A, B, out, wp.float64(weight)], device)


def restart_control(scale: wp.array, plain: wp.array, uphill: wp.array, active: wp.array) -> None:
    """The restart and step control of the Nesterov solver, per active row ``r``: the
    momentum points uphill when ``uphill[r] > 0`` (dF/dY . V); that is a restart, written
    to ``uphill[r]`` (1 / 0) and to ``plain[r]`` (the next step is without momentum), and
    when the step just taken had no momentum (``plain[r]``: it overshot the minimum along
    its own direction, as across a kink) it also halves ``scale[r]``. ``scale``, ``uphill``
    (B,) float64, ``plain`` and ``active`` int32."""
    ensure_init()
    check_type("scale", scale, wp.float64, 1)
    b = scale.shape[0]
    device = scale.device
    check("uphill", uphill, (b,), device, wp.float64)
    for name, arr in (("plain", plain), ("active", active)):
        check(name, arr, (b,), device, wp.int32)
    simt_launch(_control_kernel, b, [scale, plain, uphill, active], device)


def momentum_step(
    Y: wp.array, V: wp.array, D: wp.array, beta: float, restart: wp.array, scale: wp.array, active: wp.array
) -> None:
    """One Nesterov step per row from the step ``D`` (= -eta dF/dY): ``V <- b V + m D``,
    ``Y <- Y + m D + beta V`` with ``m = scale[r]`` on an active row (0 otherwise) and
    ``b = beta`` unless ``restart[r] > 0`` or the row is inactive (``b = 0``). ``V`` of an
    inactive row becomes 0, so the row stays where it is."""
    ensure_init()
    check_type("Y", Y)
    device, shape = Y.device, tuple(Y.shape)
    check("V", V, shape, device)
    check("D", D, shape, device)
    for name, arr in (("restart", restart), ("scale", scale)):
        check(name, arr, (shape[0],), device, wp.float64)
    check("active", active, (shape[0],), device, wp.int32)
    simt_launch(_momentum_kernel, shape, [Y, V, D, restart, scale, active, wp.float32(beta)], device)


def stop_converged(row_energy: wp.array, limits: wp.array, active: wp.array, steps: wp.array) -> None:
    """Per-sample stopping: for every row ``r`` still ``active``, if
    ``row_energy[e, r] < limits[e]`` for every edge ``e`` set ``active[r] = 0``, otherwise
    count the step about to be taken in ``steps[r]``.

    ``row_energy`` (edges x B) float64, ``limits`` (edges,) float64 (threshold x layer
    width: a per-sample sum of squares against a mean-squared-error threshold),
    ``active`` and ``steps`` (B,) int32.
    """
    ensure_init()
    check_type("row_energy", row_energy, wp.float64)
    n_edges, b = row_energy.shape
    device = row_energy.device
    check("limits", limits, (n_edges,), device, wp.float64)
    check("active", active, (b,), device, wp.int32)
    check("steps", steps, (b,), device, wp.int32)
    simt_launch(_stop_kernel, b, [row_energy, limits, active, steps], device)


def stop_settled(
    row_energy: wp.array, limits: wp.array, gnorm: wp.array, scale: wp.array, g0: wp.array, rtol2: float,
    active: wp.array, steps: wp.array,
) -> None:
    """Per-sample stopping: a row still ``active`` stops when every edge's energy is under
    its limit (as :func:`stop_converged`) or when its step is short,
    ``scale[r]^2 gnorm[r] < rtol2 g0[r]``; otherwise the step about to be taken is counted
    in ``steps[r]``."""
    ensure_init()
    check_type("row_energy", row_energy, wp.float64)
    n_edges, b = row_energy.shape
    device = row_energy.device
    check("limits", limits, (n_edges,), device, wp.float64)
    for name, arr in (("gnorm", gnorm), ("scale", scale), ("g0", g0)):
        check(name, arr, (b,), device, wp.float64)
    check("active", active, (b,), device, wp.int32)
    check("steps", steps, (b,), device, wp.int32)
    simt_launch(_stop_settled_kernel, b, [row_energy, limits, gnorm, scale, g0, wp.float64(rtol2), active, steps],
                 device)
