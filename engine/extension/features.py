"""The feature-extractor interface every place-recognition front end implements.

An extractor turns a recorded `Run` into per-sample features and compares two feature
sets with a template-match error (TME, lower = more similar). Evaluation only ever talks
to this interface, so learned, hand-crafted and third-party methods are interchangeable.
"""

from __future__ import annotations

import json
import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pydantic

from vitaplace.engine.base.atomic import atomic_path
from vitaplace.engine.base.configfile import NumbersNotBooleans, format_validation_error
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.data.dataset import Run

#: Features of one run: named arrays whose first axis is the sample index.
Features = dict[str, np.ndarray]
#: the senses an extractor configuration may declare it uses (`FeatureExtractor.modalities`)
VISUAL, TACTILE = "visual", "tactile"


class ExtractorParamsError(UserError, ValueError):
    """Invalid extractor parameters; the message names the extractor and the key."""


class ExtractorParams(NumbersNotBooleans):
    """Base of every extractor's parameter schema: unknown keys are errors, and so are
    infinite or NaN numbers (an infinite range or rate voids a run without failing it) and
    booleans where a number is expected (``epochs: true`` would be read as 1)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class FeatureExtractor(ABC):
    """A place-recognition front end: ``fit`` on a training run, ``transform`` runs, ``distance``.

    Subclasses set ``name`` and ``Params`` (a subclass of `ExtractorParams`).
    """

    name: ClassVar[str]
    Params: ClassVar[type[ExtractorParams]] = ExtractorParams
    #: Whether long fit/transform calls may show progress bars (the runner sets it).
    progress: bool = True
    #: Called by a ``fit`` that trains in epochs after each one, ``on_epoch(epoch, numbers)``
    #: (epoch from 1, numbers by name, e.g. ``energy``); the runner sets it to pass them on to
    #: the ``vitaplace_training_epoch`` hook (MLflow's per-epoch metrics). None: nobody listens.
    on_epoch: Callable[[int, dict[str, float]], None] | None = None
    #: Whether ``transform`` and ``distance`` honour missing modalities: samples of a run that lack
    #: the camera or the whiskers (`Run.lacks`, a query drop-out) are described by the sensors they
    #: have, never by the missing one's data. An extractor that leaves it False is refused, in one
    #: line at validate, by any evaluation with a ``query_dropout`` (docs/plugins.md).
    handles_missing: ClassVar[bool] = False

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        self.params = self.validate_params(params or {})

    @classmethod
    def validate_params(cls, params: Mapping[str, Any]) -> ExtractorParams:
        """Parse ``params`` with the extractor's schema; raise one clear error per bad key."""
        try:
            return cls.Params.model_validate(dict(params))
        except pydantic.ValidationError as exc:  # unknown keys with the nearest parameter suggested
            raise ExtractorParamsError(format_validation_error(f"extractor '{cls.name}'", exc, cls.Params)) from None

    @classmethod
    def memory_bytes(cls, params: ExtractorParams, train_samples: int) -> tuple[int, str, str]:
        """Memory the method needs beyond the recorded runs, for ``train_samples`` training
        samples: (bytes, the parameter that drives it, what needs it), checked against the
        machine before any compute. The default: nothing worth counting."""
        return 0, "", "nothing"

    @classmethod
    def modalities(cls, params: ExtractorParams) -> frozenset[str] | None:
        """The senses the features of this extractor with ``params`` use: a set of `VISUAL`
        and `TACTILE`, or None for "unknown" (the default). The pipeline pairs a vision-only
        and a touch-only configuration of one extractor to measure their complementarity
        (docs/plugins.md); a plugin that does not say is never paired by itself."""
        return None

    @abstractmethod
    def fit(self, train: Run) -> None:
        """Learn whatever the method needs (weights, scalers, distance scales) from a training run."""

    @abstractmethod
    def transform(self, run: Run) -> Features:
        """Per-sample features of ``run``."""

    @abstractmethod
    def distance(self, query: Features, reference: Features) -> np.ndarray:
        """Template-match error matrix, shape (n_query, n_reference), lower = more similar."""

    def training_history(self) -> dict[str, list[float]]:
        """Per-epoch training curves to plot (e.g. energy per layer); empty when not iterative."""
        return {}

    def training_summary(self) -> dict[str, object]:
        """How training ended, for the manifest (e.g. epochs run, converged or not); empty when
        not iterative."""
        return {}

    def save(self, directory: str | Path) -> None:
        """Write parameters and fitted state to ``directory`` (created if needed)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        (directory / "params.json").write_text(json.dumps(self.params.model_dump(mode="json"), indent=2))
        self.save_state(directory)

    @classmethod
    def load(cls, directory: str | Path) -> FeatureExtractor:
        """Rebuild a fitted extractor saved by `save`."""
        directory = Path(directory)
        extractor = cls(json.loads((directory / "params.json").read_text()))
        extractor.load_state(directory)
        return extractor

    @abstractmethod
    def save_state(self, directory: Path) -> None:
        """Write the fitted state (everything `fit` learned) into ``directory``."""

    @abstractmethod
    def load_state(self, directory: Path) -> None:
        """Read the fitted state written by `save_state`."""


def save_features(path: str | Path, features: Features) -> None:
    """Write features to an ``.npz`` file atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            arrays: Mapping[str, Any] = features  # Any: not allow_pickle's bool
            np.savez(f, **arrays)


def load_features(path: str | Path) -> Features:
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def warn_once(run: Run, feature: str, message: str) -> None:
    """Warn, once per run and feature, that ``feature`` cannot use ``run``'s data (e.g. a
    recorded run without contacts): logged on the ``vitaplace`` logger and kept in
    ``run.warnings``, which the runner copies into manifest.json."""
    if feature in run.warnings:
        return
    run.warnings[feature] = message
    logging.getLogger("vitaplace").warning(message)


#: the share of a channel's evaluation values inside its training range under which the facts count it
IN_RANGE_SHARE = 0.99


def feature_facts(features: Features) -> dict[str, Any]:
    """What the manifest (``features``) and the report say about one method's features of one run:
    its feature arrays (float, one row of at least one column per sample), those that are
    all zero, and, for features that record test-time inference (``inference_steps``,
    ``inference_stopped``: under the thresholds; ``inference_settled``: a stopping rule ended
    it, the same as stopped where absent), the step counts' median, 90th percentile and
    largest value, the samples under the thresholds, those that hit the step cap (not
    settled) and the number of samples; and, for features that measure the tactile input
    against its training range (``tactile_inside``: (N, C) bool per value; ``tactile_beyond``:
    (N,) the farthest excess beyond [0, 1] in scaled units; ``tactile_measured``: (N,) bool,
    the samples measured, every one where absent), the values measured and inside, the
    channels, the lowest channel's share inside, the channels under `IN_RANGE_SHARE` and the
    largest excess; and, for features that record vision's share of the drive on the joint
    latent (``drive_visual_share``, (N,); ``drive_measured``: (N,) bool, the samples with both
    modalities, every one where absent), the samples measured and the share's 10th percentile,
    median and 90th percentile over them (None without any)."""
    arrays = sorted(k for k, v in features.items() if v.dtype.kind == "f" and v.ndim >= 2)
    facts: dict[str, Any] = {"arrays": arrays, "zero": [k for k in arrays if not features[k].any()]}
    if "inference_steps" in features and "inference_stopped" in features:
        steps, stopped = features["inference_steps"], features["inference_stopped"].astype(bool)
        settled = features["inference_settled"].astype(bool) if "inference_settled" in features else stopped
        facts["inference"] = {"median": float(np.median(steps)), "p90": float(np.percentile(steps, 90)),
                              "max": steps.max().item(), "stopped": int(stopped.sum()),
                              "capped": int((~settled).sum()), "samples": int(stopped.size)}
    if "tactile_inside" in features and "tactile_beyond" in features:
        beyond = np.asarray(features["tactile_beyond"], np.float64)
        measured = (features["tactile_measured"].astype(bool) if "tactile_measured" in features
                    else np.ones(len(beyond), bool))
        inside = features["tactile_inside"].astype(bool)[measured]
        per_channel = inside.mean(axis=0) if len(inside) else np.ones(inside.shape[1])
        facts["tactile_range"] = {
            "values": int(inside.size), "inside": int(inside.sum()), "channels": int(inside.shape[1]),
            "channel_min": float(per_channel.min(initial=1.0)),
            "channels_under": int((per_channel < IN_RANGE_SHARE).sum()),
            "beyond": float(beyond[measured].max(initial=0.0)), "samples": int(measured.sum()),
        }
    if "drive_visual_share" in features:
        share = np.asarray(features["drive_visual_share"], np.float64)
        if "drive_measured" in features:
            share = share[features["drive_measured"].astype(bool)]
        p10, median, p90 = (float(v) for v in np.percentile(share, [10, 50, 90])) if len(share) else (None,) * 3
        facts["drive"] = {"samples": len(share), "p10": p10, "median": median, "p90": p90}
    return facts
