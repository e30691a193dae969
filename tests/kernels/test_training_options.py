"""Training's latents settled by a solver, and the held-out energy measured after every epoch.

Expectations come from the energy's definition: for the linear activation the energy under the
latent prior is quadratic in the latents, so its minimiser is the solution of a linear system
solved here in float64 from the energy alone (the errors evaluated at the unit vectors), never
from the code under test's own steps.
"""

import numpy as np
import pytest

from vitaplace.engine.network.pc import HeldOut, Network, NetworkError
from vitaplace.engine.network.solver import make_solver
from vitaplace.plugins.mupnet.extractor import MupnetParams, held_out_split

LINEAR = {
    "modalities": {
        "visual": {"input_size": 5, "layers": [3], "eta_y": 0.01, "eta_w": 0.0, "threshold": 0.0},
        "tactile": {"input_size": 4, "layers": [2], "eta_y": 0.01, "eta_w": 0.0, "threshold": 0.0},
    },
    "joint": {"size": 2, "eta_y": 0.01, "eta_w": 0.0, "threshold": 0.0},
    "activation": "linear",
    "slope": 0.2,
}
PRIOR = 0.5
TRAIN = {"epochs": 1, "batch_size": 4, "inference_steps": 400, "seed": 0, "converge_window": 0, "converge_tol": 0.01,
         "latent_prior": PRIOR}


def errors(net: Network, x: dict[str, np.ndarray], y: dict[str, np.ndarray]) -> np.ndarray:
    """Every edge's error E = lower - upper W (linear activation) of one sample, concatenated, in float64."""
    node = {**{f"{m}.0": x[m] for m in x}, **y}
    w = net.host_weights()
    return np.concatenate([node[e.lower] - node[e.upper] @ w[e.name].astype(np.float64) for e in net.edges])


def settled(net: Network, x: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], float]:
    """The minimiser of ||E(y)||^2 + PRIOR / 2 ||y||^2 over one sample's latents, and ||E||^2 there.

    E is affine in y: E(y) = E(0) + A y, A's columns E(unit vector) - E(0); the minimiser solves
    (2 A^T A + PRIOR I) y = -2 A^T E(0)."""
    nodes = net.latent_nodes(net.modalities)
    sizes = [net.sizes[n] for n in nodes]

    def split(v: np.ndarray) -> dict[str, np.ndarray]:
        return dict(zip(nodes, np.split(v, np.cumsum(sizes)[:-1]), strict=True))

    total = sum(sizes)
    e0 = errors(net, x, split(np.zeros(total)))
    a = np.stack([errors(net, x, split(np.eye(total)[k])) - e0 for k in range(total)], axis=1)
    y = np.linalg.solve(2 * a.T @ a + PRIOR * np.eye(total), -2 * a.T @ e0)
    return split(y), float(np.sum((e0 + a @ y) ** 2))


def sample(inputs: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    return {m: v[i].astype(np.float64) for m, v in inputs.items()}


def data(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"visual": rng.random((n, 5)).astype(np.float32), "tactile": rng.random((n, 4)).astype(np.float32)}


@pytest.mark.parametrize("solver", ["nesterov", "preconditioned"])
def test_a_solver_settles_training_latents_at_the_energy_minimum(backend, solver):
    """With frozen weights (eta_w 0) and enough solver steps, every training sample's latents
    end at the closed-form minimiser of its energy under the prior."""
    net = Network(LINEAR, seed=3, backend=backend())
    inputs = data(6)
    latents: dict[str, np.ndarray] = {}
    net.train(inputs, TRAIN, latents=latents, solver=make_solver(solver))
    for i in range(6):
        expected, _ = settled(net, sample(inputs, i))
        for node, y in expected.items():
            np.testing.assert_allclose(latents[node][i], y, atol=2e-4, err_msg=f"sample {i}, {node}")


def test_the_paper_steps_do_not_settle_in_as_many_steps():
    """The same 400 steps at eta_y 0.01 (the paper's plain steps) leave the latents short of
    the minimum: the solver, not the step count, settles them (the test above can fail)."""
    net = Network(LINEAR, seed=3, backend="numpy")
    inputs = data(6)
    latents: dict[str, np.ndarray] = {}
    net.train(inputs, {**TRAIN, "inference_steps": 40}, latents=latents)
    expected, _ = settled(net, sample(inputs, 0))
    assert max(np.abs(latents[n][0] - y).max() for n, y in expected.items()) > 1e-2


def test_the_held_out_energy_is_the_energy_at_the_settled_latents(backend):
    """Each epoch's held-out entry is the mean over the held-out samples of ||E||^2 at their
    energy minimum under the weights of that epoch's end (frozen here: every epoch the same)."""
    net = Network(LINEAR, seed=5, backend=backend())
    train, held = data(8, seed=1), data(3, seed=2)
    held_out = HeldOut(held, make_solver("preconditioned", rtol=1e-7), 2000, PRIOR)
    history = net.train(train, {**TRAIN, "epochs": 3, "inference_steps": 5}, held_out=held_out)
    expected = np.mean([settled(net, sample(held, i))[1] for i in range(3)])
    assert len(history.held_out) == 3
    for value in history.held_out:
        assert value == pytest.approx(expected, rel=1e-4)


def test_without_held_out_samples_no_held_out_energy():
    net = Network(LINEAR, seed=5, backend="numpy")
    assert net.train(data(8), TRAIN).held_out == []


def test_the_held_out_energy_follows_the_weights():
    """With learning on, the held-out energy changes from epoch to epoch (it is measured, not copied)."""
    learning = {**LINEAR, "joint": {**LINEAR["joint"], "eta_w": 0.05},
                "modalities": {m: {**c, "eta_w": 0.05} for m, c in LINEAR["modalities"].items()}}
    net = Network(learning, seed=5, backend="numpy")
    held_out = HeldOut(data(3, seed=2), make_solver("preconditioned", rtol=1e-7), 2000, PRIOR)
    history = net.train(data(8, seed=1), {**TRAIN, "epochs": 3, "inference_steps": 5}, held_out=held_out)
    assert len(set(history.held_out)) == 3
    expected = np.mean([settled(net, sample(held_out.inputs, i))[1] for i in range(3)])
    assert history.held_out[-1] == pytest.approx(expected, rel=1e-4)


def test_held_out_split_draws_the_share_with_the_seed():
    train, held = held_out_split(1000, 0.1, seed=7)
    assert len(held) == 100 and len(train) == 900
    assert np.array_equal(np.sort(np.concatenate([train, held])), np.arange(1000))
    again_train, again_held = held_out_split(1000, 0.1, seed=7)
    assert np.array_equal(held, again_held) and np.array_equal(train, again_train)
    assert not np.array_equal(held, held_out_split(1000, 0.1, seed=8)[1])
    assert np.array_equal(held, np.sort(held))  # sorted, not in draw order
    assert len(held_out_split(10, 0.0, seed=7)[1]) == 0


def test_held_out_split_leaving_nothing_to_train_is_an_error():
    with pytest.raises(NetworkError, match="held_out 0.9 of a training run of 1 samples"):
        held_out_split(1, 0.9, seed=0)


def test_training_with_the_solver_needs_a_settling_solver():
    with pytest.raises(ValueError, match="training_inference"):
        MupnetParams(training_inference="solver", inference_solver="gd")
    assert MupnetParams(training_inference="solver", inference_solver="nesterov").training_inference == "solver"


def test_a_solver_goes_on_from_the_persistent_latents(backend):
    """Each epoch's solver steps start where the last epoch's left a sample's latents: with the
    weights frozen, two epochs of 3 steps end nearer the minimiser than one (from 0.1 each
    epoch, the second would end where the first did)."""
    inputs = data(6)
    ends = []
    for epochs in (1, 2):
        net = Network(LINEAR, seed=3, backend=backend())
        latents: dict[str, np.ndarray] = {}
        net.train(inputs, {**TRAIN, "epochs": epochs, "inference_steps": 3}, latents=latents,
                  solver=make_solver("nesterov"))
        expected, _ = settled(net, sample(inputs, 0))
        ends.append(sum(float(np.sum((latents[n][0] - y) ** 2)) for n, y in expected.items()))
    assert ends[1] < 0.5 * ends[0]
