"""Weight optimisers of MuPNet's training: ``sgd`` (the paper's), ``momentum`` or ``adam``.

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
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal, get_args

import numpy as np

from vitaplace.engine.network.backends import Backend
from vitaplace.engine.network.structure import Edge

#: the weight optimisers (MuPNet's ``weight_optimizer`` parameter is this type)
WeightOptimizerName = Literal["sgd", "momentum", "adam"]
WEIGHT_OPTIMIZERS: tuple[str, ...] = get_args(WeightOptimizerName)


class WeightOptimizer:
    """The state and the step of a ``momentum`` or ``adam`` weight optimiser over ``edges``
    (``weights``: the backend's handles; ``shapes``: each edge's W shape)."""

    def __init__(self, backend: Backend, name: str, edges: Sequence[Edge], shapes: Mapping[str, tuple[int, ...]],
                 *, momentum: float = 0.9, beta1: float = 0.9, beta2: float = 0.999, eps: float = 1e-8) -> None:
        if name not in ("momentum", "adam"):
            raise ValueError(f"unknown weight optimiser '{name}'; valid: {', '.join(WEIGHT_OPTIMIZERS)}")
        self.be, self.name = backend, name
        self.momentum, self.beta1, self.beta2, self.eps = momentum, beta1, beta2, eps
        #: per edge, the step direction g = 2 Y^T G, and the moments (v; or m and s)
        self.D = {e.name: backend.empty(shapes[e.name]) for e in edges}
        moments = 1 if name == "momentum" else 2
        self.moments: dict[str, list[Any]] = {
            e.name: [backend.empty(shapes[e.name]) for _ in range(moments)] for e in edges
        }
        #: the step count t (Adam's bias correction), on the device
        self.t = backend.empty((1,), np.int32)

    @property
    def steps(self) -> int:
        """Weight steps taken so far (waits for the device)."""
        return int(self.be.download(self.t)[0])

    def step(self, weights: Mapping[str, Any], Y: Mapping[str, Any], G: Mapping[str, Any],
             edges: Sequence[Edge]) -> None:
        """One optimiser step on every edge from the minibatch's latents and gains."""
        be = self.be
        be.count_step(self.t)
        for e in edges:
            D = self.D[e.name]
            be.weight_gradient(D, Y[e.upper], G[e.name])
            if self.name == "momentum":
                (V,) = self.moments[e.name]
                be.momentum_weight_step(weights[e.name], V, D, e.eta_w, self.momentum)
            else:
                M, S = self.moments[e.name]
                be.adam_weight_step(weights[e.name], M, S, D, self.t, e.eta_w, self.beta1, self.beta2, self.eps)
