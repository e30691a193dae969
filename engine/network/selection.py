"""Choosing a backend: `get_backend` by name and precision (``auto``: Warp where a CUDA
device exists, numpy otherwise), `check_precision` (whether a precision can run here) and
`cuda_available` (whether Warp finds a CUDA device, without initialising Warp on a machine
with no NVIDIA driver).
"""

from __future__ import annotations

import sys

from vitaplace.engine.base.libraries import first_loadable
from vitaplace.engine.network.backends import Backend, BackendError, NumpyBackend, WarpBackend, known_precision
from vitaplace.engine.network.fixed_order import FixedOrderBackend
from vitaplace.engine.network.tensorcores import CublasBackend

__all__ = ["BACKENDS", "check_precision", "cuda_available", "get_backend"]

BACKENDS = ("auto", "numpy", "warp", "fixed")


def _cuda_driver_loads() -> bool:
    """Whether the NVIDIA driver library can be loaded (the dynamic loader's own search,
    so LD_LIBRARY_PATH counts), without initialising anything."""
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so.1", "libcuda.so", "libcuda.dylib")
    return first_loadable(names) is not None


def cuda_available() -> bool:
    """True when Warp finds a CUDA device. Without an NVIDIA driver library Warp is not even
    initialised (that would print its device banner and cost a second)."""
    if not _cuda_driver_loads():
        return False
    try:
        import warp as wp

        from vitaplace.kernels import warp_kernels  # noqa: F401 - sets Warp's log level

        wp.init()
        return bool(wp.is_cuda_available())
    except Exception:  # noqa: BLE001 - any failure means "no usable CUDA"
        return False


def check_precision(precision: str, backend: str = "auto") -> None:
    """Raise a one-line BackendError unless ``precision`` can run here with ``backend``."""
    if known_precision(precision) == "float32":
        return
    if backend in ("numpy", "fixed"):
        raise BackendError(
            f"precision '{precision}' runs on CUDA tensor cores; backend '{backend}' computes in float32 only"
        )
    if not cuda_available():
        raise BackendError(f"precision '{precision}' needs a CUDA device and none was found; use precision 'float32'")


def get_backend(name: str = "auto", device: str | None = None, precision: str = "float32") -> Backend:
    """Backend by name: ``numpy``, ``fixed`` (numpy's arithmetic without BLAS, `fixed_order`),
    ``warp`` (device ``cpu``/``cuda``/None = best) or ``auto``;
    a ``precision`` other than float32 gives the CublasBackend on CUDA (BackendError elsewhere)."""
    check_precision(precision, name)
    if precision != "float32":
        return CublasBackend(precision, device or "cuda")
    if name == "auto":
        name = "warp" if cuda_available() else "numpy"
    if name in ("numpy", "fixed"):
        if device not in (None, "cpu"):
            raise ValueError(f"backend '{name}' runs on the cpu only, not on device '{device}'")
        return NumpyBackend() if name == "numpy" else FixedOrderBackend()
    if name == "warp":
        return WarpBackend(device)
    raise ValueError(f"unknown backend '{name}'; valid: {', '.join(BACKENDS)}")
