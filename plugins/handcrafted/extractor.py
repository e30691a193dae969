"""`HandcraftedExtractor`: the ViTa-SLAM visuo-tactile front end as a feature plugin.

Features per sample: the visual intensity profile (``profile``, a grid of grey values), the
point feature histogram of the whisk cycle's contacts (``pfh``) and the slope distribution
array of the whiskers' deflections (``sda``). The template-match error is

    eps = |dV| / sigma_V + ||dPFH||_1 / sigma_PFH + ||dSDA||_1 / sigma_SDA

over the enabled modalities, with |dV| the shift-tolerant profile distance and each sigma
the standard deviation of that term's pairwise distances (i != j) on the training run
(the paper's alpha, beta, gamma), estimated on at most ``sigma_samples`` evenly spaced
training samples.

Missing modalities (`Run.lacks`: a query drop-out): a sample without the camera has no
profile, one without the whiskers no PFH and SDA (their rows are zeros, and the features
carry ``missing_camera`` and ``missing_whiskers``). A pair's error then sums the terms both
samples have and scales the sum to all K enabled terms, as Gower's distance treats missing
variables: eps = K / |present| * sum over the present terms, so pairs with and without a
drop-out are on one scale. A pair that shares no term (H-V and a query without its camera)
cannot be compared: its distance is +inf, never a match (not 0, which would be the best
match of every such query).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, cast

import numpy as np
import pydantic
from scipy.spatial.distance import cdist

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.plugin import TACTILE, VISUAL, ExtractorParams, FeatureExtractor, Features, Run, warn_once

from .pfh import pfh_batch, subsample
from .profile import TemplateMaker, template_distance
from .sda import sda

STATE_FILE = "handcrafted_state.json"
#: the sensor each feature comes from (`Run.lacks`)
SENSOR_OF = {"profile": "camera", "pfh": "whiskers", "sda": "whiskers"}
STATE_VERSION = 1

PositiveInt = Annotated[int, pydantic.Field(ge=1)]


#: the settings only the visual term reads, and those only the tactile terms read
VISUAL_KEYS = ("grid", "crop_fraction", "normalise", "max_shift")
TACTILE_KEYS = ("pfh_bins", "max_points", "sda_threshold", "sda_mode")


class HandcraftedParams(ExtractorParams):
    """Parameters of the hand-crafted extractor (unknown keys are errors)."""

    grid: tuple[PositiveInt, PositiveInt] = pydantic.Field(
        (40, 64),
        description="Profile grid (rows, columns); ViTa-SLAM uses 40 x 64.",
    )
    crop_fraction: float = pydantic.Field(
        0.625, gt=0.0, le=1.0,
        description="Fraction of the image rows, from the top, used for the profile (300/480 in ViTa-SLAM).",
    )
    normalise: bool = pydantic.Field(
        True,
        description="Scale each profile to mean 0.4 (OpenRatSLAM ``vt_normalisation``).",
    )
    max_shift: int = pydantic.Field(
        5, ge=0,
        description="Horizontal shift tolerance of the profile comparison, in grid cells.",
    )
    pfh_bins: int = pydantic.Field(
        3, ge=1, le=16,
        description="Bins per PFH feature (alpha, phi, theta): pfh_bins**3 histogram bins.",
    )
    max_points: int = pydantic.Field(
        64, ge=2,
        description="At most this many contacts per whisk cycle enter the PFH (evenly spaced subsample).",
    )
    sda_threshold: float = pydantic.Field(
        0.01, ge=0.0,
        description="Deflection [rad] above which a sample counts as positive (in contact) for the SDA. The "
        "simulated whiskers deflect up to ~1e-3 rad from whisking alone and 0.08-0.85 rad on "
        "contact.",
    )
    sda_mode: Literal["magnitude", "per_axis"] = pydantic.Field(
        "magnitude",
        description="How a 2-axis deflection is reduced to a slope, see `vitaplace.plugins.handcrafted.sda`.",
    )
    use_visual: bool = pydantic.Field(True, description="include the visual intensity profile term")
    use_tactile: bool = pydantic.Field(True, description="include the PFH and SDA terms")
    sigma_samples: int = pydantic.Field(
        500, ge=2,
        description="At most this many training samples (evenly spaced) are used to estimate the sigmas.",
    )
    batch_size: int = pydantic.Field(
        256, ge=1,
        description="Images converted to profiles per batch (a run is never loaded whole).",
    )
    threads: int = pydantic.Field(
        0, ge=0,
        description="Threads for the profile distance; 0 = every CPU this process may use.",
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> HandcraftedParams:
        if not (self.use_visual or self.use_tactile):
            raise ValueError("use_visual and use_tactile are both false; enable at least one modality")
        for switch, keys in (("use_visual", VISUAL_KEYS), ("use_tactile", TACTILE_KEYS)):
            unread = [key for key in keys if not getattr(self, switch)
                      and getattr(self, key) != type(self).model_fields[key].default]
            if unread:
                raise ValueError(f"{', '.join(unread)} {'is' if len(unread) == 1 else 'are'} ignored with {switch} "
                                 f"false (only the term it switches off reads {'it' if len(unread) == 1 else 'them'}); "
                                 f"leave {'it' if len(unread) == 1 else 'them'} out or set {switch} true")
        if self.max_shift >= self.grid[1]:
            raise ValueError(f"max_shift ({self.max_shift}) must be smaller than the grid width ({self.grid[1]})")
        return self


def _spread(distances: np.ndarray) -> float:
    """Standard deviation of the off-diagonal pairs (i < j) of a square distance matrix; 1 if 0 or undefined."""
    iu = np.triu_indices(len(distances), k=1)
    values = distances[iu]
    if values.size == 0:
        return 1.0
    sigma = float(np.std(values))
    return sigma if np.isfinite(sigma) and sigma > 0 else 1.0


def _has(features: Features, sensor: str, samples: int) -> np.ndarray:
    """(n,) 1/0: the samples of ``features`` that have ``sensor`` (all, without drop-out)."""
    missing = features.get(f"missing_{sensor}")
    return np.ones(samples) if missing is None else 1.0 - np.asarray(missing, dtype=np.float64)


class HandcraftedExtractor(FeatureExtractor):
    """ViTa-SLAM's hand-crafted front end: intensity profile + PFH + SDA, sigma-weighted."""

    name: ClassVar[str] = "handcrafted"
    Params: ClassVar[type[ExtractorParams]] = HandcraftedParams
    handles_missing: ClassVar[bool] = True
    params: HandcraftedParams

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        #: Fitted distance scales per feature name; None until `fit` or `load_state`.
        self.sigmas: dict[str, float] | None = None

    @classmethod
    def modalities(cls, params: ExtractorParams) -> frozenset[str]:
        """The profile term is vision, the PFH and SDA terms touch."""
        params = cast(HandcraftedParams, params)  # made by validate_params from cls.Params
        return frozenset([VISUAL] * params.use_visual + [TACTILE] * params.use_tactile)

    # -- features -------------------------------------------------------------------------

    @property
    def feature_names(self) -> list[str]:
        """Names of the features this configuration produces (and compares)."""
        names = []
        if self.params.use_visual:
            names.append("profile")
        if self.params.use_tactile:
            names += ["pfh", "sda"]
        return names

    def transform(self, run: Run) -> Features:
        p = self.params
        features: Features = {}
        n = len(run)
        if p.use_visual:
            maker = TemplateMaker(run.image_shape, p.grid, p.crop_fraction, p.normalise)
            profile = np.empty((n, *p.grid), dtype=np.float32)
            for start in range(0, n, p.batch_size):
                stop = min(start + p.batch_size, n)
                profile[start:stop] = maker(run.image_batch(start, stop))
            features["profile"] = profile
        if p.use_tactile:
            if n and int(run.contact_offsets[-1]) == 0:
                warn_once(run, "PFH", f"run {run.name} has no contacts: PFH features are all zero")
            if n and run.deflection.shape[1] < 2:
                warn_once(run, "SDA", f"run {run.name} has a single deflection sample per whisk cycle: "
                          "SDA features are all zero")
            features["pfh"] = pfh_batch(run, p.pfh_bins, p.max_points)
            features["sda"] = sda(run.deflection, p.sda_threshold, p.sda_mode)
        if run.missing:
            for key in list(features):
                features[key][run.lacks(SENSOR_OF[key])] = 0
            features.update({f"missing_{sensor}": run.lacks(sensor) for sensor in ("camera", "whiskers")})
        return features

    # -- distances ------------------------------------------------------------------------

    def term_distances(self, query: Features, reference: Features) -> dict[str, np.ndarray]:
        """Unscaled distance matrix (n_query, n_reference) of each enabled feature."""
        out: dict[str, np.ndarray] = {}
        for key in self.feature_names:
            for side, feats in (("query", query), ("reference", reference)):
                if key not in feats:
                    raise ValueError(
                        f"extractor '{self.name}': {side} features lack '{key}' "
                        f"(have {sorted(feats)}); were they made with the same parameters?"
                    )
            q, r = query[key], reference[key]
            if key == "profile":
                out[key] = template_distance(q, r, self.params.max_shift, threads=self.params.threads or None)
            else:
                q2, r2 = (np.asarray(x, dtype=np.float64) for x in (q, r))
                q2 = q2.reshape(len(q2), int(np.prod(q2.shape[1:])))
                r2 = r2.reshape(len(r2), int(np.prod(r2.shape[1:])))
                if len(q2) == 0 or len(r2) == 0:
                    out[key] = np.zeros((len(q2), len(r2)))
                else:
                    out[key] = cdist(q2, r2, "cityblock")
        return out

    def distance(self, query: Features, reference: Features) -> np.ndarray:
        if self.sigmas is None:
            raise RuntimeError(f"extractor '{self.name}' is not fitted: call fit() or load() first")
        terms = self.term_distances(query, reference)
        total: np.ndarray | None = None
        present: np.ndarray | None = None
        for key, d in terms.items():
            sigma = self.sigmas[key]
            scaled = d / sigma if np.isfinite(sigma) and sigma > 0 else d  # a zero sigma counts as 1
            both = np.outer(_has(query, SENSOR_OF[key], len(d)), _has(reference, SENSOR_OF[key], d.shape[1]))
            total = scaled * both if total is None else total + scaled * both
            present = both.astype(np.float64) if present is None else present + both
        assert total is not None and present is not None  # at least one modality is enabled (validated)
        scaled_up = np.where(present > 0, total * len(terms) / np.maximum(present, 1), np.inf)
        return np.where(present == len(terms), total, scaled_up)  # without drop-out: the sum itself, bit for bit

    # -- fitting and state ----------------------------------------------------------------

    def fit(self, train: Run) -> None:
        features = self.transform(train)
        idx = subsample(len(train), self.params.sigma_samples)
        sample = {key: value[idx] for key, value in features.items()}
        terms = self.term_distances(sample, sample)
        self.sigmas = {key: _spread(d) for key, d in terms.items()}

    def save_state(self, directory: Path) -> None:
        if self.sigmas is None:
            raise RuntimeError(f"extractor '{self.name}' is not fitted: nothing to save")
        state = {"version": STATE_VERSION, "sigmas": self.sigmas}
        write_text_atomic(Path(directory) / STATE_FILE, json.dumps(state, indent=2))

    def load_state(self, directory: Path) -> None:
        path = Path(directory) / STATE_FILE
        try:
            state = json.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"{path}: no fitted state of extractor '{self.name}'") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from None
        found = state.get("sigmas") if isinstance(state, dict) else None
        sigmas: dict[str, Any] = found if isinstance(found, dict) else {}
        missing = [key for key in self.feature_names if key not in sigmas]
        if missing:
            raise ValueError(f"{path}: state lacks sigma(s) for {', '.join(missing)}")
        self.sigmas = {key: float(sigmas[key]) for key in self.feature_names}
