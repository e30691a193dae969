"""Compute backends for the predictive-coding layer steps.

A backend owns array storage and the operations the network is built from:

    weights(W) / upload_weights(W, h) / weights_to_host(h)
                                      a layer's weights onto the device (new, or in place) and back
    predict(Y, W, X, E, G, R, k)      A = Y W, E = X - phi(A), G = phi'(A) * E, and with R:
                                      R[k, r] = sum_c E[r, c]^2   (per-sample energy, float64)
    latent_update(Y, G, W, eta, E_up, mask)
                                      Y <- Y + 2 eta mask * (G W^T - E_up)      (-eta dF/dY)
    weight_update(W, Y, G, eta)       W <- W + 2 eta (Y^T G)                    (-eta dF/dW)
    gather_rows / scatter_rows        minibatch rows of a resident store, by an index array
    stop_converged(R, limits, active, steps)   per-sample stopping of inference
    capture(fn)                       a replayable recording of fn's launches (a CUDA graph)

``numpy`` runs them with float32 BLAS through ``np.matmul(..., out=)`` (numpy's own
OpenBLAS only: never alternated with scipy's, whose thread pool would fight it for the
cores) and element-wise epilogues in preallocated buffers. ``warp`` runs the kernels of
`vitaplace.kernels.warp_kernels` on ``cpu`` or ``cuda``; on CUDA a whole minibatch is one
CUDA graph and nothing leaves the device but the energies. ``auto`` picks warp when a CUDA
device exists and numpy otherwise: Warp's CPU path is scalar single-threaded code, far
slower than BLAS on the same cores.

``CublasBackend`` (``precision`` tf32 or bf16, CUDA only) is the Warp backend with its
GEMMs moved to cuBLAS on tensor cores: TF32, or bfloat16 operands (bfloat16 copies of the
weights, latents and gains made by Warp kernels); accumulation, the weights, latents and
errors stay float32, the epilogues stay fused Warp kernels on the same stream, and a
minibatch is still one CUDA graph. cuBLAS is called through ctypes (libcublas, as shipped
with PyTorch or the ``nvidia-cublas`` wheel): nothing of it is needed on the CPU.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import site
import sys
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple, Protocol

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.kernels import reference

BACKENDS = ("auto", "numpy", "warp")
#: GEMM precisions: float32 everywhere; tf32 and bf16 run on CUDA tensor cores (CublasBackend).
PRECISIONS = ("float32", "tf32", "bf16")


class BackendError(UserError, RuntimeError):
    """A backend or precision this machine cannot run (one line)."""


class Backend(Protocol):
    """What the network needs from a backend; arrays are opaque handles (float32 matrices
    unless a dtype is given)."""

    name: str
    device: str

    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any: ...
    def to_device(self, host: np.ndarray) -> Any: ...
    def upload(self, host: np.ndarray, dst: Any) -> None: ...
    def download(self, src: Any) -> np.ndarray: ...
    def fill(self, dst: Any, value: float) -> None: ...
    def weights(self, host: np.ndarray) -> Any: ...
    def upload_weights(self, host: np.ndarray, handle: Any) -> None: ...
    def weights_to_host(self, handle: Any) -> np.ndarray: ...
    def predict(
        self, Y: Any, W: Any, X: Any, E: Any, G: Any, R: Any | None, slot: int, activation: str, slope: float
    ) -> None: ...
    def latent_update(self, Y: Any, G: Any, W: Any, eta: float, E_above: Any | None, mask: Any | None) -> None: ...
    def weight_update(self, W: Any, Y: Any, G: Any, eta: float) -> None: ...
    def gather_rows(self, src: Any, index: Any, dst: Any) -> None: ...
    def scatter_rows(self, src: Any, index: Any, dst: Any) -> None: ...
    def stop_converged(self, R: Any, limits: Any, active: Any, steps: Any) -> None: ...
    def capture(self, fn: Callable[[], None]) -> Callable[[], None]: ...


class _Scratch:
    """Scratch buffers cached per (use, shape): one instance must not be used from several
    threads at once."""

    def __init__(self) -> None:
        self._scratch: dict[tuple[str, tuple[int, ...]], Any] = {}

    def _buffer(self, use: str, shape: tuple[int, ...]) -> Any:
        buf = self._scratch.get((use, shape))
        if buf is None:
            buf = self._scratch[(use, shape)] = self.empty(shape)
        return buf


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

    def to_device(self, host: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(host, dtype=self.dtype)

    def upload(self, host: np.ndarray, dst: np.ndarray) -> None:
        np.copyto(dst, host, casting="same_kind")

    def download(self, src: np.ndarray) -> np.ndarray:
        return src.copy()

    def fill(self, dst: np.ndarray, value: float) -> None:
        dst.fill(value)

    def weights(self, host: np.ndarray) -> np.ndarray:
        return np.array(host, dtype=self.dtype)

    def upload_weights(self, host: np.ndarray, handle: np.ndarray) -> None:
        self.upload(host, handle)

    def weights_to_host(self, handle: np.ndarray) -> np.ndarray:
        return handle.copy()

    def predict(self, Y, W, X, E, G, R, slot: int, activation: str, slope: float) -> None:
        A = self._buffer("A", E.shape)
        np.matmul(Y, W, out=A)
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
        if R is not None:
            R[slot] = np.einsum("ij,ij->i", E, E)  # float32 row sums, stored as float64

    def latent_update(self, Y, G, W, eta: float, E_above, mask) -> None:
        # Y <- Y + 2 eta (G W^T - E_above): GEMM into a (batch x n_l) scratch, then small passes.
        t = self._buffer("latent", Y.shape)
        np.matmul(G, W.T, out=t)
        if E_above is not None:
            np.subtract(t, E_above, out=t)
        np.multiply(t, self.dtype.type(2.0 * eta), out=t)
        if mask is not None:
            np.multiply(t, mask[:, None], out=t)
        np.add(Y, t, out=Y)

    def weight_update(self, W, Y, G, eta: float) -> None:
        # W <- W + (2 eta Y)^T G by chunks of rows: a W-sized temporary would cost as much
        # memory again as W; 2 eta is folded into the small Y instead of a pass over W.
        n_l, n_below = W.shape
        ys = self._buffer("weight_y", Y.shape)
        np.multiply(Y, self.dtype.type(2.0 * eta), out=ys)
        step = min(self.WEIGHT_CHUNK, n_l)
        t = self._buffer("weight_t", (step, n_below))
        for i in range(0, n_l, step):
            rows = slice(i, min(i + step, n_l))
            tc = t[: rows.stop - rows.start]
            np.matmul(ys[:, rows].T, G, out=tc)
            np.add(W[rows], tc, out=W[rows])

    def gather_rows(self, src, index, dst) -> None:
        np.take(src, index, axis=0, out=dst)

    def scatter_rows(self, src, index, dst) -> None:
        dst[index] = src

    def stop_converged(self, R, limits, active, steps) -> None:
        done = np.all(R < limits[:, None], axis=0)
        active &= ~done
        steps += active

    def capture(self, fn: Callable[[], None]) -> Callable[[], None]:
        return fn


class _Weights(NamedTuple):
    W: Any
    Wt: Any


class WarpBackend(_Scratch):
    """Warp kernels on ``cpu`` or ``cuda``; on CUDA, captured sequences replay as CUDA graphs."""

    name = "warp"

    def __init__(self, device: str | None = None) -> None:
        from vitaplace.kernels import warp_kernels  # imported lazily: compiles on first use

        import warp as wp

        super().__init__()
        self._wp = wp
        self._kernels = warp_kernels
        wp.init()
        self.device = device or ("cuda" if wp.is_cuda_available() else "cpu")
        self._device = wp.get_device(self.device)

    def _tiles(self, kernel: str, rows: int):
        return self._kernels.tile_config(self._device, kernel, rows)

    _DTYPES = {np.dtype(np.float32): "float32", np.dtype(np.float64): "float64", np.dtype(np.int32): "int32"}

    def _wp_dtype(self, dtype) -> Any:
        return getattr(self._wp, self._DTYPES[np.dtype(dtype)])

    def empty(self, shape: tuple[int, ...], dtype: type = np.float32) -> Any:
        return self._wp.zeros(shape, dtype=self._wp_dtype(dtype), device=self.device)

    def to_device(self, host: np.ndarray) -> Any:
        host = np.ascontiguousarray(host, dtype=np.float32)
        return self._wp.array(host, dtype=self._wp.float32, device=self.device)

    def upload(self, host: np.ndarray, dst: Any) -> None:
        host = np.ascontiguousarray(host, dtype=self._wp.dtype_to_numpy(dst.dtype))
        src = self._wp.array(host, dtype=dst.dtype, device="cpu")
        self._wp.copy(dst, src)

    def download(self, src: Any) -> np.ndarray:
        return src.numpy().copy()

    def fill(self, dst: Any, value: float) -> None:
        dst.fill_(value)

    def weights(self, host: np.ndarray) -> _Weights:
        """``W`` and its transpose ``Wt`` (read by the latent update), kept in step by
        the weight update."""
        return _Weights(self.to_device(host), self.to_device(np.asarray(host).T))

    def upload_weights(self, host: np.ndarray, handle: _Weights) -> None:
        self.upload(host, handle.W)
        self.upload(np.asarray(host).T, handle.Wt)

    def weights_to_host(self, handle: _Weights) -> np.ndarray:
        return handle.W.numpy().copy()

    def predict(self, Y, W: _Weights, X, E, G, R, slot: int, activation: str, slope: float) -> None:
        k = self._kernels
        tiles = self._tiles("predict", Y.shape[0])
        partial = None if R is None else self._buffer("row_partial", k.row_partial_shape(Y.shape[0], W.W.shape[1], tiles))
        k.predict(Y, W.W, X, E, G, partial, R, slot, activation=activation, slope=slope, tiles=tiles)

    def latent_update(self, Y, G, W: _Weights, eta: float, E_above, mask) -> None:
        k = self._kernels
        tiles = self._tiles("latent", Y.shape[0])
        shape = k.latent_scratch_shape(Y.shape[0], Y.shape[1], W.W.shape[1], self._device, tiles)
        scratch = self._buffer("latent", shape) if shape[0] else None
        k.latent_update(Y, G, W.Wt, eta, scratch, E_above=E_above, mask=mask, tiles=tiles)

    def weight_update(self, W: _Weights, Y, G, eta: float) -> None:
        self._kernels.weight_update(W.W, Y, G, eta, Wt=W.Wt, tiles=self._tiles("weight", Y.shape[0]))

    def gather_rows(self, src, index, dst) -> None:
        self._kernels.gather_rows(src, index, dst)

    def scatter_rows(self, src, index, dst) -> None:
        self._kernels.scatter_rows(src, index, dst)

    def stop_converged(self, R, limits, active, steps) -> None:
        self._kernels.stop_converged(R, limits, active, steps)

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
    for name in ("libcublas.so.13", "libcublas.so.12", "libcublas.so"):
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    for base in site.getsitepackages() + [site.getusersitepackages()] + sys.path:
        for path in sorted(glob.glob(f"{base}/nvidia/**/libcublas.so*", recursive=True), reverse=True):
            try:
                return ctypes.CDLL(path)
            except OSError:
                continue
    raise BackendError("precision tf32/bf16 needs libcublas and none was found; pip install nvidia-cublas "
                       "(it comes with PyTorch's CUDA wheels)")


class Cublas:
    """One cuBLAS handle on the Warp stream of a CUDA device (ctypes), with its own workspace."""

    def __init__(self, device) -> None:
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


def row_major_gemm(blas, precision: str, C, A, B, trans_a: bool = False, trans_b: bool = False,
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
        if precision not in PRECISIONS:
            raise BackendError(f"unknown precision '{precision}'; valid: {', '.join(PRECISIONS)}")
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
    def _gemm(self, C, A, B, trans_a: bool = False, trans_b: bool = False, alpha: float = 1.0, beta: float = 0.0) -> None:
        if not self._kernels.planning():  # a planning pass only records the Warp kernels
            row_major_gemm(self._blas, self.precision, C, A, B, trans_a, trans_b, alpha, beta)

    def _low_buffer(self, use: str, of: Any) -> Any:
        """A bfloat16 array shaped like ``of``, one per (use, array, stream)."""
        key = (use + self._lane, of.ptr, tuple(of.shape))
        buf = self._low.get(key)
        if buf is None:
            buf = self._low[key] = self._wp.zeros(of.shape, dtype=self._wp.bfloat16, device=self.device)
        return buf

    def _operand(self, X) -> Any:
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
    def predict(self, Y, W: _LowWeights, X, E, G, R, slot: int, activation: str, slope: float) -> None:
        with self._stream_for(W, (Y, W, X), (E, G, None if R is None else (R.ptr, slot))):
            k = self._kernels
            A = self._buffer("product", tuple(E.shape))
            self._gemm(A, self._operand(Y), W.W if W.low is None else W.low)
            tiles = self._tiles("predict", Y.shape[0])
            shape = k.row_partial_shape(Y.shape[0], W.W.shape[1], tiles)
            partial = None if R is None else self._buffer("row_partial", shape)
            G_low = self._low_buffer("gain", G) if self.precision == "bf16" else None
            k.predict_epilogue(A, X, E, G, partial, R, slot, activation=activation, slope=slope, G_low=G_low,
                               tiles=tiles)

    def _gain(self, G) -> Any:
        """G at the working precision: its bfloat16 copy, written by the last predict."""
        return self._low_buffer("gain", G) if self.precision == "bf16" else G

    def latent_update(self, Y, G, W: _LowWeights, eta: float, E_above, mask) -> None:
        with self._stream_for(W, (G, W, E_above, mask), (Y,)):
            D = self._buffer("latent", tuple(Y.shape))
            self._gemm(D, self._gain(G), W.W if W.low is None else W.low, trans_b=True)
            self._kernels.latent_apply(Y, D, eta, E_above=E_above, mask=mask)

    def weight_update(self, W: _LowWeights, Y, G, eta: float) -> None:
        # W <- W + 2 eta Y^T G accumulated by cuBLAS in float32 into the float32 master copy
        with self._stream_for(W, (Y, G), (W,)):
            self._gemm(W.W, self._operand(Y), self._gain(G), trans_a=True, alpha=2.0 * eta, beta=1.0)
            self._round_weights(W)

    # ---------------------------------------------------------------- rows, stopping
    def fill(self, dst: Any, value: float) -> None:
        with self._stream_for(None, (), (dst,)):
            super().fill(dst, value)

    def gather_rows(self, src, index, dst) -> None:
        with self._stream_for(None, (src, index), (dst,)):
            super().gather_rows(src, index, dst)

    def scatter_rows(self, src, index, dst) -> None:
        with self._stream_for(None, (src, index), (dst,)):
            super().scatter_rows(src, index, dst)

    def stop_converged(self, R, limits, active, steps) -> None:
        self._join()  # reads every edge's row energies
        with self._stream_for(None, (limits,), (active, steps)):
            super().stop_converged(R, limits, active, steps)


def _cuda_driver_loads() -> bool:
    """Whether the NVIDIA driver library can be loaded (the dynamic loader's own search,
    so LD_LIBRARY_PATH counts), without initialising anything."""
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so.1", "libcuda.so", "libcuda.dylib")
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


def cuda_available() -> bool:
    """True when Warp finds a CUDA device. Without an NVIDIA driver library Warp is not even
    initialised (that would print its device banner and cost a second)."""
    if not _cuda_driver_loads():
        return False
    try:
        from vitaplace.kernels import warp_kernels  # noqa: F401 - sets Warp's log level

        import warp as wp

        wp.init()
        return bool(wp.is_cuda_available())
    except Exception:  # noqa: BLE001 - any failure means "no usable CUDA"
        return False


def check_precision(precision: str, backend: str = "auto") -> None:
    """Raise a one-line BackendError unless ``precision`` can run here with ``backend``."""
    if precision not in PRECISIONS:
        raise BackendError(f"unknown precision '{precision}'; valid: {', '.join(PRECISIONS)}")
    if precision == "float32":
        return
    if backend == "numpy":
        raise BackendError(f"precision '{precision}' runs on CUDA tensor cores; backend 'numpy' computes in float32 only")
    if not cuda_available():
        raise BackendError(f"precision '{precision}' needs a CUDA device and none was found; use precision 'float32'")


def get_backend(name: str = "auto", device: str | None = None, precision: str = "float32") -> Backend:
    """Backend by name: ``numpy``, ``warp`` (device ``cpu``/``cuda``/None = best) or ``auto``;
    a ``precision`` other than float32 gives the CublasBackend on CUDA (BackendError elsewhere)."""
    check_precision(precision, name)
    if precision != "float32":
        return CublasBackend(precision, device or "cuda")
    if name == "auto":
        name = "warp" if cuda_available() else "numpy"
    if name == "numpy":
        if device not in (None, "cpu"):
            raise ValueError(f"backend 'numpy' runs on the cpu only, not on device '{device}'")
        return NumpyBackend()
    if name == "warp":
        return WarpBackend(device)
    raise ValueError(f"unknown backend '{name}'; valid: {', '.join(BACKENDS)}")
