"""What the vision baselines `hog` and `vlad` share: one global descriptor per camera image,
unit length, compared by the Euclidean distance (for unit vectors sqrt(2 - 2 cos), so the
order of the cosine similarity).

Their libraries (scikit-image, OpenCV) are the optional extra ``vision``: they are imported
when an extractor is validated or built, never when the plugin is discovered, so without them
a scenario naming ``hog`` or ``vlad`` fails at validate in one line that names the extra.

Missing modalities (`Run.lacks`, a query drop-out): a sample without the camera has an
all-zero descriptor and the flag ``missing_camera``; a pair in which either sample lacks it
cannot be compared and is +inf apart (never a match), as the vision half of a late fusion
expects.
"""

from __future__ import annotations

import importlib
from abc import abstractmethod
from collections.abc import Iterator, Mapping
from types import ModuleType
from typing import Any, ClassVar

import numpy as np
import pydantic
from scipy.spatial.distance import cdist

from vitaplace.plugin import VISUAL, ExtractorParams, ExtractorParamsError, FeatureExtractor, Features, Run

#: ITU-R BT.601 luma weights of R, G and B (OpenCV's RGB -> grey)
LUMA = np.array([0.299, 0.587, 0.114])
EXTRA = "pip install 'vitaplace[vision]'"
#: references compared per cdist call: their float64 copy, not all of them, is what a call holds
#: (20,000 VLAD descriptors of 8,192 values are 1.3 GB in float64)
REFERENCE_BLOCK = 2048


def grey(images: np.ndarray) -> np.ndarray:
    """(n, H, W, 3) uint8 RGB -> (n, H, W) float64 luma in [0, 1]."""
    return np.asarray(images, dtype=np.float64) @ LUMA / 255.0


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Each row divided by its L2 norm; an all-zero row stays zero."""
    norms = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, norms, out=np.zeros_like(x), where=norms > 0)


def require(module: str, distribution: str, extractor: str) -> ModuleType:
    """``module`` imported, or `ExtractorParamsError` (a one-line user error) naming the extra."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ExtractorParamsError(f"extractor '{extractor}' needs {distribution} ({exc}): {EXTRA}") from None


class ImageDescriptorParams(ExtractorParams):
    """What every image-descriptor baseline takes."""

    batch_size: int = pydantic.Field(256, ge=1, description="images described per batch (a run is never loaded whole)")


class ImageDescriptorExtractor(FeatureExtractor):
    """Base of the vision baselines: ``describe`` a batch of images, compare the descriptors."""

    handles_missing: ClassVar[bool] = True
    #: the key of the descriptor in the features
    feature: ClassVar[str]
    #: module -> the distribution that brings it (both in the extra ``vision``)
    libraries: ClassVar[dict[str, str]]
    params: ImageDescriptorParams

    @classmethod
    def validate_params(cls, params: Mapping[str, Any]) -> ExtractorParams:
        """The libraries first (a missing one is the first thing to fix), then the parameters."""
        for module, distribution in cls.libraries.items():
            require(module, distribution, cls.name)
        return super().validate_params(params)

    @classmethod
    def modalities(cls, params: ExtractorParams) -> frozenset[str]:
        return frozenset([VISUAL])

    @property
    @abstractmethod
    def dimension(self) -> int:
        """d, the length of a descriptor."""

    @abstractmethod
    def describe(self, images: np.ndarray) -> np.ndarray:
        """(n, H, W, 3) uint8 RGB images, n >= 1 -> (n, d) unit-length descriptors (zero for a blank image)."""

    def image_batches(self, run: Run) -> Iterator[np.ndarray]:
        """The images of ``run``, ``batch_size`` at a time."""
        n, size = len(run), self.params.batch_size
        for start in range(0, n, size):
            yield run.image_batch(start, min(start + size, n))

    def transform(self, run: Run) -> Features:
        batches = [self.describe(images) for images in self.image_batches(run)]
        descriptors = np.concatenate(batches) if batches else np.zeros((0, self.dimension))
        features: Features = {self.feature: descriptors}
        if run.missing:
            lacks = run.lacks("camera")
            descriptors[lacks] = 0
            features["missing_camera"] = lacks
        return features

    def distance(self, query: Features, reference: Features) -> np.ndarray:
        for side, feats in (("query", query), ("reference", reference)):
            if self.feature not in feats:
                raise ValueError(f"extractor '{self.name}': {side} features lack '{self.feature}' "
                                 f"(have {sorted(feats)})")
        q, r = np.asarray(query[self.feature], dtype=np.float64), reference[self.feature]
        d = np.zeros((len(q), len(r)))
        for start in range(0, len(r) if len(q) else 0, REFERENCE_BLOCK):  # float64 a block of references at a time
            d[:, start:start + REFERENCE_BLOCK] = cdist(q, np.asarray(r[start:start + REFERENCE_BLOCK], np.float64))
        has_q, has_r = (~np.asarray(f.get("missing_camera", np.zeros(len(x), bool)), bool)
                        for f, x in ((query, q), (reference, r)))
        return np.where(np.outer(has_q, has_r), d, np.inf)
