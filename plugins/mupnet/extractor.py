"""MuPNet features: the joint latent of the multi-modal predictive-coding network.

``fit`` scales the inputs (`vitaplace.plugins.mupnet.inputs`: images to [0, 1] after
resampling to the network's image size, the tactile input chosen by ``tactile_input``
scaled by ``tactile_scaling`` fitted on the training run), trains the network, and
``transform`` infers the joint latent of every sample with frozen weights (a progress bar
over the samples unless ``progress`` is off, then one log line: samples, step cap, seconds);
tactile values outside the training range are reported once per run and measured per sample
(``tactile_inside``, ``tactile_beyond``: `inputs.range_measure`). A network fed both
modalities also records per sample vision's share of the drive on the joint latent at the
settled point (``drive_visual_share``: `vitaplace.engine.network.drive`; ``drive_measured``
says which samples had both modalities, the others read 0 and are left out of the report's
facts). Distance: L2.

Missing modalities (`Run.lacks`: a query drop-out): a sample without the camera is inferred
from its tactile input alone, one without the whiskers from its visual input alone - the
missing modality's input is not clamped and its edges are left out of the energy, so its
errors never reach the joint layer (`Network.infer` with that modality omitted; the samples
are inferred in groups of equal presence). A sample with none of the network's modalities
(L-V without its camera) keeps the joint latent's start (0.1), is flagged ``uninformed``
and is at distance +inf from every sample: never a match (its latent says nothing of it),
with a warning.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import pydantic
from pydantic import Field
from scipy.spatial.distance import cdist
from tqdm.auto import tqdm

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.network.backends import Backend, BackendError, Precision
from vitaplace.engine.network.drive import joint_drive
from vitaplace.engine.network.optimizer import WeightNorm, WeightOptimizerName
from vitaplace.engine.network.pc import (
    LATENT_INIT,
    HeldOut,
    InferenceResult,
    JointConfig,
    ModalityConfig,
    Network,
    NetworkConfig,
    NetworkError,
    TrainingConfig,
)
from vitaplace.engine.network.precision import PrecisionWeighting
from vitaplace.engine.network.selection import check_precision, get_backend
from vitaplace.engine.network.solver import Solver, SolverName, make_solver
from vitaplace.engine.sim.robot import N_WHISKERS
from vitaplace.plugin import ExtractorParams, FeatureExtractor, Features, Run, warn_once
from vitaplace.plugins.mupnet.inputs import (
    InputParams,
    TactileRange,
    range_measure,
    raw_inputs,
    report_out_of_range,
    training_range,
)

log = logging.getLogger("vitaplace.mupnet")
#: a test-time joint latent longer than this many times the longest training one has diverged
DIVERGED_FACTOR = 10.0
#: the sensor each modality comes from (`Run.lacks`)
SENSOR_OF = {"visual": "camera", "tactile": "whiskers"}


class ArchitectureParams(InputParams):
    """The layers, activation and training length MuPNet and its backprop control share."""

    visual_layers: list[pydantic.PositiveInt] = Field(
        default_factory=lambda: [1000, 300], min_length=1,
        description="latent layer sizes of the visual stack, bottom first",
    )
    tactile_layers: list[pydantic.PositiveInt] = Field(
        default_factory=lambda: [100], min_length=1, description="latent layer sizes of the tactile stack, bottom first"
    )
    joint_size: pydantic.PositiveInt = Field(200, description="size of the joint latent: the place feature")
    activation: Literal["leaky_relu", "tanh", "sigmoid", "linear"] = Field(
        "leaky_relu", description="leaky_relu, tanh, sigmoid or linear"
    )
    slope: pydantic.NonNegativeFloat = Field(0.2, description="negative slope of the leaky ReLU")

    READ_ONLY_WITH = {**InputParams.READ_ONLY_WITH, "slope": (("activation", ("leaky_relu",)),)}
    epochs: pydantic.PositiveInt = Field(
        3000, description="passes over the training run (the maximum when converge_window > 0; the paper: 10)"
    )
    converge_window: pydantic.NonNegativeInt = Field(
        20, description="stop once the training energy (the autoencoder: its reconstruction error) fell by less "
        "than converge_tol over this many epochs (0: run all epochs, the paper's)",
    )
    converge_tol: float = Field(
        0.01, gt=0, lt=1, description="relative improvement of the training energy over converge_window epochs "
        "that still counts as progress",
    )
    batch_size: pydantic.PositiveInt = Field(150, description="samples per minibatch")
    seed: int = Field(0, ge=0, description="network initialisation and minibatch order")

    @pydantic.model_validator(mode="after")
    def _tolerance_read(self) -> ArchitectureParams:
        """``converge_tol`` is read only by the criterion, which ``converge_window`` 0 turns off."""
        if self.converge_window == 0 and self.converge_tol != type(self).model_fields["converge_tol"].default:
            raise ValueError(f"converge_tol {self.converge_tol:g} is ignored by converge_window 0 (only a window "
                             "> 0 reads it); leave converge_tol out or set converge_window")
        return self


#: the MuPNet paper's algorithm where the plugin's defaults depart from it (docs/MUPNET.md,
#: "Defaults"): min-max touch unclipped, all epochs, T = 20 plain latent steps and plain SGD per
#: minibatch on unconstrained weights, no held-out samples, plain test-time steps on the energy
#: without a prior, stopped by the thresholds or at 3000 steps (scenarios/paper.yaml pins these)
PAPER_ALGORITHM: dict[str, Any] = {
    "tactile_scaling": "range", "epochs": 10, "converge_window": 0, "inference_steps": 20,
    "training_inference": "plain", "weight_optimizer": "sgd", "held_out": 0.0, "max_steps": 3000,
    "latent_prior": 0.0, "inference_solver": "gd", "inference_rtol": None, "weight_norm": "none",
}


class MupnetParams(ArchitectureParams):
    """Network, training and test-time inference settings. The architecture, step sizes and
    thresholds default to the MuPNet paper/code; training and test-time inference default to
    the converging training and the settling solver (docs/MUPNET.md, "Defaults"); the paper's
    algorithm is scenarios/paper.yaml's.

    The one definition of these settings: the engine's network and training configurations
    are built from them (`network_config`, `training_config`)."""

    eta_y_visual: pydantic.PositiveFloat = Field(4e-4, description="latent step size of the visual layers")
    eta_y_tactile: pydantic.PositiveFloat = Field(4e-3, description="latent step size of the tactile layers")
    eta_y_joint: pydantic.PositiveFloat = Field(4e-4, description="latent step size of the joint layer")
    eta_w_visual: pydantic.PositiveFloat = Field(1e-4, description="weight step size of the visual layers")
    eta_w_tactile: pydantic.PositiveFloat = Field(1e-3, description="weight step size of the tactile layers")
    eta_w_joint: pydantic.PositiveFloat = Field(1e-4, description="weight step size of the joint layer's edges")
    threshold_visual: pydantic.NonNegativeFloat = Field(
        1e-3, description="test-time stop: mean squared error of each visual layer's prediction"
    )
    threshold_tactile: pydantic.NonNegativeFloat = Field(
        1e-3, description="test-time stop: mean squared error of each tactile layer's prediction"
    )
    threshold_joint: pydantic.NonNegativeFloat = Field(
        1e-3, description="test-time stop: mean squared error of the joint layer's predictions"
    )
    inference_steps: pydantic.PositiveInt = Field(
        5, description="T latent steps per minibatch before the weight step (the paper: 20 plain steps)"
    )
    training_inference: Literal["plain", "solver"] = Field(
        "solver", description="the T latent steps of a training minibatch: plain (the paper's steps at eta_y) or "
        "solver (steps of inference_solver from the persistent latents, each layer's step from the weights of that "
        "moment; a departure from the paper, docs/MUPNET.md)",
    )
    held_out: float = Field(
        0.1, ge=0, lt=1, description="share of the training run's samples (drawn with seed) kept out of training; "
        "their energy at the latents test-time inference settles them at is measured after every epoch "
        "(training.json, the report; 0: none, the paper's)",
    )
    weight_optimizer: WeightOptimizerName = Field(
        "momentum", description="weight update in training: sgd (the paper's plain step at eta_w), momentum (heavy "
        "ball, weight_momentum) or adam (adam_beta1, adam_beta2, adam_eps; the eta_w values are then Adam's learning "
        "rates); its state is not saved with the model (docs/MUPNET.md)",
    )
    weight_momentum: float = Field(0.9, gt=0, lt=1, description="beta of the momentum weight optimiser")
    weight_norm: WeightNorm = Field(
        "rows", description="norm constraint on the weights in training: none (the paper's) or rows (every row of "
        "every W, one unit's projective field, held at its norm at the start of training, as sparse coding holds "
        "its basis functions; gives the energy under latent_prior a minimum, docs/MUPNET.md)",
    )
    adam_beta1: float = Field(0.9, ge=0, lt=1, description="Adam's decay of the mean of the weight gradient")
    adam_beta2: float = Field(0.999, ge=0, lt=1, description="Adam's decay of the mean square of the weight gradient")
    adam_eps: pydantic.PositiveFloat = Field(1e-8, description="Adam's epsilon, added to the root mean square")
    precision_weighting: PrecisionWeighting = Field(
        "none", description="error precisions (inverse variances) weighing each prediction error in the energy, "
        "estimated after every training epoch and saved with the model: none (all 1, the paper's energy), layer "
        "(one per edge) or channel (one per channel of the layer predicted); not the GEMM `precision` "
        "(docs/MUPNET.md)",
    )
    precision_floor: pydantic.PositiveFloat = Field(
        1e-3, description="floor of an error variance when estimating the error precisions (precision_weighting)"
    )
    max_steps: pydantic.PositiveInt = Field(1000, description="test-time inference step cap (the paper: 3000)")
    latent_prior: pydantic.NonNegativeFloat = Field(
        0.1, description="lambda of a Gaussian prior on the latents, energy + lambda/2 ||y||^2, in training and at "
        "test time (0: the paper's energy, which has no fixed point to settle at; docs/MUPNET.md)",
    )
    inference_solver: SolverName = Field(
        "preconditioned", description="test-time solver: gd (the paper's plain steps at eta_y), nesterov (momentum "
        "with restarts, each layer's step from its curvature bound) or preconditioned (the same with each layer's "
        "bound as a matrix; needs latent_prior > 0)",
    )
    inference_momentum: float = Field(
        0.9, gt=0, lt=1, description="the momentum of the nesterov and preconditioned solvers"
    )
    inference_rtol: float | None = Field(
        3e-6, gt=0, lt=1, description="test-time stop also when a sample's step has shrunk below this fraction "
        "(0 < rtol < 1) of its first step (None: the per-layer thresholds alone, the paper's rule)",
    )
    backend: Literal["auto", "numpy", "warp", "fixed"] = Field(
        "auto", description="auto (warp on CUDA, numpy otherwise), numpy, warp, or fixed: numpy's float32 "
        "arithmetic with every sum in a fixed order, the same bits under any BLAS kernel, about 3x slower",
    )
    precision: Precision = Field(
        "float32", description="GEMM precision: float32, or on CUDA tensor cores tf32 or bf16 operands "
        "(float32 accumulation, weights and latents)",
    )

    READ_ONLY_WITH = {
        **ArchitectureParams.READ_ONLY_WITH,
        "inference_momentum": (("inference_solver", ("nesterov", "preconditioned")),),
        "weight_momentum": (("weight_optimizer", ("momentum",)),),
        **dict.fromkeys(("adam_beta1", "adam_beta2", "adam_eps"), (("weight_optimizer", ("adam",)),)),
        "precision_floor": (("precision_weighting", ("layer", "channel")),),
        # the plain latent steps read eta_y: training's (training_inference plain) and the test-time
        # gd's; the settling solvers take each layer's step from its curvature bound (`node_steps`)
        **dict.fromkeys(("eta_y_visual", "eta_y_tactile", "eta_y_joint"),
                        (("training_inference", ("plain",)), ("inference_solver", ("gd",)))),
    }

    def network_config(self, tactile_size: int) -> NetworkConfig:
        """The engine's network configuration for inputs of ``image_size`` RGB frames and
        ``tactile_size`` tactile channels (the chosen modalities only)."""
        h, w = self.image_size
        modalities = {
            "visual": ModalityConfig(
                h * w * 3, self.visual_layers, self.eta_y_visual, self.eta_w_visual, self.threshold_visual
            ),
            "tactile": ModalityConfig(
                tactile_size, self.tactile_layers, self.eta_y_tactile, self.eta_w_tactile, self.threshold_tactile
            ),
        }
        return NetworkConfig(
            modalities={m: modalities[m] for m in self.modalities},
            joint=JointConfig(self.joint_size, self.eta_y_joint, self.eta_w_joint, self.threshold_joint),
            activation=self.activation,
            slope=self.slope,
        )

    def training_config(self) -> TrainingConfig:
        """The engine's training configuration."""
        return TrainingConfig(
            epochs=self.epochs, batch_size=self.batch_size, inference_steps=self.inference_steps, seed=self.seed,
            converge_window=self.converge_window, converge_tol=self.converge_tol, latent_prior=self.latent_prior,
            weight_optimizer=self.weight_optimizer, weight_momentum=self.weight_momentum, adam_beta1=self.adam_beta1,
            adam_beta2=self.adam_beta2, adam_eps=self.adam_eps, precision_weighting=self.precision_weighting,
            precision_floor=self.precision_floor, weight_norm=self.weight_norm,
        )

    def solver(self) -> Solver:
        """The engine's test-time solver (`make_solver`); its energy's prior is ``latent_prior``."""
        return make_solver(self.inference_solver, self.inference_momentum, self.inference_rtol)

    @pydantic.model_validator(mode="after")
    def _prior_where_needed(self) -> MupnetParams:
        """An after-validator, so that the default solver is checked too (a field validator
        does not run on a default)."""
        if make_solver(self.inference_solver).needs_prior and not self.latent_prior:
            raise ValueError(f"inference_solver {self.inference_solver} needs latent_prior > 0, got "
                             f"{self.latent_prior:g} (without the prior a layer's curvature bound can be singular)")
        return self

    @pydantic.model_validator(mode="after")
    def _settling_solver(self) -> MupnetParams:
        if self.training_inference == "solver" and self.inference_solver == "gd":
            raise ValueError("training_inference solver takes the steps of a settling inference_solver "
                             "(nesterov or preconditioned), not gd (that is training_inference plain)")
        return self

    @pydantic.model_validator(mode="after")
    def _plain_steps_settle(self) -> MupnetParams:
        """A plain latent step ``y <- y - eta_y (dF/dy + latent_prior y)`` multiplies the prior's
        part of a latent by ``1 - eta_y latent_prior``: at ``eta_y latent_prior >= 2`` that is
        -1 or less, and the steps swing ever wider instead of settling."""
        plain = [name for name, used in (("training_inference plain", self.training_inference == "plain"),
                                         ("inference_solver gd", self.inference_solver == "gd")) if used]
        steps = {f"eta_y_{node}": getattr(self, f"eta_y_{node}") for node in (*self.modalities, "joint")}
        key = max(steps, key=lambda name: steps[name])
        if plain and steps[key] * self.latent_prior >= 2:
            raise ValueError(
                f"latent_prior {self.latent_prior:g} with {key} {steps[key]:g}: the plain latent steps of {plain[0]} "
                f"multiply the prior's part of a latent by 1 - eta_y latent_prior = "
                f"{1 - steps[key] * self.latent_prior:.3g} and diverge; expected latent_prior < 2 / {key} = "
                f"{2 / steps[key]:.4g} (or a settling inference_solver and training_inference solver)"
            )
        return self

    @pydantic.field_validator("precision")
    @classmethod
    def _precision_runs_here(cls, value: str, info: pydantic.ValidationInfo) -> str:
        try:
            check_precision(value, info.data.get("backend", "auto"))
        except BackendError as exc:
            raise ValueError(str(exc)) from None
        return value


def held_out_split(n: int, share: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The training samples and the held-out ones (each sorted): ``round(share * n)`` of the
    ``n`` samples drawn at random with ``seed``; NetworkError when none would be left to train on."""
    count = round(share * n)
    if count >= n:
        raise NetworkError(f"held_out {share} of a training run of {n} samples leaves none to train on")
    held = np.random.default_rng(seed).permutation(n)[:count]
    return np.setdiff1d(np.arange(n), held), np.sort(held)


def presence(run: Run, modalities: Sequence[str]) -> np.ndarray:
    """(samples, modalities) bool: which of ``modalities`` each sample of ``run`` has."""
    return np.stack([~run.lacks(SENSOR_OF[m]) for m in modalities], axis=1)


def presence_groups(run: Run, modalities: Sequence[str]) -> list[tuple[list[str], np.ndarray]]:
    """The samples of ``run`` grouped by the modalities (of ``modalities``) they have: (the
    modalities present, the samples' indices) per group; one group of every sample without
    drop-out."""
    has = presence(run, modalities)
    kinds, group = np.unique(has, axis=0, return_inverse=True)
    return [([m for m, h in zip(modalities, kind, strict=True) if h], np.flatnonzero(group.reshape(-1) == k))
            for k, kind in enumerate(kinds)]


def _uninformed(features: Features) -> np.ndarray:
    """The samples inferred from none of the network's modalities (all False without a drop-out)."""
    flags = features.get("uninformed")
    return np.zeros(len(features["latent"]), bool) if flags is None else np.asarray(flags, bool)


class MupnetExtractor(FeatureExtractor):
    """Learned visuo-tactile place features: the joint latent of MuPNet."""

    name = "mupnet"
    Params = MupnetParams
    params: MupnetParams
    handles_missing = True

    def __init__(self, params: Mapping[str, Any] | None = None) -> None:
        super().__init__(params)
        self.network: Network | None = None
        self.energy: dict[str, list[float]] = {}
        #: largest joint-latent norm over the training samples (test-time divergence check)
        self.train_norm_max = math.inf
        #: training stopped because the energy converged (converge_window), not at the epoch cap
        self.converged = False
        #: per epoch, how far training's latent steps still moved the latents (`TrainingHistory.latent_change`)
        self.latent_change: list[float] = []
        #: the tactile channels' training range (None without the tactile modality)
        self.tactile_range: TactileRange | None = None
        #: per epoch, the energy per sample of the held-out samples (`TrainingHistory.held_out`; empty without)
        self.held_out: list[float] = []
        #: CPU seconds of this process `fit` spent measuring the held-out energy (not training)
        self.held_out_cpu_s = 0.0

    @classmethod
    def modalities(cls, params: ExtractorParams) -> frozenset[str]:
        """The modalities fed to the network."""
        params = cast(MupnetParams, params)  # made by validate_params from cls.Params
        return frozenset(params.modalities)

    @classmethod
    def memory_bytes(cls, params: ExtractorParams, train_samples: int) -> tuple[int, str, str]:
        """Every weight matrix of the network (W, its transposed copy and the weight
        optimiser's moments), the training inputs and each sample's persistent latents, in
        float32, for the simulated robot's whiskers; the parameter named is the one whose share
        is largest (a minibatch's errors and the optimiser's gradient come on top)."""
        params = cast(MupnetParams, params)  # made by validate_params from cls.Params
        h, w = params.image_size
        copies = 2 + {"sgd": 0, "momentum": 1, "adam": 2}[params.weight_optimizer]
        sizes = {"visual": h * w * 3, "tactile": params.tactile_size(N_WHISKERS)}
        layers = {"visual": params.visual_layers, "tactile": params.tactile_layers}
        shares = {"image_size": 0, "visual_layers": 0, "tactile_layers": 0,
                  "joint_size": train_samples * params.joint_size * 4}
        for modality in params.modalities:
            key = f"{modality}_layers"
            chain = [sizes[modality], *layers[modality], params.joint_size]
            owners = ["image_size" if modality == "visual" else key, *[key] * len(layers[modality]), "joint_size"]
            shares[owners[0]] += train_samples * chain[0] * 4
            shares[key] += train_samples * sum(layers[modality]) * 4
            for i in range(len(chain) - 1):  # each edge's weights to the larger of the sizes it joins
                shares[owners[i] if chain[i] >= chain[i + 1] else owners[i + 1]] += chain[i] * chain[i + 1] * 4 * copies
        key = max(shares, key=shares.__getitem__)
        what = {"image_size": f"{h}x{w} images", "visual_layers": f"visual layers {params.visual_layers}",
                "tactile_layers": f"tactile layers {params.tactile_layers}",
                "joint_size": f"joint latents of {params.joint_size}"}[key]
        return sum(shares.values()), key, what

    def _backend(self) -> str | Backend:
        """The backend name, or for tf32 / bf16 the tensor-core backend itself."""
        p = self.params
        return p.backend if p.precision == "float32" else get_backend(p.backend, precision=p.precision)

    def raw_inputs(self, run: Run) -> dict[str, np.ndarray]:
        """Unscaled network inputs (`inputs.raw_inputs`)."""
        return raw_inputs(run, self.params)

    def scaled_inputs(self, run: Run) -> dict[str, np.ndarray]:
        return self._scaled(self.raw_inputs(run))

    def _scaled(self, raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``raw`` inputs as fed: the network's scalers, then the tactile range's `saturate`."""
        assert self.network is not None
        inputs = {m: self.network.scale_input(m, x) for m, x in raw.items()}
        if "tactile" in inputs and self.tactile_range is not None:
            inputs["tactile"] = self.tactile_range.saturate(inputs["tactile"])
        return inputs

    def fit(self, train: Run) -> None:
        p = self.params
        raw = self.raw_inputs(train)
        self.network = Network(p.network_config(p.tactile_size(train.n_whiskers)), seed=p.seed, backend=self._backend())
        if "visual" in raw:
            self.network.set_scaler("visual", np.zeros(1, np.float32), np.full(1, 1 / 255, np.float32))
        if "tactile" in raw:
            self.tactile_range = training_range(train, raw["tactile"], p, self.name)
            self.network.set_scaler("tactile", *self.tactile_range.scaler())
        inputs = self._scaled(raw)
        training = p.training_config()
        fitted, held = held_out_split(len(train), p.held_out, p.seed)
        held_out = HeldOut({m: x[held] for m, x in inputs.items()}, p.solver(), p.max_steps,
                           p.latent_prior) if len(held) else None
        minibatches = training.epochs * math.ceil(len(fitted) / training.batch_size)
        with tqdm(total=minibatches, desc="train", unit="batch", disable=not self.progress) as bar:
            def on_progress(epoch: int, energy: float) -> None:
                bar.update()
                bar.set_postfix(epoch=epoch, F=f"{energy:.4g}")

            history = self.network.train({m: x[fitted] for m, x in inputs.items()}, training, on_progress=on_progress,
                                         solver=p.solver() if p.training_inference == "solver" else None,
                                         held_out=held_out, on_epoch=self.on_epoch)
        self.energy = history.energy
        self.converged = history.converged
        self.latent_change = history.latent_change
        self.held_out = history.held_out
        self.held_out_cpu_s = history.held_out_cpu_s
        self.train_norm_max = float(np.linalg.norm(self.network.train_latents["joint"], axis=1).max())

    def training_history(self) -> dict[str, list[float]]:
        return self.energy

    def training_summary(self) -> dict[str, object]:
        epochs = len(next(iter(self.energy.values()), []))
        # latent_change: per epoch, the median of how far a minibatch's T steps moved a
        # sample's latents (relative): how far from settled training's persistent latents are
        # held_out: per epoch, the energy per sample of the held-out samples at their settled latents
        return {"epochs": epochs, "max_epochs": self.params.epochs, "converged": self.converged,
                "latent_change": self.latent_change, "held_out": self.held_out}

    def transform(self, run: Run) -> Features:
        if self.network is None:
            raise RuntimeError("mupnet: fit() or load() before transform()")
        raw = self.raw_inputs(run)
        if self.tactile_range is not None:
            report_out_of_range(run, raw["tactile"], self.tactile_range, self.params, self.name)
        inputs = self._scaled(raw)
        start = time.perf_counter()
        with tqdm(total=len(run), desc=f"infer {run.name}", unit="sample", disable=not self.progress,
                  leave=False) as bar:
            features = self._infer(run, inputs, bar.update)
        latent, steps, settled = features["latent"], features["inference_steps"], features["inference_settled"]
        log.info(
            "mupnet: test-time inference of %d samples of run %r (step cap %d, %d reached it, at most %d steps) "
            "in %.1f s", len(run), run.name, self.params.max_steps, int((~settled).sum()),
            int(steps.max(initial=0)), time.perf_counter() - start,
        )
        diverged = np.linalg.norm(latent, axis=1) > DIVERGED_FACTOR * self.train_norm_max
        if diverged.any():
            where = np.flatnonzero(diverged)
            log.warning(
                "mupnet: %d of %d samples of run %r have a joint latent norm over %g x the training maximum "
                "(%.3g): diverged at test time (first: %s); their features are not trustworthy",
                len(where), len(latent), run.name, DIVERGED_FACTOR, self.train_norm_max,
                ", ".join(map(str, where[:10])),
            )
        features["diverged"] = diverged
        if run.missing:  # samples with none of the network's modalities (a query drop-out)
            features["uninformed"] = presence(run, self.params.modalities).sum(axis=1) == 0
        if self.tactile_range is not None:  # the tactile values inside the training range (without whiskers: unfed)
            features |= range_measure(raw["tactile"], self.tactile_range, ~run.lacks("whiskers"))
        return features

    def _infer(self, run: Run, inputs: dict[str, np.ndarray], on_progress: Callable[[int], object]) -> Features:
        """Joint latents, steps, stopped flags (under the thresholds) and settled flags (a
        stopping rule ended it before the cap) of every sample, each group of samples
        (`presence_groups`) inferred from the modalities it has; with both modalities in the
        network, vision's share of the joint drive too (`_drive_share`)."""
        assert self.network is not None
        n, both = len(run), set(self.params.modalities) == set(SENSOR_OF)
        # per sample: inference steps taken, whether its errors fell under their thresholds and
        # whether a stopping rule (those, or inference_rtol's) ended it before the cap (the
        # report gives their distribution)
        features: Features = {
            "latent": np.full((n, self.params.joint_size), LATENT_INIT, dtype=np.float32),
            "inference_steps": np.zeros(n, dtype=np.int64), "inference_stopped": np.ones(n, dtype=bool),
            "inference_settled": np.ones(n, dtype=bool),
        }
        if both:
            features |= {"drive_visual_share": np.zeros(n, np.float32), "drive_measured": np.zeros(n, bool)}
        for present, index in presence_groups(run, self.params.modalities):
            if not present:
                warn_once(run, "mupnet: no modality", f"run {run.name}: {len(index)} samples have none of mupnet's "
                          f"modalities ({', '.join(self.params.modalities)}): their joint latent is its start, "
                          f"{LATENT_INIT}, and they are never a match (distance +inf)")
                on_progress(len(index))
                continue
            group = {m: inputs[m][index] for m in present}
            result = self.network.infer(group, max_steps=self.params.max_steps, on_progress=on_progress,
                                        solver=self.params.solver(), latent_prior=self.params.latent_prior,
                                        sample_ids=index)
            for key, value in (("latent", result.latents["joint"]), ("inference_steps", result.steps_per_sample),
                               ("inference_stopped", result.stopped), ("inference_settled", result.settled)):
                features[key][index] = value
            if set(present) == set(SENSOR_OF):
                features["drive_visual_share"][index] = self._drive_share(group, result)
                features["drive_measured"][index] = True
        return features

    def _drive_share(self, inputs: dict[str, np.ndarray], result: InferenceResult) -> np.ndarray:
        """Per sample, vision's share ``||T_v|| / (||T_v|| + ||T_t||)`` of the drive on the joint
        latent at the latents ``result`` settled at (`joint_drive`; the prior's term is not part
        of the share, the prior acts through where the latents settled)."""
        assert self.network is not None
        return joint_drive(self.network, inputs, result.latents).shares()["visual"]

    def distance(self, query: Features, reference: Features) -> np.ndarray:
        d = cdist(query["latent"], reference["latent"])
        d[_uninformed(query), :] = np.inf
        d[:, _uninformed(reference)] = np.inf
        return d

    def save_state(self, directory: Path) -> None:
        if self.network is None:
            raise RuntimeError("mupnet: nothing to save before fit()")
        self.network.save(directory / "network")
        write_text_atomic(directory / "energy.json", json.dumps(self.energy))
        write_text_atomic(directory / "latent_norm.json", json.dumps({"train_max": self.train_norm_max}))
        write_text_atomic(directory / "training.json",
                          json.dumps({"converged": self.converged, "latent_change": self.latent_change,
                                      "held_out": self.held_out}))
        if self.tactile_range is not None:
            self.tactile_range.save(directory)

    def load_state(self, directory: Path) -> None:
        self.network = Network.load(directory / "network", backend=self._backend())
        energy = directory / "energy.json"
        self.energy = json.loads(energy.read_text()) if energy.exists() else {}
        training = directory / "training.json"
        record = json.loads(training.read_text()) if training.exists() else {}
        self.converged = bool(record.get("converged", False))
        self.latent_change = list(record.get("latent_change", []))
        self.held_out = list(record.get("held_out", []))
        norm = directory / "latent_norm.json"
        self.train_norm_max = json.loads(norm.read_text())["train_max"] if norm.exists() else math.inf
        self.tactile_range = TactileRange.load(directory) if "tactile" in self.params.modalities else None
