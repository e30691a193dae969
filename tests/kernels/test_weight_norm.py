"""``weight_norm: rows``: every row of every W held at its norm at the start of training.

Expectations: the projection of a hand-built W; the kernels against the numpy reference; a
training step under the constraint equals the unconstrained step followed by the reference's
projection (the definition), and the row norms stay those of the initial weights on every
backend, where without the constraint they move.
"""

import numpy as np
import pytest

from vitaplace.engine.network.pc import Network
from vitaplace.engine.network.selection import get_backend
from vitaplace.kernels import reference as ref
from vitaplace.plugins.mupnet.extractor import MupnetParams

NET = {
    "modalities": {
        "visual": {"input_size": 6, "layers": [4], "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
        "tactile": {"input_size": 5, "layers": [3], "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
    },
    "joint": {"size": 2, "eta_y": 0.05, "eta_w": 0.05, "threshold": 0.0},
    "activation": "leaky_relu",
    "slope": 0.2,
}
TRAIN = {"epochs": 1, "batch_size": 8, "inference_steps": 5, "seed": 0, "converge_window": 0, "converge_tol": 0.01,
         "latent_prior": 0.5, "weight_optimizer": "momentum"}


def data(n: int = 8, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"visual": rng.random((n, 6)).astype(np.float32), "tactile": rng.random((n, 5)).astype(np.float32)}


def row_norms(net: Network) -> dict[str, np.ndarray]:
    return {name: np.linalg.norm(w.astype(np.float64), axis=1) for name, w in net.host_weights().items()}


def test_the_reference_rescales_each_row_to_its_norm_and_keeps_a_zero_row():
    # row 0: |(3, 4)| = 5 -> norm 1: (0.6, 0.8); row 1 zero, kept; row 2: |(1, 0)| = 1 -> norm 5: (5, 0)
    W = np.array([[3, 4], [0, 0], [1, 0]], np.float32)
    np.testing.assert_allclose(ref.project_rows(W, np.array([1.0, 2.0, 5.0])), [[0.6, 0.8], [0, 0], [5, 0]],
                               rtol=1e-7)


def test_the_backends_project_as_the_reference_and_keep_the_transpose(backend):
    be = backend()
    rng = np.random.default_rng(3)
    W = rng.normal(size=(7, 33)).astype(np.float32)
    W[4] = 0.0
    norms = rng.uniform(0.5, 2.0, 7)
    handle = be.weights(W)
    device_norms = be.empty((7,), np.float64)
    be.upload(norms, device_norms)
    be.project_rows(handle, device_norms)
    got = be.weights_to_host(handle)
    expected = ref.project_rows(W, norms)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=0)
    np.testing.assert_allclose(np.linalg.norm(got.astype(np.float64), axis=1), np.where(W.any(axis=1), norms, 0),
                               rtol=1e-6)
    if hasattr(handle, "Wt"):
        np.testing.assert_array_equal(np.asarray(be.download(handle.Wt)), got.T)


def test_a_constrained_step_is_the_plain_step_then_the_projection():
    """One minibatch holding every sample: the same latent steps, the same weight step, so the
    constrained network's weights are the unconstrained ones projected to the initial norms."""
    free, held = (Network(NET, seed=1, backend=get_backend("numpy")) for _ in range(2))
    start = row_norms(free)
    free.train(data(), TRAIN)
    held.train(data(), {**TRAIN, "weight_norm": "rows"})
    for name, w in free.host_weights().items():
        np.testing.assert_allclose(held.host_weights()[name], ref.project_rows(w, start[name]), rtol=1e-5, atol=1e-7)


def test_training_holds_every_row_at_its_initial_norm_and_without_the_constraint_they_move(backend):
    held, free = (Network(NET, seed=2, backend=backend()) for _ in range(2))
    start = row_norms(held)
    training = {**TRAIN, "epochs": 5, "batch_size": 3}
    held.train(data(12), {**training, "weight_norm": "rows"})
    free.train(data(12), training)
    for name, norms in row_norms(held).items():
        np.testing.assert_allclose(norms, start[name], rtol=1e-5)
    moved = max(np.abs(row_norms(free)[name] / start[name] - 1).max() for name in start)
    assert moved > 1e-3


def test_an_unknown_weight_norm_is_refused_naming_the_parameter():
    with pytest.raises(ValueError, match="weight_norm"):
        MupnetParams(weight_norm="columns")
    with pytest.raises(ValueError, match="unknown weight_norm 'columns'"):
        Network(NET, seed=0, backend=get_backend("numpy")).train(data(), {**TRAIN, "weight_norm": "columns"})
