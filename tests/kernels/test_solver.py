"""Test-time solvers of the latents (`vitaplace.engine.network.solver`).

Expectations: the fixed point of the energy with a Gaussian prior on the latents, found by a
very long plain-gradient solve (its fixed point does not depend on the step size, so that
solve uses a large one) and checked to be stationary by central differences of the energy
written out here; the Warp kernels against the numpy backend's operations.
"""

import numpy as np
import pytest

from conftest import cuda_present
from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.pc import Network
from vitaplace.engine.network.selection import get_backend
from vitaplace.engine.network.solver import (
    GradientDescent,
    Nesterov,
    Preconditioned,
    curvature_preconditioners,
    curvature_steps,
    make_solver,
)
from vitaplace.kernels.reference import activation

SMALL = {
    "modalities": {
        "visual": {"input_size": 9, "layers": [6, 4], "eta_y": 0.02, "eta_w": 0.0, "threshold": 0.0},
        "tactile": {"input_size": 5, "layers": [3], "eta_y": 0.02, "eta_w": 0.0, "threshold": 0.0},
    },
    "joint": {"size": 3, "eta_y": 0.02, "eta_w": 0.0, "threshold": 0.0},
    "activation": "tanh",
    "slope": 0.2,
}
PRIOR = 0.1


def network(backend, activation_name: str = "tanh") -> Network:
    return Network({**SMALL, "activation": activation_name}, seed=5, backend=backend)


def inputs_for(net: Network, n: int = 4) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(2)
    return {m: rng.random((n, net.sizes[f"{m}.0"])) for m in net.modalities}


def energy(net: Network, x: dict[str, np.ndarray], y: dict[str, np.ndarray]) -> float:
    """sum_edges ||X_d - phi(Y_u W)||^2 + PRIOR / 2 sum ||Y||^2, in float64, written out here."""
    total = 0.0
    for e in net.active_edges(net.modalities):
        lower = y[e.lower] if e.lower in y else x[e.lower.split(".")[0]]
        pred = activation(y[e.upper] @ net.weights[e.name].astype(np.float64), net.config.activation, net.config.slope)
        total += float(np.sum((lower - pred) ** 2))
    return total + 0.5 * PRIOR * sum(float(np.sum(v**2)) for v in y.values())


@pytest.fixture(scope="module")
def reference():
    """The float64 fixed point of a 200 000-step plain-gradient solve (no stopping)."""
    net = network(NumpyBackend(np.float64))
    x = inputs_for(net)
    result = net.infer(x, max_steps=200_000, latent_prior=PRIOR)
    assert not result.settled.any()  # thresholds 0 and no relative rule: it ran to the cap
    return net, x, result.latents


def relative(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    return float(np.sqrt(sum(np.sum((a[n] - b[n]) ** 2) for n in b) / sum(np.sum(b[n] ** 2) for n in b)))


def test_the_long_plain_gradient_solve_is_a_stationary_point(reference):
    net, x, y = reference
    rng = np.random.default_rng(0)
    start = {n: np.full_like(v, 0.1) for n, v in y.items()}
    for _ in range(3):
        v = {n: rng.standard_normal(a.shape) for n, a in y.items()}
        h = 1e-5
        slope = (energy(net, x, {n: y[n] + h * v[n] for n in y})
                 - energy(net, x, {n: y[n] - h * v[n] for n in y})) / (2 * h)
        at_start = (energy(net, x, {n: start[n] + h * v[n] for n in y})
                    - energy(net, x, {n: start[n] - h * v[n] for n in y})) / (2 * h)
        assert abs(slope) < 1e-6 * max(1.0, abs(at_start)), (slope, at_start)


#: the solvers that settle: scalar steps per layer, and the same with each layer's bound as a matrix
SETTLING = ["nesterov", "preconditioned"]


def test_the_factory_builds_each_solver_from_its_name_and_settings():
    """The plugin's ``inference_solver``, ``inference_momentum`` and ``inference_rtol``; gd has
    no momentum."""
    assert make_solver("gd", 0.8, 1e-5) == GradientDescent(rtol=1e-5)
    assert make_solver("nesterov", 0.8, 1e-5) == Nesterov(momentum=0.8, rtol=1e-5)
    assert make_solver("preconditioned", 0.7, None) == Preconditioned(momentum=0.7)
    assert make_solver("preconditioned").needs_prior and not make_solver("nesterov").needs_prior


def test_the_factory_refuses_an_unknown_name_in_one_line():
    with pytest.raises(ValueError) as error:
        make_solver("adam")
    assert str(error.value) == "unknown inference solver 'adam'; expected gd, nesterov, preconditioned"


@pytest.mark.parametrize("solver", SETTLING)
@pytest.mark.parametrize("activation_name", ["tanh", "sigmoid"])
def test_the_solver_reaches_the_same_fixed_point_in_float64_within_1e_6(activation_name, solver):
    net = network(NumpyBackend(np.float64), activation_name)
    x = inputs_for(net)
    long = net.infer(x, max_steps=200_000, latent_prior=PRIOR).latents
    fast = net.infer(x, max_steps=20_000, solver=make_solver(solver, 0.9, 1e-12), latent_prior=PRIOR)
    assert fast.settled.all() and fast.steps < 20_000
    assert relative(fast.latents, long) < 1e-6


BACKENDS = [
    pytest.param(("numpy", None), id="numpy"),
    pytest.param(("fixed", None), id="fixed"),
    pytest.param(("warp", "cpu"), id="warp-cpu"),
    pytest.param(("warp", "cuda"), id="warp-cuda", marks=pytest.mark.cuda),
]


@pytest.mark.parametrize("solver", SETTLING)
@pytest.mark.parametrize("which", BACKENDS)
def test_the_solver_in_float32_is_within_1e_3_of_the_fixed_point(reference, which, solver):
    name, device = which
    if device == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    if name == "warp":
        pytest.importorskip("warp")
    _, x, y = reference
    net = network(get_backend(name, device))
    x32 = {m: v.astype(np.float32) for m, v in x.items()}
    result = net.infer(x32, max_steps=5000, solver=make_solver(solver, 0.9, 1e-5), latent_prior=PRIOR)
    assert result.settled.all()
    assert relative({n: v.astype(np.float64) for n, v in result.latents.items()}, y) < 1e-3


@pytest.mark.parametrize("solver", SETTLING)
@pytest.mark.parametrize("which", BACKENDS)
def test_on_a_leaky_relu_network_float32_stops_where_float64_does(which, solver):
    """The leaky ReLU's energy is piecewise quadratic, its minima may lie on kinks: every
    sample still stops by the relative rule (the step halves after an overshoot), in float64
    at 1e-10 and in float32 at 1e-5, and the float32 point is the float64 one within 1e-3
    (its tests are on gradients, which float32 resolves, not on energy differences)."""
    name, device = which
    if device == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    if name == "warp":
        pytest.importorskip("warp")
    net64 = network(NumpyBackend(np.float64), "leaky_relu")
    x = {m: 3 * v - 1 for m, v in inputs_for(net64, n=16).items()}  # both sides of the kinks
    exact = net64.infer(x, max_steps=20_000, solver=make_solver(solver, 0.9, 1e-10), latent_prior=PRIOR)
    assert exact.settled.all()
    net = network(get_backend(name, device), "leaky_relu")
    fast = net.infer({m: v.astype(np.float32) for m, v in x.items()}, max_steps=5000,
                     solver=make_solver(solver, 0.9, 1e-5), latent_prior=PRIOR)
    assert fast.settled.all()
    for i in range(16):
        one = {n: v[i : i + 1] for n, v in exact.latents.items()}
        assert relative({n: v[i : i + 1].astype(np.float64) for n, v in fast.latents.items()}, one) < 1e-3, i


@pytest.mark.parametrize("which", [pytest.param("numpy"), pytest.param("warp-cpu")])
def test_the_restart_control_by_hand(which):
    """Rows: uphill after a step without momentum (restart, halve), uphill after a momentum
    step (restart only), downhill after a step without momentum (momentum next), inactive
    (untouched)."""
    if which == "warp-cpu":
        pytest.importorskip("warp")
    be = NumpyBackend() if which == "numpy" else get_backend("warp", "cpu")
    scale, plain = np.array([1.0, 0.5, 0.25, 1.0]), np.array([1, 0, 1, 1], np.int32)
    uphill, active = np.array([0.3, 2.0, -0.1, 5.0]), np.array([1, 1, 1, 0], np.int32)
    arrays = [scale, plain, uphill, active]
    bufs = [be.empty(a.shape, a.dtype.type) for a in arrays]
    for a, buf in zip(arrays, bufs, strict=True):
        be.upload(a, buf)
    be.restart_control(*bufs)
    got = [be.download(buf) for buf in bufs[:3]]
    np.testing.assert_array_equal(got[0], [0.5, 0.5, 0.25, 1.0])
    np.testing.assert_array_equal(got[1], [1, 1, 0, 1])
    np.testing.assert_array_equal(got[2], [1.0, 1.0, 0.0, 5.0])


def gradient(net: Network, x: dict[str, np.ndarray], y: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """dF/dY of `energy`, written out: per edge -2 (phi'(A) * E) W^T on its upper node and
    +2 E on its lower one when that is a latent, and PRIOR * Y."""
    from vitaplace.kernels.reference import activation_derivative

    act, slope = net.config.activation, net.config.slope
    grad = {n: PRIOR * v for n, v in y.items()}
    for e in net.active_edges(net.modalities):
        w = net.weights[e.name].astype(np.float64)
        a = y[e.upper] @ w
        err = (y[e.lower] if e.lower in y else x[e.lower.split(".")[0]]) - activation(a, act, slope)
        grad[e.upper] = grad[e.upper] - 2 * (activation_derivative(a, act, slope) * err) @ w.T
        if e.lower in y:
            grad[e.lower] = grad[e.lower] + 2 * err
    return grad


@pytest.mark.parametrize("solver", SETTLING)
def test_the_first_step_is_one_plus_beta_times_the_preconditioned_descent(solver):
    """From the start (0.1, no momentum yet) one step moves the latents by (1 + beta) D with
    D = -(dF/dY) / L per layer (nesterov) or -(dF/dY) P (preconditioned), by hand here."""
    net = network(NumpyBackend(np.float64))
    x = inputs_for(net)
    nodes, edges = net.latent_nodes(net.modalities), net.active_edges(net.modalities)
    start = {n: np.full((4, net.sizes[n]), 0.1) for n in nodes}
    off = {e.name: 0.0 for e in edges}
    one = net.infer(x, max_steps=1, thresholds=off, solver=make_solver(solver, 0.9, None), latent_prior=PRIOR).latents
    g = gradient(net, x, start)
    if solver == "preconditioned":
        P = curvature_preconditioners(net.weights, edges, nodes, "tanh", 0.2, PRIOR)
        step = {n: -g[n] @ P[n] for n in nodes}
    else:
        eta = curvature_steps(net.weights, edges, nodes, "tanh", 0.2, PRIOR)
        step = {n: -eta[n] * g[n] for n in nodes}
    for n in nodes:  # the results are stored in float32
        np.testing.assert_allclose(one[n] - start[n], 1.9 * step[n], rtol=1e-5, atol=1e-7, err_msg=n)


def test_the_preconditioned_restart_test_is_on_the_gradient():
    """The momentum restarts where dF/dY . V > 0 at the new point, the gradient by hand here,
    not where the preconditioned step points against V (the two disagree on this case)."""
    net = network(NumpyBackend(np.float64), "leaky_relu")
    x = {m: 3 * v - 1 for m, v in inputs_for(net, n=16).items()}  # both sides of the kinks
    nodes, edges = net.latent_nodes(net.modalities), net.active_edges(net.modalities)
    P = curvature_preconditioners(net.weights, edges, nodes, "leaky_relu", 0.2, PRIOR)
    state = net.batch_state(16)
    state.prior = PRIOR
    solver = make_solver("preconditioned", 0.9).bind(state, {n: net.backend.weights(p) for n, p in P.items()})
    state.index[:] = np.arange(16)
    solver.start({net.input_node(m): v for m, v in x.items()})
    disagree = 0
    for _ in range(60):
        y, v = ({n: a[n].copy() for n in nodes} for a in (state.Y, solver.V))
        solver.step()
        g = gradient(net, x, y)
        np.testing.assert_array_equal(solver.uphill > 0, sum(np.sum(g[n] * v[n], axis=1) for n in nodes) > 0)
        disagree += np.sum((sum(np.sum(g[n] * v[n], 1) for n in nodes) > 0)
                           != (sum(np.sum((g[n] @ P[n]) * v[n], 1) for n in nodes) > 0))
    assert disagree > 0


COMPACTED = [
    pytest.param(make_solver("gd", rtol=1e-3), id="gd"),
    pytest.param(make_solver("nesterov", 0.9, 1e-6), id="nesterov"),
    pytest.param(make_solver("preconditioned", 0.9, 1e-6), id="preconditioned"),
]


@pytest.mark.parametrize("solver", COMPACTED)
@pytest.mark.parametrize("which", BACKENDS)
def test_compacting_a_batch_changes_no_sample_s_steps(monkeypatch, which, solver):
    """Samples that stop at different steps, inferred in one batch (compacted to the active
    ones every 5 steps here), take the same steps to the same latents as each one alone:
    the batch carries every sample's latents, step count and solver state."""
    import vitaplace.engine.network.inference as inference

    name, device = which
    if device == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    if name == "warp":
        pytest.importorskip("warp")
    monkeypatch.setattr(inference, "STEPS_PER_CHECK", 5)
    net = network(NumpyBackend(np.float64) if name == "numpy" else get_backend(name, device))
    x = inputs_for(net, n=8)
    dtype = np.float64 if name == "numpy" else np.float32
    x = {m: (v * np.linspace(0.2, 1.0, 8)[:, None]).astype(dtype) for m, v in x.items()}
    progress: list[int] = []
    together = net.infer(x, max_steps=2000, solver=solver, latent_prior=PRIOR, on_progress=progress.append)
    assert sum(progress) == 8  # each sample reported once, as it stops
    alone = [net.infer({m: v[i : i + 1] for m, v in x.items()}, max_steps=2000, solver=solver, latent_prior=PRIOR)
             for i in range(8)]
    steps = together.steps_per_sample
    assert together.settled.all() and steps.max() - steps.min() > 10  # stopped at different checks
    np.testing.assert_array_equal(steps, [a.steps for a in alone])
    tol = 1e-12 if name == "numpy" else 1e-5
    for node, y in together.latents.items():
        np.testing.assert_allclose(y, np.concatenate([a.latents[node] for a in alone]), rtol=tol, atol=tol)


def test_the_relative_rule_stops_plain_steps_once_the_step_has_shrunk():
    """With rtol 1e-3 plain steps stop long before the cap, at a point whose distance to the
    fixed point is small; without it they run to the cap (thresholds 0)."""
    net = network(NumpyBackend(np.float64))
    x = inputs_for(net)
    long = net.infer(x, max_steps=200_000, latent_prior=PRIOR).latents
    ruled = net.infer(x, max_steps=200_000, solver=make_solver("gd", rtol=1e-3), latent_prior=PRIOR)
    assert ruled.settled.all() and ruled.steps < 200_000
    assert relative(ruled.latents, long) < 0.05


def test_the_prior_moves_the_fixed_point_towards_zero(reference):
    """A stronger prior gives latents of a smaller norm (the prior's pull on the energy)."""
    _, x, y = reference
    net = network(NumpyBackend(np.float64))
    strong = net.infer(x, max_steps=20_000, solver=make_solver("nesterov", 0.9, 1e-12), latent_prior=10 * PRIOR).latents
    assert sum(np.sum(strong[n] ** 2) for n in y) < sum(np.sum(y[n] ** 2) for n in y)


def test_the_curvature_steps_are_the_gauss_newton_bound():
    """1 / (prior + 2 g^2 sum over the edges below of ||W||_2^2 + 2 when an edge is above),
    g = 1 for tanh, by hand from the spectral norms."""
    net = network(NumpyBackend(np.float64))
    nodes = net.latent_nodes(net.modalities)
    steps = curvature_steps(net.weights, net.active_edges(net.modalities), nodes, "tanh", 0.2, PRIOR)
    norm = {name: np.linalg.norm(w.astype(np.float64), 2) ** 2 for name, w in net.weights.items()}
    expected = {
        "visual.1": PRIOR + 2 * norm["visual.1"] + 2,
        "visual.2": PRIOR + 2 * norm["visual.2"] + 2,
        "tactile.1": PRIOR + 2 * norm["tactile.1"] + 2,
        "joint": PRIOR + 2 * (norm["joint.visual"] + norm["joint.tactile"]),
    }
    assert set(steps) == set(expected)
    for node, bound in expected.items():
        assert steps[node] == pytest.approx(1 / bound, rel=1e-5), node


def test_the_preconditioners_invert_the_gauss_newton_bound_matrix():
    """P = B^-1 with B = prior I + 2 g^2 sum over the edges below of W W^T + 2 I when an edge is
    above (g = 1 for tanh), built by hand here; the largest eigenvalue of B is the bound the
    scalar steps use where one edge is below (with two, the joint's, those add the edges'
    norms, which bound it from above)."""
    net = network(NumpyBackend(np.float64))
    nodes = net.latent_nodes(net.modalities)
    edges = net.active_edges(net.modalities)
    P = curvature_preconditioners(net.weights, edges, nodes, "tanh", 0.2, PRIOR)
    steps = curvature_steps(net.weights, edges, nodes, "tanh", 0.2, PRIOR)
    w = {name: v.astype(np.float64) for name, v in net.weights.items()}
    eye = {node: np.eye(net.sizes[node]) for node in nodes}
    expected = {
        "visual.1": PRIOR * eye["visual.1"] + 2 * w["visual.1"] @ w["visual.1"].T + 2 * eye["visual.1"],
        "visual.2": PRIOR * eye["visual.2"] + 2 * w["visual.2"] @ w["visual.2"].T + 2 * eye["visual.2"],
        "tactile.1": PRIOR * eye["tactile.1"] + 2 * w["tactile.1"] @ w["tactile.1"].T + 2 * eye["tactile.1"],
        "joint": PRIOR * eye["joint"] + 2 * (w["joint.visual"] @ w["joint.visual"].T
                                             + w["joint.tactile"] @ w["joint.tactile"].T),
    }
    assert set(P) == set(expected)
    for node, bound in expected.items():
        np.testing.assert_allclose(P[node] @ bound, eye[node], atol=1e-10, err_msg=node)
        np.testing.assert_array_equal(P[node], P[node].T)  # symmetric to the bit: D = G P = G P^T
        largest = np.linalg.eigvalsh(bound)[-1]
        if node == "joint":
            assert largest < 1 / steps[node]
        else:
            assert 1 / largest == pytest.approx(steps[node], rel=1e-5), node


def test_a_singular_curvature_bound_is_refused_naming_its_node():
    """Without a prior the joint layer's bound is the sum of its edges' W W^T alone: with those
    weights 0 it is singular, refused naming the node; every layer with an edge above has 2 I
    in its bound and is still inverted (P = (2 I + 2 W W^T)^-1 with W = 0 there too: I / 2)."""
    net = network(NumpyBackend(np.float64))
    nodes, edges = net.latent_nodes(net.modalities), net.active_edges(net.modalities)
    zero = {name: np.zeros_like(w) for name, w in net.weights.items()}
    with pytest.raises(ValueError, match="latent node 'joint' is singular"):
        curvature_preconditioners(zero, edges, nodes, "tanh", 0.2, 0.0)
    P = curvature_preconditioners(zero, edges, [n for n in nodes if n != "joint"], "tanh", 0.2, 0.0)
    for node, p in P.items():
        np.testing.assert_allclose(p, np.eye(net.sizes[node]) / 2, rtol=1e-15, err_msg=node)


# ---------------------------------------------------------------------------- kernels

@pytest.fixture(scope="module")
def warp_cpu():
    pytest.importorskip("warp")
    return get_backend("warp", "cpu")


def test_the_solver_kernels_match_the_numpy_backend(warp_cpu):
    rng = np.random.default_rng(4)
    b, n = 7, 5
    ref = NumpyBackend()
    Y, V, D, src = (rng.standard_normal((b, n)).astype(np.float32) for _ in range(4))
    R = rng.random((3, b))
    mask = (rng.random(b) > 0.4).astype(np.int32)
    scale, uphill = rng.random(b) + 0.5, rng.standard_normal(b)
    plain = (rng.random(b) > 0.5).astype(np.int32)
    limits, gnorm, g0 = rng.random(3), rng.random(b), rng.random(b)
    steps = np.arange(b, dtype=np.int32)
    # the relative rule's rows: scale^2 gnorm from 0.125 to 0.375 against 0.3 g0, so some stop
    # and some do not, and neither scale gnorm nor gnorm alone would stop the same ones
    half, spread, ones = np.full(b, 0.5), np.linspace(0.5, 1.5, b), np.ones(b)

    cases = [
        ("scale_add", lambda be, a: be.scale_add(a[0], a[1], 0.7, a[2]), [Y, src, mask]),
        ("scale_add all", lambda be, a: be.scale_add(a[0], a[1], -1.3, None), [Y, src]),
        ("row_dot", lambda be, a: be.row_dot(a[0], a[1], 0.5, a[2]), [Y, src, rng.random(b)]),
        ("restart_control", lambda be, a: be.restart_control(*a), [scale, plain, uphill, mask]),
        ("momentum_step", lambda be, a: be.momentum_step(a[0], a[1], a[2], 0.9, a[3], a[4], a[5]),
         [Y, V, D, (uphill > 0).astype(np.float64), scale, mask]),
        ("stop_settled", lambda be, a: be.stop_settled(a[0], a[1], a[2], a[3], a[4], 0.3, a[5], a[6]),
         [R, limits, gnorm, scale, g0, mask, steps]),
        ("stop_settled, relative rule", lambda be, a: be.stop_settled(a[0], a[1], a[2], a[3], a[4], 0.3, a[5], a[6]),
         [R, np.zeros(3), spread, half, ones, np.ones(b, np.int32), steps]),
    ]
    for label, op, arrays in cases:
        host = [a.copy() for a in arrays]
        dev = [warp_cpu.empty(a.shape, a.dtype.type) for a in arrays]
        for a, d in zip(arrays, dev, strict=True):
            warp_cpu.upload(a, d)
        op(ref, host)
        op(warp_cpu, dev)
        for k, (h, d) in enumerate(zip(host, dev, strict=True)):
            np.testing.assert_allclose(warp_cpu.download(d), h, rtol=1e-6, atol=1e-6, err_msg=f"{label}: argument {k}")
