"""The multi-modal predictive-coding network (MuPNet; maths in docs/MUPNET.md).

The network is a tree of latent nodes: each modality ``m`` has a stack ``m.1 .. m.L`` above
its input ``m.0``, and one ``joint`` node predicts the top node of every modality. Each
*edge* (upper node u -> lower node d) holds weights ``W`` (n_u x n_d) and predicts the
lower node:

    A = Y_u W,  P = phi(A),  E = Y_d - P,  G = phi'(A) * E            (eq. 1)
    F = sum over edges of ||E||^2                                       (eq. 2)
    dF/dY_u = -2 sum_{edges below u} G W^T + 2 E_{edge above u}         (eq. 3)
    dF/dW   = -2 Y_u^T G                                                (eq. 4)

Inference moves every latent one step down its gradient from the same state; learning
moves each edge's weights down eq. 4 after T inference steps. (The paper prints the update
without phi' and with the top-down sign flipped; this follows the gradient.) With error
precisions pi (``precision_weighting``, `vitaplace.engine.network.precision`) eq. 2 weighs
each error channel, F = sum_edges sum_c pi_c E_c^2: G carries its edge's pi and the
top-down term of eq. 3 is 2 pi_above E_above.
"""

from __future__ import annotations

import functools
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import numpy as np

from vitaplace.engine.base.atomic import atomic_path, write_text_atomic
from vitaplace.engine.network.backends import Backend
from vitaplace.engine.network.batch import LATENT_INIT, BatchState, NetworkError
from vitaplace.engine.network.inference import InferredSamples
from vitaplace.engine.network.optimizer import WeightOptimizer, make_weight_optimizer, row_norms
from vitaplace.engine.network.precision import PRECISION_WEIGHTINGS, PrecisionEstimator
from vitaplace.engine.network.selection import get_backend
from vitaplace.engine.network.solver import BatchSolver, GradientDescent, Solver
from vitaplace.engine.network.structure import Edge, JointConfig, ModalityConfig, NetworkConfig, TrainingConfig

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _divergence_checked(method: Callable[_P, _R]) -> Callable[_P, _R]:
    """``method`` with numpy's overflow and invalid-value warnings off: while training and
    inferring they are the divergence that `BatchState.check_finite` turns into one
    NetworkError naming the layer (a fresh errstate per call: numpy 1.x's cannot nest)."""

    @functools.wraps(method)
    def checked(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with np.errstate(over="ignore", invalid="ignore"):
            return method(*args, **kwargs)

    return checked

__all__ = ["LATENT_INIT", "BatchState", "Edge", "HeldOut", "JointConfig", "ModalityConfig", "Network", "NetworkConfig",
           "NetworkError", "TrainingConfig"]

FORMAT_VERSION = 1


@dataclass
class TrainingHistory:
    """Per-epoch mean energy per edge (sum of squared errors / samples) after inference,
    how far the latents still moved (``latent_change``), and whether training stopped
    because the energy had converged (else it ran all epochs)."""

    energy: dict[str, list[float]] = field(default_factory=dict)
    converged: bool = False
    #: per epoch, the median over samples of how far its T latent steps moved a sample's
    #: latents (`BatchState.latent_change`): how far from settled the persistent latents are
    latent_change: list[float] = field(default_factory=list)
    #: per epoch, the energy per sample of the held-out samples at their settled latents
    #: (`HeldOut`; empty without)
    held_out: list[float] = field(default_factory=list)
    #: CPU seconds (this process) spent measuring the held-out energy, not training
    held_out_cpu_s: float = 0.0

    @property
    def epochs(self) -> int:
        return len(next(iter(self.energy.values()), []))

    def total(self) -> list[float]:
        """Energy per sample of each epoch, summed over the edges."""
        return [float(sum(values)) for values in zip(*self.energy.values(), strict=True)]

    def last_epoch(self) -> dict[str, float]:
        """The last epoch's numbers by name: ``energy`` (per sample, every edge), ``energy.EDGE``,
        ``latent_change`` and, with held-out samples, ``held_out_energy``."""
        numbers = {"energy": float(sum(v[-1] for v in self.energy.values())),
                   **{f"energy.{name}": float(v[-1]) for name, v in self.energy.items()},
                   "latent_change": self.latent_change[-1]}
        return numbers | ({"held_out_energy": self.held_out[-1]} if self.held_out else {})


@dataclass
class HeldOut:
    """Samples kept out of training whose energy `Network.train` measures after every epoch:
    their (scaled) ``inputs``, inferred from the latents' start as at test time, by ``solver``
    under ``latent_prior`` with a cap of ``max_steps`` steps."""

    inputs: Mapping[str, np.ndarray]
    solver: Solver
    max_steps: int
    latent_prior: float


@dataclass
class InferenceResult:
    """Latents of every node (host arrays) and how inference ended.

    ``steps`` is the largest number of steps any sample took, ``steps_per_sample`` each
    sample's; ``mse`` the per-edge mean squared error averaged over the samples;
    ``stopped`` says per sample whether it ended under every threshold (rather than at the
    step cap) and ``converged`` whether all did; ``settled`` whether a stopping rule (the
    thresholds or the relative rule) ended it before the cap.
    """

    latents: dict[str, np.ndarray]
    mse: dict[str, float]
    steps_per_sample: np.ndarray
    stopped: np.ndarray
    settled: np.ndarray

    @property
    def steps(self) -> int:
        return int(self.steps_per_sample.max(initial=0))

    @property
    def converged(self) -> bool:
        return bool(self.stopped.all())


def glorot_uniform(rng: np.random.Generator, fan_in: int, fan_out: int) -> np.ndarray:
    """Glorot/Xavier uniform init: U(-l, l), l = sqrt(6 / (fan_in + fan_out))."""
    limit = math.sqrt(6.0 / (fan_in + fan_out))
    return rng.uniform(-limit, limit, size=(fan_in, fan_out)).astype(np.float32)


def _resumed_steps(steps: BatchSolver, count: int) -> None:
    """A solver's ``count`` steps from the latents loaded in its state (training's)."""
    steps.resume()
    steps.steps(count)


#: a training energy this many times its lowest so far has diverged (`diverged`)
DIVERGED_FACTOR = 1e4


def converged(energies: Sequence[float], window: int, tol: float) -> bool:
    """True when ``window`` > 0 and the last energy is within ``tol`` (relative) of the energy
    ``window`` epochs earlier: no longer falling, and not rising either (a rising energy has
    not converged)."""
    if window <= 0 or len(energies) <= window:
        return False
    before, now = energies[-1 - window], energies[-1]
    return abs(before - now) < tol * abs(before)


def diverged(energies: Sequence[float]) -> bool:
    """True when the last energy is more than `DIVERGED_FACTOR` times the lowest so far."""
    return len(energies) > 1 and energies[-1] > DIVERGED_FACTOR * min(energies)


def _stopped(history: TrainingHistory, cfg: TrainingConfig) -> bool:
    """Whether training stops after the epoch ``history`` ends with: True (and ``converged``
    set) once it has converged; NetworkError once it has diverged."""
    curve = history.total()
    if diverged(curve):
        lowest, epoch = int(np.argmin(curve)), len(curve)
        raise NetworkError(f"training diverged at epoch {epoch}: energy per sample {curve[-1]:.3g}, more than "
                           f"{DIVERGED_FACTOR:g} times its lowest ({curve[lowest]:.3g}, epoch {lowest + 1}); "
                           "lower the step sizes (eta_y, eta_w) or raise latent_prior")
    history.converged = converged(curve, cfg.converge_window, cfg.converge_tol)
    return history.converged


class Network:
    """MuPNet: named modalities under one joint layer, trained by local predictive-coding updates."""

    def __init__(self, config: NetworkConfig | Mapping, *, seed: int, backend: str | Backend = "auto") -> None:
        self.config = config if isinstance(config, NetworkConfig) else NetworkConfig.from_dict(config)
        self.backend = get_backend(backend) if isinstance(backend, str) else backend
        self.seed = seed
        self.sizes: dict[str, int] = {}
        self.eta_y: dict[str, float] = {}
        self.edges: list[Edge] = []
        for m, mc in self.config.modalities.items():
            self.sizes[f"{m}.0"] = mc.input_size
            for layer, size in enumerate(mc.layers, start=1):
                self.sizes[f"{m}.{layer}"] = size
                self.eta_y[f"{m}.{layer}"] = mc.eta_y
                self.edges.append(Edge(f"{m}.{layer}", f"{m}.{layer}", f"{m}.{layer - 1}", m, mc.eta_w, mc.threshold))
        jc = self.config.joint
        self.sizes["joint"] = jc.size
        self.eta_y["joint"] = jc.eta_y
        for m, mc in self.config.modalities.items():
            self.edges.append(Edge(f"joint.{m}", "joint", f"{m}.{len(mc.layers)}", m, jc.eta_w, jc.threshold))
        rng = np.random.default_rng(seed)
        self.weights: dict[str, np.ndarray] = {
            e.name: glorot_uniform(rng, self.sizes[e.upper], self.sizes[e.lower]) for e in self.edges
        }
        self.scalers: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._device_weights: dict[str, object] | None = None
        #: error precisions per edge, one per channel of its lower node (all 1: the paper's energy)
        self.precisions = {e.name: np.ones(self.sizes[e.lower], np.float32) for e in self.edges}
        #: whether the precisions are used (set by `set_precisions` and by weighted training);
        #: otherwise the backends run the paper's kernels, without them
        self.weighted = False
        self._device_precisions: dict[str, object] | None = None

    # ------------------------------------------------------------------ structure helpers
    @property
    def modalities(self) -> list[str]:
        return list(self.config.modalities)

    def input_node(self, modality: str) -> str:
        return f"{modality}.0"

    def latent_nodes(self, modalities: Sequence[str]) -> list[str]:
        nodes = [f"{m}.{layer}" for m in modalities for layer in range(1, len(self.config.modalities[m].layers) + 1)]
        return nodes + ["joint"]

    def active_edges(self, modalities: Sequence[str]) -> list[Edge]:
        return [e for e in self.edges if e.modality in modalities]

    # ------------------------------------------------------------------ input scaling
    def set_scaler(self, modality: str, offset: np.ndarray, scale: np.ndarray) -> None:
        """Inputs of ``modality`` are fed as (x - offset) * scale (e.g. min-max to [0, 1])."""
        self.scalers[modality] = (np.asarray(offset, np.float32), np.asarray(scale, np.float32))

    def scale_input(self, modality: str, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float32)
        if modality not in self.scalers:
            return x
        offset, scale = self.scalers[modality]
        return (x - offset) * scale

    # ------------------------------------------------------------------ the PC step
    def _check_inputs(self, inputs: Mapping[str, np.ndarray]) -> tuple[list[str], int]:
        unknown = set(inputs) - set(self.modalities)
        if unknown:
            raise NetworkError(f"unknown modality {sorted(unknown)}; the network has {self.modalities}")
        present = [m for m in self.modalities if m in inputs]
        if not present:
            raise NetworkError("no modality given")
        sizes = {m: np.shape(inputs[m]) for m in present}
        n = sizes[present[0]][0]
        for m, shape in sizes.items():
            if len(shape) != 2 or shape[0] != n or shape[1] != self.sizes[f"{m}.0"]:
                raise NetworkError(f"input '{m}' has shape {shape}, expected ({n}, {self.sizes[f'{m}.0']})")
        return present, n

    def set_weights(self, weights: Mapping[str, np.ndarray]) -> None:
        """Replace weights (by edge name, shapes checked); the backend copies are updated in
        place (buffers, and graphs captured over them, stay valid)."""
        for name, w in weights.items():
            if name not in self.weights or np.shape(w) != self.weights[name].shape:
                raise NetworkError(f"weights '{name}' unknown or misshaped: {np.shape(w)}")
        self._sync_weights_to_host()
        self.weights.update({name: np.array(w, np.float32) for name, w in weights.items()})
        if self._device_weights is not None:
            for name in weights:
                self.backend.upload_weights(self.weights[name], self._device_weights[name])

    def device_weights(self) -> dict[str, object]:
        """The backend's handles of the weights (made on first use; `set_weights` updates them in place)."""
        if self._device_weights is None:
            self._device_weights = {name: self.backend.weights(w) for name, w in self.weights.items()}
        return self._device_weights

    def _sync_weights_to_host(self) -> None:
        if self._device_weights is not None:
            for name, handle in self._device_weights.items():
                self.weights[name] = self.backend.weights_to_host(handle)

    def host_weights(self) -> dict[str, np.ndarray]:
        """The weights as host arrays, copied back from the backend first."""
        self._sync_weights_to_host()
        return self.weights

    def set_precisions(self, precisions: Mapping[str, np.ndarray]) -> None:
        """Replace error precisions (by edge name; one positive value per channel of the edge's
        lower node) and use them from now on; the backend copies are updated in place."""
        for name, pi in precisions.items():
            if name not in self.precisions or np.shape(pi) != self.precisions[name].shape:
                raise NetworkError(f"precisions '{name}' unknown or misshaped: {np.shape(pi)}")
            if not np.all(np.isfinite(pi)) or np.any(np.asarray(pi) <= 0):
                raise NetworkError(f"precisions '{name}' must be finite and > 0")
        self.precisions.update({name: np.array(pi, np.float32) for name, pi in precisions.items()})
        self.weighted = True
        if self._device_precisions is not None:
            for name in precisions:
                self.backend.upload(self.precisions[name], self._device_precisions[name])

    def device_precisions(self) -> dict[str, object] | None:
        """The backend's copies of the precisions (made on first use), or None while they are
        not used (`weighted`)."""
        if not self.weighted:
            return None
        if self._device_precisions is None:
            self._device_precisions = {name: self.backend.to_device(pi.copy()) for name, pi in self.precisions.items()}
        return self._device_precisions

    def batch_state(self, batch: int, modalities: Sequence[str] | None = None) -> BatchState:
        """Buffers for a minibatch of ``batch`` samples of the given (default: all) modalities."""
        return BatchState(self, batch, self.modalities if modalities is None else modalities)

    def _cached_state(self, states: dict[int, BatchState], batch: int, modalities: Sequence[str]) -> BatchState:
        """One BatchState per minibatch size (a run has at most two: full and last)."""
        if batch not in states:
            states[batch] = self.batch_state(batch, modalities)
        return states[batch]

    def energy(self, inputs: Mapping[str, np.ndarray], latents: Mapping[str, np.ndarray]) -> dict[str, float]:
        """F per edge (eq. 2) for given scaled inputs and latents, computed with the backend."""
        present, n = self._check_inputs(inputs)
        state = self.batch_state(n, present)
        state.load(inputs, latents)
        state.predict_all()
        return state.energies()

    # ------------------------------------------------------------------ training
    @_divergence_checked
    def train(
        self,
        inputs: Mapping[str, np.ndarray],
        training: TrainingConfig | Mapping,
        latents: dict[str, np.ndarray] | None = None,
        on_progress: Callable[[int, float], None] | None = None,
        solver: Solver | None = None,
        held_out: HeldOut | None = None,
        on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    ) -> TrainingHistory:
        """Learn the weights from (already scaled) inputs of N samples.

        Each sample's latents persist across epochs (initialised to 0.1, or ``latents`` to
        continue; that dict is updated in place). Per minibatch: T inference steps (the
        paper's plain steps at eta_y, or with ``solver`` T of its steps from the persistent
        latents, each layer's step from the weights of that moment, a sample stopping early
        only by the solver's relative rule), then one weight step (eq. 4; or the
        ``weight_optimizer``'s step from eq. 4's direction, its state fresh for every call).
        Inputs, latents and weights stay on the backend's device for the whole run; with the
        paper's steps a minibatch is one captured sequence (a CUDA graph on CUDA) and only its
        energies come back to the host. ``held_out``: after every epoch, the energy of those
        samples at their settled latents (`TrainingHistory.held_out`). With ``precision_weighting``
        the error precisions are estimated from each epoch's final errors, used from the next on.
        ``on_progress(epoch, energy)`` is called after every minibatch with the epoch (from 1)
        and the minibatch's energy per sample, for progress bars (as `infer`'s);
        ``on_epoch(epoch, numbers)`` after every epoch with `TrainingHistory.last_epoch`.
        Raises NetworkError naming the epoch and minibatch when an error becomes NaN/Inf.
        """
        cfg = training if isinstance(training, TrainingConfig) else TrainingConfig(**training)
        present, n = self._check_inputs(inputs)
        nodes = self.latent_nodes(present)
        store = latents if latents is not None else {}
        for node in nodes:
            store.setdefault(node, np.full((n, self.sizes[node]), LATENT_INIT, dtype=np.float32))
        be = self.backend
        resident_x = {self.input_node(m): be.to_device(inputs[m]) for m in present}
        resident_y = {node: be.to_device(store[node]) for node in nodes}
        edges = self.active_edges(present)
        history = TrainingHistory({e.name: [] for e in edges})
        rng = np.random.default_rng(cfg.seed)
        states: dict[int, BatchState] = {}
        runs: dict[int, Callable[[], None]] = {}
        batches_per_epoch = math.ceil(n / cfg.batch_size)
        optimizer = self._weight_optimizer(cfg, edges)
        norms = row_norms(be, cfg.weight_norm, self.host_weights(), edges)
        estimator = self._precision_estimator(cfg, edges)
        for epoch in range(cfg.epochs):
            order = rng.permutation(n)
            totals = dict.fromkeys(history.energy, 0.0)
            change = np.empty(n)
            for b in range(batches_per_epoch):
                index = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size])
                state = self._cached_state(states, len(index), present)
                state.prior = cfg.latent_prior
                state.optimizer, state.row_norms, state.estimator = optimizer, norms, estimator
                be.upload(index.astype(np.int32), state.index)
                self._minibatch(state, runs, resident_x, resident_y, cfg, solver, present)
                energy = state.energies()
                state.check_finite(energy, f"epoch {epoch + 1}, minibatch {b + 1}")
                change[index] = state.latent_change()
                for name, value in energy.items():
                    totals[name] += value
                if on_progress is not None:
                    on_progress(epoch + 1, sum(energy.values()) / len(index))
            self._record_epoch(history, {name: total / n for name, total in totals.items()}, change, estimator,
                               held_out)
            if on_epoch is not None:
                on_epoch(epoch + 1, history.last_epoch())
            if _stopped(history, cfg):
                break
        for node in nodes:
            store[node][...] = be.download(resident_y[node])
        self._sync_weights_to_host()
        self.train_latents = store
        return history

    def _record_epoch(self, history: TrainingHistory, energy: Mapping[str, float], change: np.ndarray,
                      estimator: PrecisionEstimator | None, held_out: HeldOut | None) -> None:
        """Append an epoch's ``energy`` per edge (per sample) and the median of the samples'
        latent ``change`` to ``history``; set the precisions the epoch estimated; measure the
        held-out energy (its CPU time apart)."""
        for name, value in energy.items():
            history.energy[name].append(value)
        history.latent_change.append(float(np.median(change)))
        if estimator is not None:
            self.set_precisions(estimator.end_epoch(len(change)))
        if held_out is not None:
            start = time.process_time()
            history.held_out.append(self._held_out_energy(held_out))
            history.held_out_cpu_s += time.process_time() - start

    def _minibatch(self, state: BatchState, runs: dict[int, Callable[[], None]], inputs: Mapping[str, object],
                   latents: Mapping[str, object], cfg: TrainingConfig, solver: Solver | None,
                   present: Sequence[str]) -> None:
        """One training minibatch on ``state`` (its rows uploaded): with the paper's steps a
        sequence captured once per batch size (``runs``), with ``solver`` its steps bound
        afresh from the weights of this moment (not captured)."""
        if solver is None:
            if state.batch not in runs:
                settle = functools.partial(state.plain_steps, cfg.inference_steps)
                runs[state.batch] = self.backend.capture(functools.partial(state.minibatch, inputs, latents, settle))
            runs[state.batch]()
            return
        steps = solver.bind(state, solver.node_steps(self, present, cfg.latent_prior))
        self.backend.fill(state.limits, 0.0)  # no threshold stop in training
        state.minibatch(inputs, latents, functools.partial(_resumed_steps, steps, cfg.inference_steps))

    def _held_out_energy(self, held_out: HeldOut) -> float:
        """The energy per sample of the held-out samples at the latents test-time inference settles
        them at: each edge's mean squared error (over samples, `InferenceResult.mse`) times its width."""
        result = self.infer(held_out.inputs, held_out.max_steps, solver=held_out.solver,
                            latent_prior=held_out.latent_prior)
        return sum(result.mse[e.name] * self.sizes[e.lower] for e in self.active_edges(list(held_out.inputs)))

    def _weight_optimizer(self, cfg: TrainingConfig, edges: Sequence[Edge]) -> WeightOptimizer | None:
        """A fresh optimiser state for one training run (None: sgd, the fused step); not saved
        with the model."""
        shapes = {e.name: self.weights[e.name].shape for e in edges}
        return make_weight_optimizer(self.backend, cfg.weight_optimizer, edges, shapes, momentum=cfg.weight_momentum,
                                     beta1=cfg.adam_beta1, beta2=cfg.adam_beta2, eps=cfg.adam_eps)

    def _precision_estimator(self, cfg: TrainingConfig, edges: Sequence[Edge]) -> PrecisionEstimator | None:
        """The error precisions' estimate of one training run (None: ``none``, the precisions
        left as they are); the precisions are in use from its first epoch, at their values then."""
        if cfg.precision_weighting not in PRECISION_WEIGHTINGS:
            raise NetworkError(f"unknown precision_weighting '{cfg.precision_weighting}'; valid: "
                               f"{', '.join(PRECISION_WEIGHTINGS)}")
        if cfg.precision_weighting == "none":
            return None
        self.weighted = True
        return PrecisionEstimator(self.backend, edges, self.sizes, cfg.precision_weighting, cfg.precision_floor)

    # ------------------------------------------------------------------ inference
    @_divergence_checked
    def infer(
        self,
        inputs: Mapping[str, np.ndarray],
        max_steps: int,
        thresholds: Mapping[str, float] | None = None,
        batch_size: int = 500,
        on_progress: Callable[[int], object] | None = None,
        solver: Solver | None = None,
        latent_prior: float = 0.0,
        sample_ids: np.ndarray | None = None,
    ) -> InferenceResult:
        """Latents for (scaled) inputs with frozen weights, from 0.1, batch by batch.

        Each sample stops on its own, as soon as every active edge's mean squared error
        for that sample is below its threshold (or ``solver``'s relative rule holds), or
        after ``max_steps`` steps; the others in its batch go on, and whenever samples have
        stopped (`vitaplace.engine.network.inference`) the batch is compacted to those
        still active, so a batch costs the sum of its samples' steps rather than its slowest
        sample's times its size. ``solver`` takes the steps (`vitaplace.engine.network.solver`;
        default: the paper's plain steps) on the energy with the Gaussian prior
        ``latent_prior`` on the latents (0: the paper's energy). Missing
        modalities are left out (their errors do not reach the joint layer).
        ``on_progress(k)`` is called whenever k more samples are done, for progress bars;
        ``sample_ids`` (default 0..n-1) number the samples in a divergence's message.
        """
        present, n = self._check_inputs(inputs)
        edges = self.active_edges(present)
        limits = {e.name: e.threshold for e in edges}
        limits.update(thresholds or {})
        threshold = np.array([limits[e.name] for e in edges], dtype=np.float64)
        ids = np.arange(n) if sample_ids is None else np.asarray(sample_ids)
        samples = InferredSamples(self, present, n, solver or GradientDescent(), latent_prior, threshold, ids)
        resident_x = {self.input_node(m): self.backend.to_device(inputs[m]) for m in present}
        for start in range(0, n, batch_size):
            samples.infer(np.arange(start, min(start + batch_size, n)), resident_x, max_steps, on_progress)
        stopped = np.all(samples.mse < threshold[:, None], axis=0)
        means = {e.name: float(samples.mse[k].mean()) for k, e in enumerate(edges)}
        return InferenceResult(samples.latents, means, samples.steps, stopped, samples.settled)

    def reconstruct(self, joint: np.ndarray, modality: str) -> np.ndarray:
        """Top-down prediction of a modality's scaled input from joint latents (host numpy)."""
        from vitaplace.kernels.reference import activation

        act, slope = self.config.activation, self.config.slope
        y = np.asarray(joint, np.float32)
        top = len(self.config.modalities[modality].layers)
        y = activation(y @ self.weights[f"joint.{modality}"], act, slope)
        for layer in range(top, 0, -1):
            y = activation(y @ self.weights[f"{modality}.{layer}"], act, slope)
        return y

    # ------------------------------------------------------------------ persistence
    def save(self, directory: str | Path) -> Path:
        """Write config.json, weights.npz, precisions.npz (the error precisions, when in use)
        and scalers.npz to ``directory`` (each atomically)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self._sync_weights_to_host()
        meta = {"format_version": FORMAT_VERSION, "seed": self.seed, "config": asdict(self.config)}
        # typed Any: np.savez's stub gives ``**kwds`` ArrayLike but would also bind a key named allow_pickle
        arrays: dict[str, Any] = self.weights
        with atomic_path(directory / "weights.npz") as tmp, open(tmp, "wb") as f:
            np.savez(f, **arrays)
        scalers: dict[str, Any] = {
            f"{m}/{part}": arr
            for m, pair in self.scalers.items()
            for part, arr in zip(("offset", "scale"), pair, strict=True)
        }
        with atomic_path(directory / "scalers.npz") as tmp, open(tmp, "wb") as f:
            np.savez(f, **scalers)
        precisions = directory / "precisions.npz"
        if self.weighted:
            arrays = dict(self.precisions)
            with atomic_path(precisions) as tmp, open(tmp, "wb") as f:
                np.savez(f, **arrays)
        else:
            precisions.unlink(missing_ok=True)
        write_text_atomic(directory / "config.json", json.dumps(meta, indent=2))
        return directory

    @classmethod
    def load(cls, directory: str | Path, backend: str | Backend = "auto") -> Network:
        """Read a network written by `save`; refuses other format versions. Without
        precisions.npz (unweighted, or saved before precision weighting) every precision is 1."""
        directory = Path(directory)
        meta_path = directory / "config.json"
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise NetworkError(f"{meta_path}: cannot read a saved network ({exc})") from None
        version = meta.get("format_version")
        if version != FORMAT_VERSION:
            raise NetworkError(
                f"{meta_path}: network format version {version}, "
                f"this vitaplace reads version {FORMAT_VERSION}; retrain it"
            )
        net = cls(meta["config"], seed=meta["seed"], backend=backend)
        with np.load(directory / "weights.npz") as weights:
            missing = [e.name for e in net.edges if e.name not in weights]
            if missing:
                raise NetworkError(f"{directory / 'weights.npz'}: weights {missing} missing")
            try:
                net.set_weights({e.name: weights[e.name] for e in net.edges})
            except NetworkError as exc:
                raise NetworkError(f"{directory / 'weights.npz'}: {exc}") from None
        if (directory / "precisions.npz").exists():
            with np.load(directory / "precisions.npz") as precisions:
                try:
                    net.set_precisions({key: precisions[key] for key in precisions.files})
                except NetworkError as exc:
                    raise NetworkError(f"{directory / 'precisions.npz'}: {exc}") from None
        with np.load(directory / "scalers.npz") as scalers:
            for key in scalers.files:
                m, part = key.split("/")
                offset: Any  # None, as is scale, until the file's other part of the pair is read
                scale: Any
                offset, scale = net.scalers.get(m, (None, None))
                net.scalers[m] = (scalers[key], scale) if part == "offset" else (offset, scalers[key])
        return net
