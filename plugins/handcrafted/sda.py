"""Slope distribution array (SDA): one deflection slope per whisker per whisk cycle.

The method's slope is ``slope = (y_max - y_init) / (x_max - x_init)`` with init = the first positive
sample and max over the positive values, 0 when the denominator is 0, without saying what
"positive" and "max" mean for a two-axis (x, y) deflection. Two readings are implemented:

``mode="magnitude"`` (default)
    A sample is *positive* when the deflection magnitude ``sqrt(x^2 + y^2)`` exceeds
    ``threshold`` (contact). *init* is the first positive sample, *max* the sample of largest
    magnitude (the first one on a tie). Both coordinates are read from those two samples,
    so the slope is the direction, in the x-y deflection plane, of the whisker's deflection
    path from contact onset to peak deflection -- the quantity that encodes the orientation
    of the touched surface. It does not depend on the sign conventions of the two axes.

``mode="per_axis"`` (ViTa-SLAM's ``compute_SDA``)
    Each axis on its own: ``x_init`` = the first x sample ``> threshold``, ``x_max`` = the
    largest x sample, both 0 when no x sample exceeds the threshold; likewise for y (with
    threshold 0 this is exactly the C++ code). x and y may come from different samples and
    deflections of negative sign are ignored, which is why it is not the default; it is
    kept for reproducing ViTa-SLAM.

The default threshold, 0.01 rad, is ~10x the deflection the simulated whiskers show from
whisking in free air (~1e-3 rad) and well below contact deflections (0.08-0.85 rad seen).

In both modes the slope is 0 when the denominator is exactly 0, which covers a whisker
without contact, a single contact sample, and contact onset at the peak. All whiskers are
used (the C++ comparison drops the 24th).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

SdaMode = Literal["magnitude", "per_axis"]


def _slope(dy: np.ndarray, dx: np.ndarray) -> np.ndarray:
    out = np.zeros(dx.shape, dtype=np.float64)
    np.divide(dy, dx, out=out, where=dx != 0)
    return out


def sda(deflection: np.ndarray, threshold: float = 0.01, mode: SdaMode = "magnitude") -> np.ndarray:
    """Slopes (N, W) float32 of deflection series (N, S, W, 2) (last axis: x, y)."""
    d = np.asarray(deflection, dtype=np.float64)
    if d.ndim != 4 or d.shape[-1] != 2:
        raise ValueError(f"deflection must have shape (N, S, W, 2), got {d.shape}")
    n, s, w, _ = d.shape
    if s == 0:
        return np.zeros((n, w), dtype=np.float32)
    if mode == "magnitude":
        mag = np.hypot(d[..., 0], d[..., 1])  # (N, S, W)
        positive = mag > threshold
        any_pos = np.any(positive, axis=1)  # (N, W)
        first = positive.argmax(axis=1)[:, None, :, None]  # first True along S
        peak = mag.argmax(axis=1)[:, None, :, None]
        init = np.take_along_axis(d, first, axis=1)[:, 0]  # (N, W, 2)
        top = np.take_along_axis(d, peak, axis=1)[:, 0]
        delta = np.where(any_pos[..., None], top - init, 0.0)
        return _slope(delta[..., 1], delta[..., 0]).astype(np.float32)
    if mode == "per_axis":
        positive = d > threshold  # (N, S, W, 2)
        any_pos = positive.any(axis=1)  # (N, W, 2)
        first = positive.argmax(axis=1)[:, None]  # (N, 1, W, 2)
        init = np.where(any_pos, np.take_along_axis(d, first, axis=1)[:, 0], 0.0)
        top = np.where(any_pos, d.max(axis=1), 0.0)
        delta = top - init
        return _slope(delta[..., 1], delta[..., 0]).astype(np.float32)
    raise ValueError(f"unknown SDA mode {mode!r}; expected 'magnitude' or 'per_axis'")
