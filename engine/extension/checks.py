"""Checks of what an extractor is given and hands back, the same in the pipeline's stages, the
Python API and the reinforcement-learning task: features with one finite row per sample, a
distance matrix of the expected shape whose entries are finite or +inf (a pair the method
cannot compare, e.g. a vision-only method and a query without its camera: never a match), and
runs of the shape the extractor was fitted on. A failure is one line, a `StageError` naming
the stage or method and item."""

from __future__ import annotations

from typing import Any

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.data.dataset import Run, shape_problem
from vitaplace.engine.extension.features import FeatureExtractor, Features


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


def check_methods(extractor: FeatureExtractor, plugin: str, train: Run) -> FeatureExtractor:
    """``extractor`` (of ``plugin``, fitted on ``train``) with its ``transform`` and ``distance``
    checked as the pipeline checks them: ``transform`` given a `Run` of ``train``'s whiskers and
    image size, its features one finite row per sample; ``distance`` given such features, its
    matrix `check_distance`'s. Set on the instance, so it stays of its plugin's class (and
    picklable)."""
    trained_on = (train.n_whiskers, train.image_shape)
    extractor.transform = _CheckedTransform(extractor, plugin, trained_on)  # type: ignore[method-assign]
    extractor.distance = _CheckedDistance(extractor, plugin, trained_on)  # type: ignore[method-assign]
    return extractor


class _Checked:
    """An extractor's method checked (`check_methods`); a failure is one line naming the
    method and its plugin."""

    method = ""

    def __init__(self, extractor: FeatureExtractor, plugin: str, trained_on: tuple[int, tuple[int, ...]]) -> None:
        self.extractor, self.what, self.trained_on = extractor, f"{self.method} (plugin '{plugin}')", trained_on


class _CheckedTransform(_Checked):
    """``transform``: a `Run` of the training run's shape in, one finite row per sample out."""

    method = "transform"

    def __call__(self, run: Run) -> Features:
        if not isinstance(run, Run):
            raise StageError(f"{self.what}: run={run!r:.80}: expected a Run "
                             "(vitaplace.open_run(path) reads a run file)")
        problem = shape_problem(run, *self.trained_on, "the extractor's training run")
        if problem:
            raise StageError(f"{self.what}: {problem}")
        return check_features(type(self.extractor).transform(self.extractor, run), len(run), self.what)


class _CheckedDistance(_Checked):
    """``distance``: features as ``transform`` gives them in (NaN refused), a matrix of real
    numbers of shape (n_query, n_reference), finite or +inf, out."""

    method = "distance"

    def __call__(self, query: Features, reference: Features) -> np.ndarray:
        shape = (_rows(query), _rows(reference))
        for features, side, rows in zip((query, reference), ("query", "reference"), shape, strict=True):
            check_features(features, rows, f"{self.what}, its {side} features")
        return check_distance(type(self.extractor).distance(self.extractor, query, reference), shape, self.what)


def _rows(features: Any) -> int:
    """The samples of ``features``: the rows of its first array (0 for anything else)."""
    first: Any = next(iter(features.values()), None) if isinstance(features, dict) else None
    return int(np.shape(first)[0]) if np.ndim(first) else 0
