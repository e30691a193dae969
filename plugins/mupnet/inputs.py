"""The network inputs MuPNet and its backprop control (the ``autoencoder`` plugin) share.

* visual: the camera frame resampled (bilinear) to ``image_size`` and scaled to [0, 1];
* tactile, by ``tactile_input``:

  - ``instant`` (the paper's): theta and xy at the instant of maximum protraction, ``3 W``
    values (W theta, then x, y of each whisker);
  - ``cycle``: the xy deflection series of the whole whisk cycle at ``cycle_points`` (P)
    phase points per whisker (`cycle_series`), then one contact flag per whisker: 1 when its
    deflection ``|xy|`` exceeded the touch threshold (0.01 rad) at any of the cycle's S
    samples (`contact_flags`), ``W (2 P + 1)`` values. Theta is left out: it is the
    commanded protraction, not a reading of the world.

Each tactile channel is scaled on the training run by ``tactile_scaling``:

* ``range`` (the paper's, the default): min-max, ``(x - low) / max(high - low, floor)``, the
  floor ``tactile_min_range`` for measured channels and 1 for the contact flags (their own
  range); not clipped;
* ``clip``: the same, clipped to the training range: values beyond it saturate at its ends;
* ``robust``: ``(x - median) / max(IQR, tactile_min_range)`` of the training run (numpy's
  default percentiles), not clipped; the contact flags keep their own 0/1 scale.

Test values outside a channel's training range ``[low, high]`` are counted and reported once
per run (`report_out_of_range`), and measured per sample (`range_measure`: which values lie
inside it and how far the farthest lies beyond [0, 1] in the ``range`` scaling, whatever the
method's scaling), for the manifest's and the report's facts (`feature_facts`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import pydantic
from pydantic import Field
from scipy.ndimage import zoom

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.data.dataset import MAX_DEFLECTION_SAMPLES, TOUCH_THRESHOLD
from vitaplace.plugin import ExtractorParams, Run, warn_once

Modality = Literal["visual", "tactile"]
TactileInput = Literal["instant", "cycle"]
TactileScaling = Literal["range", "clip", "robust"]
#: the file a fitted extractor keeps its tactile channels' training range in
RANGE_FILE = "tactile_range.json"
#: a setting and the choices of it that read another setting (`InputParams.READ_ONLY_WITH`)
Reader = tuple[str, tuple[str, ...]]


def _both_modalities() -> list[Modality]:
    return ["visual", "tactile"]


class InputParams(ExtractorParams):
    """What the network is fed and how it is scaled."""

    modalities: list[Modality] = Field(
        default_factory=_both_modalities, min_length=1,
        description="modalities fed to the network (an ablation leaves one out; the left-out modality's settings "
        "- its layers, step sizes, thresholds, scaling, image size - are then accepted and not read, so that an "
        "ablation can share the whole network's settings block, as the shipped studies' YAML merge keys do)",
    )
    image_size: tuple[pydantic.PositiveInt, pydantic.PositiveInt] = Field(
        (45, 80), description="(rows, columns) the camera frames are resampled to"
    )
    tactile_input: TactileInput = Field(
        "instant", description="instant: theta and xy at maximum protraction (3 values per whisker, the paper's); "
        "cycle: the xy deflection series of the whisk cycle at cycle_points phase points plus a contact flag "
        "per whisker (2 cycle_points + 1 values per whisker; docs/MUPNET.md)",
    )
    cycle_points: pydantic.PositiveInt = Field(
        8, description="phase points of the whisk cycle the deflection series is interpolated at (tactile_input "
        f"cycle; the last is maximum protraction); at most {MAX_DEFLECTION_SAMPLES}, the most samples a simulated "
        "run's series holds (robot.deflection_samples)",
    )
    tactile_min_range: pydantic.NonNegativeFloat = Field(
        0.05,
        description="floor on each tactile channel's min-max range before scaling (theta and xy units): a channel "
        "that barely moved in training is not blown up to unit range",
    )
    tactile_scaling: TactileScaling = Field(
        "clip", description="how each tactile channel is scaled from the training run: range: (x - min) / "
        "max(max - min, tactile_min_range), not clipped (the paper's); clip (the default): the same clipped to the "
        "training range, so values beyond it saturate at its ends and the network is never fed touch it has not "
        "seen; robust: (x - median) / max(IQR, tactile_min_range), not clipped "
        "(the cycle input's contact flags keep their 0/1 scale; docs/MUPNET.md)",
    )

    #: settings that only some choices of other settings read: key -> the readers, each (a
    #: setting, the choices of it that read the key), any one of them enough; with none of
    #: them chosen a value other than the key's default would be ignored, so it is refused
    #: (`_no_ignored_setting`). A left-out modality's settings are not refused (`modalities`).
    READ_ONLY_WITH: ClassVar[dict[str, tuple[Reader, ...]]] = {
        "cycle_points": (("tactile_input", ("cycle",)),),
    }

    @pydantic.model_validator(mode="after")
    def _no_ignored_setting(self) -> InputParams:
        for key, readers in self.READ_ONLY_WITH.items():
            value = getattr(self, key)
            if any(getattr(self, setting) in choices for setting, choices in readers):
                continue
            if value != type(self).model_fields[key].default:
                chosen = " and ".join(f"{setting} {getattr(self, setting)}" for setting, _ in readers)
                choose = " or ".join(f"{setting} {' or '.join(choices)}" for setting, choices in readers)
                reading = " or ".join(readers[0][1]) if len(readers) == 1 else choose
                raise ValueError(f"{key} {value} is ignored by {chosen} (only {reading} reads it); leave {key} out "
                                 f"or choose {choose}")
        return self

    @pydantic.field_validator("cycle_points")
    @classmethod
    def _no_more_points_than_samples(cls, value: int) -> int:
        if value > MAX_DEFLECTION_SAMPLES:
            raise ValueError(f"{value} phase points: expected at most {MAX_DEFLECTION_SAMPLES}, the most samples a "
                             "simulated run's deflection series holds per whisk cycle (robot.deflection_samples)")
        return value

    @pydantic.field_validator("modalities")
    @classmethod
    def _distinct(cls, value: list[str]) -> list[str]:
        if len(set(value)) != len(value):
            raise ValueError("modalities must not repeat")
        return value

    def tactile_size(self, n_whiskers: int) -> int:
        """Tactile channels for ``n_whiskers`` whiskers."""
        return n_whiskers * (3 if self.tactile_input == "instant" else 2 * self.cycle_points + 1)


def resample_images(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bilinear resampling of a (N, H, W, 3) uint8 stack to (N, h, w, 3) float32 in [0, 255]."""
    n, h, w, _ = images.shape
    if (h, w) == tuple(size):
        return images.astype(np.float32)
    factors = (1.0, size[0] / h, size[1] / w, 1.0)
    return zoom(images.astype(np.float32), factors, order=1, grid_mode=True, mode="nearest")


def cycle_series(deflection: np.ndarray, points: int) -> np.ndarray:
    """(N, P, W, 2) float32: a (N, S, W, 2) deflection series at P phase points.

    Sample s of the series is taken at phase (s + 1) / S of the cycle, phase point k at
    (k + 1) / P, i.e. at position ``(k + 1) S / P - 1`` of the series: linear interpolation
    between its two neighbours, the first sample held before it. The last point is the
    sample instant (maximum protraction); a single-sample series gives P copies of it."""
    d = np.asarray(deflection, dtype=np.float64)
    samples = d.shape[1]
    position = np.clip(np.arange(1, points + 1) * samples / points - 1, 0, samples - 1)
    below = np.floor(position).astype(int)
    above = np.minimum(below + 1, samples - 1)
    weight = (position - below)[None, :, None, None]
    return (d[:, below] * (1 - weight) + d[:, above] * weight).astype(np.float32)


def contact_flags(deflection: np.ndarray) -> np.ndarray:
    """(N, W) float32: 1 where a whisker's deflection ``|xy|`` exceeded the touch threshold
    at some sample of the (N, S, W, 2) series, else 0."""
    return (np.linalg.norm(deflection, axis=3) > TOUCH_THRESHOLD).any(axis=1).astype(np.float32)


def tactile_values(run: Run, params: InputParams) -> np.ndarray:
    """(N, tactile_size) float32 unscaled tactile input of every sample of ``run``."""
    n = len(run)
    if params.tactile_input == "instant":
        return np.concatenate([run.theta, run.xy.reshape(n, -1)], axis=1).astype(np.float32)
    if run.deflection.shape[1] < 2:
        warn_once(run, "tactile cycle", f"run {run.name} has a single deflection sample per whisk cycle: "
                  "tactile_input 'cycle' repeats the instant's deflection at every phase point")
    series = cycle_series(run.deflection, params.cycle_points).reshape(n, -1)
    return np.concatenate([series, contact_flags(run.deflection)], axis=1)


def touched(run: Run, params: InputParams) -> np.ndarray:
    """(N,) bool: samples with a touch in what the tactile input covers (the instant, or the cycle)."""
    return run.touch_mask() if params.tactile_input == "instant" else np.any(contact_flags(run.deflection), axis=1)


def raw_inputs(run: Run, params: InputParams) -> dict[str, np.ndarray]:
    """Unscaled network inputs of the chosen modalities: flattened resampled RGB, tactile values."""
    inputs = {}
    if "visual" in params.modalities:
        batches = [
            resample_images(run.image_batch(i, i + 512), params.image_size).reshape(-1)
            for i in range(0, len(run), 512)
        ]
        inputs["visual"] = np.concatenate(batches).reshape(len(run), -1)
    if "tactile" in params.modalities:
        inputs["tactile"] = tactile_values(run, params)
    return inputs


def training_range(run: Run, values: np.ndarray, params: InputParams, who: str) -> TactileRange:
    """The tactile channels' range on the training ``run`` (`TactileRange.fit` of its ``values``);
    UserError naming ``who``'s modalities when no sample of the run touches anything: every
    channel would then be scaled from the whiskers at rest, and each touch seen later would lie
    outside it."""
    if not touched(run, params).any():
        raise UserError(f"{who}: modalities include 'tactile' but no sample of the training run {run.name!r} touches "
                        f"anything (no whisker deflected past {TOUCH_THRESHOLD}): train on a run whose drive reaches "
                        "landmarks (a foraging or visits run), or set modalities: [visual]")
    return TactileRange.fit(values, params)


def _inverse(span: np.ndarray) -> np.ndarray:
    """1 / span, 0 where the span is 0 (a flat channel with no floor)."""
    return np.where(span > 0, 1 / np.where(span > 0, span, 1), 0).astype(np.float32)


@dataclass
class TactileRange:
    """Each tactile channel's range on the training run and the floor of its scaling span, and
    how the channels are scaled (`InputParams.tactile_scaling`; ``robust``: each channel's
    median ``center`` and floored IQR ``spread``, 0 and 1 for the contact flags)."""

    low: np.ndarray
    high: np.ndarray
    floor: np.ndarray
    scaling: TactileScaling = "range"
    center: np.ndarray | None = None
    spread: np.ndarray | None = None

    @classmethod
    def fit(cls, values: np.ndarray, params: InputParams) -> TactileRange:
        """The range of (N, C) training ``values``; floors per `InputParams.tactile_input`;
        the median and IQR too for ``tactile_scaling`` robust."""
        floor = np.full(values.shape[1], params.tactile_min_range, np.float32)
        flags = np.zeros(values.shape[1], bool)
        if params.tactile_input == "cycle":
            flags[-(values.shape[1] // (2 * params.cycle_points + 1)):] = True  # the last W channels
            floor[flags] = 1.0  # the contact flags
        fitted = cls(values.min(axis=0), values.max(axis=0), floor, params.tactile_scaling)
        if params.tactile_scaling == "robust":
            q1, median, q3 = np.percentile(values, [25, 50, 75], axis=0)
            fitted.center = np.where(flags, 0, median).astype(np.float32)
            fitted.spread = np.where(flags, 1, np.maximum(q3 - q1, floor)).astype(np.float32)
        return fitted

    def range_scaler(self) -> tuple[np.ndarray, np.ndarray]:
        """(offset, scale) of the ``range`` scaling: the training range to [0, 1] (its span floored)."""
        return self.low, _inverse(np.maximum(self.high - self.low, self.floor))

    def scaler(self) -> tuple[np.ndarray, np.ndarray]:
        """(offset, scale): channels are fed as ``(x - offset) * scale`` (then `saturate`)."""
        if self.scaling == "robust":
            assert self.center is not None and self.spread is not None  # fitted or loaded with them
            return self.center, _inverse(self.spread)
        return self.range_scaler()

    def saturate(self, scaled: np.ndarray) -> np.ndarray:
        """``scaled`` values as fed: for ``clip``, clipped to the training range itself (scaled:
        0 to (high - low) / span, which is 1 unless the span was floored), so no value beyond
        what training saw reaches the network; else unchanged (the same array)."""
        if self.scaling != "clip":
            return scaled
        _, scale = self.range_scaler()
        return np.clip(scaled, 0, (self.high - self.low) * scale)

    def scale(self, values: np.ndarray) -> np.ndarray:
        """(N, C) tactile ``values`` as fed to the network: `scaler`, then `saturate`."""
        offset, scale = self.scaler()
        return self.saturate((values - offset) * scale)

    def outside(self, values: np.ndarray) -> np.ndarray:
        """(N, C) bool: values outside their channel's training range."""
        return (values < self.low) | (values > self.high)

    def save(self, directory: Path) -> None:
        data: dict[str, object] = {"low": self.low.tolist(), "high": self.high.tolist(), "floor": self.floor.tolist(),
                                   "scaling": self.scaling}
        if self.center is not None and self.spread is not None:
            data |= {"center": self.center.tolist(), "spread": self.spread.tolist()}
        write_text_atomic(directory / RANGE_FILE, json.dumps(data))

    @classmethod
    def load(cls, directory: Path) -> TactileRange:
        """The range `save` wrote; a file from before ``tactile_scaling`` (no ``scaling``) means ``range``."""
        data = json.loads((directory / RANGE_FILE).read_text())
        low, high, floor = (np.asarray(data[key], np.float32) for key in ("low", "high", "floor"))
        center, spread = (np.asarray(data[key], np.float32) if key in data else None for key in ("center", "spread"))
        return cls(low, high, floor, scaling=data.get("scaling", "range"), center=center, spread=spread)


def range_measure(values: np.ndarray, fitted: TactileRange,
                  measured: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-sample arrays on how (N, C) tactile ``values`` sit in the training range, for the
    features (`feature_facts` sums them up): ``tactile_inside`` (N, C) bool, each value inside
    its channel's training range ``[low, high]``; ``tactile_beyond`` (N,) float32, how far the
    sample's farthest value lies beyond [0, 1] in the ``range`` scaling (`range_scaler`, units
    of the channel's floored training span, whatever ``tactile_scaling`` feeds; 0 when none
    does); ``tactile_measured`` (N,) bool, ``measured`` (default: every sample). A sample not
    measured (e.g. without the whiskers: not fed) counts as inside, at 0, and is left out of
    the facts (`feature_facts`)."""
    offset, scale = fitted.range_scaler()
    scaled = (values - offset) * scale
    beyond = np.maximum(scaled - 1, 0 - scaled).max(axis=1, initial=0).astype(np.float32)  # 0 - x: never -0
    inside = ~fitted.outside(values)
    measured = np.ones(len(values), bool) if measured is None else np.asarray(measured, bool)
    inside[~measured] = True
    beyond[~measured] = 0.0
    return {"tactile_inside": inside, "tactile_beyond": beyond, "tactile_measured": measured}


#: what `report_out_of_range` says of the values outside the training range, per tactile_scaling
CLIPPED = {"range": "they are not clipped",
           "clip": "they are clipped to the training range (tactile_scaling clip: beyond it they saturate at its ends)",
           "robust": "they are not clipped (tactile_scaling robust: median and IQR scaling; the excess is in units of "
           "the training range)"}


def report_out_of_range(run: Run, values: np.ndarray, fitted: TactileRange, params: InputParams, who: str) -> None:
    """Warn once per run (`warn_once`: log, manifest, report) when some of ``run``'s tactile
    ``values`` lie outside the training range: how many samples (and touched samples), values
    and channels, how far beyond [0, 1] the farthest lies in the ``range`` scaling
    (`range_measure`), and whether they are clipped (``tactile_scaling`` clip) or not."""
    outside = fitted.outside(values)
    if not outside.any():
        return
    beyond = float(range_measure(values, fitted)["tactile_beyond"].max())
    rows = outside.any(axis=1)
    touch = touched(run, params)
    kind = "instant" if params.tactile_input == "instant" else f"cycle, {params.cycle_points} points"
    warn_once(
        run, f"{who} tactile range ({kind})",
        f"{who} (tactile_input {kind}): {int(rows.sum())} of {len(run)} samples of run {run.name!r} "
        f"({int((rows & touch).sum())} of its {int(touch.sum())} touched samples) have tactile values outside the "
        f"training run's range ({int(outside.sum())} values in {int(outside.any(axis=0).sum())} of "
        f"{values.shape[1]} channels, up to {beyond:.3g} scaled units beyond [0, 1]); {CLIPPED[fitted.scaling]}",
    )
