"""A plugin's calls in the pipeline: a plugin method that raises is named by `call_plugin` and
`plugin_failure`; what it hands back is checked by `vitaplace.engine.extension.checks`
(re-exported here for the stages)."""

from __future__ import annotations

import contextlib
import traceback
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.extension.checks import StageError, check_distance, check_features, check_finite
from vitaplace.engine.extension.features import FeatureExtractor
from vitaplace.engine.outputs.outdir import SEED_ERROR

#: the file of the output folder that keeps a failed plugin call's traceback (a sweep's seed
#: folder keeps its failure's in the same file)
PLUGIN_TRACEBACK = SEED_ERROR
#: the attribute `call_plugin` sets on a plugin's exception: (the call, the traceback's file)
PLUGIN_CALL = "vitaplace_plugin_call"

__all__ = ["PLUGIN_CALL", "PLUGIN_TRACEBACK", "StageError", "call_plugin", "check_distance", "check_features",
           "check_finite", "plugin_failure"]


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
