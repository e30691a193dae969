"""Compute backends for the predictive-coding layer steps.

A backend owns array storage and the operations the network is built from:

    weights(W) / upload_weights(W, h) / weights_to_host(h)
                                      a layer's weights onto the device (new, or in place) and back
    predict(Y, W, X, E, G, R, k, pi)  A = Y W, E = X - phi(A), G = pi * phi'(A) * E, and with R:
                                      R[k, r] = sum_c pi_c E[r, c]^2   (per-sample energy, float64;
                                      pi: the edge's error precisions, 1 when None)
    latent_update(Y, G, W, eta, E_up, mask, pi_up)
                                      Y <- Y + 2 eta mask * (G W^T - pi_up * E_up)   (-eta dF/dY)
    weight_update(W, Y, G, eta)       W <- W + 2 eta (Y^T G)                    (-eta dF/dW)
    weight_gradient(D, Y, G)          D <- 2 Y^T G, the step direction -dF/dW (D shaped as W)
    column_squares(E, S)              S[c] += sum_r E[r, c]^2 (float64): the error precisions' estimate
    count_step(t)                     t[0] += 1: an optimiser's step count, on the device
    momentum_weight_step(W, V, D, eta, beta)
                                      V <- beta V + D, W <- W + eta V          (heavy ball)
    adam_weight_step(W, M, S, D, t, eta, beta1, beta2, eps)
                                      Adam, bias-corrected at step t[0]        (kernels/reference.py)
    project_rows(W, norms)            W[r] <- W[r] norms[r] / |W[r]|   (weight_norm rows; norms float64)
    gather_rows / scatter_rows        minibatch rows of a resident store, by an index array
    stop_converged(R, limits, active, steps)   per-sample stopping of inference
    scale_add(dst, src, alpha, mask)  dst <- dst + alpha mask * src   (the solvers' vector steps)
    row_dot(A, B, weight, out)        out[r] += weight sum_c A[r, c] B[r, c]   (float64)
    restart_control(scale, plain, uphill, active)
    momentum_step(Y, V, D, beta, restart, scale, active)
                                      Nesterov with restarts (kernels/solver_kernels.py)
    stop_settled(R, limits, gnorm, scale, g0, rtol2, active, steps)
                                      stop_converged, or scale^2 gnorm < rtol2 g0 (the relative rule)
    capture(fn)                       a replayable recording of fn's launches (a CUDA graph)

``numpy`` runs them with float32 BLAS through ``np.matmul(..., out=)`` (numpy's own
OpenBLAS only: never alternated with scipy's, whose thread pool would fight it for the
cores) and element-wise epilogues in preallocated buffers. ``warp`` runs the kernels of
`vitaplace.kernels.warp_kernels` on ``cpu`` or ``cuda``; on CUDA a whole minibatch is one
CUDA graph and nothing leaves the device but the energies. ``auto`` picks warp when a CUDA
device exists and numpy otherwise (`vitaplace.engine.network.selection.get_backend`):
Warp's CPU path is scalar single-threaded code, far slower than BLAS on the same cores.
The tensor-core backend (precision tf32 or bf16) is `vitaplace.engine.network.tensorcores`;
``fixed``, numpy with every sum in a fixed order (the same bits under any BLAS kernel), is
`vitaplace.engine.network.fixed_order`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, Protocol, get_args

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.kernels import reference

if TYPE_CHECKING:
    from vitaplace.kernels.tiles import TileConfig

#: GEMM precisions: float32 everywhere; tf32 and bf16 run on CUDA tensor cores
#: (`tensorcores.CublasBackend`). The one spelling of them: MuPNet's ``precision`` parameter is this type.
Precision = Literal["float32", "tf32", "bf16"]
PRECISIONS: tuple[str, ...] = get_args(Precision)


class BackendError(UserError, RuntimeError):
    """A backend or precision this machine cannot run (one line)."""


def known_precision(precision: str) -> str:
    """``precision`` if it is one of `PRECISIONS`, else a one-line BackendError naming them."""
    if precision not in PRECISIONS:
        raise BackendError(f"unknown precision '{precision}'; valid: {', '.join(PRECISIONS)}")
    return precision


class Backend(Protocol):
    """What the network needs from a backend; arrays are opaque handles (float32 matrices
    unless a dtype is given)."""

    name: str
    device: str
    #: whether every sum, the solvers' curvature matrices' included, runs in an order of its own (no BLAS)
    fixed_order: bool

    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any: ...
    def to_device(self, host: np.ndarray) -> Any: ...
    def upload(self, host: np.ndarray, dst: Any) -> None: ...
    def download(self, src: Any) -> np.ndarray: ...
    def fill(self, dst: Any, value: float) -> None: ...
    def weights(self, host: np.ndarray) -> Any: ...
    def upload_weights(self, host: np.ndarray, handle: Any) -> None: ...
    def weights_to_host(self, handle: Any) -> np.ndarray: ...
    def predict(
        self, Y: Any, W: Any, X: Any, E: Any, G: Any, R: Any | None, slot: int, activation: str, slope: float,
        precision: Any | None = None,
    ) -> None: ...
    def latent_update(
        self, Y: Any, G: Any, W: Any, eta: float, E_above: Any | None, mask: Any | None,
        precision_above: Any | None = None,
    ) -> None: ...
    def column_squares(self, E: Any, out: Any) -> None: ...
    def weight_update(self, W: Any, Y: Any, G: Any, eta: float) -> None: ...
    def weight_gradient(self, D: Any, Y: Any, G: Any) -> None: ...
    def count_step(self, t: Any) -> None: ...
    def momentum_weight_step(self, W: Any, V: Any, D: Any, eta: float, beta: float) -> None: ...
    def project_rows(self, W: Any, norms: Any) -> None: ...
    def adam_weight_step(
        self, W: Any, M: Any, S: Any, D: Any, t: Any, eta: float, beta1: float, beta2: float, eps: float
    ) -> None: ...
    def gather_rows(self, src: Any, index: Any, dst: Any) -> None: ...
    def scatter_rows(self, src: Any, index: Any, dst: Any) -> None: ...
    def stop_converged(self, R: Any, limits: Any, active: Any, steps: Any) -> None: ...
    def scale_add(self, dst: Any, src: Any, alpha: float, mask: Any | None) -> None: ...
    def row_dot(self, A: Any, B: Any, weight: float, out: Any) -> None: ...
    def restart_control(self, scale: Any, plain: Any, uphill: Any, active: Any) -> None: ...
    def momentum_step(self, Y: Any, V: Any, D: Any, beta: float, restart: Any, scale: Any, active: Any) -> None: ...
    def stop_settled(
        self, R: Any, limits: Any, gnorm: Any, scale: Any, g0: Any, rtol2: float, active: Any, steps: Any
    ) -> None: ...
    def capture(self, fn: Callable[[], None]) -> Callable[[], None]: ...


class _Scratch(ABC):
    """Scratch buffers cached per (use, shape): one instance must not be used from several
    threads at once."""

    fixed_order = False

    def __init__(self) -> None:
        self._scratch: dict[tuple[str, tuple[int, ...]], Any] = {}

    @abstractmethod
    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any:
        """A zeroed array on the backend's device (each backend's own)."""

    def _buffer(self, use: str, shape: tuple[int, ...]) -> Any:
        buf = self._scratch.get((use, shape))
        if buf is None:
            buf = self._scratch[(use, shape)] = self.empty(shape)
        return buf


class _Weights(NamedTuple):
    """A layer's weights ``W`` (n_l x n_below) and a contiguous copy of their transpose ``Wt``,
    which the latent update reads (``G Wt``: row-major in the summed index, up to twice as fast
    as ``G W^T`` for the few rows a compacted inference batch has); the weight update keeps the
    two equal element for element."""

    W: Any
    Wt: Any


class NumpyBackend(_Scratch):
    """numpy + BLAS (float32 by default; float64 for gradient checks), in preallocated arrays.

    Every GEMM goes through ``np.matmul(..., out=)``, i.e. numpy's own OpenBLAS, in the
    orientation numpy picks for ``Y @ W``, ``G @ W.T`` and ``Y.T @ G``. scipy's BLAS is a
    second OpenBLAS build with its own thread pool: alternating the two pools makes each
    one's spinning worker threads steal the cores from the other (measured on 2 cores: the
    training step ran at less than half speed), so the backend never mixes them
    (bench/pc_step.py, docs/PERFORMANCE.md).
    """

    name = "numpy"
    device = "cpu"

    #: Rows of W per chunk of the weight update (GEMM into a scratch, then add).
    WEIGHT_CHUNK = 128

    def __init__(self, dtype: np.dtype | type = np.float32) -> None:
        super().__init__()
        self.dtype = np.dtype(dtype)

    def empty(self, shape: tuple[int, ...], dtype: type | None = None) -> np.ndarray:
        return np.zeros(shape, dtype=self.dtype if dtype in (None, np.float32) else dtype)

    def _matmul(self, a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
        """out = a b: every GEMM of the backend (BLAS here; `FixedOrderBackend` its own sums)."""
        np.matmul(a, b, out=out)

    def to_device(self, host: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(host, dtype=self.dtype)

    def upload(self, host: np.ndarray, dst: np.ndarray) -> None:
        np.copyto(dst, host, casting="same_kind")

    def download(self, src: np.ndarray) -> np.ndarray:
        return src.copy()

    def fill(self, dst: np.ndarray, value: float) -> None:
        dst.fill(value)

    def weights(self, host: np.ndarray) -> _Weights:
        W = np.array(host, dtype=self.dtype)
        # a copy: for a single row or column W.T is contiguous already and would be W's own memory
        return _Weights(W, np.array(W.T, order="C"))

    def upload_weights(self, host: np.ndarray, handle: _Weights) -> None:
        self.upload(host, handle.W)
        self.upload(np.asarray(host).T, handle.Wt)

    def weights_to_host(self, handle: _Weights) -> np.ndarray:
        return handle.W.copy()

    def predict(self, Y: np.ndarray, W: _Weights, X: np.ndarray, E: np.ndarray, G: np.ndarray, R: np.ndarray | None,
                slot: int, activation: str, slope: float, precision: np.ndarray | None = None) -> None:
        A = self._buffer("A", E.shape)
        self._matmul(Y, W.W, A)
        if activation == "leaky_relu" and 0.0 <= slope <= 1.0:
            # Leaky ReLU is positively homogeneous: phi(a) = phi'(a) a with
            # phi'(a) = max([a > 0], s) for 0 <= s <= 1. Four plain passes, no masked copy
            # (np.copyto(where=) alone took 9 ms of a 12 ms epilogue at 150 x 10800).
            np.greater(A, 0, out=G)
            np.maximum(G, self.dtype.type(slope), out=G)  # G = phi'(A)
            np.multiply(A, G, out=E)
            np.subtract(X, E, out=E)
            np.multiply(G, E, out=G)
        else:
            np.subtract(X, reference.activation(A, activation, slope), out=E)
            np.multiply(reference.activation_derivative(A, activation, slope), E, out=G)
        if precision is None:
            if R is not None:
                R[slot] = np.einsum("ij,ij->i", E, E)  # float32 row sums, stored as float64
            return
        np.multiply(G, precision, out=G)
        if R is not None:  # (pi E) . E: the unweighted sum's own order, so pi = 1 gives its bits
            weighted = self._buffer("weighted_error", E.shape)
            np.multiply(E, precision, out=weighted)
            R[slot] = np.einsum("ij,ij->i", weighted, E)

    def latent_update(self, Y: np.ndarray, G: np.ndarray, W: _Weights, eta: float, E_above: np.ndarray | None,
                      mask: np.ndarray | None, precision_above: np.ndarray | None = None) -> None:
        # Y <- Y + 2 eta (G W^T - pi_above E_above): GEMM into a (batch x n_l) scratch, then small passes.
        t = self._buffer("latent", Y.shape)
        self._matmul(G, W.Wt, t)
        if E_above is not None:
            if precision_above is not None:
                e = self._buffer("latent_above", Y.shape)
                np.multiply(E_above, precision_above, out=e)
                E_above = e
            np.subtract(t, E_above, out=t)
        np.multiply(t, self.dtype.type(2.0 * eta), out=t)
        if mask is not None:
            np.multiply(t, mask[:, None], out=t)
        np.add(Y, t, out=Y)

    def weight_update(self, W: _Weights, Y: np.ndarray, G: np.ndarray, eta: float) -> None:
        # W <- W + (2 eta Y)^T G by chunks of rows: a W-sized temporary would cost as much
        # memory again as W; 2 eta is folded into the small Y instead of a pass over W. The
        # same chunk is added to the columns of Wt, so Wt stays W^T exactly.
        n_l, n_below = W.W.shape
        ys = self._buffer("weight_y", Y.shape)
        np.multiply(Y, self.dtype.type(2.0 * eta), out=ys)
        step = min(self.WEIGHT_CHUNK, n_l)
        t = self._buffer("weight_t", (step, n_below))
        for i in range(0, n_l, step):
            rows = slice(i, min(i + step, n_l))
            tc = t[: rows.stop - rows.start]
            self._matmul(ys[:, rows].T, G, tc)
            np.add(W.W[rows], tc, out=W.W[rows])
            np.add(W.Wt[:, rows], tc.T, out=W.Wt[:, rows])

    def weight_gradient(self, D: np.ndarray, Y: np.ndarray, G: np.ndarray) -> None:
        # D <- (2 Y)^T G: one GEMM straight into D (it is W-sized already), 2 folded into Y
        ys = self._buffer("weight_y", Y.shape)
        np.multiply(Y, self.dtype.type(2.0), out=ys)
        self._matmul(ys.T, G, D)

    def count_step(self, t: np.ndarray) -> None:
        t += 1

    def column_squares(self, E: np.ndarray, out: np.ndarray) -> None:
        out += np.einsum("ij,ij->j", E, E, dtype=np.float64)

    def _apply_weight_step(self, W: _Weights, step: np.ndarray) -> None:
        # the same element-wise sums into W and into the columns of Wt: Wt stays W^T exactly
        np.add(W.W, step, out=W.W)
        np.add(W.Wt, step.T, out=W.Wt)

    def momentum_weight_step(self, W: _Weights, V: np.ndarray, D: np.ndarray, eta: float, beta: float) -> None:
        np.multiply(V, self.dtype.type(beta), out=V)
        np.add(V, D, out=V)
        step = self._buffer("optimizer_step", V.shape)
        np.multiply(V, self.dtype.type(eta), out=step)
        self._apply_weight_step(W, step)

    def project_rows(self, W: _Weights, norms: np.ndarray) -> None:
        W.W[...] = reference.project_rows(W.W, norms)
        W.Wt[...] = W.W.T

    def adam_weight_step(self, W: _Weights, M: np.ndarray, S: np.ndarray, D: np.ndarray, t: np.ndarray, eta: float,
                         beta1: float, beta2: float, eps: float) -> None:
        f = self.dtype.type
        step = self._buffer("optimizer_step", M.shape)
        np.multiply(M, f(beta1), out=M)
        np.multiply(D, f(1.0 - beta1), out=step)
        np.add(M, step, out=M)
        np.multiply(S, f(beta2), out=S)
        np.multiply(D, D, out=step)
        np.multiply(step, f(1.0 - beta2), out=step)
        np.add(S, step, out=S)
        n = int(t[0])
        c1, c2 = f(1.0 - beta1**n), f(1.0 - beta2**n)
        np.divide(S, c2, out=step)
        np.sqrt(step, out=step)
        np.add(step, f(eps), out=step)  # step = sqrt(S / c2) + eps
        denom = step
        num = self._buffer("optimizer_num", M.shape)
        np.divide(M, c1, out=num)
        np.divide(num, denom, out=num)
        np.multiply(num, f(eta), out=num)
        self._apply_weight_step(W, num)

    def gather_rows(self, src: np.ndarray, index: np.ndarray, dst: np.ndarray) -> None:
        np.take(src, index, axis=0, out=dst)

    def scatter_rows(self, src: np.ndarray, index: np.ndarray, dst: np.ndarray) -> None:
        dst[index] = src

    def stop_converged(self, R: np.ndarray, limits: np.ndarray, active: np.ndarray, steps: np.ndarray) -> None:
        done = np.all(R < limits[:, None], axis=0)
        active &= ~done
        steps += active

    def scale_add(self, dst: np.ndarray, src: np.ndarray, alpha: float, mask: np.ndarray | None) -> None:
        t = self._buffer("scale_add", dst.shape)
        np.multiply(src, self.dtype.type(alpha), out=t)
        if mask is not None:
            np.multiply(t, mask[:, None], out=t)
        np.add(dst, t, out=dst)

    def row_dot(self, A: np.ndarray, B: np.ndarray, weight: float, out: np.ndarray) -> None:
        out += weight * np.einsum("ij,ij->i", A, B, dtype=np.float64)

    def restart_control(self, scale: np.ndarray, plain: np.ndarray, uphill: np.ndarray, active: np.ndarray) -> None:
        live = active != 0
        restart = uphill > 0
        scale[live & restart & (plain != 0)] *= 0.5
        uphill[live] = restart[live]
        plain[live] = restart[live]

    def momentum_step(self, Y: np.ndarray, V: np.ndarray, D: np.ndarray, beta: float, restart: np.ndarray,
                      scale: np.ndarray, active: np.ndarray) -> None:
        live = active != 0
        keep = np.where(live & ~(restart > 0), beta, 0.0).astype(self.dtype)
        d = self._buffer("momentum", D.shape)
        np.multiply(D, np.where(live, scale, 0.0).astype(self.dtype)[:, None], out=d)
        np.multiply(V, keep[:, None], out=V)
        np.add(V, d, out=V)
        np.add(Y, d, out=Y)
        np.multiply(V, self.dtype.type(beta), out=d)
        np.add(Y, d, out=Y)

    def stop_settled(self, R: np.ndarray, limits: np.ndarray, gnorm: np.ndarray, scale: np.ndarray, g0: np.ndarray,
                     rtol2: float, active: np.ndarray, steps: np.ndarray) -> None:
        done = np.all(R < limits[:, None], axis=0) | (scale * scale * gnorm < rtol2 * g0)
        active &= ~done
        steps += active

    def capture(self, fn: Callable[[], None]) -> Callable[[], None]:
        return fn


class WarpBackend(_Scratch):
    """Warp kernels on ``cpu`` or ``cuda``; on CUDA, captured sequences replay as CUDA graphs.

    Arrays are ``wp.array``; a weight handle is opaque (`Backend`): a `_Weights` here, the
    tensor-core subclass's own in `tensorcores.CublasBackend`, hence ``Any``."""

    name = "warp"

    def __init__(self, device: str | None = None) -> None:
        import warp as wp

        from vitaplace.kernels import solver_kernels, warp_kernels  # imported lazily: compiles on first use

        super().__init__()
        self._wp = wp
        self._kernels = warp_kernels
        self._solver_kernels = solver_kernels
        wp.init()
        self.device = device or ("cuda" if wp.is_cuda_available() else "cpu")
        self._device = wp.get_device(self.device)

    def _tiles(self, kernel: str, rows: int) -> TileConfig:
        return self._kernels.tile_config(self._device, kernel, rows)

    _DTYPES = {np.dtype(np.float32): "float32", np.dtype(np.float64): "float64", np.dtype(np.int32): "int32"}

    def _wp_dtype(self, dtype: type | np.dtype) -> Any:
        return getattr(self._wp, self._DTYPES[np.dtype(dtype)])

    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any:
        return self._wp.zeros(shape, dtype=self._wp_dtype(dtype), device=self.device)

    def to_device(self, host: np.ndarray) -> Any:
        host = np.ascontiguousarray(host, dtype=np.float32)
        return self._wp.array(host, dtype=self._wp.float32, device=self.device)

    def upload(self, host: np.ndarray, dst: Any) -> None:
        host = np.ascontiguousarray(host, dtype=self._wp.dtype_to_numpy(dst.dtype))
        src: Any = self._wp.array(host, dtype=dst.dtype, device="cpu")
        self._wp.copy(dst, src)

    def download(self, src: Any) -> np.ndarray:
        return src.numpy().copy()

    def fill(self, dst: Any, value: float) -> None:
        dst.fill_(value)

    def weights(self, host: np.ndarray) -> Any:
        """``W`` and its transpose ``Wt`` (read by the latent update), kept in step by
        the weight update."""
        return _Weights(self.to_device(host), self.to_device(np.asarray(host).T))

    def upload_weights(self, host: np.ndarray, handle: Any) -> None:
        self.upload(host, handle.W)
        self.upload(np.asarray(host).T, handle.Wt)

    def weights_to_host(self, handle: Any) -> np.ndarray:
        return handle.W.numpy().copy()

    def predict(self, Y: Any, W: Any, X: Any, E: Any, G: Any, R: Any | None, slot: int, activation: str,
                slope: float, precision: Any | None = None) -> None:
        k = self._kernels
        tiles = self._tiles("predict", Y.shape[0])
        partial = (None if R is None
                   else self._buffer("row_partial", k.row_partial_shape(Y.shape[0], W.W.shape[1], tiles)))
        k.predict(Y, W.W, X, E, G, partial, R, slot, activation=activation, slope=slope, tiles=tiles,
                  precision=precision)

    def latent_update(self, Y: Any, G: Any, W: Any, eta: float, E_above: Any | None, mask: Any | None,
                      precision_above: Any | None = None) -> None:
        k = self._kernels
        tiles = self._tiles("latent", Y.shape[0])
        shape = k.latent_scratch_shape(Y.shape[0], Y.shape[1], W.W.shape[1], self._device, tiles)
        scratch = self._buffer("latent", shape) if shape[0] else None
        k.latent_update(Y, G, W.Wt, eta, scratch, E_above=E_above, mask=mask, tiles=tiles,
                        precision_above=precision_above)

    def weight_update(self, W: Any, Y: Any, G: Any, eta: float) -> None:
        self._kernels.weight_update(W.W, Y, G, eta, Wt=W.Wt, tiles=self._tiles("weight", Y.shape[0]))

    def weight_gradient(self, D: Any, Y: Any, G: Any) -> None:
        # the weight kernel on zeroed "weights" D at eta 1: D <- 0 + 2 Y^T G
        D.zero_()
        self._kernels.weight_update(D, Y, G, 1.0, tiles=self._tiles("weight", Y.shape[0]))

    def count_step(self, t: Any) -> None:
        self._kernels.count_step(t)

    def column_squares(self, E: Any, out: Any) -> None:
        self._kernels.column_squares(E, out)

    def momentum_weight_step(self, W: Any, V: Any, D: Any, eta: float, beta: float) -> None:
        self._kernels.momentum_weight_step(W.W, V, D, eta, beta, Wt=W.Wt)

    def project_rows(self, W: Any, norms: Any) -> None:
        self._kernels.project_rows(W.W, norms, Wt=W.Wt)

    def adam_weight_step(self, W: Any, M: Any, S: Any, D: Any, t: Any, eta: float, beta1: float, beta2: float,
                         eps: float) -> None:
        self._kernels.adam_weight_step(W.W, M, S, D, t, eta, beta1, beta2, eps, Wt=W.Wt)

    def gather_rows(self, src: Any, index: Any, dst: Any) -> None:
        self._kernels.gather_rows(src, index, dst)

    def scatter_rows(self, src: Any, index: Any, dst: Any) -> None:
        self._kernels.scatter_rows(src, index, dst)

    def stop_converged(self, R: Any, limits: Any, active: Any, steps: Any) -> None:
        self._kernels.stop_converged(R, limits, active, steps)

    def scale_add(self, dst: Any, src: Any, alpha: float, mask: Any | None) -> None:
        self._solver_kernels.scale_add(dst, src, alpha, mask)

    def row_dot(self, A: Any, B: Any, weight: float, out: Any) -> None:
        self._solver_kernels.row_dot(A, B, weight, out)

    def restart_control(self, scale: Any, plain: Any, uphill: Any, active: Any) -> None:
        self._solver_kernels.restart_control(scale, plain, uphill, active)

    def momentum_step(self, Y: Any, V: Any, D: Any, beta: float, restart: Any, scale: Any, active: Any) -> None:
        self._solver_kernels.momentum_step(Y, V, D, beta, restart, scale, active)

    def stop_settled(self, R: Any, limits: Any, gnorm: Any, scale: Any, g0: Any, rtol2: float, active: Any,
                     steps: Any) -> None:
        self._solver_kernels.stop_settled(R, limits, gnorm, scale, g0, rtol2, active, steps)

    def capture(self, fn: Callable[[], None]) -> Callable[[], None]:
        """Compile every kernel ``fn`` launches, in parallel, then return its replay: on
        CUDA ``fn`` runs once directly (allocating its scratch), is recorded as a CUDA graph
        the next time, and that graph is replayed from then on; elsewhere ``fn`` itself."""
        with self._kernels.planned_kernels() as plan:
            fn()
        self._kernels.preload(self._device, plan)
        if not self._device.is_cuda:
            return fn
        wp = self._wp
        graph = None
        calls = 0

        def replay() -> None:
            nonlocal graph, calls
            calls += 1
            if calls == 1:
                fn()
                return
            if graph is None:
                with wp.ScopedCapture(device=self._device, force_module_load=False) as capture:
                    fn()
                graph = capture.graph
            wp.capture_launch(graph)

        return replay
