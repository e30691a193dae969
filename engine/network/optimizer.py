"""Weight optimisers of MuPNet's training: ``sgd`` (the paper's), ``momentum`` or ``adam``;
and the weights' norm constraint ``weight_norm``.

The paper moves each edge's weights one plain step down eq. 4 per minibatch,
``W <- W + eta_w g`` with ``g = 2 Y^T G`` (= -dF/dW): ``sgd``, the backend's fused
``weight_update``, unchanged. The other two drive the same direction ``g`` through an
optimiser's state, as pcx drives its weights with optax (docs/MUPNET.md, a documented
departure from the paper), written with the backend's own operations:

* ``momentum`` (heavy ball): ``v <- beta v + g``, ``W <- W + eta_w v``
* ``adam``: ``m <- b1 m + (1 - b1) g``, ``s <- b2 s + (1 - b2) g^2``,
  ``W <- W + eta_w (m / (1 - b1^t)) / (sqrt(s / (1 - b2^t)) + eps)``; each edge's eta_w is
  then Adam's learning rate (a step of about eta_w per weight, whatever the size of g)

The state (``v``, or ``m`` and ``s``, per edge, and the step count ``t``) lives on the
backend for one `Network.train` run: it is not saved with the model, and training always
starts it fresh.

``weight_norm: rows`` projects every row of every edge's W (the projective field of one unit
of the layer above) back to its norm at the start of training after each weight step, as
sparse coding keeps its basis functions at a fixed norm. Without it the energy under a latent
prior has no minimum: scaling a row up by c and its unit's latents down by c keeps every
prediction and shrinks the prior's term, so training can lower the energy for ever by growing
the weights (docs/MUPNET.md, "What the criterion can and cannot say").
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, Literal, get_args

import numpy as np

from vitaplace.engine.network.backends import Backend
from vitaplace.engine.network.structure import Edge

#: the weight optimisers (MuPNet's ``weight_optimizer`` parameter is this type)
WeightOptimizerName = Literal["sgd", "momentum", "adam"]
WEIGHT_OPTIMIZERS: tuple[str, ...] = get_args(WeightOptimizerName)
#: the weights' norm constraints (MuPNet's ``weight_norm`` parameter is this type)
WeightNorm = Literal["none", "rows"]
WEIGHT_NORMS: tuple[str, ...] = get_args(WeightNorm)


class WeightOptimizer(ABC):
    """The state and the step of a weight optimiser over ``edges`` (``shapes``: each edge's W
    shape): per edge the step direction g = 2 Y^T G and the optimiser's moments, and the step
    count t on the device. `make_weight_optimizer` builds one from its name."""

    #: how many W-shaped moments per edge the rule keeps
    MOMENTS = 0

    def __init__(self, backend: Backend, edges: Sequence[Edge], shapes: Mapping[str, tuple[int, ...]]) -> None:
        self.be = backend
        self.D = {e.name: backend.empty(shapes[e.name]) for e in edges}
        self.moments: dict[str, list[Any]] = {
            e.name: [backend.empty(shapes[e.name]) for _ in range(self.MOMENTS)] for e in edges
        }
        self.t = backend.empty((1,), np.int32)

    @property
    def steps(self) -> int:
        """Weight steps taken so far (waits for the device)."""
        return int(self.be.download(self.t)[0])

    def step(self, weights: Mapping[str, Any], Y: Mapping[str, Any], G: Mapping[str, Any],
             edges: Sequence[Edge]) -> None:
        """One optimiser step on every edge from the minibatch's latents and gains."""
        self.be.count_step(self.t)
        for e in edges:
            D = self.D[e.name]
            self.be.weight_gradient(D, Y[e.upper], G[e.name])
            self.edge_step(weights[e.name], self.moments[e.name], D, e.eta_w)

    @abstractmethod
    def edge_step(self, W: Any, moments: list[Any], D: Any, eta: float) -> None:
        """One edge's step from its direction ``D`` and its ``moments``."""


class Momentum(WeightOptimizer):
    """Heavy ball: ``v <- beta v + g``, ``W <- W + eta_w v``."""

    MOMENTS = 1

    def __init__(self, backend: Backend, edges: Sequence[Edge], shapes: Mapping[str, tuple[int, ...]], *,
                 momentum: float = 0.9) -> None:
        super().__init__(backend, edges, shapes)
        self.momentum = momentum

    def edge_step(self, W: Any, moments: list[Any], D: Any, eta: float) -> None:
        (V,) = moments
        self.be.momentum_weight_step(W, V, D, eta, self.momentum)


class Adam(WeightOptimizer):
    """Adam with bias correction; each edge's eta_w is its learning rate."""

    MOMENTS = 2

    def __init__(self, backend: Backend, edges: Sequence[Edge], shapes: Mapping[str, tuple[int, ...]], *,
                 beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8) -> None:
        super().__init__(backend, edges, shapes)
        self.beta1, self.beta2, self.eps = beta1, beta2, eps

    def edge_step(self, W: Any, moments: list[Any], D: Any, eta: float) -> None:
        M, S = moments
        self.be.adam_weight_step(W, M, S, D, self.t, eta, self.beta1, self.beta2, self.eps)


def make_weight_optimizer(backend: Backend, name: str, edges: Sequence[Edge], shapes: Mapping[str, tuple[int, ...]],
                          *, momentum: float = 0.9, beta1: float = 0.9, beta2: float = 0.999,
                          eps: float = 1e-8) -> WeightOptimizer | None:
    """The optimiser ``name`` names (the one place a name maps to a rule): None for ``sgd``
    (the paper's fused step), else a fresh `Momentum` or `Adam` state."""
    if name == "sgd":
        return None
    if name == "momentum":
        return Momentum(backend, edges, shapes, momentum=momentum)
    if name == "adam":
        return Adam(backend, edges, shapes, beta1=beta1, beta2=beta2, eps=eps)
    raise ValueError(f"unknown weight optimiser '{name}'; valid: {', '.join(WEIGHT_OPTIMIZERS)}")


def row_norms(backend: Backend, name: str, weights: Mapping[str, np.ndarray], edges: Sequence[Edge]) -> dict[str, Any]:
    """Per edge, the float64 norms of its W's rows on the device, which ``weight_norm: rows``
    holds them at (`Backend.project_rows`); empty for ``none``."""
    if name not in WEIGHT_NORMS:
        raise ValueError(f"unknown weight_norm '{name}'; valid: {', '.join(WEIGHT_NORMS)}")
    if name == "none":
        return {}
    norms = {}
    for e in edges:
        host = np.linalg.norm(np.asarray(weights[e.name], np.float64), axis=1)
        norms[e.name] = backend.empty(host.shape, np.float64)
        backend.upload(host, norms[e.name])
    return norms
