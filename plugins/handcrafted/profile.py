"""Visual intensity profile: the OpenRatSLAM / ViTa-SLAM view template.

A template is the upper part of the camera frame, grey-scaled and block-averaged into a
small grid (ViTa-SLAM: 64 x 40 cells from a 640 x 300 crop of a 640 x 480 frame), optionally
scaled so that its mean is 0.4. Two templates are compared by the minimum, over horizontal
shifts s in [-max_shift, max_shift] cells, of the mean absolute difference over the columns
that overlap at that shift.

Choices (and how they differ from the C++ code):

* Grey value = mean of R, G, B divided by 255 (as OpenRatSLAM / ViTa-SLAM ``preprocess_vision``).
* Block averaging is exact *area* resampling: output cell (i, j) is the area-weighted mean of
  the input pixels its footprint covers. For an integer block size this is the plain block
  mean; for a non-integer one (300 rows -> 40 cells = 7.5 rows per cell) fractional pixels
  are weighted by their overlap instead of the remainder being dropped as the C++ code does;
  when the crop is smaller than the grid (e.g. 45 x 80 robot images) each cell takes the
  overlap-weighted blend of the (at most two) pixels under it. It is a separable linear map
  ``Ry @ grey @ Rx.T``, so a batch costs two matrix products.
* Normalisation scales the template to mean 0.4 exactly. The C++ code also clips to [0, 1],
  which makes the mean drift below 0.4 when cells saturate; we do not clip. An all-black
  template (mean 0) is left unchanged.
* Shift comparison: cell column c of the query is compared with column c - s of the
  reference, over all columns where both exist (w - |s| columns), and the sum is divided by
  the number of compared cells. OpenRatSLAM instead compares a fixed central window of width
  w - 2*max_shift of the query with every shifted window of the reference; ours uses every
  overlapping cell and is symmetric: d(a, b) == d(b, a).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.spatial.distance import cdist

from vitaplace.engine.base.cpus import usable_cpus

#: Mean of a normalised template (OpenRatSLAM ``vt_normalisation``).
TARGET_MEAN = 0.4


def _area_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) matrix whose row i averages the input interval [i, i+1) * n_in / n_out."""
    scale = n_in / n_out
    lo = np.arange(n_out)[:, None] * scale
    hi = lo + scale
    pix = np.arange(n_in)[None, :]
    overlap = np.clip(np.minimum(hi, pix + 1) - np.maximum(lo, pix), 0.0, None)
    return (overlap / scale).astype(np.float32)


def crop_rows(height: int, crop_fraction: float) -> int:
    """Number of top rows kept by the crop (at least one)."""
    return max(1, min(height, int(round(height * crop_fraction))))


class TemplateMaker:
    """Turns image batches of one shape into templates (the resampling matrices are cached)."""

    def __init__(
        self,
        image_shape: tuple[int, ...],
        grid: tuple[int, int] = (40, 64),
        crop_fraction: float = 0.625,
        normalise: bool = True,
    ) -> None:
        height, width = int(image_shape[0]), int(image_shape[1])
        self.rows = crop_rows(height, crop_fraction)
        self.grid = (int(grid[0]), int(grid[1]))
        self.normalise = normalise
        self._ry = _area_weights(self.rows, self.grid[0])
        self._rxt = np.ascontiguousarray(_area_weights(width, self.grid[1]).T)

    def __call__(self, images: np.ndarray) -> np.ndarray:
        images = np.asarray(images)
        if images.ndim == 3:  # already grey
            grey = images[:, : self.rows].astype(np.float32)
        else:
            grey = images[:, : self.rows].astype(np.float32).mean(axis=-1)
        grey *= np.float32(1.0 / 255.0)
        out = np.matmul(np.matmul(self._ry, grey), self._rxt)
        if self.normalise and len(out):
            mean = out.mean(axis=(1, 2), keepdims=True)
            safe = np.where(mean > 0, mean, 1.0)
            out = np.where(mean > 0, out * (TARGET_MEAN / safe), out)
        return np.ascontiguousarray(out, dtype=np.float32)


def templates(
    images: np.ndarray,
    grid: tuple[int, int] = (40, 64),
    crop_fraction: float = 0.625,
    normalise: bool = True,
) -> np.ndarray:
    """Templates (N, grid_h, grid_w) float32 of uint8 images (N, H, W, 3) (or grey (N, H, W)).

    Keeps the top ``crop_fraction`` of the rows, grey-scales (channel mean / 255),
    area-averages into ``grid`` = (rows, columns) and, if ``normalise``, scales each template
    to mean 0.4.
    """
    images = np.asarray(images)
    if images.ndim not in (3, 4):
        raise ValueError(f"images must have shape (N, H, W, 3) or (N, H, W), got {images.shape}")
    return TemplateMaker(images.shape[1:], grid, crop_fraction, normalise)(images)


def _shift_slices(width: int, shift: int) -> tuple[slice, slice]:
    """Column slices (query, reference) comparing query column c with reference column c - shift."""
    if shift >= 0:
        return slice(shift, width), slice(0, width - shift)
    return slice(0, width + shift), slice(-shift, width)


def template_distance(
    query: np.ndarray,
    reference: np.ndarray,
    max_shift: int = 5,
    *,
    threads: int | None = None,
    block: tuple[int, int] = (128, 64),
) -> np.ndarray:
    """Shift-tolerant template distance matrix (Nq, Nr) float64.

    ``D[i, j] = min over s in [-max_shift, max_shift] of mean |query[i][:, c] - reference[j][:, c - s]|``
    over the columns c where both exist (shifts are limited to |s| < w).

    For each shift the mean absolute difference over the overlapping columns is a batched L1
    distance between the flattened overlapping slices (``cdist(..., 'cityblock')``), computed
    in cache-sized blocks on ``threads`` threads (default: the CPUs this process may use, `usable_cpus`; SciPy
    releases the GIL).
    """
    q = np.asarray(query, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    if q.ndim != 3 or r.ndim != 3 or q.shape[1:] != r.shape[1:]:
        raise ValueError(f"templates must be (N, h, w) with equal (h, w), got {q.shape} and {r.shape}")
    nq, nr = len(q), len(r)
    h, w = q.shape[1:]
    best = np.full((nq, nr), np.inf)
    if nq == 0 or nr == 0:
        return best
    m = max(0, min(int(max_shift), w - 1))
    threads = threads or usable_cpus()
    bq, br = block
    q_blocks = [(i, min(i + bq, nq)) for i in range(0, nq, bq)]

    def run_block(args: tuple[int, int, np.ndarray, np.ndarray, float]) -> None:
        lo, hi, qs, rs, scale = args
        rows = best[lo:hi]
        for j in range(0, nr, br):
            d = cdist(qs[lo:hi], rs[j : j + br], "cityblock")
            d *= scale
            np.minimum(rows[:, j : j + br], d, out=rows[:, j : j + br])

    pool = ThreadPoolExecutor(threads) if threads > 1 and len(q_blocks) > 1 else None
    try:
        for s in range(-m, m + 1):
            cq, cr = _shift_slices(w, s)
            qs = np.ascontiguousarray(q[:, :, cq]).reshape(nq, -1)
            rs = np.ascontiguousarray(r[:, :, cr]).reshape(nr, -1)
            scale = 1.0 / qs.shape[1]
            tasks = [(lo, hi, qs, rs, scale) for lo, hi in q_blocks]
            if pool is None:
                for task in tasks:
                    run_block(task)
            else:
                list(pool.map(run_block, tasks))
    finally:
        if pool is not None:
            pool.shutdown()
    return best
