"""The ``fixed`` backend: numpy's float32 arithmetic with every sum in an order of its own.

OpenBLAS picks its GEMM kernel by CPU (or ``OPENBLAS_CORETYPE``), and each kernel adds a
dot product's terms in another order: the last bits of every GEMM differ, and over hundreds
of epochs a trained network drifts as far as another seed's (docs/DESIGN.md, "Rounding").
Accumulating in float64 is not enough: the rare float64 sum on the other side of a float32
rounding boundary is one differing bit, and training amplifies it as well. Here no sum goes
through BLAS or LAPACK:

* every GEMM is numpy's ``einsum`` (its own loops, never BLAS; optimize off);
* the preconditioned solver's curvature matrices are Gram matrices by ``einsum`` and their
  inverses by a Cholesky factor whose sums are numpy reductions (`spd_inverse`), in float64;
* the momentum solver's scalar step, from LAPACK's largest eigenvalue, is rounded down to
  `STEP_BITS` significant bits (`rounded_step`), which a last-bit difference of the
  eigenvalue cannot move but with a chance of about 2^-40 per step.

So a run gives the same bits under every BLAS kernel of one machine (numpy's own loops pick
their SIMD width by CPU: another CPU generation may still round differently). It costs about
3x the ``numpy`` backend's time (docs/PERFORMANCE.md).
"""

from __future__ import annotations

import math

import numpy as np

from vitaplace.engine.network.backends import NumpyBackend

__all__ = ["STEP_BITS", "FixedOrderBackend", "gram", "matmul", "rounded_step", "spd_inverse"]

#: significant bits kept of a scalar step computed through LAPACK
STEP_BITS = 12


class FixedOrderBackend(NumpyBackend):
    """`NumpyBackend` with its GEMMs as ``einsum``: the same bits under any BLAS kernel."""

    name = "fixed"
    fixed_order = True

    def _matmul(self, a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
        matmul(a, b, out)


def matmul(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``a @ b`` of two matrices by ``einsum``: numpy's own loops, the same bits under any BLAS
    kernel (also what the backprop control uses on ``backend: fixed``)."""
    return np.einsum("ij,jk->ik", a, b, out=out)


def gram(w: np.ndarray) -> np.ndarray:
    """``w w^T`` by ``einsum`` (no BLAS), summed over w's columns one after another (a
    contiguous copy of w^T makes the rows of the product the inner loop: twice as fast)."""
    columns = np.ascontiguousarray(w.T)
    return np.einsum("ki,kj->ij", columns, columns)


def spd_inverse(b: np.ndarray) -> np.ndarray:
    """The inverse of the symmetric positive definite ``b`` (float64) through its Cholesky
    factor L (b = L L^T): L^-1 by forward substitution, then L^-T L^-1, every sum an
    ``einsum`` (no LAPACK, no BLAS); exactly symmetric. ValueError when a pivot
    is not positive (b not positive definite)."""
    n = len(b)
    factor = np.zeros_like(b)
    for j in range(n):
        pivot = b[j, j] - np.einsum("k,k->", factor[j, :j], factor[j, :j])
        if not pivot > 0:
            raise ValueError(f"not positive definite (pivot {j} is {pivot:g})")
        factor[j, j] = math.sqrt(pivot)
        factor[j + 1:, j] = (b[j + 1:, j] - np.einsum("ik,k->i", factor[j + 1:, :j], factor[j, :j])) / factor[j, j]
    inverse = np.zeros_like(b)  # L^-1, lower triangular, row by row
    for i in range(n):
        row = -np.einsum("k,kj->j", factor[i, :i], inverse[:i, : i + 1])
        row[i] += 1.0
        inverse[i, : i + 1] = row / factor[i, i]
    product = np.einsum("ki,kj->ij", inverse, inverse)
    upper = np.triu(product)
    return upper + np.triu(upper, 1).T


def rounded_step(step: float) -> float:
    """``step`` (> 0) rounded down to `STEP_BITS` significant bits: a smaller step, so still
    within the curvature bound it came from."""
    mantissa, exponent = math.frexp(step)
    return math.ldexp(math.floor(math.ldexp(mantissa, STEP_BITS)), exponent - STEP_BITS)
