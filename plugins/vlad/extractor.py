"""`VladExtractor`: VLAD (vector of locally aggregated descriptors) over dense SIFT.

Local descriptors: OpenCV's SIFT computed at fixed keypoints on a dense grid of the grey
image (BT.601 luma), every ``step`` pixels, each ``patch_size`` pixels across and upright
(angle 0) — dense rather than detected keypoints, since the camera's small frames give a
detector few and unstable points. An image smaller than one patch has one keypoint, at its
centre.

Vocabulary: k-means (scikit-learn's KMeans, k-means++ seeded by ``seed``) of ``clusters``
centres c_k, fitted on the training run's descriptors only (at most ``max_descriptors`` of
them, drawn by ``seed``), in float64 (`vocabulary`), saved and loaded with the extractor;
`transform` never changes it.

VLAD of an image with descriptors x_i (Jegou et al. 2010; Arandjelovic & Zisserman 2013):
v_k = sum of (x_i - c_k) over the x_i whose nearest centre is c_k; then the signed square
root sign(v) sqrt(|v|), each v_k scaled to unit length (intra-normalisation: no one bursty
visual word dominates), and the whole (clusters x 128) vector to unit length. Two samples are
as far apart as their VLADs (Euclidean).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pydantic
from sklearn.cluster import KMeans

from vitaplace.plugin import ExtractorParams, ExtractorParamsError, Features, Run

from ..image_descriptor import ImageDescriptorExtractor, ImageDescriptorParams, grey, require, unit_rows

VOCABULARY_FILE = "vlad_vocabulary.npy"
#: length of a SIFT descriptor
SIFT_SIZE = 128


class VladParams(ImageDescriptorParams):
    """Parameters of the VLAD baseline (unknown keys are errors)."""

    clusters: int = pydantic.Field(64, ge=1, description="visual words k of the vocabulary (k-means centres)")
    step: int = pydantic.Field(8, ge=1, description="spacing of the dense keypoint grid [px]")
    patch_size: int = pydantic.Field(16, ge=2, description="diameter of a keypoint's patch [px] (SIFT's size)")
    max_descriptors: int = pydantic.Field(
        50_000, ge=1, description="at most this many training descriptors (drawn by seed) enter k-means")
    seed: int = pydantic.Field(0, ge=0, le=2**32 - 1, description="seed of the descriptors drawn and of k-means++")


def grid(rows: int, cols: int, step: int, patch: int) -> list[tuple[float, float]]:
    """(x, y) keypoint centres every ``step`` px with the whole patch inside the image; the
    centre alone when the image is smaller than a patch."""
    def axis(size: int) -> np.ndarray:
        centres = np.arange(patch / 2, size - patch / 2 + 1e-9, step)
        return centres if len(centres) else np.array([(size - 1) / 2])
    return [(float(x), float(y)) for y in axis(rows) for x in axis(cols)]


def vocabulary(descriptors: np.ndarray, clusters: int, seed: int) -> np.ndarray:
    """The (clusters, d) k-means centres of ``descriptors``, float64. In float32 the result
    depends on the BLAS kernel and the thread count: an assignment that flips in one iteration
    sends the rest elsewhere (on a training run of the third study, two kernels agreed on 20 %
    of the labels); in float64 they agree on every label and on the centres to ~1e-14."""
    kmeans = KMeans(n_clusters=clusters, n_init=1, random_state=seed).fit(np.asarray(descriptors, dtype=np.float64))
    return np.asarray(kmeans.cluster_centers_, dtype=np.float64)


def vlad(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """VLAD of one image's (m, d) descriptors with the (k, d) vocabulary: (k * d,), unit length
    (all zeros without descriptors); see the module's docstring."""
    k, d = centres.shape
    v = np.zeros((k, d))
    if len(descriptors):
        x = np.asarray(descriptors, dtype=np.float64)
        squared = (x ** 2).sum(1)[:, None] - 2 * x @ centres.T + (centres ** 2).sum(1)[None, :]
        nearest = np.argmin(squared, axis=1)
        np.add.at(v, nearest, x - centres[nearest])
    v = unit_rows(np.sign(v) * np.sqrt(np.abs(v)))
    return unit_rows(v.reshape(-1))


class VladExtractor(ImageDescriptorExtractor):
    """Vision baseline: VLAD of dense SIFT with a k-means vocabulary of the training run, Euclidean distance."""

    name: ClassVar[str] = "vlad"
    Params: ClassVar[type[ExtractorParams]] = VladParams
    feature: ClassVar[str] = "vlad"
    libraries: ClassVar[dict[str, str]] = {"cv2": "opencv-python-headless"}
    params: VladParams

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        #: (clusters, 128) k-means centres of the training run's descriptors; None until fit or load
        self.vocabulary: np.ndarray | None = None

    @property
    def dimension(self) -> int:
        return self.params.clusters * SIFT_SIZE

    def local_descriptors(self, images: np.ndarray) -> list[np.ndarray]:
        """Dense SIFT of each image: one (m, 128) float32 array per image (SIFT's own type, half
        the memory of the training run's descriptors that k-means holds)."""
        cv2 = require("cv2", "opencv-python-headless", self.name)
        sift = cv2.SIFT_create()
        p = self.params
        centres = grid(images.shape[1], images.shape[2], p.step, p.patch_size)
        out = []
        for image in np.rint(grey(images) * 255).astype(np.uint8):
            _, found = sift.compute(image, [cv2.KeyPoint(x, y, p.patch_size, 0) for x, y in centres])
            out.append(np.zeros((0, SIFT_SIZE), np.float32) if found is None else found)
        return out

    def describe(self, images: np.ndarray) -> np.ndarray:
        assert self.vocabulary is not None  # transform checks
        return np.stack([vlad(x, self.vocabulary) for x in self.local_descriptors(images)]).astype(np.float32)

    def transform(self, run: Run) -> Features:
        if self.vocabulary is None:
            raise RuntimeError(f"extractor '{self.name}' is not fitted: call fit() or load() first")
        return super().transform(run)

    def fit(self, train: Run) -> None:
        p = self.params
        descriptors = np.concatenate([np.zeros((0, SIFT_SIZE), np.float32)] + [
            x for images in self.image_batches(train) for x in self.local_descriptors(images)])
        if len(descriptors) < p.clusters:
            raise ExtractorParamsError(f"extractor '{self.name}': clusters={p.clusters} is more than the "
                                       f"{len(descriptors)} local descriptors of training run {train.name}; "
                                       "lower clusters (or step)")
        rng = np.random.default_rng(p.seed)
        if len(descriptors) > p.max_descriptors:
            descriptors = descriptors[np.sort(rng.choice(len(descriptors), p.max_descriptors, replace=False))]
        self.vocabulary = vocabulary(descriptors, p.clusters, p.seed)

    def save_state(self, directory: Path) -> None:
        if self.vocabulary is None:
            raise RuntimeError(f"extractor '{self.name}' is not fitted: nothing to save")
        np.save(Path(directory) / VOCABULARY_FILE, self.vocabulary)

    def load_state(self, directory: Path) -> None:
        path = Path(directory) / VOCABULARY_FILE
        if not path.is_file():
            raise ValueError(f"{path}: no fitted state of extractor '{self.name}'")
        vocabulary = np.load(path)
        if vocabulary.shape != (self.params.clusters, SIFT_SIZE):
            raise ValueError(f"{path}: a vocabulary of shape {vocabulary.shape}, expected "
                             f"({self.params.clusters}, {SIFT_SIZE}) for clusters={self.params.clusters}")
        self.vocabulary = vocabulary
