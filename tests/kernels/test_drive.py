"""The joint layer's gradient split per modality edge (`vitaplace.engine.network.drive`).

Expectations come from a hand computation, from central finite differences of each edge's
own energy in float64, and from the stationarity of a settled inference, never from the code
under test.
"""

import numpy as np
import pytest

from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.drive import joint_drive
from vitaplace.engine.network.pc import Network
from vitaplace.engine.network.solver import make_solver

SMALL = {
    "modalities": {
        "visual": {"input_size": 7, "layers": [5, 4], "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
        "tactile": {"input_size": 6, "layers": [3], "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
    },
    "joint": {"size": 3, "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
    "activation": "leaky_relu",
    "slope": 0.2,
}


def tiny() -> Network:
    """Joint size 2, each modality one latent layer of one unit above a one-value input."""
    one = {"input_size": 1, "layers": [1], "eta_y": 0.1, "eta_w": 0.1, "threshold": 0.0}
    config = {"modalities": {"visual": one, "tactile": one}, "joint": {"size": 2, "eta_y": 0.1, "eta_w": 0.1,
              "threshold": 0.0}, "activation": "leaky_relu", "slope": 0.2}
    net = Network(config, seed=0, backend=NumpyBackend(np.float64))
    net.set_weights({"joint.visual": np.array([[2.0], [1.0]]), "joint.tactile": np.array([[1.0], [3.0]])})
    return net


def test_a_hand_computed_case():
    # joint (1, -1): visual A = 2 - 1 = 1 > 0, P = 1, E = 3 - 1 = 2, G = 2, T = -2 G W^T = (-8, -4);
    # tactile A = 1 - 3 = -2 < 0, P = -0.4, E = 0.6 + 0.4 = 1, G = 0.2, T = -2 (0.2) (1, 3) = (-0.4, -1.2)
    net = tiny()
    inputs = {"visual": np.array([[0.5]]), "tactile": np.array([[0.5]])}
    latents = {"visual.1": np.array([[3.0]]), "tactile.1": np.array([[0.6]]), "joint": np.array([[1.0, -1.0]])}
    drive = joint_drive(net, inputs, latents, prior=0.5)
    np.testing.assert_allclose(drive.terms["visual"], [[-8.0, -4.0]])
    np.testing.assert_allclose(drive.terms["tactile"], [[-0.4, -1.2]])
    np.testing.assert_allclose(drive.errors["visual"], [[2.0]])
    np.testing.assert_allclose(drive.errors["tactile"], [[1.0]])
    np.testing.assert_allclose(drive.prior, [[0.5, -0.5]])
    visual, tactile = np.sqrt(80.0), np.sqrt(1.6)
    shares = drive.shares()
    np.testing.assert_allclose(shares["visual"], [visual / (visual + tactile)])
    np.testing.assert_allclose(shares["tactile"], [tactile / (visual + tactile)])
    np.testing.assert_allclose(drive.gradient(), [[-7.9, -5.7]])
    # cos between (-8, -4) and (-0.4, -1.2): (3.2 + 4.8) / (sqrt(80) sqrt(1.6))
    np.testing.assert_allclose(drive.alignment("visual", "tactile"), [8.0 / (visual * tactile)])
    # curvature: 2 phi'^2 ||W column||^2: visual 2 (1) (4 + 1) = 10, tactile 2 (0.04) (1 + 9) = 0.8
    np.testing.assert_allclose(drive.curvature["visual"], [10.0])
    np.testing.assert_allclose(drive.curvature["tactile"], [0.8])
    np.testing.assert_allclose(drive.stiffness_shares()["tactile"], [0.8 / 10.8])


def edge_energy(net: Network, edge: str, lower: np.ndarray, joint: np.ndarray) -> np.ndarray:
    """||Y_lower - phi(Y_joint W)||^2 per sample, written out here in float64."""
    a = joint @ net.weights[edge].astype(np.float64)
    p = np.where(a > 0, a, net.config.slope * a)
    return ((lower - p) ** 2).sum(axis=1)


def test_each_term_is_the_gradient_of_its_edge_energy():
    net = Network(SMALL, seed=3, backend=NumpyBackend(np.float64))
    rng = np.random.default_rng(1)
    inputs = {m: rng.random((5, net.sizes[f"{m}.0"])) for m in net.modalities}
    latents = {node: rng.normal(0.3, 0.5, (5, net.sizes[node])) for node in net.latent_nodes(net.modalities)}
    drive = joint_drive(net, inputs, latents, prior=0.7)
    h = 1e-6
    for m, lower in (("visual", latents["visual.2"]), ("tactile", latents["tactile.1"])):
        numeric = np.empty_like(latents["joint"])
        for k in range(net.sizes["joint"]):
            step = np.zeros_like(latents["joint"])
            step[:, k] = h
            up = edge_energy(net, f"joint.{m}", lower, latents["joint"] + step)
            down = edge_energy(net, f"joint.{m}", lower, latents["joint"] - step)
            numeric[:, k] = (up - down) / (2 * h)
        np.testing.assert_allclose(drive.terms[m], numeric, rtol=1e-6, atol=1e-8)
    # the curvature: the trace of the Hessian of the edge's energy, by central differences of
    # the energy (piecewise quadratic for the leaky ReLU: exact away from its kinks)
    for m, lower in (("visual", latents["visual.2"]), ("tactile", latents["tactile.1"])):
        trace = np.zeros(len(lower))
        h2 = 1e-3
        for k in range(net.sizes["joint"]):
            step = np.zeros_like(latents["joint"])
            step[:, k] = h2
            up = edge_energy(net, f"joint.{m}", lower, latents["joint"] + step)
            mid = edge_energy(net, f"joint.{m}", lower, latents["joint"])
            down = edge_energy(net, f"joint.{m}", lower, latents["joint"] - step)
            trace += (up - 2 * mid + down) / h2**2
        np.testing.assert_allclose(drive.curvature[m], trace, rtol=1e-5)
    # the prior's term: the gradient of 0.7 / 2 ||Y_joint||^2
    np.testing.assert_allclose(drive.prior, 0.7 * latents["joint"])


def test_the_terms_balance_the_prior_at_a_settled_point():
    # the network's own inference settles the latents: the split gradient sums to about 0
    # there, and each term is far from 0 (the modalities pull, the prior holds). tanh: with the
    # leaky ReLU a minimum may lie on a kink, where the gradient of either side is not 0
    net = Network({**SMALL, "activation": "tanh"}, seed=3, backend=NumpyBackend(np.float64))
    inputs = {m: np.random.default_rng(2).random((6, net.sizes[f"{m}.0"])) for m in net.modalities}
    result = net.infer(inputs, max_steps=20000, solver=make_solver("preconditioned", rtol=1e-10), latent_prior=0.5)
    drive = joint_drive(net, inputs, result.latents, prior=0.5)
    assert (drive.residual() < 1e-6).all()
    unsettled = joint_drive(net, inputs, {k: v + 0.1 for k, v in result.latents.items()}, prior=0.5)
    assert (unsettled.residual() > 1e-3).all()
    for share in drive.shares().values():
        assert ((share > 0) & (share < 1)).all()


def test_a_missing_modality_has_no_term():
    net = tiny()
    latents = {"visual.1": np.array([[3.0]]), "joint": np.array([[1.0, -1.0]])}
    drive = joint_drive(net, {"visual": np.array([[0.5]])}, latents)
    assert list(drive.terms) == ["visual"]
    np.testing.assert_allclose(drive.shares()["visual"], [1.0])
    np.testing.assert_allclose(drive.prior, 0.0)
    with pytest.raises(ValueError, match="no modality"):
        joint_drive(net, {}, latents)
