"""Test-time solvers of MuPNet's latents (docs/MUPNET.md, "Test-time inference that settles").

The energy of the latents with frozen weights, with the optional Gaussian prior of standard
predictive coding (``prior`` = lambda; 0: the paper's energy) and the network's error
precisions ``pi`` (1 everywhere unless trained with ``precision_weighting``),

    F_lambda(Y) = sum_edges sum_c pi_c E_c^2 + lambda / 2 sum_latents ||Y||^2,

is minimised per sample by a `Solver`, the value `Network.infer` is given (`make_solver` builds
one from the MuPNet plugin's ``inference_solver``, the one place a name becomes a solver):

* ``gd`` (the paper's, `GradientDescent`): ``Y <- Y - eta_y dF/dY`` with each layer's ``eta_y``;
* ``nesterov`` (`Nesterov`): Nesterov momentum ``beta`` with restarts, each layer's step 1 / L, L the
  Gauss-Newton bound of its block of the Hessian (`curvature_steps`), in the form whose
  gradient is taken at the iterate itself: ``D = -s eta dF/dY``, ``V <- b V + D``,
  ``Y <- Y + D + beta V``;
* ``preconditioned`` (`Preconditioned`): the same momentum, restarts and step control, with each layer's step
  the inverse of the Gauss-Newton bound of its block as a matrix rather than its largest
  eigenvalue (`curvature_preconditioners`): ``D = -s (dF/dY) P``. A layer whose weights have a
  few large singular values (the inputs' common mode) is then not held to the step of its
  stiffest direction in every other one.

In both, a sample's momentum restarts (b = 0, else beta) when it points uphill
(``dF/dY . V > 0``, O'Donoghue and Candes' gradient restart), and an uphill test failed
right after a step taken without momentum (that step overshot the minimum along its own
direction) halves the sample's step scale ``s`` (from 1). The energy is piecewise quadratic
for the leaky ReLU, and its minimum may lie on a kink, where fixed steps zig-zag across it
for ever; halving after such an overshoot makes the steps shrink there and reach the kink.
Every test is on gradients, never on differences of the energy: in float32 those are
rounding (about 1e-4 of an energy of 300) by the time the steps are short, and a rule on
them halves steps at random (docs/MUPNET.md).

Besides the per-edge thresholds, a sample stops once the norm of its step ``D`` (the
gradient scaled by each layer's step, or preconditioned, and by ``s``) is below ``rtol``
times its value at the start (off when ``rtol`` is None). A stopped sample is frozen, as
under the thresholds.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, get_args

import numpy as np
from scipy.linalg import lapack

from vitaplace.engine.network.batch import BatchState
from vitaplace.engine.network.fixed_order import gram, rounded_step, spd_inverse
from vitaplace.engine.network.structure import NetworkView

#: the names of the solvers (the MuPNet plugin's ``inference_solver``; `make_solver`)
SolverName = Literal["gd", "nesterov", "preconditioned"]
#: largest phi' of each activation (the Gauss-Newton curvature bound's gain)
_MAX_GAIN = {"leaky_relu": None, "tanh": 1.0, "sigmoid": 0.25, "linear": 1.0}


def _largest_gain(activation: str, slope: float) -> float:
    gain = _MAX_GAIN[activation]
    return max(1.0, slope) if gain is None else gain


def _scaled_weights(weights: Mapping[str, np.ndarray], precisions: Mapping[str, np.ndarray] | None,
                    name: str) -> np.ndarray:
    """``W diag(sqrt(pi))`` of edge ``name`` in float64 (``W`` where it has no precisions):
    its Gram matrix is ``W diag(pi) W^T``."""
    w = np.asarray(weights[name], np.float64)
    if precisions is None or name not in precisions:
        return w
    return w * np.sqrt(np.asarray(precisions[name], np.float64))


def _largest_precision(precisions: Mapping[str, np.ndarray] | None, name: str) -> float:
    return 1.0 if precisions is None or name not in precisions else float(np.max(precisions[name]))


def curvature_steps(
    weights: Mapping[str, np.ndarray], edges: Sequence, nodes: Sequence[str], activation: str, slope: float,
    prior: float, precisions: Mapping[str, np.ndarray] | None = None, fixed_order: bool = False,
) -> dict[str, float]:
    """Per latent node 1 / L, L = 2 g^2 sum_{edges below} ||W diag(pi) W^T||_2 + 2 max(pi_above) + prior.

    L bounds the node's diagonal block of the energy's Gauss-Newton Hessian
    ``2 J^T diag(pi) J`` (the Hessian itself almost everywhere for a piecewise-linear
    activation) for every sample; g is the largest phi', ``pi`` each edge's error precisions
    (``precisions``; 1 where not given). ``||W diag(pi) W^T||_2`` (``||W||_2^2`` at pi = 1) is
    the largest eigenvalue of the smaller Gram matrix of ``W diag(sqrt(pi))`` (float64),
    raised by 1e-6 relative for rounding; each term is the exact norm of its own block, so
    their sum bounds the block. With ``fixed_order`` (the ``fixed`` backend) the Gram matrix is
    summed in a fixed order and each step rounded down (`fixed_order.rounded_step`), so that
    LAPACK's last bits do not reach it.
    """
    gain = _largest_gain(activation, slope)
    bound = dict.fromkeys(nodes, prior)
    for e in edges:
        w = _scaled_weights(weights, precisions, e.name)
        w = w if w.shape[0] <= w.shape[1] else w.T
        product = gram(w) if fixed_order else w @ w.T
        bound[e.upper] += 2.0 * gain**2 * float(np.linalg.eigvalsh(product)[-1]) * (1 + 1e-6)
        if e.lower in bound:
            bound[e.lower] += 2.0 * _largest_precision(precisions, e.name)
    return {node: rounded_step(1.0 / b) if fixed_order else 1.0 / b for node, b in bound.items()}


def curvature_preconditioners(
    weights: Mapping[str, np.ndarray], edges: Sequence, nodes: Sequence[str], activation: str, slope: float,
    prior: float, precisions: Mapping[str, np.ndarray] | None = None, fixed_order: bool = False,
) -> dict[str, np.ndarray]:
    """Per latent node P = B^-1, B = 2 g^2 sum_{edges below} W diag(pi) W^T + 2 diag(pi_above) + prior I.

    B bounds the node's diagonal block of the Gauss-Newton Hessian ``2 J^T diag(pi) J`` for
    every sample (``J^T diag(pi) J = W diag(pi phi'^2) W^T <= g^2 W diag(pi) W^T``, the edge
    above's term ``2 diag(pi_above)`` exactly; ``pi`` 1 where ``precisions`` gives none);
    `curvature_steps`' L bounds its largest eigenvalue. With a prior B >= prior I is positive
    definite; it is inverted in float64 through its Cholesky factor (LAPACK potrf and potri,
    a fifth of an eigendecomposition's time) and P made exactly symmetric; with ``fixed_order``
    (the ``fixed`` backend) B is summed and inverted in a fixed order instead
    (`fixed_order.gram`, `fixed_order.spd_inverse`), slower and the same under any BLAS.
    """
    gain = _largest_gain(activation, slope)
    bound: dict[str, np.ndarray] = {}
    for e in edges:
        w = _scaled_weights(weights, precisions, e.name)
        bound[e.upper] = bound.get(e.upper, 0.0) + 2.0 * gain**2 * (gram(w) if fixed_order else w @ w.T)
    above = {e.lower: e.name for e in edges}
    out = {}
    for node in nodes:
        if node in above and precisions is not None and above[node] in precisions:
            diagonal = 2.0 * np.asarray(precisions[above[node]], np.float64) + prior
        else:
            diagonal = np.full(len(bound[node]), (2.0 if node in above else 0.0) + prior)
        out[node] = _inverse(bound[node] + np.diag(diagonal), fixed_order, node)
    return out


def _inverse(b: np.ndarray, fixed_order: bool, node: str) -> np.ndarray:
    """The exactly symmetric inverse of latent node ``node``'s curvature bound ``b``."""
    singular = ValueError(f"the curvature bound of latent node '{node}' is singular; the preconditioned "
                          "solver needs a latent prior > 0")
    if fixed_order:
        try:
            return spd_inverse(b)
        except ValueError:
            raise singular from None
    factor, info = lapack.dpotrf(b)
    if info != 0:
        raise singular
    inverse, info = lapack.dpotri(factor)
    upper = np.triu(inverse)
    return upper + np.triu(upper, 1).T


class BatchSolver:
    """A solver's steps on one `BatchState` (`Solver.bind`). This one is the paper's loop:
    plain steps at eta_y, a sample stopped by the thresholds alone, no state of its own."""

    def __init__(self, state: BatchState) -> None:
        self.state = state

    def per_sample(self) -> dict[str, Any]:
        """The buffers that carry a sample's solver state from one step to the next (the
        rest is recomputed at each step)."""
        return {}

    def start(self, inputs: Mapping[str, object], carried: Mapping[str, np.ndarray] | None = None) -> None:
        """`BatchState.start_inference`; with ``carried`` (`carry` of a larger batch) each
        sample's solver state too, so its steps go on as if uninterrupted."""
        self.state.start_inference(inputs, carried)

    def resume(self) -> None:
        """Start from the inputs and latents already in the state (training's persistent
        latents: `Network.train` with a solver), the solver's own state fresh."""
        self.state.begin()

    def carry(self, keep: np.ndarray) -> dict[str, np.ndarray]:
        """Host copies of the rows ``keep`` (a boolean mask) of all a sample's inference goes
        on from: its latents and steps (`BatchState.carry`) and its solver state."""
        rows = self.state.carry(keep)
        rows.update({name: self.state.be.download(buf)[keep] for name, buf in self.per_sample().items()})
        return rows

    def step(self) -> None:
        """One step of every active sample, after the stopping test on the current state."""
        state = self.state
        state.be.stop_converged(state.R, state.limits, state.active, state.steps)
        state.latent_step(state.active)
        state.predict_all()

    def steps(self, count: int) -> None:
        """``count`` test-time steps with per-sample stopping (samples that stopped are frozen
        and no longer counted); only launches work, so it can be captured."""
        for _ in range(count):
            self.step()


class ScaledSteps(BatchSolver):
    """The steps ``D`` of a solver other than the paper's loop, with the relative stopping
    rule: each layer's scalar step ``eta`` or its ``preconditioners``, and Nesterov momentum
    ``momentum`` with restarts and step halving (None: plain steps)."""

    def __init__(self, state: BatchState, eta: Mapping[str, float], *, rtol: float | None,
                 momentum: float | None = None, preconditioners: Mapping[str, Any] | None = None) -> None:
        """``preconditioners``: per latent node the backend's weight handle of its
        `curvature_preconditioners` matrix (then ``eta`` is 1)."""
        super().__init__(state)
        be = state.be
        self.momentum = momentum
        self.rtol2 = 0.0 if rtol is None else float(rtol) ** 2
        shapes = {node: (state.batch, state.net.sizes[node]) for node in state.nodes}
        self.D = {node: be.empty(shape) for node, shape in shapes.items()}
        self.V = {node: be.empty(shape) for node, shape in shapes.items()} if momentum is not None else {}
        self.P, self.eta = dict(preconditioners or {}), dict(eta)
        #: -dF/dY, which the preconditioners multiply (without them, the step itself)
        self.descent = {node: be.empty(shape) for node, shape in shapes.items()} if self.P else self.D
        rows = {name: be.empty((state.batch,), np.float64) for name in ("gnorm", "g0", "scale", "uphill")}
        self.gnorm, self.g0, self.scale, self.uphill = rows.values()
        self.plain = be.empty((state.batch,), np.int32)

    def _step_vector(self, norm: Any) -> None:
        """D = -eta dF/dY, or -(dF/dY) P (rows of the active samples; 0 elsewhere), and its
        squared norm per sample into ``norm``."""
        state, be = self.state, self.state.be
        for d in self.descent.values():
            be.fill(d, 0.0)
        state.descend(self.descent, self.eta, state.active)
        for node, P in self.P.items():  # D = descent P^T = descent P (P symmetric): the latent update's GEMM
            be.fill(self.D[node], 0.0)
            be.latent_update(self.D[node], self.descent[node], P, 0.5, None, None)
        be.fill(norm, 0.0)
        for d in self.D.values():
            be.row_dot(d, d, 1.0, norm)

    def per_sample(self) -> dict[str, Any]:
        rows = {"g0": self.g0, "scale": self.scale, "plain": self.plain}
        rows.update({f"V/{node}": v for node, v in self.V.items()})
        return rows

    def start(self, inputs: Mapping[str, object], carried: Mapping[str, np.ndarray] | None = None) -> None:
        """After the first prediction: no momentum, full steps, the first step's norm into
        ``g0`` (the relative rule's reference); or the per-sample state in ``carried``."""
        super().start(inputs, carried)
        if carried is not None:
            for name, buf in self.per_sample().items():
                self.state.be.upload(carried[name], buf)
            return
        self._fresh()

    def resume(self) -> None:
        super().resume()
        self._fresh()

    def _fresh(self) -> None:
        be = self.state.be
        for v in self.V.values():
            be.fill(v, 0.0)
        be.fill(self.scale, 1.0)
        be.fill(self.plain, 1)
        self._step_vector(self.g0)

    def _control(self) -> None:
        """Nesterov's restart test and step control (`solver_kernels.restart_control`)."""
        be = self.state.be
        be.fill(self.uphill, 0.0)
        for node, d in self.descent.items():  # dF/dY . V = -(descent . V) / eta
            be.row_dot(d, self.V[node], -1.0 / self.eta[node], self.uphill)
        be.restart_control(self.scale, self.plain, self.uphill, self.state.active)

    def step(self) -> None:
        state, be = self.state, self.state.be
        self._step_vector(self.gnorm)
        if self.momentum is not None:
            self._control()
        be.stop_settled(state.R, state.limits, self.gnorm, self.scale, self.g0, self.rtol2, state.active, state.steps)
        if self.momentum is not None:
            for node, d in self.D.items():
                be.momentum_step(state.Y[node], self.V[node], d, self.momentum, self.uphill, self.scale, state.active)
        else:
            for node, d in self.D.items():
                be.scale_add(state.Y[node], d, 1.0, state.active)
        state.predict_all()


@dataclass(frozen=True, kw_only=True)
class Solver(ABC):
    """A test-time solver of the latents, the value `Network.infer` is given: its settings,
    each layer's step (`node_steps`, once per call) and its steps on a batch (`bind`).
    ``rtol``: the relative stopping rule (None: off). `make_solver` builds one by name."""

    rtol: float | None = None
    #: whether its steps need a latent prior > 0 (the curvature bound is singular without)
    needs_prior: ClassVar[bool] = False

    @abstractmethod
    def node_steps(self, net: NetworkView, present: Sequence[str], prior: float) -> Mapping[str, Any]:
        """Per latent node of the modalities ``present`` its step (under the latent prior
        ``prior``): a number or a backend handle."""

    @abstractmethod
    def bind(self, state: BatchState, node_steps: Mapping[str, Any]) -> BatchSolver:
        """The solver's steps on ``state`` with the steps of `node_steps`."""

    @property
    @abstractmethod
    def remedy(self) -> str:
        """What to change when this inference diverges."""


@dataclass(frozen=True, kw_only=True)
class GradientDescent(Solver):
    """``gd``: plain steps at each layer's eta_y; without ``rtol``, the paper's loop exactly."""

    def node_steps(self, net: NetworkView, present: Sequence[str], prior: float) -> Mapping[str, Any]:
        return net.eta_y

    def bind(self, state: BatchState, node_steps: Mapping[str, Any]) -> BatchSolver:
        return BatchSolver(state) if self.rtol is None else ScaledSteps(state, node_steps, rtol=self.rtol)

    @property
    def remedy(self) -> str:
        return "lower the latent step sizes (eta_y)"


def _bound(net: NetworkView, present: Sequence[str], prior: float) -> tuple:
    """The arguments of the curvature bounds (`curvature_steps`) of the modalities ``present``."""
    weights = net.host_weights()
    return (weights, net.active_edges(present), net.latent_nodes(present), net.config.activation, net.config.slope,
            prior, net.precisions if net.weighted else None, net.backend.fixed_order)


@dataclass(frozen=True, kw_only=True)
class Nesterov(Solver):
    """``nesterov``: momentum ``momentum`` with restarts, each layer's step 1 / L (`curvature_steps`)."""

    momentum: float = 0.9

    def node_steps(self, net: NetworkView, present: Sequence[str], prior: float) -> Mapping[str, Any]:
        return curvature_steps(*_bound(net, present, prior))

    def bind(self, state: BatchState, node_steps: Mapping[str, Any]) -> BatchSolver:
        return ScaledSteps(state, node_steps, rtol=self.rtol, momentum=self.momentum)

    @property
    def remedy(self) -> str:
        return f"lower inference_momentum ({self.momentum}) or use inference_solver gd"


@dataclass(frozen=True, kw_only=True)
class Preconditioned(Nesterov):
    """``preconditioned``: the same momentum, each layer's step its bound's inverse as a
    matrix (`curvature_preconditioners`, applied on the backend)."""

    needs_prior: ClassVar[bool] = True

    def node_steps(self, net: NetworkView, present: Sequence[str], prior: float) -> Mapping[str, Any]:
        preconditioners = curvature_preconditioners(*_bound(net, present, prior))
        return {node: net.backend.weights(p) for node, p in preconditioners.items()}

    def bind(self, state: BatchState, node_steps: Mapping[str, Any]) -> BatchSolver:
        return ScaledSteps(state, dict.fromkeys(node_steps, 1.0), rtol=self.rtol, momentum=self.momentum,
                           preconditioners=node_steps)


def make_solver(name: str, momentum: float = 0.9, rtol: float | None = None) -> Solver:
    """The solver called ``name`` (the MuPNet plugin's ``inference_solver``), with the
    momentum of the momentum solvers and the relative rule ``rtol``: the one place a name
    becomes a solver."""
    if name == "gd":
        return GradientDescent(rtol=rtol)
    if name == "nesterov":
        return Nesterov(momentum=momentum, rtol=rtol)
    if name == "preconditioned":
        return Preconditioned(momentum=momentum, rtol=rtol)
    raise ValueError(f"unknown inference solver {name!r}; expected {', '.join(get_args(SolverName))}")
