"""Tile sizes of the tile-GEMM kernels, per device kind, and the split of the latent GEMM.

Shapes need not be multiples of the tile sizes: ``wp.tile_load`` reads elements past the
array's extent as zero and ``wp.tile_store`` skips writes past it. The zero padding along K
keeps the edge tiles exact; padded output rows / columns are computed, never stored.
"""

from typing import NamedTuple

import warp as wp

__all__ = ["TileConfig", "cdiv", "latent_splits", "round_rows", "set_tile_config", "tile_config"]


class TileConfig(NamedTuple):
    """Static tile sizes of one GEMM (output tile tm x tn, K step tk), the launch
    ``block_dim``, and whether ``tile_matmul`` goes through libmathdx (cuBLASDx) on CUDA
    (``False``: Warp's own tile GEMM, which compiles in seconds rather than tens of
    seconds)."""

    tm: int
    tn: int
    tk: int
    block_dim: int
    mathdx: bool = True


# CPU: Warp runs each tile serially with one thread through its scalar register-blocked
# GEMM, so the tile sizes only trade padding waste against per-tile load / loop overhead.
# Measured at B=150, n_l=1000, n_below=10800 (predict): 16^3 ~0.68 s, 32^3 ~0.39 s,
# 64x64x32 ~0.33 s, 64x128x32 ~0.28 s.
_CPU_TILES = {
    "predict": TileConfig(64, 128, 32, 1),
    "latent": TileConfig(64, 128, 32, 1),
    "weight": TileConfig(64, 128, 32, 1),
}
# CUDA: chosen by bench/tile_sweep.py on an H100 at the paper's largest edge (B=150,
# n_l=1000, n_below=10800; docs/PERFORMANCE.md). 64x64 output tiles with a 32-deep K step and
# 128 threads beat 64x128, 128x64 and 128x128 in every kernel, and Warp's own tile GEMM
# matched or beat cuBLASDx there (predict 270 vs 281 us, latent 218 vs 226 us, weight 195 vs
# 300 us) while compiling in seconds instead of ~35 s per kernel.
_CUDA_TILES = {
    "predict": TileConfig(64, 64, 32, 128, mathdx=False),
    "latent": TileConfig(64, 64, 32, 128, mathdx=False),
    "weight": TileConfig(64, 64, 32, 128, mathdx=False),
}


def set_tile_config(kernel: str, tiles: TileConfig, cuda: bool = True) -> None:
    """Use ``tiles`` for ``kernel`` (``predict``, ``latent``, ``weight``) from now on, on
    CUDA devices (or on the CPU with ``cuda=False``): e.g. the winner of a tile sweep on
    another GPU model."""
    table = _CUDA_TILES if cuda else _CPU_TILES
    if kernel not in table:
        raise ValueError(f"unknown kernel {kernel!r}; valid: {', '.join(table)}")
    table[kernel] = TileConfig(*tiles)


def round_rows(m: int, cap: int) -> int:
    """Smallest power of two >= m (at least 1), capped: avoids computing 31 padded rows
    for a single-sample batch."""
    t = 1
    while t < m and t < cap:
        t *= 2
    return t


def tile_config(device: wp.DeviceLike, kernel: str, rows: int) -> TileConfig:
    """Tile sizes of ``kernel`` (``predict``, ``latent``, ``weight``) on ``device``.

    ``rows`` is the batch: the output rows of predict / latent (the row tile shrinks to
    the next power of two >= batch) and the K of the weight update (so is its K step).
    """
    cfg = (_CUDA_TILES if wp.get_device(device).is_cuda else _CPU_TILES)[kernel]
    if kernel == "weight":
        return cfg._replace(tk=round_rows(rows, cfg.tk))
    return cfg._replace(tm=round_rows(rows, cfg.tm))


def cdiv(a: int, b: int) -> int:
    """``a / b`` rounded up: the tiles of size ``b`` that cover ``a``."""
    return (a + b - 1) // b


def latent_splits(device: wp.DeviceLike, tiles: TileConfig, batch: int, n_l: int, n_below: int) -> int:
    """How many K-slices the latent GEMM is split into: 1 on CPU; on CUDA enough blocks for
    two waves over the multiprocessors, each slice at least 16 K-steps long."""
    dev = wp.get_device(device)
    if not dev.is_cuda:
        return 1
    blocks = cdiv(batch, tiles.tm) * cdiv(n_l, tiles.tn)
    want = cdiv(2 * dev.sm_count, blocks)
    return max(1, min(want, cdiv(n_below, 16 * tiles.tk)))
