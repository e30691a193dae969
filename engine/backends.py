"""Compute backends for the predictive-coding layer steps (DESIGN §7).

A backend owns array storage and the three fused operations of one prediction edge:

    predict(Y, W, X, A, P, E, G)      A = Y W, P = phi(A), E = X - P, G = phi'(A) * E
    latent_update(Y, G, W, eta, E_up) Y <- Y + 2 eta (G W^T) - 2 eta E_up     (-eta dF/dY)
    weight_update(W, Y, G, eta)       W <- W + 2 eta (Y^T G)                   (-eta dF/dW)

``numpy`` runs them with float32 BLAS through ``np.matmul(..., out=)`` (numpy's own
OpenBLAS only: never alternated with scipy's, whose thread pool would fight it for the
cores) and element-wise epilogues in preallocated buffers. ``warp`` runs the tile kernels
of `vitaplace.kernels.warp_kernels` on ``cpu`` or ``cuda``. ``auto`` picks warp when a CUDA
device exists and numpy otherwise: Warp's CPU path is scalar single-threaded code, far
slower than BLAS on the same cores.
"""

from __future__ import annotations

import ctypes.util
from typing import Any, Protocol

import numpy as np

from vitaplace.kernels import reference

BACKENDS = ("auto", "numpy", "warp")


class Backend(Protocol):
    """What the network needs from a backend; arrays are opaque handles of float32 matrices."""

    name: str
    device: str

    def empty(self, shape: tuple[int, int]) -> Any: ...
    def upload(self, host: np.ndarray, dst: Any) -> None: ...
    def download(self, src: Any) -> np.ndarray: ...
    def predict(self, Y: Any, W: Any, X: Any, A: Any, P: Any, E: Any, G: Any, activation: str, slope: float) -> None: ...
    def latent_update(self, Y: Any, G: Any, W: Any, eta: float, E_above: Any | None) -> None: ...
    def weight_update(self, W: Any, Y: Any, G: Any, eta: float) -> None: ...
    def squared_norm(self, E: Any) -> float: ...


class NumpyBackend:
    """numpy + BLAS (float32 by default; float64 for gradient checks), in preallocated arrays.

    Every GEMM goes through ``np.matmul(..., out=)``, i.e. numpy's own OpenBLAS, in the
    orientation numpy picks for ``Y @ W``, ``G @ W.T`` and ``Y.T @ G``. scipy's BLAS is a
    second OpenBLAS build with its own thread pool: alternating the two pools makes each
    one's spinning worker threads steal the cores from the other (measured on 2 cores: the
    training step ran at less than half speed), so the backend never mixes them
    (bench/pc_step.py, docs/PERFORMANCE.md). Scratch buffers are cached per shape, so one
    instance must not be used from several threads at once.
    """

    name = "numpy"
    device = "cpu"

    #: Rows of W per chunk of the weight update (GEMM into a scratch, then add).
    WEIGHT_CHUNK = 128

    def __init__(self, dtype: np.dtype | type = np.float32) -> None:
        self.dtype = np.dtype(dtype)
        self._scratch: dict[tuple[str, tuple[int, int]], np.ndarray] = {}

    def _buffer(self, use: str, shape: tuple[int, int]) -> np.ndarray:
        buf = self._scratch.get((use, shape))
        if buf is None:
            buf = self._scratch[(use, shape)] = np.empty(shape, dtype=self.dtype)
        return buf

    def empty(self, shape: tuple[int, int]) -> np.ndarray:
        return np.zeros(shape, dtype=self.dtype)

    def upload(self, host: np.ndarray, dst: np.ndarray) -> None:
        np.copyto(dst, host, casting="same_kind")

    def download(self, src: np.ndarray) -> np.ndarray:
        return src.copy()

    def predict(self, Y, W, X, A, P, E, G, activation: str, slope: float) -> None:
        np.matmul(Y, W, out=A)
        if activation == "leaky_relu" and 0.0 <= slope <= 1.0:
            # Leaky ReLU is positively homogeneous: phi(a) = phi'(a) a with
            # phi'(a) = max([a > 0], s) for 0 <= s <= 1. Five plain passes, no masked copy
            # (np.copyto(where=) alone took 9 ms of a 12 ms epilogue at 150 x 10800).
            np.greater(A, 0, out=G)
            np.maximum(G, self.dtype.type(slope), out=G)  # G = phi'(A)
            np.multiply(A, G, out=P)
            np.subtract(X, P, out=E)
            np.multiply(G, E, out=G)
        else:
            P[...] = reference.activation(A, activation, slope)
            np.subtract(X, P, out=E)
            np.multiply(reference.activation_derivative(A, activation, slope), E, out=G)

    def latent_update(self, Y, G, W, eta: float, E_above) -> None:
        # Y <- Y + 2 eta (G W^T - E_above): GEMM into a (batch x n_l) scratch, then small passes.
        t = self._buffer("latent", Y.shape)
        np.matmul(G, W.T, out=t)
        if E_above is not None:
            np.subtract(t, E_above, out=t)
        np.multiply(t, self.dtype.type(2.0 * eta), out=t)
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

    def squared_norm(self, E: np.ndarray) -> float:
        flat = E.reshape(-1)
        return float(np.dot(flat, flat))


class WarpBackend:
    """Warp tile kernels on ``cpu`` or ``cuda``."""

    name = "warp"

    def __init__(self, device: str | None = None) -> None:
        from vitaplace.kernels import warp_kernels  # imported lazily: compiles on first use

        import warp as wp

        self._wp = wp
        self._kernels = warp_kernels
        wp.init()
        self.device = device or ("cuda" if wp.is_cuda_available() else "cpu")

    def empty(self, shape: tuple[int, int]) -> Any:
        return self._wp.zeros(shape, dtype=self._wp.float32, device=self.device)

    def upload(self, host: np.ndarray, dst: Any) -> None:
        src = self._wp.array(np.ascontiguousarray(host, dtype=np.float32), dtype=self._wp.float32, device="cpu")
        self._wp.copy(dst, src)

    def download(self, src: Any) -> np.ndarray:
        return src.numpy().copy()

    def predict(self, Y, W, X, A, P, E, G, activation: str, slope: float) -> None:
        self._kernels.predict(Y, W, X, A, P, E, G, activation=activation, slope=slope)

    def latent_update(self, Y, G, W, eta: float, E_above) -> None:
        self._kernels.latent_update(Y, G, W, eta, E_above=E_above)

    def weight_update(self, W, Y, G, eta: float) -> None:
        self._kernels.weight_update(W, Y, G, eta)

    def squared_norm(self, E: Any) -> float:
        return self._kernels.squared_norm(E)


def cuda_available() -> bool:
    """True when Warp finds a CUDA device. Without an NVIDIA driver library Warp is not even
    initialised (that would print its device banner and cost a second)."""
    if ctypes.util.find_library("cuda") is None:
        return False
    try:
        from vitaplace.kernels import warp_kernels  # noqa: F401 - sets Warp's log level

        import warp as wp

        wp.init()
        return bool(wp.is_cuda_available())
    except Exception:  # noqa: BLE001 - any failure means "no usable CUDA"
        return False


def get_backend(name: str = "auto", device: str | None = None) -> Backend:
    """Backend by name: ``numpy``, ``warp`` (device ``cpu``/``cuda``/None = best) or ``auto``."""
    if name == "auto":
        name = "warp" if cuda_available() else "numpy"
    if name == "numpy":
        if device not in (None, "cpu"):
            raise ValueError(f"backend 'numpy' runs on the cpu only, not on device '{device}'")
        return NumpyBackend()
    if name == "warp":
        return WarpBackend(device)
    raise ValueError(f"unknown backend '{name}'; valid: {', '.join(BACKENDS)}")
