"""Which modality drives the joint latent: the joint layer's energy gradient split per edge.

The joint node predicts the top node of every modality stack (edge ``joint.m``, `Network`'s
convention: upper node ``joint``, lower node ``m.L``). With the energy of
`vitaplace.engine.network.solver` (``F = sum_edges ||E||^2 + lambda / 2 sum_latents ||Y||^2``),
the joint layer has no edge above it, so its gradient is a sum of one term per modality edge
and the prior's term (eq. 3 of `vitaplace.engine.network.pc`):

    dF/dY_joint = sum_m T_m + lambda Y_joint,   T_m = -2 G_m W_m^T,   G_m = pi_m * phi'(Y_joint W_m) * E_m

``T_m`` is the gradient of that edge's own energy ``||E_m||^2`` in the joint latent: how hard
modality ``m`` pulls the joint latent. A modality's *share* of the drive is
``||T_m|| / sum_k ||T_k||`` over the modality edges (the prior excluded; at a settled point the
prior's term balances the modalities' sum). Everything here is float64 host numpy on the
network's host weights, independent of the backends.

At a settled point the terms balance, so their norms say how hard the modalities pull
against each other there, not who wins. Where the joint latent settles between them is set
by each edge's stiffness, the curvature of its energy in the joint latent: its Gauss-Newton
Hessian ``H_m = 2 W_m diag(phi'^2) W_m^T`` (exact where phi'' = 0, the leaky ReLU's case);
near the minimum ``Y_joint = (sum_m H_m + lambda I)^-1 sum_m H_m Y_m`` for each modality's
preferred latent ``Y_m``. ``JointDrive.curvature`` keeps its trace per sample.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from vitaplace.engine.network.structure import NetworkView
from vitaplace.kernels.reference import activation_derivative, predict

__all__ = ["JointDrive", "joint_drive"]


@dataclass
class JointDrive:
    """Per sample, each modality edge's term of the joint layer's gradient and the prior's.

    ``terms[m]`` (samples x joint size) is ``T_m``; ``errors[m]`` the edge's prediction error
    ``E_m`` (samples x size of the top node of ``m``); ``prior`` is ``lambda Y_joint``;
    ``curvature[m]`` (samples) the trace of the edge's Gauss-Newton Hessian in the joint
    latent, ``2 sum_j pi_j phi'(A_j)^2 ||W_m[:, j]||^2`` (``pi`` the edge's error precisions, 1
    unless the network weighs its errors).
    """

    terms: dict[str, np.ndarray]
    errors: dict[str, np.ndarray]
    prior: np.ndarray
    curvature: dict[str, np.ndarray]

    def norms(self) -> dict[str, np.ndarray]:
        """Per modality, per sample ``||T_m||``."""
        return {m: np.linalg.norm(t, axis=1) for m, t in self.terms.items()}

    def shares(self) -> dict[str, np.ndarray]:
        """Per modality, per sample ``||T_m|| / sum_k ||T_k||`` (0 where every term is 0)."""
        norms = self.norms()
        total = np.sum(list(norms.values()), axis=0)
        safe = np.where(total > 0, total, 1.0)
        return {m: np.where(total > 0, n / safe, 0.0) for m, n in norms.items()}

    def stiffness_shares(self) -> dict[str, np.ndarray]:
        """Per modality, per sample ``tr H_m / sum_k tr H_k``: its say in where the latent settles."""
        total = np.sum(list(self.curvature.values()), axis=0)
        return {m: c / np.where(total > 0, total, 1.0) for m, c in self.curvature.items()}

    def gradient(self) -> np.ndarray:
        """dF/dY_joint: the terms and the prior summed (about 0 at a settled point)."""
        return np.sum(list(self.terms.values()), axis=0) + self.prior

    def residual(self) -> np.ndarray:
        """Per sample ``||dF/dY_joint|| / (sum_m ||T_m|| + ||lambda Y_joint||)``: how far from
        settled the latents are, relative to the drive (0: a stationary point)."""
        total = np.sum(list(self.norms().values()), axis=0) + np.linalg.norm(self.prior, axis=1)
        return np.linalg.norm(self.gradient(), axis=1) / np.where(total > 0, total, 1.0)

    def alignment(self, a: str, b: str) -> np.ndarray:
        """Per sample, the cosine between ``T_a`` and ``T_b`` (-1: they pull against each other)."""
        ta, tb = self.terms[a], self.terms[b]
        norms = np.linalg.norm(ta, axis=1) * np.linalg.norm(tb, axis=1)
        return np.einsum("ij,ij->i", ta, tb) / np.where(norms > 0, norms, 1.0)


def joint_drive(net: NetworkView, inputs: Mapping[str, np.ndarray], latents: Mapping[str, np.ndarray],
                prior: float = 0.0) -> JointDrive:
    """The joint layer's gradient split per edge (`JointDrive`) for clamped (scaled) ``inputs``
    and ``latents`` (by node, e.g. `Network.infer`'s settled ones), under the latent prior
    ``prior`` (lambda). The modalities are those in ``inputs``; a missing one has no edge and
    no term, as in `Network.infer`."""
    present = [m for m in net.config.modalities if m in inputs]
    if not present:
        raise ValueError("joint_drive: no modality given")
    weights = net.host_weights()
    act, slope = net.config.activation, net.config.slope
    joint = np.asarray(latents["joint"], np.float64)
    terms, errors, curvature = {}, {}, {}
    for e in net.active_edges(present):
        if e.upper != "joint":
            continue
        lower = inputs[e.modality] if e.lower == net.input_node(e.modality) else latents[e.lower]
        w = np.asarray(weights[e.name], np.float64)
        pi = np.asarray(net.precisions[e.name], np.float64) if net.weighted else np.ones(w.shape[1])
        a, _, error, gain = predict(joint, w, np.asarray(lower, np.float64), act, slope, precision=pi)
        terms[e.modality] = -2.0 * gain @ w.T
        errors[e.modality] = error
        curvature[e.modality] = 2.0 * (activation_derivative(a, act, slope) ** 2 * pi) @ (w * w).sum(axis=0)
    return JointDrive(terms, errors, prior * joint, curvature)
