"""Checks of what an extractor hands back: features with one finite row per sample, a distance
matrix of the expected shape whose entries are finite or +inf (a pair the method cannot
compare, e.g. a vision-only method and a query without its camera: never a match). A failure
is a `StageError` naming the stage and item. A plugin method that raises is named by
`call_plugin` and `plugin_failure`."""

from __future__ import annotations

import contextlib
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.extension.features import FeatureExtractor, Features
from vitaplace.engine.outputs.outdir import SEED_ERROR

#: the file of the output folder that keeps a failed plugin call's traceback (a sweep's seed
#: folder keeps its failure's in the same file)
PLUGIN_TRACEBACK = SEED_ERROR
#: the attribute `call_plugin` sets on a plugin's exception: (the call, the traceback's file)
PLUGIN_CALL = "vitaplace_plugin_call"


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



def call_plugin(out: Path, what: str, extractor: FeatureExtractor, name: str, *args: Any) -> Any:
    """``extractor.name(*args)``. An exception of the plugin's own (anything but vitaplace's
    `UserError`, already one line, and `KeyboardInterrupt`) is a bug of the plugin, not of the
    user's input: its traceback is written to `PLUGIN_TRACEBACK` in ``out`` and the exception,
    raised on unchanged (a sweep reports its seed's failure by it), carries the call
    (``PLUGIN_CALL``), for `plugin_failure`'s line."""
    try:
        return getattr(extractor, name)(*args)
    except UserError:
        raise
    except Exception as exc:
        path = Path(out) / PLUGIN_TRACEBACK
        write_text_atomic(path, traceback.format_exc())
        with contextlib.suppress(AttributeError):  # an exception type without a __dict__ keeps its traceback only
            setattr(exc, PLUGIN_CALL, (f"{what}: {name}()", str(path)))
        raise


def plugin_failure(exc: BaseException) -> str | None:
    """The one line of a plugin's failed call (`call_plugin`): ``WHAT: NAME() raised TYPE:
    MESSAGE (traceback in OUT/error.txt)``, the message's first line; None for any other exception."""
    call = getattr(exc, PLUGIN_CALL, None)
    if call is None:
        return None
    lines = str(exc).strip().splitlines()
    return f"{call[0]} raised {type(exc).__name__}: {lines[0] if lines else ''} (traceback in {call[1]})"
