"""The backprop control of MuPNet (``autoencoder``): the same architecture, inputs, scaling,
activation, minibatches and epochs, trained end to end by backprop as an autoencoder
(`vitaplace.plugins.autoencoder.model`); the feature of a sample is its joint code, the
encoder's output (one pass, no test-time inference). Distance: L2.

It answers whether the *learning rule* matters: MuPNet's local predictive-coding updates and
iterative inference against gradient descent on the reconstruction error of the same
generative path (docs/MUPNET.md, "The backprop control").
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import pydantic
from pydantic import Field
from scipy.spatial.distance import cdist
from tqdm.auto import tqdm

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.plugin import ExtractorParams, FeatureExtractor, Features, Run
from vitaplace.plugins.autoencoder.model import Autoencoder, Encoder, OptimizerName, TrainingSettings, train
from vitaplace.plugins.mupnet.extractor import ArchitectureParams
from vitaplace.plugins.mupnet.inputs import TactileRange, range_measure, raw_inputs, report_out_of_range, training_range

WEIGHTS_FILE = "weights.npz"


class AutoencoderParams(ArchitectureParams):
    """MuPNet's architecture and training length (the same keys and defaults), and the backprop settings."""

    encoder: Encoder = Field(
        "learned", description="learned: an encoder of its own mirroring the generative path; tied: the "
        "generative path's transposed weights (MuPNet's parameter count)",
    )
    optimizer: OptimizerName = Field("adam", description="adam (Kingma and Ba's decay rates) or sgd (plain steps)")
    learning_rate: pydantic.PositiveFloat = Field(1e-3, description="step size of the optimizer")
    backend: Literal["numpy", "fixed"] = Field(
        "numpy", description="numpy (products of matrices through BLAS), or fixed: through numpy's own loops, "
        "the same bits under any BLAS kernel, as MuPNet's fixed backend",
    )

    def training_settings(self) -> TrainingSettings:
        return TrainingSettings(self.epochs, self.batch_size, self.learning_rate, self.optimizer, self.seed,
                                self.converge_window, self.converge_tol)


class AutoencoderExtractor(FeatureExtractor):
    """Backprop control of MuPNet: its architecture trained as an autoencoder, the joint code as the feature."""

    name = "autoencoder"
    Params = AutoencoderParams
    params: AutoencoderParams

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        self.model: Autoencoder | None = None
        self.tactile_range: TactileRange | None = None
        self.history: dict[str, list[float]] = {}
        self.converged = False

    @classmethod
    def memory_bytes(cls, params: ExtractorParams, train_samples: int) -> tuple[int, str, str]:
        """The first visual layer's weights (decoder, encoder unless tied), their gradients and
        optimizer moments, and the training images."""
        params = cast(AutoencoderParams, params)  # made by validate_params from cls.Params
        h, w = params.image_size
        inputs = h * w * 3 if "visual" in params.modalities else 0
        copies = (1 if params.encoder == "tied" else 2) * (4 if params.optimizer == "adam" else 2)
        need = inputs * params.visual_layers[0] * 4 * copies + train_samples * inputs * 4
        return need, "image_size", f"{h}x{w} images"

    def _new_model(self, sizes: Mapping[str, list[int]]) -> Autoencoder:
        """The model of these parameters with layer ``sizes`` (per modality, input first)."""
        p = self.params
        return Autoencoder(sizes, p.joint_size, activation=p.activation, slope=p.slope, encoder=p.encoder,
                           seed=p.seed, fixed_order=p.backend == "fixed")

    def _scaled(self, raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        scaled = {}
        if "visual" in raw:
            scaled["visual"] = raw["visual"] * np.float32(1 / 255)
        if "tactile" in raw:
            assert self.tactile_range is not None  # fitted with the tactile input, or loaded
            scaled["tactile"] = self.tactile_range.scale(raw["tactile"])  # tactile_scaling
        return scaled

    def fit(self, train_run: Run) -> None:
        p = self.params
        raw = raw_inputs(train_run, p)
        if "tactile" in raw:
            self.tactile_range = training_range(train_run, raw["tactile"], p, self.name)
        inputs = self._scaled(raw)
        layers = {"visual": p.visual_layers, "tactile": p.tactile_layers}
        self.model = self._new_model({m: [x.shape[1], *layers[m]] for m, x in inputs.items()})
        minibatches = p.epochs * math.ceil(len(train_run) / p.batch_size)
        with tqdm(total=minibatches, desc="train", unit="batch", disable=not self.progress) as bar:
            def on_progress(epoch: int, loss: float) -> None:
                bar.update()
                bar.set_postfix(epoch=epoch, L=f"{loss:.4g}")

            self.history, self.converged = train(self.model, inputs, p.training_settings(), on_progress, self.on_epoch)

    def training_history(self) -> dict[str, list[float]]:
        return self.history

    def training_summary(self) -> dict[str, object]:
        epochs = len(next(iter(self.history.values()), []))
        return {"epochs": epochs, "max_epochs": self.params.epochs, "converged": self.converged}

    def transform(self, run: Run) -> Features:
        if self.model is None:
            raise RuntimeError("autoencoder: fit() or load() before transform()")
        raw = raw_inputs(run, self.params)
        features = {"latent": self.model.encode(self._scaled(raw))}
        if self.tactile_range is not None:  # the tactile values inside the training range (`range_measure`)
            report_out_of_range(run, raw["tactile"], self.tactile_range, self.params, self.name)
            features |= range_measure(raw["tactile"], self.tactile_range, ~run.lacks("whiskers"))
        return features

    def distance(self, query: Features, reference: Features) -> np.ndarray:
        return cdist(query["latent"], reference["latent"])

    def save_state(self, directory: Path) -> None:
        if self.model is None:
            raise RuntimeError("autoencoder: nothing to save before fit()")
        weights: dict[str, Any] = self.model.weights  # Any: np.savez's stub would bind a key named allow_pickle
        np.savez(directory / WEIGHTS_FILE, **weights)
        model = {"sizes": self.model.sizes, "converged": self.converged, "history": self.history}
        write_text_atomic(directory / "model.json", json.dumps(model))
        if self.tactile_range is not None:
            self.tactile_range.save(directory)

    def load_state(self, directory: Path) -> None:
        p = self.params
        model = json.loads((directory / "model.json").read_text())
        self.model = self._new_model(model["sizes"])
        with np.load(directory / WEIGHTS_FILE) as saved:
            self.model.weights = {name: saved[name] for name in saved.files}
        self.history, self.converged = model["history"], model["converged"]
        self.tactile_range = TactileRange.load(directory) if "tactile" in p.modalities else None
