"""Sensor drop-out at query time: which samples lose a sensor (`dropout_masks`), the
hand-crafted method's distance over the sensors left (closed form), MuPNet's inference from
the modality left (against a plain numpy loop of the reference kernels), bad input."""

from __future__ import annotations

import numpy as np
import pytest

from vitaplace.engine.cli.main import main
from vitaplace.engine.data.dataset import Run, dropout_masks
from vitaplace.kernels import reference as ref
from vitaplace.plugins.handcrafted.extractor import HandcraftedExtractor
from vitaplace.plugins.mupnet.extractor import PAPER_ALGORITHM, MupnetExtractor

# --------------------------------------------------------------------------- the masks


@pytest.mark.parametrize("n, camera, whiskers", [(10, 0.3, 0.2), (7, 0.5, 0.5), (40, 0.0, 0.25), (5, 1.0, 0.0)])
def test_the_shares_are_as_stated_disjoint_and_drawn_from_the_seed(n, camera, whiskers, seed):
    masks = dropout_masks(n, {"camera": camera, "whiskers": whiskers}, seed)
    # round(share * n) samples each; 7 * 0.5 = 3.5 rounds to 4 (half to even), the rest 3 for the whiskers
    expected_camera = round(camera * n)
    assert masks["camera"].sum() == expected_camera
    assert masks["whiskers"].sum() == min(round(whiskers * n), n - expected_camera)
    assert not (masks["camera"] & masks["whiskers"]).any()
    again = dropout_masks(n, {"camera": camera, "whiskers": whiskers}, seed)
    assert all(np.array_equal(masks[s], again[s]) for s in masks)


def test_another_seed_drops_other_samples():
    a, b = (dropout_masks(100, {"camera": 0.3}, s)["camera"] for s in (1, 2))
    assert a.sum() == b.sum() == 30 and not np.array_equal(a, b)


def tiny_run(n: int, rng: np.random.Generator, name: str = "run") -> Run:
    """A run of ``n`` samples of random 12 x 16 frames and 2 whiskers, with one contact each."""
    points = rng.normal(size=(n, 3)).astype(np.float32)
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    return Run.from_arrays(
        images=rng.integers(0, 256, (n, 12, 16, 3), dtype=np.uint8), theta=rng.uniform(0, 1, (n, 2)),
        xy=rng.uniform(-0.2, 0.2, (n, 2, 2)), poses=np.c_[rng.uniform(-1, 1, (n, 2)), np.zeros(n)],
        deflection=rng.uniform(-0.2, 0.2, (n, 4, 2, 2)), contact_points=points, contact_normals=normals,
        contact_offsets=np.arange(n + 1), name=name)


def test_a_run_without_drop_out_lacks_nothing_and_a_subset_keeps_its_masks(seed):
    run = tiny_run(6, np.random.default_rng(seed))
    assert not run.lacks("camera").any() and not run.lacks("whiskers").any()
    run.missing = dropout_masks(6, {"camera": 0.5}, seed)
    assert np.array_equal(run.subset(slice(1, 4)).lacks("camera"), run.lacks("camera")[1:4])
    with pytest.raises(ValueError, match="unknown sensor 'lidar'"):
        run.lacks("lidar")


# --------------------------------------------------------------------------- the hand-crafted method


def test_handcrafted_distance_uses_only_the_present_terms_scaled_to_all_three():
    """Three queries: 0 has everything, 1 lacks the camera, 2 the whiskers; one reference.
    Profiles constant (|c_q - c_r| is their distance), sigmas 2 (profile), 4 (pfh), 0.5 (sda):

        terms of query 0: profile |0.7 - 0.2| = 0.5, pfh |1 - 0| + |2 - 2| = 1, sda |3 - 1| = 2
              scaled:     0.25 + 0.25 + 4 = 4.5
        query 1 (no camera): pfh 1 / 4 + sda 2 / 0.5 = 4.25, times 3 / 2 = 6.375
        query 2 (no whiskers): profile 0.5 / 2 = 0.25, times 3 / 1 = 0.75
    """
    ext = HandcraftedExtractor({"grid": [2, 8], "max_shift": 0})
    ext.sigmas = {"profile": 2.0, "pfh": 4.0, "sda": 0.5}
    query = {"profile": np.full((3, 2, 8), 0.7), "pfh": np.tile([1.0, 2.0], (3, 1)), "sda": np.full((3, 1), 3.0),
             "missing_camera": np.array([False, True, False]), "missing_whiskers": np.array([False, False, True])}
    reference = {"profile": np.full((1, 2, 8), 0.2), "pfh": np.array([[0.0, 2.0]]), "sda": np.array([[1.0]])}
    np.testing.assert_allclose(ext.distance(query, reference), [[4.5], [6.375], [0.75]], rtol=1e-12)
    # the same when the reference run carries masks with nothing missing, and when the roles swap
    reference.update(missing_camera=np.zeros(1, bool), missing_whiskers=np.zeros(1, bool))
    np.testing.assert_allclose(ext.distance(query, reference), [[4.5], [6.375], [0.75]], rtol=1e-12)
    np.testing.assert_allclose(ext.distance(reference, query), [[4.5, 6.375, 0.75]], rtol=1e-12)


def test_handcrafted_without_drop_out_is_the_plain_sum(seed):
    rng = np.random.default_rng(seed)
    ext = HandcraftedExtractor({"grid": [4, 8]})
    train, query = tiny_run(12, rng), tiny_run(5, rng)
    ext.fit(train)
    q, r = ext.transform(query), ext.transform(train)
    assert "missing_camera" not in q
    terms = ext.term_distances(q, r)
    assert np.array_equal(ext.distance(q, r), sum(d / ext.sigmas[k] for k, d in terms.items()))


def test_handcrafted_features_of_a_lost_sensor_do_not_depend_on_its_data(seed):
    rng = np.random.default_rng(seed)
    ext = HandcraftedExtractor({"grid": [4, 8]})
    ext.fit(tiny_run(12, rng))
    run = tiny_run(8, rng)
    run.missing = {"camera": np.arange(8) < 3, "whiskers": np.arange(8) >= 6}
    features = ext.transform(run)
    assert np.array_equal(features["missing_camera"], run.lacks("camera"))
    assert not features["profile"][:3].any() and not features["pfh"][6:].any() and not features["sda"][6:].any()
    other = tiny_run(8, np.random.default_rng(seed + 1))  # other images and whiskers everywhere
    mixed = Run.from_arrays(images=np.concatenate([other.images[:3], run.images[3:]]), theta=run.theta, xy=run.xy,
                            poses=run.poses, deflection=run.deflection, contact_points=run._get("contact_points"),
                            contact_normals=run._get("contact_normals"), contact_offsets=run.contact_offsets)
    mixed.missing = run.missing
    assert np.array_equal(ext.transform(mixed)["profile"], features["profile"])


# --------------------------------------------------------------------------- MuPNet

#: the paper's plain test-time steps (the float64 reference below takes them), on a tiny network
TINY_NET = {**PAPER_ALGORITHM, "image_size": [6, 8], "visual_layers": [10], "tactile_layers": [5], "joint_size": 4,
            "epochs": 2,
            "batch_size": 6, "backend": "numpy", "threshold_visual": 0.0, "threshold_tactile": 0.0,
            "threshold_joint": 0.0, "max_steps": 25}


def reference_inference(net, inputs: dict[str, np.ndarray], steps: int) -> np.ndarray:
    """The joint latents after ``steps`` inference steps from 0.1 over the edges of the given
    modalities only, in float64 with `kernels.reference` (eq. 1 and 3 of docs/MUPNET.md)."""
    act, slope = net.config.activation, net.config.slope
    n = len(next(iter(inputs.values())))
    edges = [e for e in net.edges if e.modality in inputs]
    Y = {node: np.full((n, net.sizes[node]), 0.1) for node in {e.upper for e in edges}}
    X = {f"{m}.0": np.asarray(x, np.float64) for m, x in inputs.items()}
    for _ in range(steps):
        E, G = {}, {}
        for e in edges:
            lower = Y[e.lower] if e.lower in Y else X[e.lower]
            _, _, E[e.name], G[e.name] = ref.predict(Y[e.upper], net.weights[e.name].astype(np.float64), lower, act,
                                                     slope)
        new = {}
        for node in Y:
            below = [e for e in edges if e.upper == node]
            above = [e for e in edges if e.lower == node]
            y = Y[node]
            for k, e in enumerate(below):
                y = ref.latent_step(y, G[e.name], net.weights[e.name].astype(np.float64), net.eta_y[node],
                                    E[above[0].name] if (above and k == 0) else None)
            new[node] = y
        Y = new
    return Y["joint"]


@pytest.fixture(scope="module")
def mupnet():
    rng = np.random.default_rng(20261202)
    ext = MupnetExtractor(TINY_NET)
    ext.progress = False
    ext.fit(tiny_run(12, rng))
    return ext, rng


def test_mupnet_infers_a_sample_without_a_camera_from_its_whiskers_alone(mupnet):
    ext, rng = mupnet
    run = tiny_run(9, rng)
    run.missing = {"camera": np.isin(np.arange(9), [1, 4, 5]), "whiskers": np.isin(np.arange(9), [7])}
    features = ext.transform(run)
    inputs = ext.scaled_inputs(run)
    for sensor, left in (("camera", ["tactile"]), ("whiskers", ["visual"])):
        rows = run.lacks(sensor)
        expected = reference_inference(ext.network, {m: inputs[m][rows] for m in left}, TINY_NET["max_steps"])
        np.testing.assert_allclose(features["latent"][rows], expected, rtol=2e-4, atol=1e-6)
    full = ~(run.lacks("camera") | run.lacks("whiskers"))
    expected = reference_inference(ext.network, {m: x[full] for m, x in inputs.items()}, TINY_NET["max_steps"])
    np.testing.assert_allclose(features["latent"][full], expected, rtol=2e-4, atol=1e-6)
    assert np.all(features["inference_steps"] == TINY_NET["max_steps"])  # thresholds 0: every sample runs to the cap


def test_mupnet_features_of_a_lost_camera_do_not_depend_on_its_frames(mupnet):
    ext, rng = mupnet
    run = tiny_run(6, rng)
    run.missing = {"camera": np.arange(6) < 2}
    other = Run.from_arrays(images=np.concatenate([255 - run.images[:2], run.images[2:]]), theta=run.theta, xy=run.xy,
                            poses=run.poses, deflection=run.deflection)
    other.missing = run.missing
    a, b = ext.transform(run)["latent"], ext.transform(other)["latent"]
    assert np.array_equal(a, b)
    run.missing = {}
    assert not np.allclose(ext.transform(run)["latent"][:2], a[:2])  # with its frames, another latent


def test_mupnet_without_drop_out_is_unchanged(mupnet):
    ext, rng = mupnet
    run = tiny_run(7, rng)
    expected = ext.network.infer(ext.scaled_inputs(run), max_steps=TINY_NET["max_steps"]).latents["joint"]
    assert np.array_equal(ext.transform(run)["latent"], expected)


# --------------------------------------------------------------------------- bad input

BAD = {
    "a share over 1": ("evaluations.0.query_dropout={camera: 1.5}",
                       "evaluations.0.query_dropout.camera: Input should be less than or equal to 1"),
    "a negative share": ("evaluations.0.query_dropout={whiskers: -0.1}",
                         "evaluations.0.query_dropout.whiskers: Input should be greater than or equal to 0"),
    "shares over 1 together": ("evaluations.0.query_dropout={camera: 0.6, whiskers: 0.6}",
                               "evaluations.0.query_dropout: camera + whiskers is 1.2: a sample loses at most one"),
    "an unknown sensor": ("evaluations.0.query_dropout={lidar: 0.2}", "evaluations.0.query_dropout.lidar: unknown key"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_drop_out_is_refused_at_validate_in_one_line(capsys, case):
    override, message = BAD[case]
    assert main(["validate", "quickstart", "--set", override]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: ") and message in lines[0], lines


def test_a_method_that_cannot_handle_missing_modalities_is_refused(capsys, monkeypatch):
    monkeypatch.setattr(HandcraftedExtractor, "handles_missing", False)
    assert main(["validate", "quickstart", "--set", "evaluations.0.query_dropout={camera: 0.2}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and ("evaluations.0.query_dropout: method H's extractor 'handcrafted' does not handle "
                                "missing modalities") in lines[0], lines
    assert main(["validate", "quickstart"]) == 0  # without drop-out it is welcome


# --------------------------------------------------------------------------- nothing left to compare


def test_a_handcrafted_pair_that_shares_no_term_is_never_a_match():
    """H-V (profile only) and a query without its camera share no term: distance +inf, never
    0 (0 would make that query's best match its first reference, accepted at any threshold)."""
    ext = HandcraftedExtractor({"grid": [2, 8], "max_shift": 0, "use_tactile": False})
    ext.sigmas = {"profile": 2.0}
    query = {"profile": np.full((2, 2, 8), 0.7), "missing_camera": np.array([False, True]),
             "missing_whiskers": np.zeros(2, bool)}
    reference = {"profile": np.full((1, 2, 8), 0.2)}
    # query 0: |0.7 - 0.2| per cell, mean over the 2 x 8 profile with no shift: 0.5, / sigma 2 = 0.25
    np.testing.assert_allclose(ext.distance(query, reference), [[0.25], [np.inf]], rtol=1e-12)
    np.testing.assert_allclose(ext.distance(reference, query), [[0.25, np.inf]], rtol=1e-12)


def test_a_mupnet_sample_with_none_of_its_modalities_is_never_a_match(mupnet):
    ext, rng = mupnet
    visual_only = MupnetExtractor({**TINY_NET, "modalities": ["visual"]})
    visual_only.progress = False
    visual_only.fit(tiny_run(12, rng))
    run = tiny_run(5, rng)
    run.missing = {"camera": np.arange(5) == 3}
    features = visual_only.transform(run)
    assert features["uninformed"].tolist() == [False, False, False, True, False]
    reference = visual_only.transform(tiny_run(4, rng))
    d = visual_only.distance(features, reference)
    assert np.isinf(d[3]).all() and np.isfinite(np.delete(d, 3, axis=0)).all()
    assert np.isinf(visual_only.distance(reference, features)[:, 3]).all()
    # the joint network keeps the sample: it still has its whiskers
    assert not ext.transform(run)["uninformed"].any()
