"""The vision baselines `hog` and `vlad`, found through their entry points as a third-party
plugin's would be: the contract suite, descriptors worked by hand (HOG of a
step edge, VLAD of one to a few descriptors), the vocabulary learned from the training run
alone, a camera drop-out, and one line naming the extra when a library is missing."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vitaplace.plugin import ExtractorParamsError, Run, discover
from vitaplace.plugins.image_descriptor import grey
from vitaplace.testing import parametrize_with_checks, synthetic_run

pytest.importorskip("skimage", reason="the extra vision (scikit-image) is not installed")
pytest.importorskip("cv2", reason="the extra vision (OpenCV) is not installed")

REGISTRY = discover(only="hog,vlad")
HOG, VLAD = REGISTRY.get("hog"), REGISTRY.get("vlad")


def test_both_are_discovered_from_their_entry_points():
    assert REGISTRY.failed == {} and REGISTRY.names() == ["hog", "vlad"]
    assert REGISTRY.sources["hog"].startswith("hog") and REGISTRY.sources["vlad"].startswith("vlad")


@parametrize_with_checks([
    ("hog", HOG, {}),
    ("hog-one-block", HOG, {"image_size": [16, 16], "orientations": 4}),
    ("vlad", VLAD, {"clusters": 4}),
    ("vlad-coarse", VLAD, {"clusters": 2, "step": 12, "patch_size": 20, "max_descriptors": 10, "batch_size": 3}),
])
def test_the_vision_baselines_keep_the_contract(extractor, params, check):
    check(extractor, params, synthetic_run())


def images_run(images: np.ndarray) -> Run:
    """A run of these (n, H, W) grey or (n, H, W, 3) RGB uint8 images; the rest is neutral."""
    images = np.asarray(images, dtype=np.uint8)
    if images.ndim == 3:
        images = np.repeat(images[..., None], 3, axis=3)
    n = len(images)
    return Run.from_arrays(images=images, theta=np.zeros((n, 24)), xy=np.zeros((n, 24, 2)), poses=np.zeros((n, 3)))


def test_grey_is_the_bt601_luma():
    pixels = np.array([[[[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]]]], np.uint8)
    np.testing.assert_allclose(grey(pixels), [[[0.299, 0.587, 0.114, 1.0]]], rtol=1e-12)


# --------------------------------------------------------------------------- HOG


def step_edges() -> np.ndarray:
    """16 x 16: a vertical edge (dark left half) and a horizontal one (dark top half)."""
    vertical = np.zeros((16, 16), np.uint8)
    vertical[:, 8:] = 255
    return np.stack([vertical, vertical.T])


def test_hog_of_a_step_edge_by_hand():
    """One 2 x 2-cell block of 8 px cells: a vertical edge between columns 7 and 8 has, by
    central differences, a horizontal gradient (orientation 0 deg, bin 0 of [0, 20)) at
    columns 7 and 8 only: 8 pixels in each of the 4 cells, so the block is 4 equal entries in
    bin 0, which L2-Hys (0.5 each, clipped at 0.2, 0.5 again) and the unit length leave 0.5.
    The horizontal edge: orientation 90 deg, bin 4 of [80, 100)."""
    features = HOG({"image_size": [16, 16]}).transform(images_run(step_edges()))["hog"]
    assert features.shape == (2, 36)  # 1 block x 4 cells x 9 bins
    for row, bin_ in zip(features, (0, 4), strict=True):
        expected = np.zeros(36)
        expected[[bin_, 9 + bin_, 18 + bin_, 27 + bin_]] = 0.5
        np.testing.assert_allclose(row, expected, atol=1e-12)


def test_hog_clips_each_block_as_dalal_and_triggs_l2_hys():
    """Columns 0-3 black, 4-11 white, 12-15 grey 170 (luma 2/3), the same in every row: bin 0
    only, 2 columns of gradient 1 in the left cells (16 px x 1 / 64 = 1/4) and 2 of 1/3 in the
    right ones (1/12). L2: (3, 1, 3, 1) / sqrt(20), each entry over 0.2, so clipped to 0.2 and
    renormalised: 0.5 each (plain L2 or L1 would keep the 3 : 1)."""
    image = np.zeros((16, 16), np.uint8)
    image[:, 4:12], image[:, 12:] = 255, 170
    features = HOG({"image_size": [16, 16]}).transform(images_run(image[None]))["hog"]
    expected = np.zeros(36)
    expected[[0, 9, 18, 27]] = 0.5
    np.testing.assert_allclose(features[0], expected, atol=1e-12)


def test_a_flat_image_has_a_zero_hog_and_any_other_unit_length():
    run = images_run(np.stack([np.full((24, 32), 40), np.full((24, 32), 200), step_edges()[0].repeat(2, 0)[:24, :]
                               .repeat(2, 1)]))
    hog = HOG()
    features = hog.transform(run)["hog"]
    # Dalal & Triggs's 64 x 128 window: 7 x 15 blocks x 4 cells x 9 bins, even for no image at all
    assert features.shape == (3, 3780) and hog.transform(run.subset([]))["hog"].shape == (0, 3780)
    np.testing.assert_array_equal(features[:2], 0.0)
    assert np.linalg.norm(features[2]) == pytest.approx(1.0)
    # Euclidean between descriptors: two flat images 0 apart, a unit one 1 from either
    np.testing.assert_allclose(hog.distance({"hog": features}, {"hog": features}),
                               [[0, 0, 1], [0, 0, 1], [1, 1, 0]], atol=1e-12)


def test_hog_refuses_an_image_size_without_a_whole_block():
    with pytest.raises(ExtractorParamsError, match=r"extractor 'hog'.*image_size \[12, 40\] is smaller than one "
                       r"block of pixels_per_cell x cells_per_block = 16 px"):
        HOG({"image_size": [12, 40]})


# --------------------------------------------------------------------------- VLAD


vlad_module = sys.modules[VLAD.__module__]
CENTRES = np.array([[0.0, 0.0], [10.0, 0.0]])


def test_vlad_of_one_descriptor_is_its_residual_rooted_and_normalised():
    # [9, 4] is nearest to c_1 = [10, 0]: residual [-1, 4] -> signed root [-1, 2] -> / sqrt(5)
    np.testing.assert_allclose(vlad_module.vlad(np.array([[9.0, 4.0]]), CENTRES),
                               [0, 0, -1 / np.sqrt(5), 2 / np.sqrt(5)])


def test_vlad_sums_the_residuals_of_a_word_before_the_root():
    # [9, 4] and [11, 0] both to c_1: residuals [-1, 4] + [1, 0] = [0, 4] -> root [0, 2] -> [0, 1]
    np.testing.assert_allclose(vlad_module.vlad(np.array([[9.0, 4.0], [11.0, 0.0]]), CENTRES), [0, 0, 0, 1])


def test_vlad_intra_normalises_each_word():
    # residuals [1, 0] (c_0) and [0, 9] (c_1): roots [1, 0] and [0, 3], each unit, then all / sqrt(2);
    # without intra-normalisation the second word would weigh 3 times the first
    np.testing.assert_allclose(vlad_module.vlad(np.array([[1.0, 0.0], [10.0, 9.0]]), CENTRES),
                               [1 / np.sqrt(2), 0, 0, 1 / np.sqrt(2)])


def test_vlad_ignores_the_order_of_the_descriptors_and_is_zero_without_any():
    rng = np.random.default_rng(3)
    descriptors, centres = rng.normal(size=(40, 5)), rng.normal(size=(3, 5))
    np.testing.assert_allclose(vlad_module.vlad(descriptors[rng.permutation(40)], centres),
                               vlad_module.vlad(descriptors, centres), rtol=1e-12)
    np.testing.assert_array_equal(vlad_module.vlad(np.zeros((0, 5)), centres), np.zeros(15))


def test_the_dense_grid_keeps_each_patch_inside_or_takes_the_centre():
    # 24 x 32 px, 16 px patches every 8 px: rows 8, 16 and columns 8, 16, 24
    assert vlad_module.grid(24, 32, 8, 16) == [(x, y) for y in (8.0, 16.0) for x in (8.0, 16.0, 24.0)]
    assert vlad_module.grid(10, 12, 8, 16) == [(5.5, 4.5)]


def test_the_vocabulary_comes_from_the_training_run_alone():
    train, other = synthetic_run(seed=0), synthetic_run(seed=1)
    vlad = VLAD({"clusters": 1})
    vlad.fit(train)
    # one word: k-means's centre is the mean of the training run's descriptors (6 per 24 x 32 image)
    descriptors = np.concatenate(vlad.local_descriptors(train.images))
    assert descriptors.shape == (48, 128)
    np.testing.assert_allclose(vlad.vocabulary, descriptors.astype(np.float64).mean(axis=0, keepdims=True), rtol=1e-5)
    before = vlad.vocabulary.copy()
    vlad.transform(other)
    np.testing.assert_array_equal(vlad.vocabulary, before)
    refitted = VLAD({"clusters": 1})
    refitted.fit(other)
    assert not np.allclose(refitted.vocabulary, before)


def test_the_vocabulary_is_saved_and_a_mismatched_one_refused(tmp_path):
    vlad = VLAD({"clusters": 2})
    vlad.fit(synthetic_run())
    vlad.save(tmp_path / "fitted")
    np.testing.assert_array_equal(np.load(tmp_path / "fitted" / "vlad_vocabulary.npy"), vlad.vocabulary)
    wrong = VLAD({"clusters": 3})
    with pytest.raises(ValueError, match=r"vocabulary of shape \(2, 128\), expected \(3, 128\) for clusters=3"):
        wrong.load_state(tmp_path / "fitted")
    with pytest.raises(ValueError, match="no fitted state of extractor 'vlad'"):
        wrong.load_state(tmp_path)


def test_more_words_than_training_descriptors_is_one_line_naming_clusters():
    with pytest.raises(ExtractorParamsError, match=r"^extractor 'vlad': clusters=49 is more than the 48 local "
                       r"descriptors of training run synthetic-0; lower clusters"):
        VLAD({"clusters": 49}).fit(synthetic_run())


# --------------------------------------------------------------------------- both


@pytest.mark.parametrize("cls, params", [(HOG, {}), (VLAD, {"clusters": 2})], ids=["hog", "vlad"])
def test_a_sample_without_its_camera_matches_nothing(cls, params):
    query, reference = synthetic_run(4), synthetic_run(4)
    extractor = cls(params)
    extractor.fit(query)
    query.missing = {"camera": np.array([False, True, False, False])}
    reference.missing = {"camera": np.array([False, False, True, False])}
    distances = extractor.distance(extractor.transform(query), extractor.transform(reference))
    # the query's sample 1 and the reference's sample 2 are compared with nothing
    assert np.isinf(distances[1]).all() and np.isinf(distances[:, 2]).all()
    assert np.isfinite(np.delete(np.delete(distances, 1, 0), 2, 1)).all()
    assert extractor.modalities(extractor.params) == {"visual"}


def test_the_distance_a_block_of_references_at_a_time_is_scipy_s_cdist_bit_for_bit(monkeypatch):
    """Unit rows compared 3 references per cdist call (the memory bound's blocks) give exactly
    cdist of them all, the last block short; a query or reference side of none gives (q, 0) / (0, r)."""
    from scipy.spatial.distance import cdist

    import vitaplace.plugins.image_descriptor as descriptor

    monkeypatch.setattr(descriptor, "REFERENCE_BLOCK", 3)
    rng = np.random.default_rng(0)
    q, r = rng.random((4, 6), dtype=np.float32), rng.random((8, 6), dtype=np.float32)
    extractor = HOG({})
    got = extractor.distance({"hog": q}, {"hog": r})
    assert np.array_equal(got, cdist(q.astype(np.float64), r.astype(np.float64)))
    assert extractor.distance({"hog": q[:0]}, {"hog": r}).shape == (0, 8)
    assert extractor.distance({"hog": q}, {"hog": r[:0]}).shape == (4, 0)


@pytest.mark.parametrize("cls, module, distribution", [(HOG, "skimage", "scikit-image"),
                                                       (VLAD, "cv2", "opencv-python-headless")], ids=["hog", "vlad"])
def test_without_its_library_a_baseline_is_one_line_naming_the_extra(monkeypatch, cls, module, distribution):
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    with pytest.raises(ExtractorParamsError, match=rf"^extractor '{cls.name}' needs {distribution} \(.*\): "
                       r"pip install 'vitaplace\[vision\]'$"):
        cls()
