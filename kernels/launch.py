"""Warp's set-up, the argument checks and the launches that every kernel module shares.

* Kernels are compiled forward-only, each in its own Warp module (:func:`tiled_kernel`);
  the modules that build them from static parameters cache the factories, so each
  configuration compiles once per process (and is cached on disk by Warp).
* No code depends on ``block_dim`` or the lane index: only cooperative tile operations.
  On CPU Warp runs a tile with one thread.
* Every operation only launches kernels (no host synchronisation, no allocation once its
  scratch exists), so a sequence of them can be captured as a CUDA graph.
* While :func:`planned_kernels` records, launches are recorded instead of run, for
  :func:`preload` to compile them all in parallel.
* Kernels and Warp functions carry ``@no_type_check``: Warp compiles them from their source
  in its own language (array types as annotations, ``wp.tid()`` unpacked, Warp's scalar
  types), which mypy cannot check; the host code around them is checked.
"""

import contextlib
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import warp as wp

from vitaplace.engine.base.cpus import usable_cpus
from vitaplace.kernels.tiles import TileConfig

__all__ = [
    "BF16_2D", "F32", "F32_2D", "F32_3D", "F64", "F64_2D", "I32", "check", "check_type", "ensure_init", "placeholder",
    "planned_kernels", "planning", "preload", "simt_launch", "tiled_kernel", "tiled_launch",
]

#: Kernel argument types (Warp reads them as annotations of its kernels)
F32_2D: wp.array2d = wp.array2d(dtype=wp.float32)
F32_3D: wp.array3d = wp.array3d(dtype=wp.float32)
F64_2D: wp.array2d = wp.array2d(dtype=wp.float64)
BF16_2D: wp.array2d = wp.array2d(dtype=wp.bfloat16)
I32: wp.array = wp.array(dtype=wp.int32)
F32: wp.array = wp.array(dtype=wp.float32)
F64: wp.array = wp.array(dtype=wp.float64)

#: Element-wise / per-row kernels: threads per block on CUDA.
_SIMT_BLOCK = 256


def _quiet_warp() -> None:
    """Silence Warp's greeting and per-module load messages (warnings still shown)."""
    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)


_quiet_warp()

_init_lock = threading.Lock()
_initialised = False


def ensure_init() -> None:
    """Initialise Warp once, lazily (keeps ``import`` cheap and silent)."""
    global _initialised
    if not _initialised:
        with _init_lock:
            if not _initialised:
                wp.init()
                _initialised = True


def tiled_kernel(fn: Callable[..., None], name: str, tiles: TileConfig | None = None) -> wp.Kernel:
    """Compile ``fn`` as a forward-only kernel in its own module, named ``name`` (and the
    tile GEMM's options)."""
    mathdx = tiles is None or tiles.mathdx
    if tiles is not None:
        name += "" if mathdx else "_nomathdx"
    fn.__name__ = fn.__qualname__ = name
    return wp.kernel(fn, enable_backward=False, module="unique", module_options={"enable_mathdx_gemm": mathdx})


def check_type(name: str, arr: Any, dtype: Any = wp.float32, ndim: int = 2) -> None:
    """``arr`` is a Warp array of ``ndim`` dimensions and ``dtype`` (else a TypeError)."""
    if not isinstance(arr, wp.array) or arr.ndim != ndim or arr.dtype != dtype:
        raise TypeError(f"{name} must be a wp.array{ndim}d(dtype={dtype.__name__}), got {arr!r}")


def check(name: str, arr: Any, shape: tuple[int, ...], device: wp.DeviceLike, dtype: Any = wp.float32) -> None:
    """``arr`` is a contiguous Warp array of ``shape`` and ``dtype`` on ``device``."""
    check_type(name, arr, dtype, len(shape))
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} has shape {tuple(arr.shape)}, expected {tuple(shape)}")
    if arr.device != device:
        raise ValueError(f"{name} is on {arr.device}, expected {device}")
    if not arr.is_contiguous:
        raise ValueError(f"{name} must be contiguous")


_placeholders: dict[tuple[str, type, int], wp.array] = {}


def placeholder(device: wp.DeviceLike, dtype: Any, ndim: int = 2) -> wp.array:
    """An empty array standing in for an argument a kernel configuration never reads (one
    per device, made once: nothing is allocated while a CUDA graph is captured)."""
    key = (str(device), dtype, ndim)
    if key not in _placeholders:
        _placeholders[key] = wp.empty((0,) * ndim, dtype=dtype, device=device)
    return _placeholders[key]


# While a plan is being recorded (see `planned_kernels`), launches are recorded, not run.
_plan: list[tuple[wp.Kernel, int]] | None = None


def tiled_launch(
    kernel: wp.Kernel, dim: Sequence[int], inputs: list[Any], block_dim: int, device: wp.DeviceLike
) -> None:
    """Launch a tile kernel over the grid of tiles ``dim`` (or record it in the plan)."""
    if _plan is not None:
        _plan.append((kernel, block_dim))
        return
    wp.launch_tiled(kernel, dim=dim, inputs=inputs, block_dim=block_dim, device=device)


def simt_launch(kernel: wp.Kernel, dim: int | Sequence[int], inputs: list[Any], device: wp.DeviceLike) -> None:
    """Launch an element-wise or per-row kernel over ``dim`` (or record it in the plan)."""
    block_dim = _SIMT_BLOCK if wp.get_device(device).is_cuda else 1
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


def planning() -> bool:
    """True while :func:`planned_kernels` records launches instead of running them: work
    that is not a Warp kernel (a cuBLAS call) must then be skipped as well."""
    return _plan is not None


def preload(device: wp.DeviceLike, kernels: list[tuple[wp.Kernel, int]], workers: int | None = None) -> None:
    """Compile and load ``kernels`` on ``device`` in parallel threads (one per usable CPU by
    default). A cuBLASDx tile GEMM takes tens of seconds to compile on CUDA; compiled
    modules are cached on disk by Warp, so this costs nothing the second time."""
    ensure_init()
    by_block: dict[int, list] = {}
    for kernel, block_dim in kernels:
        modules = by_block.setdefault(block_dim, [])
        if kernel.module not in modules:
            modules.append(kernel.module)
    for block_dim, modules in by_block.items():
        wp.force_load(device=device, modules=modules, block_dim=block_dim, max_workers=workers or usable_cpus())
