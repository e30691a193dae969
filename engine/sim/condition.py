"""The condition a run is recorded under: its lighting and the state of its camera.

Visual place-recognition datasets revisit places under other conditions (another season,
night instead of day, fog, a dirty lens); a run's ``condition:`` (`Condition`) does that to a
simulated drive. It has three parts:

* ``light`` (`LightCondition`) changes the environment's lights in the MuJoCo model
  (`engine/sim/build.py`): every light level (suns, ambient, headlight) is multiplied by
  ``intensity``, every sun travels along ``direction`` instead of its own, and every light is
  tinted by the colour of a black body at ``colour_temperature_k`` (`kelvin_rgb`);
* ``camera`` (`CameraCondition`) degrades each rendered frame (`degrade`), in the order a
  camera does it: optical blur (a Gaussian of ``blur_sigma_px``), the sensor's gain
  (``exposure``: intensities times it), additive Gaussian sensor noise (``noise_std`` grey
  levels), rounding and clipping to 0-255, then the occluded part of the image set to 0
  (``occlusion``: ``share`` of the rows or columns from ``side``);
* ``fog`` (`Fog`) fills the air between the camera and the world, as MuJoCo's renderer draws
  it (OpenGL's linear fog, set in the compiled model by `engine/sim/simulate.py`): a surface
  at depth z along the camera's axis is seen as ``f`` times its own colour plus ``1 - f``
  times the fog's, ``f = (end_m - z) / (end_m - start_m)`` clipped to [0, 1] (before the
  camera's degradation, which acts on the frame).

The noise is drawn from its own random stream of the run's seed (`noise_rng`), apart from
the controller's, so a run is reproducible and a noisy drive follows the same path as a
clean one. The defaults change nothing: a run whose condition is the default records exactly
the frames of a run without one, and its cache key is the same (`is_default`).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import ConfigDict, Field, field_validator, model_validator

from vitaplace.engine.base.configfile import NumbersNotBooleans

__all__ = ["Condition", "LightCondition", "CameraCondition", "Fog", "Occlusion", "kelvin_rgb", "light_rgb",
           "degrade", "noise_rng", "is_default", "NOISE_STREAM"]

#: the entropy word that separates the camera noise's stream from the controller's (`noise_rng`)
NOISE_STREAM = 0xC0FFEE


class _Settings(NumbersNotBooleans):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class LightCondition(_Settings):
    """How the environment's lights differ in this run."""

    intensity: float = Field(
        1.0, ge=0, le=10, description="every light level of the environment (suns, ambient, headlight) times this"
    )
    direction: tuple[float, float, float] | None = Field(
        None, description="direction every sun travels [x, y, z] (e.g. [1, 0, -0.2]: low, from the west); "
        "null: each sun's own"
    )
    colour_temperature_k: float | None = Field(
        None, ge=1000, le=40000, description="colour of every light: a black body at this temperature [K] "
        "(Helland's fit, `kelvin_rgb`; 6600 K is white); null: white"
    )

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is not None and not any(v):
            raise ValueError("direction must not be zero")
        return v


class Occlusion(_Settings):
    """A part of the image blanked (set to 0), e.g. a lens covered from one edge."""

    share: float = Field(0.0, ge=0, lt=1, description="share of the image's rows (top, bottom) or columns "
                         "(left, right) blanked, rounded to whole pixels; below 1 (a camera that sees nothing is "
                         "a lost one: an evaluation's query_dropout)")
    side: Literal["top", "bottom", "left", "right"] = Field("bottom", description="the edge the blanked part starts at")


class CameraCondition(_Settings):
    """How each rendered frame is degraded (in this order: blur, exposure, noise, occlusion)."""

    blur_sigma_px: float = Field(0.0, ge=0, le=20, description="std of the Gaussian blur [pixels]; 0: sharp")
    exposure: float = Field(1.0, gt=0, le=16, description="sensor gain: every intensity times this, clipped to 255")
    noise_std: float = Field(
        0.0, ge=0, le=128, description="std of additive Gaussian sensor noise [grey levels of 0-255], per pixel and "
        "channel"
    )
    occlusion: Occlusion = Field(Occlusion(), description="the part of the image blanked")


class Fog(_Settings):
    """Nearer than ``start_m`` a surface is seen as it is, from ``end_m`` on only the fog's
    colour, mixed linearly in its depth in between."""

    start_m: float = Field(0.0, ge=0, le=100, description="depth along the camera's axis where the fog starts [m]")
    end_m: float = Field(gt=0, le=100, description="depth from which only the fog is seen [m] (> start_m)")
    colour: tuple[float, float, float] = Field(
        (0.75, 0.75, 0.75), description="the fog's RGB, each in [0, 1] (default a light grey)"
    )

    @field_validator("colour")
    @classmethod
    def _unit(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(0.0 <= c <= 1.0 for c in v):
            raise ValueError("colour must be three values in [0, 1]")
        return v

    @model_validator(mode="after")
    def _ordered(self) -> Fog:
        if self.end_m <= self.start_m:
            raise ValueError(f"end_m ({self.end_m}) must be greater than start_m ({self.start_m})")
        return self


class Condition(_Settings):
    """The condition of a run: its lighting, its camera's state and the fog (defaults: unchanged)."""

    light: LightCondition = Field(LightCondition(), description="lighting: intensity, direction, colour temperature")
    camera: CameraCondition = Field(
        CameraCondition(), description="camera degradation: blur, exposure, noise, occlusion"
    )
    fog: Fog | None = Field(None, description="fog between the camera and the world (null: clear air)")


def is_default(condition: Condition | None) -> bool:
    """Whether ``condition`` changes nothing (None or every field at its default)."""
    return condition is None or condition == Condition()


def kelvin_rgb(kelvin: float) -> tuple[float, float, float]:
    """RGB in [0, 1] of a black body at ``kelvin`` (1000-40000 K), by Tanner Helland's fit to
    Mitchell Charity's black-body table: with t = kelvin / 100,

        R = 255                                 if t <= 66, else 329.698727446 (t - 60)^-0.1332047592
        G = 99.4708025861 ln t - 161.1195681661 if t <= 66, else 288.1221695283 (t - 60)^-0.0755148492
        B = 255 if t >= 66, 0 if t <= 19,       else 138.5177312231 ln(t - 10) - 305.0447927307

    each clipped to [0, 255] and divided by 255 (6600 K gives white)."""
    t = kelvin / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = 99.4708025861 * math.log(t) - 161.1195681661 if t <= 66 else 288.1221695283 * (t - 60) ** -0.0755148492
    b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * math.log(t - 10) - 305.0447927307)
    return tuple(min(max(c, 0.0), 255.0) / 255.0 for c in (r, g, b))  # type: ignore[return-value]


def light_rgb(level: float, light: LightCondition | None) -> list[float]:
    """The RGB of a light of grey ``level`` under ``light``: level x intensity x colour."""
    if light is None:
        return [level] * 3
    colour = (1.0, 1.0, 1.0) if light.colour_temperature_k is None else kelvin_rgb(light.colour_temperature_k)
    return [level * light.intensity * c for c in colour]


def noise_rng(seed: int) -> np.random.Generator:
    """The camera noise's random stream of a run of ``seed`` (independent of the controller's)."""
    return np.random.default_rng([int(seed), NOISE_STREAM])


def occluded(shape: tuple[int, ...], occlusion: Occlusion) -> tuple[slice, slice]:
    """The (rows, columns) slice of an image of ``shape`` that ``occlusion`` blanks."""
    height, width = shape[:2]
    if occlusion.side in ("top", "bottom"):
        k = int(round(occlusion.share * height))
        rows = slice(0, k) if occlusion.side == "top" else slice(height - k, height)
        return rows, slice(0, width)
    k = int(round(occlusion.share * width))
    return slice(0, height), (slice(0, k) if occlusion.side == "left" else slice(width - k, width))


def degrade(image: np.ndarray, camera: CameraCondition, rng: np.random.Generator) -> np.ndarray:
    """``image`` (H, W, 3) uint8 as the degraded camera records it (module docstring's order);
    the image itself when ``camera`` is the default."""
    if camera == CameraCondition():
        return image
    out = image.astype(np.float64)
    if camera.blur_sigma_px > 0:
        from scipy.ndimage import gaussian_filter

        out = gaussian_filter(out, sigma=(camera.blur_sigma_px, camera.blur_sigma_px, 0), mode="nearest")
    out *= camera.exposure
    if camera.noise_std > 0:
        out += rng.normal(0.0, camera.noise_std, size=out.shape)
    result = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    result[occluded(result.shape, camera.occlusion)] = 0
    return result
