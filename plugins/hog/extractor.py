"""`HogExtractor`: a histogram of oriented gradients (Dalal & Triggs 2005) of each camera image.

Each image is turned to grey (BT.601 luma), resized to ``image_size`` and described by
scikit-image's HOG: unsigned gradient orientations in ``orientations`` bins per cell of
``pixels_per_cell`` square, the cells' histograms normalised per block of ``cells_per_block``
square cells with L2-Hys (L2, clipped at 0.2, L2 again), all blocks concatenated. The
descriptor is then scaled to unit L2 length and two samples are as far apart as their unit
descriptors (Euclidean). A flat image has no gradient: its descriptor is all zeros.

The defaults are Dalal & Triggs's best pedestrian detector: 9 orientation bins over 0-180
degrees, 8 x 8-pixel cells, 2 x 2-cell blocks, L2-Hys, on a 64 x 128 window, here laid on its
side (64 rows, 128 columns) like the camera's landscape frame. Nothing is learned: ``fit``
does nothing and the extractor has no state to save.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar

import numpy as np
import pydantic

from vitaplace.plugin import ExtractorParams, Run

from ..image_descriptor import ImageDescriptorExtractor, ImageDescriptorParams, grey, require, unit_rows

PositiveInt = Annotated[int, pydantic.Field(ge=1)]


class HogParams(ImageDescriptorParams):
    """Parameters of the HOG baseline (unknown keys are errors)."""

    image_size: tuple[PositiveInt, PositiveInt] = pydantic.Field(
        (64, 128), description="(rows, columns) each grey image is resized to: Dalal & Triggs's 64 x 128 window, "
        "landscape")
    orientations: int = pydantic.Field(9, ge=1, description="orientation bins over 0-180 degrees (unsigned)")
    pixels_per_cell: int = pydantic.Field(8, ge=1, description="side of a square cell [px of the resized image]")
    cells_per_block: int = pydantic.Field(2, ge=1, description="side of a square block [cells], normalised with L2-Hys")

    @pydantic.model_validator(mode="after")
    def _one_block_fits(self) -> HogParams:
        block = self.pixels_per_cell * self.cells_per_block
        if min(self.image_size) < block:
            raise ValueError(f"image_size {list(self.image_size)} is smaller than one block of "
                             f"pixels_per_cell x cells_per_block = {block} px")
        return self


class HogExtractor(ImageDescriptorExtractor):
    """Vision baseline: HOG of the grey camera image (Dalal & Triggs), unit length, Euclidean distance."""

    name: ClassVar[str] = "hog"
    Params: ClassVar[type[ExtractorParams]] = HogParams
    feature: ClassVar[str] = "hog"
    libraries: ClassVar[dict[str, str]] = {"skimage": "scikit-image"}
    params: HogParams

    @property
    def dimension(self) -> int:
        p = self.params
        blocks = [size // p.pixels_per_cell - p.cells_per_block + 1 for size in p.image_size]
        return blocks[0] * blocks[1] * p.cells_per_block ** 2 * p.orientations

    def describe(self, images: np.ndarray) -> np.ndarray:
        feature = require("skimage.feature", "scikit-image", self.name)
        transform = require("skimage.transform", "scikit-image", self.name)
        p = self.params
        rows = [feature.hog(transform.resize(image, p.image_size, anti_aliasing=True), orientations=p.orientations,
                            pixels_per_cell=(p.pixels_per_cell,) * 2, cells_per_block=(p.cells_per_block,) * 2,
                            block_norm="L2-Hys", feature_vector=True)
                for image in grey(images)]
        return unit_rows(np.stack(rows))

    def fit(self, train: Run) -> None:
        """Nothing to learn."""

    def save_state(self, directory: Path) -> None:
        """No state: the parameters (params.json) are the whole extractor."""

    def load_state(self, directory: Path) -> None:
        """No state to read."""
