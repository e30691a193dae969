"""The tensor-core backend: `CublasBackend` (``precision`` tf32 or bf16, CUDA only) is the
Warp backend (`vitaplace.engine.network.backends.WarpBackend`) with its GEMMs moved to cuBLAS
on tensor cores: TF32, or bfloat16 operands (bfloat16 copies of the weights, latents and
gains made by Warp kernels); accumulation, the weights, latents and errors stay float32, the
epilogues stay fused Warp kernels on the same stream, and a minibatch is still one CUDA graph.
cuBLAS is called through ctypes (`Cublas`: libcublas, as shipped with PyTorch or the
``nvidia-cublas`` wheel): nothing of it is needed on the CPU. `StreamOrder` orders the
operations of small edges run on a second stream.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import site
import sys
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import numpy as np

from vitaplace.engine.base.libraries import first_loadable
from vitaplace.engine.network.backends import BackendError, WarpBackend, known_precision

__all__ = ["Cublas", "CublasBackend", "StreamOrder", "row_major_gemm"]


class _LowWeights(NamedTuple):
    W: Any
    low: Any  # W rounded to bfloat16 (bf16 precision), else None


# cuBLAS enumerations (cublas_api.h, library_types.h)
_OP = {False: 0, True: 1}  # CUBLAS_OP_N, CUBLAS_OP_T
_CUDA_R_32F, _CUDA_R_16BF = 0, 14
_COMPUTE = {"float32": 68, "tf32": 77, "bf16": 68}  # CUBLAS_COMPUTE_32F, CUBLAS_COMPUTE_32F_FAST_TF32
_GEMM_DEFAULT = -1
#: cuBLAS workspace (Hopper wants 32 MiB): set explicitly so that no GEMM allocates while a
#: CUDA graph is being captured.
_WORKSPACE_BYTES = 32 << 20


def _load_cublas() -> ctypes.CDLL:
    """libcublas from the loader's path, or from the ``nvidia`` wheels (PyTorch's own)."""
    wheels = (path for base in site.getsitepackages() + [site.getusersitepackages()] + sys.path
              for path in sorted(glob.glob(f"{base}/nvidia/**/libcublas.so*", recursive=True), reverse=True))
    found = first_loadable(("libcublas.so.13", "libcublas.so.12", "libcublas.so")) or first_loadable(wheels)
    if found is not None:
        return found
    raise BackendError("precision tf32/bf16 needs libcublas and none was found; pip install nvidia-cublas "
                       "(it comes with PyTorch's CUDA wheels)")


class Cublas:
    """One cuBLAS handle on the Warp stream of a CUDA device (ctypes), with its own workspace."""

    def __init__(self, device: Any) -> None:
        import warp as wp

        self._wp, self._device = wp, device
        self._lib = _load_cublas()
        handle = ctypes.c_void_p()
        self._check(self._lib.cublasCreate_v2(ctypes.byref(handle)), "cublasCreate")
        self._handle = handle
        self._workspaces: dict[int, Any] = {}  # one per stream: streams may run GEMMs at once
        self._stream = None

    def _check(self, status: int, what: str) -> None:
        if status != 0:
            raise RuntimeError(f"{what} failed with cuBLAS status {status}")

    def _bind_stream(self) -> None:
        """Follow Warp's current stream of the device (setting a stream resets the workspace)."""
        stream = self._wp.get_stream(self._device).cuda_stream
        if stream != self._stream:
            if stream not in self._workspaces:
                self._workspaces[stream] = self._wp.empty(_WORKSPACE_BYTES, dtype=self._wp.uint8, device=self._device)
            self._check(self._lib.cublasSetStream_v2(self._handle, ctypes.c_void_p(stream)), "cublasSetStream")
            self._check(self._lib.cublasSetWorkspace_v2(self._handle, ctypes.c_void_p(self._workspaces[stream].ptr),
                                                        ctypes.c_size_t(_WORKSPACE_BYTES)), "cublasSetWorkspace")
            self._stream = stream

    def gemm_ex(self, trans_a: int, trans_b: int, m: int, n: int, k: int, alpha: float, a: int, a_type: int, lda: int,
                b: int, b_type: int, ldb: int, beta: float, c: int, c_type: int, ldc: int, compute: int) -> None:
        """``cublasGemmEx`` (column-major); alpha and beta are host float32 scalars."""
        self._bind_stream()
        i, p = ctypes.c_int, ctypes.c_void_p
        alpha_, beta_ = ctypes.c_float(alpha), ctypes.c_float(beta)
        status = self._lib.cublasGemmEx(
            self._handle, i(trans_a), i(trans_b), i(m), i(n), i(k), ctypes.byref(alpha_), p(a), i(a_type), i(lda),
            p(b), i(b_type), i(ldb), ctypes.byref(beta_), p(c), i(c_type), i(ldc), i(compute), i(_GEMM_DEFAULT),
        )
        self._check(status, "cublasGemmEx")


def row_major_gemm(blas: Any, precision: str, C: Any, A: Any, B: Any, trans_a: bool = False, trans_b: bool = False,
                   alpha: float = 1.0, beta: float = 0.0) -> None:
    """``C = alpha op(A) op(B) + beta C`` on row-major Warp arrays through a column-major
    ``blas.gemm_ex``: the row-major C is the column-major C^T = op(B)^T op(A)^T, and a
    row-major matrix read as column-major is its transpose, so B comes first, each operand
    keeps its own transpose flag, and every leading dimension is a row length.
    C float32; A and B bfloat16 for ``bf16``, float32 otherwise."""
    m, n = C.shape
    k = A.shape[0] if trans_a else A.shape[1]
    operand = _CUDA_R_16BF if precision == "bf16" else _CUDA_R_32F
    blas.gemm_ex(_OP[trans_b], _OP[trans_a], n, m, k, alpha, B.ptr, operand, B.shape[1], A.ptr, operand, A.shape[1],
                 beta, C.ptr, _CUDA_R_32F, n, _COMPUTE[precision])


class StreamOrder:
    """Program order of buffer accesses across streams (a hazard tracker over buffer keys).

    :meth:`waits` names the streams an operation about to run on ``stream`` must wait for:
    the last writer of every buffer it reads or writes, and every stream that read a buffer
    it writes since that buffer was last written. :meth:`joined` records that ``into``
    waited for everything issued on ``other`` so far."""

    def __init__(self) -> None:
        self._writer: dict[Any, Any] = {}
        self._readers: dict[Any, list[Any]] = {}

    def waits(self, stream: Any, reads: tuple, writes: tuple) -> list[Any]:
        deps: list[Any] = []

        def need(other: Any) -> None:
            if other is not None and other is not stream and not any(other is d for d in deps):
                deps.append(other)

        for key in (*reads, *writes):
            need(self._writer.get(key))
        for key in writes:
            for reader in self._readers.get(key, ()):
                need(reader)
        for key in reads:
            readers = self._readers.setdefault(key, [])
            if not any(r is stream for r in readers):
                readers.append(stream)
        for key in writes:
            self._writer[key], self._readers[key] = stream, []
        return deps

    def joined(self, into: Any, other: Any) -> None:
        for key, writer in self._writer.items():
            if writer is other:
                self._writer[key] = into
        for key, readers in self._readers.items():
            if any(r is other for r in readers):
                self._readers[key] = [r for r in readers if r is not other and r is not into] + [into]


class CublasBackend(WarpBackend):
    """The Warp backend with its GEMMs in cuBLAS at ``precision`` (module docstring).

    ``blas`` replaces cuBLAS (an object with :meth:`Cublas.gemm_ex`): with a host
    implementation the whole path runs on Warp's CPU device, for tests.

    ``small_edges_beside`` (CUDA): the operations of edges whose weights have fewer
    elements run on a second stream, beside the big edge's, ordered against everything
    else by the buffers they read and write (`StreamOrder`); the captured minibatch forks
    to that stream at its start and joins it at its end (0: one stream)."""

    name = "warp"

    def __init__(self, precision: str = "bf16", device: str | None = None, blas: Any = None,
                 small_edges_beside: int = 0) -> None:
        known_precision(precision)
        super().__init__(device)
        if blas is None:
            if not self._device.is_cuda:
                raise BackendError(f"precision '{precision}' needs a CUDA device, not '{self.device}'")
            blas = Cublas(self._device)
        if small_edges_beside and not self._device.is_cuda:
            raise BackendError("small_edges_beside needs a CUDA device (streams)")
        self.precision = precision
        self._blas = blas
        self._low: dict[tuple[str, int, tuple[int, ...]], Any] = {}
        self._beside = small_edges_beside
        self._lane = ""  # scratch buffers are per stream ("" main, "@side")
        if small_edges_beside:
            self._main, self._side = self._wp.get_stream(self._device), self._wp.Stream(self._device)
            self._order = StreamOrder()

    # ---------------------------------------------------------------- streams
    @staticmethod
    def _key(x: Any) -> Any:
        return x if isinstance(x, tuple) else x.W.ptr if isinstance(x, _LowWeights) else x.ptr

    @contextlib.contextmanager
    def _stream_for(self, W: _LowWeights | None, reads: tuple, writes: tuple) -> Iterator[None]:
        """Run the block on the stream of edge ``W`` (None: the main stream), after the waits
        that keep its reads and writes in order."""
        if not self._beside:
            yield
            return
        side = W is not None and W.W.size < self._beside
        stream = self._side if side else self._main
        keys = lambda xs: tuple(self._key(x) for x in xs if x is not None)  # noqa: E731
        for other in self._order.waits(stream, keys(reads), keys(writes)):
            stream.wait_stream(other)
        self._lane = "@side" if side else ""
        try:
            with self._wp.ScopedStream(stream, sync_enter=False):
                yield
        finally:
            self._lane = ""

    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any:
        return self._made_on_main(super().empty(shape, dtype))

    def to_device(self, host: np.ndarray) -> Any:
        return self._made_on_main(super().to_device(host))

    def _made_on_main(self, arr: Any) -> Any:
        """A new array filled on the main stream: later reads on the side stream wait for it."""
        if self._beside:
            self._order.waits(self._main, (), (self._key(arr),))
        return arr

    def _join(self) -> None:
        """The main stream waits for everything issued on the side stream."""
        if self._beside:
            self._main.wait_stream(self._side)
            self._order.joined(self._main, self._side)

    def capture(self, fn: Callable[[], None]) -> Callable[[], None]:
        if not self._beside:
            return super().capture(fn)

        def forked() -> None:
            self._side.wait_stream(self._main)
            fn()
            self._join()

        return super().capture(forked)

    def _buffer(self, use: str, shape: tuple[int, ...]) -> Any:
        return super()._buffer(use + self._lane, shape)

    # ---------------------------------------------------------------- host transfers
    def upload(self, host: np.ndarray, dst: Any) -> None:
        self._join()
        with self._stream_for(None, (), (dst,)):
            super().upload(host, dst)

    def download(self, src: Any) -> np.ndarray:
        self._join()
        return super().download(src)

    def weights_to_host(self, handle: _LowWeights) -> np.ndarray:
        self._join()
        return super().weights_to_host(handle)

    # ---------------------------------------------------------------- precision
    def _gemm(self, C: Any, A: Any, B: Any, trans_a: bool = False, trans_b: bool = False, alpha: float = 1.0,
              beta: float = 0.0) -> None:
        if not self._kernels.planning():  # a planning pass only records the Warp kernels
            row_major_gemm(self._blas, self.precision, C, A, B, trans_a, trans_b, alpha, beta)

    def _low_buffer(self, use: str, of: Any) -> Any:
        """A bfloat16 array shaped like ``of``, one per (use, array, stream)."""
        key = (use + self._lane, of.ptr, tuple(of.shape))
        buf = self._low.get(key)
        if buf is None:
            buf = self._low[key] = self._wp.zeros(of.shape, dtype=self._wp.bfloat16, device=self.device)
        return buf

    def _operand(self, X: Any) -> Any:
        """A GEMM operand at the working precision (bf16: a fresh rounded copy)."""
        if self.precision != "bf16":
            return X
        low = self._low_buffer("operand", X)
        self._kernels.to_bfloat16(X, low)
        return low

    def weights(self, host: np.ndarray) -> _LowWeights:
        W = self.to_device(host)
        handle = _LowWeights(W, self._low_buffer("weights", W) if self.precision == "bf16" else None)
        self._round_weights(handle)  # on the main stream, after W's upload there
        return handle

    def _round_weights(self, handle: _LowWeights) -> None:
        if handle.low is not None:
            self._kernels.to_bfloat16(handle.W, handle.low)

    def upload_weights(self, host: np.ndarray, handle: _LowWeights) -> None:
        self.upload(host, handle.W)
        with self._stream_for(None, (handle,), (handle,)):
            self._round_weights(handle)

    # ---------------------------------------------------------------- the step
    def predict(self, Y: Any, W: _LowWeights, X: Any, E: Any, G: Any, R: Any | None, slot: int, activation: str,
                slope: float, precision: Any | None = None) -> None:
        with self._stream_for(W, (Y, W, X, precision), (E, G, None if R is None else (R.ptr, slot))):
            k = self._kernels
            A = self._buffer("product", tuple(E.shape))
            self._gemm(A, self._operand(Y), W.W if W.low is None else W.low)
            tiles = self._tiles("predict", Y.shape[0])
            shape = k.row_partial_shape(Y.shape[0], W.W.shape[1], tiles)
            partial = None if R is None else self._buffer("row_partial", shape)
            G_low = self._low_buffer("gain", G) if self.precision == "bf16" else None
            k.predict_epilogue(A, X, E, G, partial, R, slot, activation=activation, slope=slope, G_low=G_low,
                               tiles=tiles, precision=precision)

    def _gain(self, G: Any) -> Any:
        """G at the working precision: its bfloat16 copy, written by the last predict."""
        return self._low_buffer("gain", G) if self.precision == "bf16" else G

    def latent_update(self, Y: Any, G: Any, W: _LowWeights, eta: float, E_above: Any | None, mask: Any | None,
                      precision_above: Any | None = None) -> None:
        with self._stream_for(W, (G, W, E_above, mask, precision_above), (Y,)):
            D = self._buffer("latent", tuple(Y.shape))
            self._gemm(D, self._gain(G), W.W if W.low is None else W.low, trans_b=True)
            self._kernels.latent_apply(Y, D, eta, E_above=E_above, mask=mask, precision_above=precision_above)

    def weight_update(self, W: _LowWeights, Y: Any, G: Any, eta: float) -> None:
        # W <- W + 2 eta Y^T G accumulated by cuBLAS in float32 into the float32 master copy
        with self._stream_for(W, (Y, G), (W,)):
            self._gemm(W.W, self._operand(Y), self._gain(G), trans_a=True, alpha=2.0 * eta, beta=1.0)
            self._round_weights(W)

    def weight_gradient(self, D: Any, Y: Any, G: Any) -> None:
        # D <- 2 Y^T G by cuBLAS (beta 0: D's old contents are not read); D belongs to W's edge
        with self._stream_for(None, (Y, G), (D,)):
            self._gemm(D, self._operand(Y), self._gain(G), trans_a=True, alpha=2.0, beta=0.0)

    def count_step(self, t: Any) -> None:
        with self._stream_for(None, (t,), (t,)):
            super().count_step(t)

    def column_squares(self, E: Any, out: Any) -> None:
        with self._stream_for(None, (E, out), (out,)):
            super().column_squares(E, out)

    def momentum_weight_step(self, W: _LowWeights, V: Any, D: Any, eta: float, beta: float) -> None:
        with self._stream_for(None, (V, D), (W, V)):
            self._kernels.momentum_weight_step(W.W, V, D, eta, beta)
            self._round_weights(W)

    def project_rows(self, W: _LowWeights, norms: Any) -> None:
        with self._stream_for(None, (norms,), (W,)):
            self._kernels.project_rows(W.W, norms)
            self._round_weights(W)

    def adam_weight_step(self, W: _LowWeights, M: Any, S: Any, D: Any, t: Any, eta: float, beta1: float,
                         beta2: float, eps: float) -> None:
        with self._stream_for(None, (M, S, D, t), (W, M, S)):
            self._kernels.adam_weight_step(W.W, M, S, D, t, eta, beta1, beta2, eps)
            self._round_weights(W)

    # ---------------------------------------------------------------- rows, stopping
    def fill(self, dst: Any, value: float) -> None:
        with self._stream_for(None, (), (dst,)):
            super().fill(dst, value)

    def gather_rows(self, src: Any, index: Any, dst: Any) -> None:
        with self._stream_for(None, (src, index), (dst,)):
            super().gather_rows(src, index, dst)

    def scatter_rows(self, src: Any, index: Any, dst: Any) -> None:
        with self._stream_for(None, (src, index), (dst,)):
            super().scatter_rows(src, index, dst)

    def stop_converged(self, R: Any, limits: Any, active: Any, steps: Any) -> None:
        self._join()  # reads every edge's row energies
        with self._stream_for(None, (limits,), (active, steps)):
            super().stop_converged(R, limits, active, steps)

    # the solvers' vector steps: on the main stream, after everything the side stream issued
    def scale_add(self, dst: Any, src: Any, alpha: float, mask: Any | None) -> None:
        self._join()
        with self._stream_for(None, (src, mask), (dst,)):
            super().scale_add(dst, src, alpha, mask)

    def row_dot(self, A: Any, B: Any, weight: float, out: Any) -> None:
        self._join()
        with self._stream_for(None, (A, B), (out,)):
            super().row_dot(A, B, weight, out)

    def restart_control(self, scale: Any, plain: Any, uphill: Any, active: Any) -> None:
        self._join()
        with self._stream_for(None, (active,), (scale, plain, uphill)):
            super().restart_control(scale, plain, uphill, active)

    def momentum_step(self, Y: Any, V: Any, D: Any, beta: float, restart: Any, scale: Any, active: Any) -> None:
        self._join()
        with self._stream_for(None, (D, restart, scale, active), (Y, V)):
            super().momentum_step(Y, V, D, beta, restart, scale, active)

    def stop_settled(self, R: Any, limits: Any, gnorm: Any, scale: Any, g0: Any, rtol2: float, active: Any,
                     steps: Any) -> None:
        self._join()
        with self._stream_for(None, (limits, gnorm, scale, g0), (active, steps)):
            super().stop_settled(R, limits, gnorm, scale, g0, rtol2, active, steps)
