"""MuPNet's architecture trained by backprop: an autoencoder whose decoder is MuPNet's
generative path.

Decoder, edge for edge MuPNet's (weights ``W`` of shape n_upper x n_lower, no biases, the
same names: ``joint.m``, ``m.l``): the joint code z predicts the top layer of each modality
``m`` as ``phi(z W_joint.m)``, each layer the one below as ``phi(y_l W_m.l)``, down to the
reconstruction of the input ``x_m``. Encoder (``encoder``):

* ``learned``: weights ``V`` of its own mirroring the decoder (n_lower x n_upper, named
  ``encoder.<edge>``): ``h_0 = x_m``, ``h_l = phi(h_(l-1) V_m.l)``, and
  ``z = phi(sum_m h_top,m V_joint.m)``;
* ``tied``: ``V = W^T`` for every edge (the transposed-weight path: the decoder's own
  weights, MuPNet's parameter count).

Loss of a minibatch of B samples: ``L = (1/B) sum_m ||x_m - xhat_m||^2`` (per sample, a sum of
squares without 1/2, as MuPNet's energy). Gradients by backprop; with tied weights an edge's
gradient is the sum of its decoder use and the transpose of its encoder use. Every array
keeps the model's dtype (float32 for runs, float64 for the gradient checks).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from vitaplace.engine.network.fixed_order import matmul as fixed_order_matmul
from vitaplace.engine.network.pc import NetworkError, converged, glorot_uniform
from vitaplace.kernels.reference import activation, activation_derivative

Encoder = Literal["learned", "tied"]
OptimizerName = Literal["adam", "sgd"]
#: Adam's decay rates and denominator floor (Kingma and Ba's defaults)
ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8


@dataclass
class Layer:
    """One dense step ``out = phi(x @ w)``: its input and pre-activation (for backprop)."""

    x: np.ndarray
    a: np.ndarray


class Autoencoder:
    """The two-branch-plus-joint autoencoder; ``sizes[m]`` = [input, layer 1, ..., top] of modality m.
    With ``fixed_order`` every product of matrices is `fixed_order_matmul` (numpy's loops, no
    BLAS): the same bits under any BLAS kernel, as MuPNet's ``fixed`` backend."""

    def __init__(self, sizes: Mapping[str, list[int]], joint: int, *, activation: str, slope: float,
                 encoder: Encoder, seed: int, dtype: type = np.float32, fixed_order: bool = False) -> None:
        self.sizes = {m: list(s) for m, s in sizes.items()}
        self.activation, self.slope, self.encoder = activation, slope, encoder
        self.dtype = np.dtype(dtype)
        self._matmul: Callable[[np.ndarray, np.ndarray], np.ndarray] = (
            fixed_order_matmul if fixed_order else np.matmul)
        rng = np.random.default_rng(seed)
        # the decoder drawn as MuPNet's Network draws its edges: every stack bottom up, then the joint edges
        shapes = {f"{m}.{k}": (s[k], s[k - 1]) for m, s in self.sizes.items() for k in range(1, len(s))}
        shapes.update({f"joint.{m}": (joint, s[-1]) for m, s in self.sizes.items()})
        self.weights = {name: glorot_uniform(rng, *shape).astype(self.dtype) for name, shape in shapes.items()}
        if encoder == "learned":
            self.weights.update({f"encoder.{name}": glorot_uniform(rng, lower, upper).astype(self.dtype)
                                 for name, (upper, lower) in shapes.items()})

    def _phi(self, a: np.ndarray) -> np.ndarray:
        return activation(a, self.activation, self.slope)

    def _dense(self, x: np.ndarray, w: np.ndarray, layers: list[Layer]) -> np.ndarray:
        a = self._matmul(x, w)
        layers.append(Layer(x, a))
        return self._phi(a)

    def encoder_weight(self, edge: str) -> np.ndarray:
        """The encoder's weights of ``edge`` (n_lower x n_upper)."""
        return self.weights[f"encoder.{edge}"] if self.encoder == "learned" else self.weights[edge].T

    def encode(self, inputs: Mapping[str, np.ndarray]) -> np.ndarray:
        """The joint code (B, joint) of the inputs of every modality."""
        return self._encode(inputs, {})[0]

    def _encode(self, inputs: Mapping[str, np.ndarray],
                stacks: dict[str, list[Layer]]) -> tuple[np.ndarray, np.ndarray]:
        total: Any = 0  # the joint pre-activation: each modality's share (B, joint) added to 0
        for m, s in self.sizes.items():
            h = np.asarray(inputs[m], self.dtype)
            stacks[m] = []
            for k in range(1, len(s)):
                h = self._dense(h, self.encoder_weight(f"{m}.{k}"), stacks[m])
            # the stack's top and its share of the joint pre-activation (phi is applied to the sum)
            stacks[m].append(Layer(h, self._matmul(h, self.encoder_weight(f"joint.{m}"))))
            total = total + stacks[m][-1].a
        return self._phi(total), total

    def _decode(self, z: np.ndarray, m: str, layers: list[Layer]) -> np.ndarray:
        y = self._dense(z, self.weights[f"joint.{m}"], layers)
        for k in range(len(self.sizes[m]) - 1, 0, -1):
            y = self._dense(y, self.weights[f"{m}.{k}"], layers)
        return y

    def _backward(self, layers: list[Layer], weights: list[np.ndarray], grad: np.ndarray,
                  into: list[np.ndarray], to_input: bool = True) -> np.ndarray | None:
        """Backprop ``grad`` (of the last layer's output) through dense ``layers`` (last
        first); the weights' gradients appended to ``into``; returns the first input's
        gradient (None unless ``to_input``: the data's gradient is not needed)."""
        for i, (layer, w) in enumerate(zip(reversed(layers), reversed(weights), strict=True)):
            g = grad * activation_derivative(layer.a, self.activation, self.slope)
            into.append(self._matmul(layer.x.T, g))
            if i == len(layers) - 1 and not to_input:
                return None
            grad = self._matmul(g, w.T)
        return grad

    def loss_and_gradients(self, inputs: Mapping[str, np.ndarray]) -> tuple[dict[str, float], dict[str, np.ndarray]]:
        """Per modality ``(1/B) ||x_m - xhat_m||^2`` and dL/dweights of their sum, by name."""
        stacks: dict[str, list[Layer]] = {}
        z, a_z = self._encode(inputs, stacks)
        batch = len(z)
        losses: dict[str, float] = {}
        grads: dict[str, np.ndarray] = {}
        dz = np.zeros_like(z)
        for m, s in self.sizes.items():
            layers: list[Layer] = []
            error = np.asarray(inputs[m], self.dtype) - self._decode(z, m, layers)
            losses[m] = float(np.sum(error * error)) / batch
            names = [f"joint.{m}"] + [f"{m}.{k}" for k in range(len(s) - 1, 0, -1)]
            found: list[np.ndarray] = []
            dz += self._backward(layers, [self.weights[n] for n in names], error * (-2 / batch), found)
            grads.update(zip(reversed(names), found, strict=True))
        gz = dz * activation_derivative(a_z, self.activation, self.slope)
        for m, s in self.sizes.items():
            names = [f"{m}.{k}" for k in range(1, len(s))]
            top = stacks[m][-1]
            encoder_grads = {f"joint.{m}": self._matmul(top.x.T, gz)}
            found = []
            self._backward(stacks[m][:-1], [self.encoder_weight(n) for n in names],
                           self._matmul(gz, self.encoder_weight(f"joint.{m}").T), found, to_input=False)
            encoder_grads.update(zip(reversed(names), found, strict=True))
            for name, g in encoder_grads.items():
                if self.encoder == "learned":
                    grads[f"encoder.{name}"] = g
                else:
                    grads[name] = grads[name] + g.T
        return losses, grads


class Optimizer:
    """Adam (Kingma and Ba, 2015, their Algorithm 1: bias-corrected moments, the floor added to
    the corrected root), or plain SGD (``optimizer`` sgd)."""

    def __init__(self, weights: Mapping[str, np.ndarray], learning_rate: float, optimizer: OptimizerName) -> None:
        self.rate, self.optimizer, self.t = learning_rate, optimizer, 0
        self.m = {k: np.zeros_like(w) for k, w in weights.items()} if optimizer == "adam" else {}
        self.v = {k: np.zeros_like(w) for k, w in weights.items()} if optimizer == "adam" else {}

    def step(self, weights: dict[str, np.ndarray], grads: Mapping[str, np.ndarray]) -> None:
        self.t += 1
        if self.optimizer == "sgd":
            for k, g in grads.items():
                weights[k] -= self.rate * g
            return
        b1, b2 = ADAM_BETAS
        correct1, correct2 = 1 - b1 ** self.t, 1 - b2 ** self.t
        for k, g in grads.items():
            self.m[k] = b1 * self.m[k] + (1 - b1) * g
            self.v[k] = b2 * self.v[k] + (1 - b2) * g * g
            step = self.rate * (self.m[k] / correct1) / (np.sqrt(self.v[k] / correct2) + ADAM_EPS)
            weights[k] -= step.astype(weights[k].dtype)


@dataclass
class TrainingSettings:
    epochs: int
    batch_size: int
    learning_rate: float
    optimizer: OptimizerName
    seed: int
    converge_window: int
    converge_tol: float


def _check_finite(losses: Mapping[str, float], where: str, settings: TrainingSettings) -> None:
    """A NetworkError naming the modality when a reconstruction error is no longer finite."""
    for m, loss in losses.items():
        if not np.isfinite(loss):
            raise NetworkError(f"autoencoder: the reconstruction error of the {m} input became {loss} at {where}; "
                               f"lower learning_rate ({settings.learning_rate:g}, optimizer {settings.optimizer})")


def train(model: Autoencoder, inputs: Mapping[str, np.ndarray], settings: TrainingSettings,
          on_progress: Callable[[int, float], None] | None = None,
          on_epoch: Callable[[int, dict[str, float]], None] | None = None) -> tuple[dict[str, list[float]], bool]:
    """Minibatch training, a new order each epoch from ``(seed, 1)``. Returns the history
    (per modality, each epoch's mean per-sample reconstruction error, measured before each
    step as MuPNet's energy is) and whether it stopped by ``converge_window``.
    ``on_epoch(epoch, numbers)`` after every epoch (from 1): ``loss`` (every modality) and
    ``loss.MODALITY``."""
    n = len(next(iter(inputs.values())))
    order_rng = np.random.default_rng((settings.seed, 1))
    optimiser = Optimizer(model.weights, settings.learning_rate, settings.optimizer)
    history: dict[str, list[float]] = {m: [] for m in model.sizes}
    for epoch in range(settings.epochs):
        sums = dict.fromkeys(model.sizes, 0.0)
        order = order_rng.permutation(n)
        for start in range(0, n, settings.batch_size):
            rows = order[start:start + settings.batch_size]
            with np.errstate(over="ignore", invalid="ignore"):  # divergence: named next, in one line
                losses, grads = model.loss_and_gradients({m: x[rows] for m, x in inputs.items()})
                optimiser.step(model.weights, grads)
            _check_finite(losses, f"epoch {epoch + 1}, minibatch {start // settings.batch_size + 1}", settings)
            for m, loss in losses.items():
                sums[m] += loss * len(rows)
            if on_progress is not None:
                on_progress(epoch, sum(losses.values()))
        for m in model.sizes:
            history[m].append(sums[m] / n)
        totals = [sum(values) for values in zip(*history.values(), strict=True)]
        if on_epoch is not None:
            on_epoch(epoch + 1, {"loss": totals[-1], **{f"loss.{m}": values[-1] for m, values in history.items()}})
        if converged(totals, settings.converge_window, settings.converge_tol):
            return history, True
    return history, False
