"""The buffers and steps of one minibatch of MuPNet's network (maths in docs/MUPNET.md).

`BatchState` holds a minibatch's backend buffers and builds the training and test-time steps
from the backend's operations (eq. 1-4 of `vitaplace.engine.network.pc`); each of its step
sequences only launches work, so it can be captured once and replayed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.network.optimizer import WeightOptimizer
from vitaplace.engine.network.precision import PrecisionEstimator
from vitaplace.engine.network.structure import NetworkView

LATENT_INIT = 0.1


class NetworkError(UserError, RuntimeError):
    """Training or inference cannot go on (divergence, incompatible file, bad input)."""


class BatchState:
    """Backend buffers of one minibatch: latents Y per node, inputs X, errors E and gains G
    per edge, per-sample energies R (edges x batch, float64), and the int32 row index,
    active mask and step counts of the samples.

    `predict_all` computes eq. 1-2, `latent_step` and `weight_step` apply eq. 3 and eq. 4;
    `minibatch` (training) and a solver's steps (test time, `vitaplace.engine.network.solver`)
    are built from these and only launch work on the backend, so each can be captured once
    and replayed.
    """

    def __init__(self, net: NetworkView, batch: int, modalities: Sequence[str]) -> None:
        be = net.backend
        self.net, self.be, self.batch = net, be, batch
        self.nodes = net.latent_nodes(modalities)
        self.edges = net.active_edges(modalities)
        self.weights = net.device_weights()
        self.Y = {node: be.empty((batch, net.sizes[node])) for node in self.nodes}
        self.X = {net.input_node(m): be.empty((batch, net.sizes[net.input_node(m)])) for m in modalities}
        self.E = {e.name: be.empty((batch, net.sizes[e.lower])) for e in self.edges}
        self.G = {e.name: be.empty((batch, net.sizes[e.lower])) for e in self.edges}
        self.R = be.empty((len(self.edges), batch), np.float64)
        self.index = be.empty((batch,), np.int32)
        self.active = be.empty((batch,), np.int32)
        self.steps = be.empty((batch,), np.int32)
        self.limits = be.empty((len(self.edges),), np.float64)
        #: a minibatch's latents before its T steps, then minus those after (`minibatch`)
        self.Y_start = {node: be.empty((batch, net.sizes[node])) for node in self.nodes}
        #: per sample, ||Y_after - Y_before||^2 and ||Y_after||^2 over every latent node
        self.moved = be.empty((batch,), np.float64)
        self.size2 = be.empty((batch,), np.float64)
        self.edge_above = {e.lower: e.name for e in self.edges}
        #: lambda of the Gaussian prior on the latents (energy + lambda / 2 ||Y||^2; 0: none)
        self.prior = 0.0
        # The top-down term (+2 E_above) of a node is applied once, with its first edge below.
        self.first_below = {e.upper: e.name for e in reversed(self.edges)}
        #: the weight optimiser of a training run (`vitaplace.engine.network.optimizer`); None: the paper's SGD
        self.optimizer: WeightOptimizer | None = None
        #: per edge, the device norms ``weight_norm: rows`` holds W's rows at (empty: none)
        self.row_norms: Mapping[str, Any] = {}
        #: the error precisions per edge on the device (None: all 1, the paper's kernels)
        self.Pi = net.device_precisions()
        #: a training run's sums of squared errors for the error precisions; None: not estimated
        self.estimator: PrecisionEstimator | None = None

    def load(self, inputs: Mapping[str, np.ndarray], latents: Mapping[str, np.ndarray] | None) -> None:
        """Host inputs and latents (default: all 0.1) into the buffers."""
        for m, x in inputs.items():
            self.be.upload(np.asarray(x), self.X[self.net.input_node(m)])
        for node, y in self.Y.items():
            host = latents[node] if latents is not None else np.full((self.batch, self.net.sizes[node]), LATENT_INIT)
            self.be.upload(np.asarray(host), y)

    def _node(self, name: str) -> Any:
        return self.Y[name] if name in self.Y else self.X[name]

    def predict_all(self, energy: bool = True) -> None:
        """Eq. 1 on every edge from the current latents, and (``energy``) each sample's
        energy per edge into ``R``."""
        act, slope = self.net.config.activation, self.net.config.slope
        R = self.R if energy else None
        for slot, e in enumerate(self.edges):
            n = e.name
            self.be.predict(self.Y[e.upper], self.weights[n], self._node(e.lower), self.E[n], self.G[n], R, slot, act,
                            slope, self._precision(n))

    def _precision(self, edge: str | None) -> Any | None:
        return None if self.Pi is None or edge is None else self.Pi[edge]

    def energies(self) -> dict[str, float]:
        """F per edge (eq. 2) of the last `predict_all` (waits for the device)."""
        sums = self.be.download(self.R).sum(axis=1)
        return {e.name: float(s) for e, s in zip(self.edges, sums, strict=True)}

    def latent_step(self, mask: Any | None = None) -> None:
        """Y <- Y - eta_y dF/dY for every node (eq. 3, and the prior's lambda Y), all from
        the errors of one predict_all; only the rows where ``mask`` is non-zero, when given."""
        self.descend(self.Y, self.net.eta_y, mask)

    def descend(self, targets: Mapping[str, Any], eta: Mapping[str, float], mask: Any | None = None) -> None:
        """``targets[node] += -eta[node] dF/dY`` (eq. 3, with ``-eta lambda Y`` under a prior)
        on the rows of ``mask``; the targets are the latents themselves or step buffers."""
        if self.prior:
            for node in self.nodes:
                self.be.scale_add(targets[node], self.Y[node], -eta[node] * self.prior, mask)
        for e in self.edges:
            above = self.edge_above.get(e.upper) if self.first_below[e.upper] == e.name else None
            self.be.latent_update(
                targets[e.upper], self.G[e.name], self.weights[e.name], eta[e.upper], self.E[above] if above else None,
                mask, self._precision(above),
            )

    def weight_step(self) -> None:
        """W <- W - eta_w dF/dW on every edge (eq. 4), or the weight optimiser's step; then
        each row of W back to its norm in ``row_norms``, when given."""
        if self.optimizer is not None:
            self.optimizer.step(self.weights, self.Y, self.G, self.edges)
        else:
            for e in self.edges:
                self.be.weight_update(self.weights[e.name], self.Y[e.upper], self.G[e.name], e.eta_w)
        for name, norms in self.row_norms.items():
            self.be.project_rows(self.weights[name], norms)

    def minibatch(self, inputs: Mapping[str, object], latents: Mapping[str, object],
                  settle: Callable[[], None]) -> None:
        """One training minibatch: rows ``index`` of the resident inputs and latents, the
        latent steps ``settle`` takes on them (`plain_steps`, or a solver's: `Network.train`;
        each leaves the errors of its final state in ``E``, ``G`` and ``R``), one weight step,
        the latents written back; how far the steps moved each sample's latents into
        ``moved`` and ``size2`` (`latent_change`); the final errors into the ``estimator``'s
        sums, when there is one."""
        for node, x in self.X.items():
            self.be.gather_rows(inputs[node], self.index, x)
        be = self.be
        for node, y in self.Y.items():
            be.gather_rows(latents[node], self.index, y)
            be.fill(self.Y_start[node], 0.0)
            be.scale_add(self.Y_start[node], y, 1.0, None)
        settle()
        self.weight_step()
        if self.estimator is not None:
            self.estimator.accumulate(self.E)
        be.fill(self.moved, 0.0)
        be.fill(self.size2, 0.0)
        for node, y in self.Y.items():
            be.scale_add(self.Y_start[node], y, -1.0, None)
            be.row_dot(self.Y_start[node], self.Y_start[node], 1.0, self.moved)
            be.row_dot(y, y, 1.0, self.size2)
            be.scatter_rows(y, self.index, latents[node])

    def plain_steps(self, steps: int) -> None:
        """The paper's learning steps on the loaded minibatch: T plain inference steps at
        eta_y (the energies of the final state in ``R``)."""
        self.predict_all(energy=steps == 0)
        for step in range(1, steps + 1):
            self.latent_step()
            self.predict_all(energy=step == steps)

    def train_steps(self, steps: int) -> None:
        """The paper's learning step on the loaded minibatch: T plain inference steps, then
        one weight step."""
        self.plain_steps(steps)
        self.weight_step()

    def start_inference(self, inputs: Mapping[str, object], carried: Mapping[str, np.ndarray] | None = None) -> None:
        """Rows ``index`` of the resident inputs, every sample active, latents at 0.1 and no
        steps taken; or, with ``carried`` (`carry` of a larger batch), each sample's latents
        and steps where it left them (its solver's state: `BatchSolver.start`)."""
        for node, x in self.X.items():
            self.be.gather_rows(inputs[node], self.index, x)
        for node, y in self.Y.items():
            if carried is None:
                self.be.fill(y, LATENT_INIT)
            else:
                self.be.upload(carried[f"Y/{node}"], y)
        if carried is None:
            self.begin()
        else:
            self.be.fill(self.active, 1)
            self.be.upload(carried["steps"], self.steps)
            self.predict_all()

    def begin(self) -> None:
        """Inference from the loaded inputs and latents: every sample active, no steps taken,
        the first prediction made."""
        self.be.fill(self.active, 1)
        self.be.fill(self.steps, 0)
        self.predict_all()

    def carry(self, keep: np.ndarray) -> dict[str, np.ndarray]:
        """Host copies of the rows ``keep`` (a boolean mask) of the latents and steps a
        sample's inference goes on from (its solver's state: `BatchSolver.carry`)."""
        rows = {f"Y/{node}": self.be.download(y)[keep] for node, y in self.Y.items()}
        rows["steps"] = self.be.download(self.steps)[keep]
        return rows

    def latent_change(self) -> np.ndarray:
        """Per sample of the last `minibatch`, ||Y_after - Y_before|| / ||Y_after|| over
        every latent node: how far its T steps still moved its latents (0 once settled)."""
        moved, size2 = self.be.download(self.moved), self.be.download(self.size2)
        return np.sqrt(moved / np.maximum(size2, np.finfo(np.float64).tiny))

    def check_finite(self, energy: Mapping[str, float], where: str,
                     remedy: str = "lower the learning rates (eta_y, eta_w)") -> None:
        for name, value in energy.items():
            if not math.isfinite(value):
                raise NetworkError(f"error of layer '{name}' became {value} at {where}; {remedy}")

    def download_latents(self) -> dict[str, np.ndarray]:
        return {node: self.be.download(y) for node, y in self.Y.items()}
