"""The predictive-coding network: gradients, inference, learning, persistence.

Expectations come from the energy's definition (finite differences in float64), from
monotonicity of gradient descent with a small step, and from the generative structure of
a synthetic dataset (known causes), never from outputs of the code under test.
"""

import json
import warnings

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.pc import Network, NetworkError

SMALL = {
    "modalities": {
        "visual": {"input_size": 7, "layers": [5, 4], "eta_y": 1.0, "eta_w": 1.0, "threshold": 1e-3},
        "tactile": {"input_size": 6, "layers": [3], "eta_y": 1.0, "eta_w": 1.0, "threshold": 1e-3},
    },
    "joint": {"size": 3, "eta_y": 1.0, "eta_w": 1.0, "threshold": 1e-3},
    "activation": "leaky_relu",
    "slope": 0.2,
}


def random_state(net: Network, n: int, seed: int):
    rng = np.random.default_rng(seed)
    inputs = {m: rng.random((n, net.sizes[f"{m}.0"])) for m in net.modalities}
    latents = {node: rng.normal(0.3, 0.5, (n, net.sizes[node])) for node in net.latent_nodes(net.modalities)}
    return inputs, latents


def total_energy(net: Network, inputs, latents) -> float:
    return sum(net.energy(inputs, latents).values())


@pytest.mark.parametrize("activation", ["leaky_relu", "tanh", "sigmoid", "linear"])
def test_latent_and_weight_gradients_match_finite_differences(activation):
    def network() -> Network:
        return Network({**SMALL, "activation": activation}, seed=3, backend=NumpyBackend(np.float64))

    net = network()
    inputs, latents = random_state(net, n=4, seed=1)
    state = net.batch_state(4)
    state.load(inputs, latents)
    state.predict_all()
    state.latent_step()  # eta_y = 1: Y' = Y - dF/dY
    analytic_dy = {node: latents[node] - net.backend.download(state.Y[node]) for node in state.Y}
    learner = network()  # the weight step changes weights in place: use a second, identical network
    state = learner.batch_state(4)
    state.load(inputs, latents)
    state.predict_all()
    before = {name: learner.backend.weights_to_host(w) for name, w in state.weights.items()}
    state.weight_step()  # eta_w = 1: W' = W - dF/dW
    analytic_dw = {name: before[name] - learner.backend.weights_to_host(w) for name, w in state.weights.items()}

    h = 1e-6
    for node, y in latents.items():
        for index in [(0, 0), (3, y.shape[1] - 1), (1, y.shape[1] // 2)]:
            plus = {k: v.copy() for k, v in latents.items()}
            minus = {k: v.copy() for k, v in latents.items()}
            plus[node][index] += h
            minus[node][index] -= h
            numeric = (total_energy(net, inputs, plus) - total_energy(net, inputs, minus)) / (2 * h)
            assert analytic_dy[node][index] == pytest.approx(numeric, rel=1e-5, abs=1e-7), (node, index)

    weights = {name: w.astype(np.float64) for name, w in before.items()}
    for name, w in weights.items():
        for index in [(0, 0), (w.shape[0] - 1, w.shape[1] - 1)]:
            values = []
            for sign in (+1, -1):
                probe = network()
                changed = {k: v.copy() for k, v in weights.items()}
                changed[name][index] += sign * h
                probe.set_weights(changed)
                # set_weights stores float32; write the float64 perturbation into the backend copy.
                probe.backend.upload_weights(changed[name], probe.device_weights()[name])
                values.append(total_energy(probe, inputs, latents))
            numeric = (values[0] - values[1]) / (2 * h)
            assert analytic_dw[name][index] == pytest.approx(numeric, rel=1e-5, abs=1e-7), (name, index)


def test_inference_with_small_step_never_increases_energy(backend):
    config = {
        "modalities": {
            "visual": {"input_size": 20, "layers": [10, 6], "eta_y": 0.01, "eta_w": 1e-4, "threshold": 1e-3},
            "tactile": {"input_size": 8, "layers": [5], "eta_y": 0.01, "eta_w": 1e-4, "threshold": 1e-3},
        },
        "joint": {"size": 4, "eta_y": 0.01, "eta_w": 1e-4, "threshold": 1e-3},
        "activation": "leaky_relu",
        "slope": 0.2,
    }
    net = Network(config, seed=0, backend=backend())
    inputs, latents = random_state(net, n=16, seed=2)
    state = net.batch_state(16)
    state.load(inputs, latents)
    state.predict_all()
    energies = [sum(state.energies().values())]
    for _ in range(200):
        state.latent_step()
        state.predict_all()
        energies.append(sum(state.energies().values()))
    steps = np.diff(energies)
    assert np.all(steps <= 1e-5 * energies[0]), f"energy rose at step {int(np.argmax(steps))}"
    assert energies[-1] < 0.9 * energies[0]


def synthetic(n: int = 400, causes: int = 5, seed: int = 0):
    """Two modalities generated from shared causes: x_m = f_m(z_k + noise) for cause k."""
    rng = np.random.default_rng(seed)
    centres = rng.random((causes, 4))
    labels = np.arange(n) % causes
    z = centres[labels] + 0.03 * rng.normal(size=(n, 4))
    visual = 1 / (1 + np.exp(-(z @ rng.normal(size=(4, 40)))))
    tactile = np.tanh(z @ rng.normal(size=(4, 10))) * 0.5 + 0.5
    return {"visual": visual.astype(np.float32), "tactile": tactile.astype(np.float32)}, labels


SYNTH = {
    "modalities": {
        "visual": {"input_size": 40, "layers": [20], "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
        "tactile": {"input_size": 10, "layers": [8], "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
    },
    "joint": {"size": 6, "eta_y": 0.05, "eta_w": 0.005, "threshold": 1e-3},
    "activation": "leaky_relu",
    "slope": 0.2,
}
TRAIN = {"epochs": 30, "batch_size": 50, "inference_steps": 20, "seed": 0, "converge_window": 0, "converge_tol": 0.01,
         "latent_prior": 0.0}
NO_STOP = {"visual.1": 0.0, "tactile.1": 0.0, "joint.visual": 0.0, "joint.tactile": 0.0}


def reconstruction_mse(net: Network, inputs) -> dict[str, float]:
    joint = net.infer(inputs, max_steps=300, thresholds=NO_STOP).latents["joint"]
    return {m: float(np.mean((net.reconstruct(joint, m) - inputs[m]) ** 2)) for m in inputs}


@pytest.fixture(scope="module")
def trained(backend):
    inputs, labels = synthetic()
    net = Network(SYNTH, seed=0, backend=backend())
    before = reconstruction_mse(net, inputs)
    history = net.train(inputs, TRAIN)
    return net, inputs, labels, before, history


def test_training_lowers_reconstruction_error_of_both_modalities(trained):
    net, inputs, _, before, history = trained
    after = reconstruction_mse(net, inputs)
    for m in inputs:
        assert after[m] < before[m] / 20, (m, before[m], after[m])
    for name, energy in history.energy.items():
        assert len(energy) == TRAIN["epochs"]
        assert energy[-1] < energy[0], name


def test_joint_latents_group_samples_by_cause(trained):
    net, inputs, labels, _, _ = trained
    joint = net.infer(inputs, max_steps=300, thresholds=NO_STOP).latents["joint"]
    d = cdist(joint, joint)
    same = labels[:, None] == labels[None, :]
    np.fill_diagonal(same, False)
    different = labels[:, None] != labels[None, :]
    assert d[same].mean() < 0.25 * d[different].mean()
    np.fill_diagonal(d, np.inf)
    nearest = labels[np.argmin(d, axis=1)]
    assert np.mean(nearest == labels) > 0.95


def test_missing_modality_is_reconstructed_better_than_the_mean(trained):
    net, inputs, _, _, _ = trained
    result = net.infer({"visual": inputs["visual"]}, max_steps=300)
    assert set(result.latents) == {"visual.1", "joint"}
    guess = net.reconstruct(result.latents["joint"], "tactile")
    mean_predictor = np.mean((inputs["tactile"] - inputs["tactile"].mean(axis=0)) ** 2)
    assert np.mean((guess - inputs["tactile"]) ** 2) < 0.75 * mean_predictor


def test_inference_stops_at_threshold_or_step_cap(trained):
    net, inputs, _, _, _ = trained
    capped = net.infer(inputs, max_steps=7, thresholds=NO_STOP)
    assert capped.steps == 7 and not capped.converged
    loose = net.infer(inputs, max_steps=500, thresholds=dict.fromkeys(NO_STOP, 1e9))
    assert loose.steps == 0 and loose.converged
    for node, y in loose.latents.items():  # no step taken: MuPNet's initial latents, 0.1 everywhere
        np.testing.assert_array_equal(y, np.full_like(y, 0.1), err_msg=node)
    moderate = net.infer(inputs, max_steps=3000, thresholds=dict.fromkeys(NO_STOP, 5e-3))
    assert moderate.converged and all(v < 5e-3 for v in moderate.mse.values())


def test_each_sample_stops_on_its_own(trained):
    """Per-sample stopping: a batch gives every sample the steps and latents it gets when
    inferred alone (samples never interact), and the samples do stop at different steps."""
    net, inputs, _, _, _ = trained
    subset = {m: x[:12] for m, x in inputs.items()}
    limits = dict.fromkeys(NO_STOP, 4e-3)
    batched = net.infer(subset, max_steps=400, thresholds=limits, batch_size=12)
    alone = [net.infer({m: x[i : i + 1] for m, x in subset.items()}, max_steps=400, thresholds=limits)
             for i in range(12)]
    np.testing.assert_array_equal(batched.steps_per_sample, [r.steps for r in alone])
    assert len(set(batched.steps_per_sample)) > 3, batched.steps_per_sample
    assert batched.steps == max(r.steps for r in alone)
    for node, y in batched.latents.items():
        np.testing.assert_allclose(y, np.concatenate([r.latents[node] for r in alone]), rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(batched.stopped, [r.converged for r in alone])
    # every sample that stopped is under every threshold; the mean mse is the samples' mean
    for name in limits:
        assert batched.mse[name] == pytest.approx(np.mean([r.mse[name] for r in alone]), rel=1e-4)


def test_a_sample_at_the_cap_is_not_stopped(trained):
    net, inputs, _, _, _ = trained
    subset = {m: x[:12] for m, x in inputs.items()}
    limits = dict.fromkeys(NO_STOP, 4e-3)
    free = net.infer(subset, max_steps=400, thresholds=limits).steps_per_sample
    cap = int(np.median(free))
    result = net.infer(subset, max_steps=cap, thresholds=limits)
    assert not result.converged and result.steps == cap
    late = free > cap
    assert late.any() and not result.stopped[late].any()
    np.testing.assert_array_equal(result.steps_per_sample, np.minimum(free, cap))
    assert result.stopped[~late].all()


def test_save_load_gives_identical_inference(trained, backend, tmp_path):
    net, inputs, _, _, _ = trained
    net.set_scaler("tactile", np.zeros(10), np.full(10, 2.0))
    net.save(tmp_path / "net")
    loaded = Network.load(tmp_path / "net", backend=backend())
    a = net.infer(inputs, max_steps=50).latents
    b = loaded.infer(inputs, max_steps=50).latents
    for node in a:
        np.testing.assert_array_equal(a[node], b[node])
    np.testing.assert_array_equal(loaded.scalers["tactile"][1], np.full(10, 2.0))


def test_load_refuses_other_format_version(trained, tmp_path):
    net = trained[0]
    net.save(tmp_path / "net")
    meta = json.loads((tmp_path / "net" / "config.json").read_text())
    meta["format_version"] = 999
    (tmp_path / "net" / "config.json").write_text(json.dumps(meta))
    with pytest.raises(NetworkError, match="format version 999"):
        Network.load(tmp_path / "net")


def test_training_moves_every_sample_every_epoch(backend):
    """With 60 samples in minibatches of 25 (25, 25, 10) every sample is trained once per
    epoch: after one epoch no sample's latents are still at their initial 0.1."""
    inputs, _ = synthetic(n=60)
    net = Network(SYNTH, seed=2, backend=backend())
    latents: dict[str, np.ndarray] = {}
    net.train(inputs, {**TRAIN, "epochs": 1, "batch_size": 25}, latents=latents)
    for node, y in latents.items():
        assert y.shape[0] == 60
        assert np.all(np.any(y != np.float32(0.1), axis=1)), f"{node}: samples never trained"


def test_energy_history_is_the_per_sample_energy_of_the_epoch(backend):
    """With the weights frozen (eta_w = 0) every minibatch's final energy is F of its samples'
    final latents under the same weights, so an epoch's history entry must equal
    Network.energy of all samples at their final latents, divided by the sample count."""
    inputs, _ = synthetic(n=60)
    frozen = {**SYNTH, "modalities": {m: {**mc, "eta_w": 0.0} for m, mc in SYNTH["modalities"].items()},
              "joint": {**SYNTH["joint"], "eta_w": 0.0}}
    net = Network(frozen, seed=4, backend=backend())
    latents: dict[str, np.ndarray] = {}
    history = net.train(inputs, {**TRAIN, "epochs": 1, "batch_size": 25}, latents=latents)
    expected = net.energy(inputs, latents)
    for name, value in expected.items():
        assert history.energy[name][0] == pytest.approx(value / 60, rel=1e-5), name


def test_training_reports_each_minibatch_with_its_epoch_and_energy_per_sample():
    """60 samples in minibatches of 25 (25, 25, 10) for 2 epochs: on_progress is called 6 times,
    with epochs 1, 1, 1, 2, 2, 2; with the weights frozen, the three energies of an epoch add
    up, weighted by minibatch size, to the epoch's history entry times 60."""
    inputs, _ = synthetic(n=60)
    frozen = {**SYNTH, "modalities": {m: {**mc, "eta_w": 0.0} for m, mc in SYNTH["modalities"].items()},
              "joint": {**SYNTH["joint"], "eta_w": 0.0}}
    calls: list[tuple[int, float]] = []
    history = Network(frozen, seed=4, backend="numpy").train(
        inputs, {**TRAIN, "epochs": 2, "batch_size": 25}, on_progress=lambda epoch, f: calls.append((epoch, f)))
    assert [epoch for epoch, _ in calls] == [1, 1, 1, 2, 2, 2]
    first = sum(size * f for size, (_, f) in zip((25, 25, 10), calls[:3], strict=True))
    assert first == pytest.approx(60 * history.total()[0], rel=1e-5)


@pytest.mark.parametrize("shape", [(150, 129, 300), (40, 1000, 300), (20, 300, 1000)], ids=str)
def test_numpy_backend_matches_the_reference_on_wide_layers(shape):
    """Layers wider than the weight update's 128-row chunks: every row of W must learn."""
    from vitaplace.kernels import reference as ref

    b, n_l, n_below = shape
    rng = np.random.default_rng(21)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W = (rng.standard_normal((n_l, n_below)) / np.sqrt(n_l)).astype(np.float32)
    X = rng.random((b, n_below)).astype(np.float32)
    E_above = rng.standard_normal((b, n_l)).astype(np.float32)
    be = NumpyBackend()
    E, G = np.zeros((b, n_below), np.float32), np.zeros((b, n_below), np.float32)
    R = np.zeros((1, b))
    be.predict(Y, be.weights(W), X, E, G, R, 0, "leaky_relu", 0.2)
    _, _, e, g = ref.predict(*(a.astype(np.float64) for a in (Y, W, X)))
    np.testing.assert_allclose(E, e, rtol=1e-5, atol=1e-5 * np.abs(e).max())
    np.testing.assert_allclose(R[0], np.sum(e**2, axis=1), rtol=1e-4)
    y = Y.copy()
    be.latent_update(y, G, be.weights(W), 0.01, E_above, None)
    expected = ref.latent_step(Y.astype(np.float64), G.astype(np.float64), W.astype(np.float64), 0.01,
                               E_above.astype(np.float64))
    np.testing.assert_allclose(y, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    handle = be.weights(W)
    be.weight_update(handle, Y, G, 0.01)
    w = be.weights_to_host(handle)
    expected = ref.weight_step(W.astype(np.float64), Y.astype(np.float64), G.astype(np.float64), 0.01)
    np.testing.assert_allclose(w, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    assert np.all(np.any(w != W, axis=1)), "some rows of W did not learn"
    np.testing.assert_array_equal(handle.Wt, w.T)  # the latent update's copy learns the same, exactly


def test_same_seed_gives_identical_training():
    inputs, _ = synthetic(n=100)
    runs = []
    for _ in range(2):
        net = Network(SYNTH, seed=5, backend="numpy")
        net.train(inputs, {**TRAIN, "epochs": 3, "seed": 9})
        runs.append(net.weights)
    for name in runs[0]:
        np.testing.assert_array_equal(runs[0][name], runs[1][name])


def test_divergence_names_the_layer_and_suggests_lower_rates():
    """The error is the one message: numpy's overflow warnings on the way are not shown."""
    inputs, _ = synthetic(n=50)
    config = {**SYNTH, "modalities": {**SYNTH["modalities"], "visual": {**SYNTH["modalities"]["visual"], "eta_y": 1e3}}}
    net = Network(config, seed=0, backend="numpy")
    with pytest.raises(NetworkError, match=r"layer '.*' became (nan|inf).*lower the learning rates"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            net.train(inputs, {**TRAIN, "epochs": 2})


def test_diverging_inference_names_the_layer_and_the_samples():
    inputs, _ = synthetic(n=20)
    config = {**SYNTH, "joint": {**SYNTH["joint"], "eta_y": 1e4}}
    net = Network(config, seed=0, backend="numpy")
    with pytest.raises(NetworkError, match=r"layer '.*' became (nan|inf) at inference of samples 0-19"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            net.infer(inputs, max_steps=50, thresholds=NO_STOP)


def test_bad_input_shape_is_reported():
    net = Network(SYNTH, seed=0, backend="numpy")
    with pytest.raises(NetworkError, match=r"input 'visual' has shape \(3, 39\), expected \(3, 40\)"):
        net.infer({"visual": np.zeros((3, 39))}, max_steps=10)
    with pytest.raises(NetworkError, match="unknown modality"):
        net.infer({"audio": np.zeros((3, 4))}, max_steps=10)


@pytest.mark.parametrize("backend", ["numpy", "warp-cpu"])
def test_latent_change_is_how_far_each_epoch_s_steps_moved_the_latents(backend):
    """One epoch, one minibatch: the recorded latent change is the median over samples of
    ||Y_after - Y_before|| / ||Y_after|| (every latent node), computed here on the host from
    the persistent latents before and after; it is 0 when the steps are 0."""
    if backend == "warp-cpu":
        pytest.importorskip("warp")
        from vitaplace.engine.network.backends import WarpBackend

        backend = WarpBackend("cpu")
    inputs, _ = synthetic(n=30)
    net = Network(SYNTH, seed=3, backend=backend)
    rng = np.random.default_rng(4)
    before = {node: rng.random((30, net.sizes[node]), dtype=np.float32) for node in net.latent_nodes(net.modalities)}
    latents = {node: y.copy() for node, y in before.items()}
    history = net.train(inputs, {**TRAIN, "epochs": 1, "batch_size": 30, "inference_steps": 7}, latents=latents)
    moved = np.sqrt(sum(np.sum((latents[n].astype(np.float64) - before[n]) ** 2, axis=1) for n in before))
    size = np.sqrt(sum(np.sum(latents[n].astype(np.float64) ** 2, axis=1) for n in before))
    assert history.latent_change[0] == pytest.approx(float(np.median(moved / size)), rel=1e-5)
    assert history.latent_change[0] > 0
    still = net.train(inputs, {**TRAIN, "epochs": 2, "batch_size": 30, "inference_steps": 0}, latents=latents)
    assert still.latent_change == [0.0, 0.0]


def test_numpy_and_warp_backends_agree(device):
    """Training (two minibatch sizes: 25 and the last 10, replayed from captured graphs on
    CUDA) and per-sample-stopping inference give the same numbers on the numpy backend
    and on Warp on every device."""
    pytest.importorskip("warp")
    from vitaplace.engine.network.backends import WarpBackend

    inputs, _ = synthetic(n=60)
    runs = {}
    for name, backend in (("numpy", "numpy"), ("warp", WarpBackend(device))):
        net = Network(SYNTH, seed=1, backend=backend)
        history = net.train(inputs, {**TRAIN, "epochs": 3, "batch_size": 25, "inference_steps": 5})
        result = net.infer(inputs, max_steps=200, thresholds=dict.fromkeys(NO_STOP, 0.1), batch_size=40)
        runs[name] = (net.weights, net.train_latents, history, result)
    (w_np, y_np, h_np, r_np), (w_wp, y_wp, h_wp, r_wp) = runs["numpy"], runs["warp"]
    for name, w in w_np.items():
        np.testing.assert_allclose(w_wp[name], w, rtol=1e-4, atol=1e-5, err_msg=name)
    for node, y in y_np.items():
        np.testing.assert_allclose(y_wp[node], y, rtol=1e-4, atol=1e-5, err_msg=node)
    for name, energy in h_np.energy.items():
        np.testing.assert_allclose(h_wp.energy[name], energy, rtol=1e-4, err_msg=name)
    assert len(set(r_np.steps_per_sample)) > 1
    # a sample whose error crosses its threshold within rounding may stop one step apart
    assert np.abs(r_wp.steps_per_sample - r_np.steps_per_sample).max() <= 1
    assert np.mean(r_wp.steps_per_sample == r_np.steps_per_sample) > 0.9
    same = r_wp.steps_per_sample == r_np.steps_per_sample
    np.testing.assert_allclose(r_wp.latents["joint"][same], r_np.latents["joint"][same], rtol=1e-4, atol=1e-5)


def test_convergence_rule_by_hand():
    from vitaplace.engine.network.pc import converged

    # window 2, tol 0.1: 10 -> 9.5 over two epochs is a 5 % improvement: converged
    assert converged([12.0, 10.0, 9.8, 9.5], 2, 0.1)
    assert not converged([12.0, 10.0, 9.0, 8.5], 2, 0.1)  # 15 %: still improving
    assert not converged([10.0, 9.9], 2, 0.1)  # not enough epochs for the window
    assert not converged([10.0, 10.0, 10.0, 10.0], 0, 0.1)  # off
    assert not converged([12.0, 10.0, 10.5, 11.5], 2, 0.1)  # rising 15 %: not converged either
    assert converged([12.0, 10.0, 10.5, 10.9], 2, 0.1)  # within 9 % either way


def test_divergence_rule_by_hand():
    from vitaplace.engine.network.pc import diverged

    assert not diverged([5.0]) and not diverged([5.0, 2.0, 2e4])  # 1e4 times the lowest: not yet
    assert diverged([5.0, 2.0, 2.1e4]) and diverged([1.0, 1e5])


def test_a_training_that_diverges_stops_with_the_epoch_and_a_remedy(backend, monkeypatch):
    """The rule as the training loop applies it, made to fire at once: at a factor of 0.5 any
    second epoch (whose energy is above half the lowest) counts as diverged."""
    import vitaplace.engine.network.pc as pc

    monkeypatch.setattr(pc, "DIVERGED_FACTOR", 0.5)
    inputs, _ = synthetic(n=60)
    net = Network(SYNTH, seed=1, backend=backend())
    with pytest.raises(NetworkError, match=r"^training diverged at epoch 2: energy per sample [0-9.e+]+, more than "
                       r"0.5 times its lowest \([0-9.e+-]+, epoch [12]\); lower the step sizes \(eta_y, eta_w\) "
                       r"or raise latent_prior$"):
        net.train(inputs, {**TRAIN, "epochs": 5, "batch_size": 25})


def test_training_stops_when_the_energy_has_converged(backend):
    inputs, _ = synthetic(n=60)
    net = Network(SYNTH, seed=1, backend=backend())
    cfg = {**TRAIN, "epochs": 200, "batch_size": 25, "converge_window": 5, "converge_tol": 0.02}
    history = net.train(inputs, cfg)
    assert history.converged and 5 < history.epochs < 200
    total = history.total()
    assert total[-6] - total[-1] < 0.02 * total[-6]  # the rule held at the stop
    assert abs(total[-7] - total[-2]) >= 0.02 * total[-7]  # and not one epoch earlier
