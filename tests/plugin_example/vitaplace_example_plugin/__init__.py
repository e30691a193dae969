"""A minimal third-party vitaplace feature extractor: the mean colour of each camera image.

Feature of a sample = (mean R, mean G, mean B) of its image and the mean protraction angle
theta of its whiskers; distance = L1 (city-block), with theta scaled by ``theta_weight``.
``fit`` learns the mean feature of the training run, which ``transform`` subtracts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pydantic
from scipy.spatial.distance import cdist

from vitaplace.plugin import ExtractorParams, FeatureExtractor, Features, Run, hookimpl


class MeanColourParams(ExtractorParams):
    """Parameters of ``example-mean-colour``; unknown keys are rejected by `ExtractorParams`."""

    theta_weight: float = pydantic.Field(1.0, ge=0.0, description="weight of mean theta [1/rad] in the L1 distance")


class MeanColourExtractor(FeatureExtractor):
    """Mean RGB colour + mean whisker theta per sample, compared with the L1 distance."""

    name = "example-mean-colour"
    Params = MeanColourParams
    params: MeanColourParams

    def __init__(self, params=None) -> None:
        super().__init__(params)
        self.centre: np.ndarray | None = None  # the fitted state: mean feature of the training run

    def _raw(self, run: Run) -> np.ndarray:
        colour = run.images.reshape(len(run), -1, 3).mean(axis=1)  # (N, 3)
        theta = run.theta.mean(axis=1, keepdims=True) * self.params.theta_weight  # (N, 1)
        return np.concatenate([colour, theta], axis=1).astype(np.float64)

    def fit(self, train: Run) -> None:
        self.centre = self._raw(train).mean(axis=0)

    def transform(self, run: Run) -> Features:
        if self.centre is None:
            raise RuntimeError(f"{self.name}: fit() or load() before transform()")
        return {"colour_theta": self._raw(run) - self.centre}

    def distance(self, query: Features, reference: Features) -> np.ndarray:
        return cdist(query["colour_theta"], reference["colour_theta"], metric="cityblock")

    def save_state(self, directory: Path) -> None:
        if self.centre is None:
            raise RuntimeError(f"{self.name}: nothing to save before fit()")
        np.save(directory / "centre.npy", self.centre)

    def load_state(self, directory: Path) -> None:
        self.centre = np.load(directory / "centre.npy")


@hookimpl
def vitaplace_register_features(register) -> None:
    register(MeanColourExtractor)
