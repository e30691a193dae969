"""Checks of what an extractor hands back: features with one finite row per sample, a distance
matrix of the expected shape whose entries are finite or +inf (a pair the method cannot
compare, e.g. a vision-only method and a query without its camera: never a match). A failure
is a `StageError` naming the stage and item."""

from __future__ import annotations

from typing import Any

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.extension.features import Features


class StageError(UserError, RuntimeError):
    """A stage produced unusable output (e.g. non-finite features); names the stage and item."""


def check_finite(features: Features, what: str) -> Features:
    """Raise StageError if any feature array holds NaN or infinite values."""
    for key, values in features.items():
        values = np.asarray(values)
        if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
            rows = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1)).all(axis=1))
            raise StageError(
                f"{what}: feature '{key}' has NaN or infinite values in {len(rows)} samples (first: {rows[0]}); "
                "check the method's parameters (e.g. lower learning rates) and the dataset"
            )
    return features


def check_features(features: Any, samples: int, what: str) -> Features:
    """An extractor's ``transform`` output must be a mapping of arrays with one row per sample."""
    if not isinstance(features, dict) or not features:
        raise StageError(
            f"{what}: transform returned {type(features).__name__}, expected a non-empty mapping of arrays")
    for key, values in features.items():
        shape = np.shape(values)
        if not shape or shape[0] != samples:
            raise StageError(f"{what}: feature '{key}' has shape {shape}, expected {samples} rows (one per sample)")
    return check_finite(features, what)


def check_distance(tme: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    """An extractor's ``distance`` output must be an (n_query, n_reference) matrix of real
    numbers (a float or integer dtype, as the contract suite asks: complex, boolean and object
    arrays are refused, never cast), finite or +inf (a pair that cannot be compared); NaN and
    -inf are refused."""
    tme = np.asarray(tme)
    if tme.shape != shape:
        raise StageError(f"{what}: distance returned shape {tme.shape}, expected {shape} (queries x references)")
    if tme.dtype.kind not in "iuf":
        raise StageError(f"{what}: distance returned an array of {tme.dtype}, expected real numbers (a float or "
                         "integer dtype), finite or +inf")
    if tme.dtype.kind == "f":
        check_finite({"distance": np.where(np.isposinf(tme), 0.0, tme)}, what)
    return tme
