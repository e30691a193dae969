"""Compute backends for the predictive-coding layer steps (DESIGN §7).

A backend owns array storage and the three fused operations of one prediction edge:

    predict(Y, W, X, A, P, E, G)      A = Y W, P = phi(A), E = X - P, G = phi'(A) * E
    latent_update(Y, G, W, eta, E_up) Y <- Y + 2 eta (G W^T) - 2 eta E_up     (-eta dF/dY)
    weight_update(W, Y, G, eta)       W <- W + 2 eta (Y^T G)                   (-eta dF/dW)

``numpy`` runs them with float32 BLAS through scipy's ``gemm`` so that the step is fused
into the GEMM (beta = 1, in place) and the element-wise epilogue reuses preallocated
buffers. ``warp`` runs the tile kernels of `vitaplace.kernels.warp_kernels` on ``cpu`` or
``cuda``. ``auto`` picks warp when a CUDA device exists and numpy otherwise: Warp's CPU
path is scalar single-threaded code, far slower than BLAS on the same cores.
"""

from __future__ import annotations

import ctypes.util
from typing import Any, Protocol

import numpy as np
from scipy.linalg import blas

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
    """numpy + BLAS (float32 by default; float64 for gradient checks), in preallocated arrays."""

    name = "numpy"
    device = "cpu"

    def __init__(self, dtype: np.dtype | type = np.float32) -> None:
        self.dtype = np.dtype(dtype)
        self._gemm = blas.get_blas_funcs("gemm", dtype=self.dtype)

    def empty(self, shape: tuple[int, int]) -> np.ndarray:
        return np.zeros(shape, dtype=self.dtype)

    def upload(self, host: np.ndarray, dst: np.ndarray) -> None:
        np.copyto(dst, host, casting="same_kind")

    def download(self, src: np.ndarray) -> np.ndarray:
        return src.copy()

    def predict(self, Y, W, X, A, P, E, G, activation: str, slope: float) -> None:
        # A^T = W^T Y^T in Fortran order is A = Y W in C order: no copies, result in A.
        self._gemm(1.0, W.T, Y.T, beta=0.0, c=A.T, overwrite_c=True)
        if activation == "leaky_relu" and 0.0 <= slope <= 1.0:
            np.multiply(A, self.dtype.type(slope), out=P)
            np.maximum(A, P, out=P)  # max(a, s a) = leaky ReLU for 0 <= s <= 1
            np.subtract(X, P, out=E)
            np.multiply(E, self.dtype.type(slope), out=G)
            np.copyto(G, E, where=A > 0)
        else:
            P[...] = reference.activation(A, activation, slope)
            np.subtract(X, P, out=E)
            np.multiply(reference.activation_derivative(A, activation, slope), E, out=G)

    def latent_update(self, Y, G, W, eta: float, E_above) -> None:
        if E_above is not None:
            Y -= self.dtype.type(2.0 * eta) * E_above
        # Y^T <- 2 eta W G^T + Y^T, in place (Y^T is Fortran-contiguous).
        self._gemm(2.0 * eta, W.T, G.T, beta=1.0, c=Y.T, trans_a=1, overwrite_c=True)

    def weight_update(self, W, Y, G, eta: float) -> None:
        # W^T <- 2 eta G^T Y + W^T, in place.
        self._gemm(2.0 * eta, G.T, Y.T, beta=1.0, c=W.T, trans_b=1, overwrite_c=True)

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
