"""Copies on the device: minibatch rows in and out of a device-resident store, and float32
rounded to bfloat16 (an operand of the tensor-core GEMMs)."""

from typing import no_type_check

import warp as wp

from vitaplace.kernels.launch import BF16_2D, F32_2D, I32, check, check_type, ensure_init, simt_launch

__all__ = ["gather_rows", "scatter_rows", "to_bfloat16"]


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _gather_kernel(src: F32_2D, index: I32, dst: F32_2D):
    r, c = wp.tid()
    dst[r, c] = src[index[r], c]


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _scatter_kernel(src: F32_2D, index: I32, dst: F32_2D):
    r, c = wp.tid()
    dst[index[r], c] = src[r, c]


@wp.kernel(enable_backward=False, module="unique")
@no_type_check
def _bfloat16_kernel(src: F32_2D, dst: BF16_2D):
    r, c = wp.tid()
    dst[r, c] = wp.bfloat16(src[r, c])


def to_bfloat16(src: wp.array, dst: wp.array) -> None:
    """``dst = src`` rounded to bfloat16 (to nearest, ties to even); both 2-d, one shape."""
    ensure_init()
    check_type("src", src)
    check("dst", dst, tuple(src.shape), src.device, wp.bfloat16)
    simt_launch(_bfloat16_kernel, tuple(src.shape), [src, dst], src.device)


def _move_rows(kernel: wp.Kernel, src: wp.array, index: wp.array, dst: wp.array, small: wp.array) -> None:
    """Launch ``kernel`` over the rows of ``small`` (the side ``index`` runs along)."""
    ensure_init()
    check_type("src", src)
    check_type("dst", dst)
    check("index", index, (small.shape[0],), src.device, wp.int32)
    if dst.shape[1] != src.shape[1]:
        raise ValueError(f"dst has {dst.shape[1]} columns, src {src.shape[1]}")
    simt_launch(kernel, tuple(small.shape), [src, index, dst], src.device)


def gather_rows(src: wp.array, index: wp.array, dst: wp.array) -> None:
    """``dst[r] = src[index[r]]`` (``index`` int32 of length ``dst.shape[0]``)."""
    _move_rows(_gather_kernel, src, index, dst, dst)


def scatter_rows(src: wp.array, index: wp.array, dst: wp.array) -> None:
    """``dst[index[r]] = src[r]`` (``index`` int32 of length ``src.shape[0]``, no repeats)."""
    _move_rows(_scatter_kernel, src, index, dst, src)
