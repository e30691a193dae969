"""The hand-crafted ViTa-SLAM front end: profile, PFH, SDA and the extractor plugin.

Expected values come from hand computation (written out in comments), from direct Python
loops over the definitions, or from the generative structure of synthetic data, never from
outputs of the code under test.
"""

import json
import math
from importlib.metadata import entry_points

import numpy as np
import pluggy
import pytest

from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension import hookspecs
from vitaplace.engine.extension.features import ExtractorParamsError
from vitaplace.plugins import handcrafted
from vitaplace.plugins.handcrafted import HandcraftedExtractor, pfh, sda, template_distance, templates
from vitaplace.plugins.handcrafted.pfh import pfh_batch

# ---------------------------------------------------------------------------------------
# PFH


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def random_contacts(rng: np.random.Generator, k: int) -> tuple[np.ndarray, np.ndarray]:
    points = rng.normal(scale=0.05, size=(k, 3))
    normals = rng.normal(size=(k, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, normals


def test_pfh_three_points_by_hand():
    a = 1 / math.sqrt(2)
    c = math.sqrt(3) / 2
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    normals = np.array([[0.0, 0, 1], [a, 0, a], [0, 0.5, -c]])
    # Bins (b = 3): alpha, phi in [-1,-1/3) | [-1/3,1/3) | [1/3,1]; theta in [-pi,-pi/3) | [-pi/3,pi/3) | [pi/3,pi].
    # Bin index = (i_alpha * 3 + i_phi) * 3 + i_theta.
    #
    # Pair (0,1): d = (1,0,0); |n0.d| = 0 < |n1.d| = a, so source 1, target 0, d = p0 - p1 = (-1,0,0).
    #   u = (a,0,a); phi = u.d = -a = -0.707 -> 0; v = d x u = (0,a,0)/a = (0,1,0);
    #   w = u x v = (-a,0,a); alpha = v.n0 = 0 -> 1; theta = atan2(w.n0, u.n0) = atan2(a, a) = pi/4 -> 1.
    #   -> (1,0,1) = bin 10.
    # Pair (0,2): d = (0,1,0); |n0.d| = 0 < |n2.d| = 1/2, so source 2, target 0, d = (0,-1,0).
    #   u = (0,1/2,-c); phi = u.d = -1/2 -> 0; v = d x u = (c,0,0)/c = (1,0,0);
    #   w = u x v = (0,-c,-1/2); alpha = v.n0 = 0 -> 1; theta = atan2(-1/2, -c) = -5pi/6 -> 0.
    #   -> (1,0,0) = bin 9.
    # Pair (1,2): d = (-1,1,0), |d| = sqrt2; |n1.d|/|d| = 1/2 > |n2.d|/|d| = 0.354, so source 1, target 2.
    #   u = (a,0,a); phi = u.d/|d| = -1/2 -> 0; v = d x u = (a,a,-a)/(a sqrt3) = (1,1,-1)/sqrt3;
    #   w = u x v = (-a,2a,a)/sqrt3; alpha = v.n2 = (1/2 + c)/sqrt3 = 0.789 -> 2;
    #   theta = atan2(w.n2, u.n2) = atan2(a(1-c)/sqrt3, -a c) = atan2(0.0547, -0.612) = 3.05 -> 2.
    #   -> (2,0,2) = bin 20.
    expected = np.zeros(27)
    expected[[9, 10, 20]] = 100 / 3
    hist = pfh(points, normals, bins=3)
    assert hist.shape == (27,) and hist.dtype == np.float32
    np.testing.assert_allclose(hist, expected, atol=1e-4)
    # The choice of source does not depend on the order of the contacts.
    np.testing.assert_allclose(pfh(points[::-1], normals[::-1], bins=3), expected, atol=1e-4)


def test_pfh_value_on_a_bins_upper_edge_goes_to_the_last_bin():
    """Two contacts with alpha = 1 exactly (the upper edge of its range).
    Source (0,0,0) with n = (0,0,1), target (1,0,0) with n = (0,-1,0) (|n.d| ties at 0, so the
    first point is the source): u = (0,0,1), d = (1,0,0), v = d x u = (0,-1,0), w = u x v =
    (1,0,0); alpha = v.n_t = 1 -> bin 2 (last), phi = u.d = 0 -> bin 1, theta = atan2(w.n_t,
    u.n_t) = atan2(0, 0) = 0 -> bin 1: index (2*3 + 1)*3 + 1 = 22 (swapping source and target
    gives the same three values)."""
    hist = pfh(np.array([[0.0, 0, 0], [1, 0, 0]]), np.array([[0.0, 0, 1], [0, -1, 0]]))
    expected = np.zeros(27, dtype=np.float32)
    expected[22] = 100.0
    np.testing.assert_allclose(hist, expected)


def test_pfh_invariant_to_rigid_motion_and_sums_to_100(seed):
    rng = np.random.default_rng(seed)
    for k in (2, 5, 30):
        points, normals = random_contacts(rng, k)
        rot = random_rotation(rng)
        shift = rng.normal(size=3)
        base = pfh(points, normals)
        moved = pfh(points @ rot.T + shift, normals @ rot.T)
        np.testing.assert_allclose(base, moved, atol=1e-4)
        assert base.sum() == pytest.approx(100.0, abs=1e-3)
        # 4 bins per feature: other bin edges, same invariance.
        np.testing.assert_allclose(pfh(points, normals, bins=4), pfh(points @ rot.T + shift, normals @ rot.T, bins=4))


def test_pfh_zero_for_fewer_than_two_contacts_and_degenerate_pairs():
    assert np.array_equal(pfh(np.zeros((0, 3)), np.zeros((0, 3))), np.zeros(27))
    assert np.array_equal(pfh(np.ones((1, 3)), np.array([[0.0, 0, 1]])), np.zeros(27))
    # Coincident points: no frame.
    assert np.array_equal(pfh(np.ones((2, 3)), np.array([[0.0, 0, 1], [1.0, 0, 0]])), np.zeros(27))
    # Connecting line parallel to the source normal: no frame.
    assert np.array_equal(pfh(np.array([[0.0, 0, 0], [0, 0, 1]]), np.array([[0.0, 0, 1], [0, 0, 1]])), np.zeros(27))
    # A degenerate pair is skipped, the valid ones still count: 3 points, one duplicated.
    a = 1 / math.sqrt(2)
    points = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0]])
    normals = np.array([[0.0, 0, 1], [a, 0, a], [a, 0, a]])
    hist = pfh(points, normals)
    expected = np.zeros(27)
    expected[10] = 100  # both valid pairs are the pair (0,1) of the hand-computed case
    np.testing.assert_allclose(hist, expected, atol=1e-4)


def test_pfh_caps_contacts_and_batch_matches_single(seed):
    rng = np.random.default_rng(seed)
    counts = [0, 1, 3, 200]
    sets = [random_contacts(rng, k) for k in counts]
    run = small_run(
        n=len(counts),
        contact_points=np.concatenate([p for p, _ in sets]),
        contact_normals=np.concatenate([nrm for _, nrm in sets]),
        contact_offsets=np.cumsum([0, *counts]),
    )
    batch = pfh_batch(run, bins=3, max_points=16)
    assert batch.shape == (4, 27)
    for i, (p, nrm) in enumerate(sets):
        expected = pfh(p.astype(np.float32), nrm.astype(np.float32), bins=3, max_points=16)
        np.testing.assert_allclose(batch[i], expected, atol=1e-4)
    # 200 contacts capped at 16: the histogram is that of 16 evenly spaced contacts (120 pairs).
    keep = np.unique(np.linspace(0, 199, 16).round().astype(int))
    p, nrm = sets[3]
    np.testing.assert_allclose(batch[3], pfh(p[keep], nrm[keep], bins=3, max_points=10_000), atol=1e-3)
    counts = batch[3] * 120 / 100  # pair counts: integers
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-3)


# ---------------------------------------------------------------------------------------
# SDA


def deflection_series() -> np.ndarray:
    """(1, S=5, W=6, 2) hand-written deflection series."""
    x = np.array(
        [
            [0.0, 0.01, 0.03, 0.05, 0.02],  # w0: slope from sample 1 to sample 3
            [0.0, 0.0, 0.0, 0.0, 0.0],  # w1: no contact
            [0.0, 0.02, 0.02, 0.02, 0.0],  # w2: x does not change -> denominator 0
            [0.0, -0.01, -0.03, -0.02, 0.0],  # w3: negative deflections
            [0.0, 1e-4, 2e-4, 0.0, 0.0],  # w4: below the 1e-3 threshold
            [0.01, 0.04, 0.02, 0.0, 0.0],  # w5: x and y peak at different samples
        ]
    )
    y = np.array(
        [
            [0.0, 0.02, 0.04, 0.08, 0.01],
            [0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.01, 0.05, 0.03, 0.0],
            [0.0, -0.01, 0.03, 0.01, 0.0],
            [0.0, 1e-4, 3e-4, 0.0, 0.0],
            [0.0, 0.0, 0.01, 0.05, 0.0],
        ]
    )
    return np.stack([x.T, y.T], axis=-1)[None]  # (1, 5, 6, 2)


def test_sda_magnitude_mode_by_hand():
    slopes = sda(deflection_series(), threshold=1e-3)
    assert slopes.shape == (1, 6) and slopes.dtype == np.float32
    # w0: |d| = 0, .022, .05, .094, .022 -> init sample 1 (.01,.02), max sample 3 (.05,.08): .06/.04 = 1.5
    # w1: no positive sample -> 0
    # w2: init sample 1 (.02,.01), max sample 2 (.02,.05): dx = 0 -> 0
    # w3: init sample 1 (-.01,-.01), max sample 2 (-.03,.03): (.03+.01)/(-.03+.01) = -2
    # w4: |d| <= 3.6e-4 < 1e-3 -> no contact -> 0
    # w5: |d| = .01, .04, .022, .05, 0 -> init sample 0 (.01,0), max sample 3 (0,.05): .05/-.01 = -5
    np.testing.assert_allclose(slopes[0], [1.5, 0, 0, -2, 0, -5], rtol=1e-5)
    # With threshold 0, w4 counts: init sample 1 (1e-4,1e-4), max sample 2 (2e-4,3e-4): 2e-4/1e-4 = 2.
    assert sda(deflection_series(), threshold=0.0)[0, 4] == pytest.approx(2.0, rel=1e-5)


def test_sda_per_axis_mode_is_vitaslam():
    slopes = sda(deflection_series(), threshold=0.0, mode="per_axis")
    # Each axis alone: init = first value > 0, max = largest value (0 if none positive).
    # w0: x .01 -> .05, y .02 -> .08: .06/.04 = 1.5
    # w1: 0; w2: x .02 -> .02: dx = 0 -> 0
    # w3: no x > 0 -> x_init = x_max = 0 -> 0
    # w4: x 1e-4 -> 2e-4, y 1e-4 -> 3e-4: 2
    # w5: x .01 -> .04, y .01 -> .05: .04/.03
    np.testing.assert_allclose(slopes[0], [1.5, 0, 0, 0, 2, 0.04 / 0.03], rtol=1e-5)


def test_sda_per_axis_with_a_threshold():
    """Threshold 0.015 on each axis: init = first value above it, max = the largest value."""
    slopes = sda(deflection_series(), threshold=0.015, mode="per_axis")
    # w0: x 0 .01 .03 .05 .02 -> init .03, max .05; y 0 .02 .04 .08 .01 -> init .02, max .08:
    #     .06/.02 = 3 (threshold 0 would give init .01 and 1.5)
    # w2: x 0 .02 .02 .02 0 -> dx 0 -> 0;  w5: x .01 .04 .02 0 0 -> init .04 = max -> dx 0 -> 0
    assert slopes[0, 0] == pytest.approx(3.0, rel=1e-5)
    assert slopes[0, 2] == 0.0 and slopes[0, 5] == 0.0


def test_sda_vectorised_over_samples(seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(scale=0.01, size=(7, 9, 5, 2))
    d[2, :, 1] = 0.0  # one whisker without contact
    slopes = sda(d, threshold=0.005)
    for n in range(7):
        for w in range(5):
            mag = [math.hypot(*d[n, s, w]) for s in range(9)]
            pos = [s for s in range(9) if mag[s] > 0.005]
            expected = 0.0
            if pos:
                i, m = pos[0], int(np.argmax(mag))
                dx = d[n, m, w, 0] - d[n, i, w, 0]
                expected = 0.0 if dx == 0 else (d[n, m, w, 1] - d[n, i, w, 1]) / dx
            assert slopes[n, w] == pytest.approx(expected, rel=1e-5, abs=1e-6)
    assert np.all(slopes[2, 1] == 0)


# ---------------------------------------------------------------------------------------
# Visual intensity profile


def test_profile_block_average_grey_and_crop(seed):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, size=(2, 80, 128, 3), dtype=np.uint8)
    t = templates(img, grid=(40, 64), crop_fraction=0.5, normalise=False)
    assert t.shape == (2, 40, 64) and t.dtype == np.float32
    # crop: top 40 rows; cells are 1 row x 2 columns; grey = channel mean / 255.
    for n in range(2):
        for i in (0, 17, 39):
            for j in (0, 31, 63):
                block = img[n, i, 2 * j : 2 * j + 2].astype(float)
                assert t[n, i, j] == pytest.approx(block.mean() / 255, abs=1e-6)
    # Rows below the crop do not matter.
    img2 = img.copy()
    img2[:, 40:] = 0
    np.testing.assert_array_equal(templates(img2, crop_fraction=0.5, normalise=False), t)
    # Pure red is one third grey.
    red = np.zeros((1, 480, 640, 3), dtype=np.uint8)
    red[..., 0] = 255
    np.testing.assert_allclose(templates(red, normalise=False), 1 / 3, atol=1e-6)


def test_profile_non_integer_and_small_images():
    # 480 x 640 (ViTa-SLAM): 300 rows -> 7.5 rows per cell. A frame whose top 150 rows are white
    # and the rest black: the first 20 cell rows (rows 0..150) are 1, the others 0.
    img = np.zeros((1, 480, 640, 3), dtype=np.uint8)
    img[:, :150] = 255
    t = templates(img, normalise=False)[0]
    np.testing.assert_allclose(t[:20], 1.0, atol=1e-6)
    np.testing.assert_allclose(t[20:], 0.0, atol=1e-6)
    # A white row band 0..154 (cell 20 covers rows 150..157.5: 5 of 7.5 rows white).
    img[:, :155] = 255
    assert templates(img, normalise=False)[0, 20, 0] == pytest.approx(5 / 7.5, abs=1e-5)
    # Recorded 120 x 160 and robot 45 x 80 images: constant stays constant, shape is the grid.
    for shape in ((120, 160), (45, 80)):
        const = np.full((3, *shape, 3), 102, dtype=np.uint8)
        t = templates(const, normalise=False)
        assert t.shape == (3, 40, 64)
        np.testing.assert_allclose(t, 102 / 255, atol=1e-6)
        np.testing.assert_allclose(templates(const), 0.4, atol=1e-6)


def test_profile_normalisation_mean(seed):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, size=(4, 120, 160, 3), dtype=np.uint8)
    img[1] //= 8  # a dark frame
    t = templates(img)
    np.testing.assert_allclose(t.mean(axis=(1, 2)), 0.4, atol=1e-6)
    # Normalisation is a scaling of the unnormalised template.
    raw = templates(img, normalise=False)
    np.testing.assert_allclose(t, raw * (0.4 / raw.mean(axis=(1, 2), keepdims=True)), rtol=1e-5)
    # A black frame stays black instead of dividing by zero.
    assert np.array_equal(templates(np.zeros((1, 48, 64, 3), dtype=np.uint8)), np.zeros((1, 40, 64)))


def test_profile_horizontal_shift_is_tolerated(seed):
    rng = np.random.default_rng(seed)
    k = 3  # cells; one cell = 10 pixels of a 640-wide frame
    wide = rng.integers(0, 256, size=(480, 640 + 10 * k, 3), dtype=np.uint8)
    a = wide[None, :, :640]
    b = wide[None, :, 10 * k : 640 + 10 * k]
    ta, tb = templates(a, normalise=False), templates(b, normalise=False)
    # Column c of b is column c + k of a.
    np.testing.assert_allclose(tb[0, :, : 64 - k], ta[0, :, k:], atol=1e-6)
    assert template_distance(ta, tb, max_shift=5)[0, 0] < 1e-6
    assert template_distance(tb, ta, max_shift=k)[0, 0] < 1e-6
    unshifted = template_distance(ta, tb, max_shift=0)[0, 0]
    too_small = template_distance(ta, tb, max_shift=k - 1)[0, 0]
    # Independent random cells differ by ~0.1 on average (block means of 75 uniform pixels).
    assert unshifted > 0.02 and too_small > 0.02


def loop_distance(q: np.ndarray, r: np.ndarray, max_shift: int) -> np.ndarray:
    """Direct per-pair, per-shift definition."""
    h, w = q.shape[1:]
    out = np.zeros((len(q), len(r)))
    for i in range(len(q)):
        for j in range(len(r)):
            best = math.inf
            for s in range(-max_shift, max_shift + 1):
                total, count = 0.0, 0
                for c in range(w):
                    if 0 <= c - s < w:
                        for row in range(h):
                            total += abs(float(q[i, row, c]) - float(r[j, row, c - s]))
                            count += 1
                best = min(best, total / count)
            out[i, j] = best
    return out


@pytest.mark.parametrize("threads, block", [(1, (128, 64)), (2, (2, 3))])
def test_profile_distance_matches_loop(threads, block, seed):
    rng = np.random.default_rng(seed)
    q = rng.random((5, 4, 12)).astype(np.float32)
    r = rng.random((7, 4, 12)).astype(np.float32)
    r[3] = np.roll(q[1], 2, axis=1)  # a shifted copy, so one minimum is at s != 0
    expected = loop_distance(q, r, 3)
    got = template_distance(q, r, max_shift=3, threads=threads, block=block)
    assert got.shape == (5, 7)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-7)
    # Symmetric definition, and shifts beyond the width are clamped to |s| < w.
    np.testing.assert_allclose(template_distance(r, q, max_shift=3), expected.T, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(template_distance(q, r, max_shift=50), loop_distance(q, r, 11), rtol=1e-6)
    assert template_distance(q[:0], r).shape == (0, 7)


# ---------------------------------------------------------------------------------------
# The extractor


def small_run(n: int, **fields) -> Run:
    arrays = {
        "images": np.zeros((n, 8, 8, 3), dtype=np.uint8),
        "theta": np.zeros((n, 24)),
        "xy": np.zeros((n, 24, 2)),
        "poses": np.zeros((n, 3)),
    }
    arrays.update(fields)
    return Run.from_arrays(**arrays)


def whisk_cycle(rng: np.random.Generator, samples: int = 10, whiskers: int = 24) -> np.ndarray:
    """(S, W, 2) deflections: each touching whisker bends along a straight line in the x-y plane,
    from contact onset to a peak, then relaxes (so its SDA slope is tan of the bending direction)."""
    out = np.zeros((samples, whiskers, 2))
    for w in range(whiskers):
        if rng.random() < 0.25:
            continue  # no contact
        onset = rng.integers(1, 4)
        peak = rng.integers(onset + 2, samples - 1)
        amplitude = rng.uniform(0.02, 0.06)
        direction = rng.uniform(-1.0, 1.0) + np.pi * rng.integers(0, 2)
        ramp = np.zeros(samples)
        ramp[onset : peak + 1] = np.arange(1, peak - onset + 2) / (peak - onset + 1)
        ramp[peak + 1 :] = np.linspace(1, 0, samples - peak)[1:]
        out[:, w] = amplitude * ramp[:, None] * [np.cos(direction), np.sin(direction)]
    return out


def place_runs(places: int = 6, visits: int = 3, seed: int = 8) -> tuple[Run, Run]:
    """Two runs visiting the same places, each place with its own scene, contacts and whisking."""
    rng = np.random.default_rng(seed)
    scenes = rng.integers(20, 236, size=(places, 64, 96, 3))
    surfaces = [random_contacts(rng, 12) for _ in range(places)]
    whisks = np.array([whisk_cycle(rng) for _ in range(places)])

    def record(noise_seed: int) -> Run:
        noise = np.random.default_rng(noise_seed)
        order = np.repeat(np.arange(places), visits)
        images, deflection, points, normals, counts = [], [], [], [], [0]
        for place in order:
            images.append(np.clip(scenes[place] + noise.normal(0, 6, scenes[place].shape), 0, 255))
            deflection.append(whisks[place] + noise.normal(0, 2e-4, whisks[place].shape))
            p, nrm = surfaces[place]
            points.append(p + noise.normal(0, 1e-4, p.shape))
            normals.append(nrm + noise.normal(0, 1e-3, nrm.shape))
            counts.append(len(p))
        poses = np.zeros((len(order), 3))
        poses[:, 0] = order
        return Run.from_arrays(
            images=np.asarray(images, dtype=np.uint8),
            theta=np.zeros((len(order), 24)),
            xy=np.asarray(deflection)[:, -1],
            poses=poses,
            deflection=np.asarray(deflection),
            contact_points=np.concatenate(points),
            contact_normals=np.concatenate(normals),
            contact_offsets=np.cumsum(counts),
        )

    return record(100), record(200)


@pytest.mark.parametrize(
    "params, keys",
    [
        ({}, {"profile", "pfh", "sda"}),
        ({"use_tactile": False}, {"profile"}),
        ({"use_visual": False}, {"pfh", "sda"}),
    ],
)
def test_extractor_same_place_is_closer(params, keys):
    reference, query = place_runs()
    extractor = HandcraftedExtractor(params)
    extractor.fit(reference)
    fq, fr = extractor.transform(query), extractor.transform(reference)
    assert set(fq) == keys
    if "profile" in keys:
        assert fq["profile"].shape == (len(query), 40, 64)
    if "pfh" in keys:
        assert fq["pfh"].shape == (len(query), 27) and fq["sda"].shape == (len(query), 24)
    d = extractor.distance(fq, fr)
    assert d.shape == (len(query), len(reference))
    same = query.poses[:, 0][:, None] == reference.poses[:, 0][None, :]
    for i in range(len(query)):
        assert d[i][same[i]].max() < d[i][~same[i]].min()


def test_extractor_sigmas_are_pairwise_spreads():
    reference, _ = place_runs(places=4, visits=2)
    extractor = HandcraftedExtractor({"max_shift": 2})
    extractor.fit(reference)
    f = extractor.transform(reference)
    n = len(reference)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    pfh_d = [np.abs(f["pfh"][i].astype(float) - f["pfh"][j]).sum() for i, j in pairs]
    sda_d = [np.abs(f["sda"][i].astype(float) - f["sda"][j]).sum() for i, j in pairs]
    assert extractor.sigmas["pfh"] == pytest.approx(np.std(pfh_d), rel=1e-5)
    assert extractor.sigmas["sda"] == pytest.approx(np.std(sda_d), rel=1e-5)
    vis = loop_distance(f["profile"], f["profile"], 2)
    assert extractor.sigmas["profile"] == pytest.approx(np.std([vis[i, j] for i, j in pairs]), rel=1e-5)
    # Total = sum of the terms divided by their sigmas.
    d = extractor.distance(f, f)
    i, j = 1, 5
    expected = vis[i, j] / extractor.sigmas["profile"] + pfh_d[pairs.index((i, j))] / extractor.sigmas["pfh"]
    expected += sda_d[pairs.index((i, j))] / extractor.sigmas["sda"]
    assert d[i, j] == pytest.approx(expected, rel=1e-5)


def test_extractor_zero_sigma_and_subsampled_fit(seed):
    # No contacts and no deflection: PFH and SDA are all zero, their sigmas fall back to 1.
    rng = np.random.default_rng(seed)
    run = small_run(30, images=rng.integers(0, 256, size=(30, 16, 16, 3), dtype=np.uint8))
    extractor = HandcraftedExtractor({"sigma_samples": 10, "batch_size": 7})
    extractor.fit(run)
    assert extractor.sigmas["pfh"] == 1.0 and extractor.sigmas["sda"] == 1.0
    f = extractor.transform(run)
    idx = np.unique(np.linspace(0, 29, 10).round().astype(int))
    vis = template_distance(f["profile"][idx], f["profile"][idx])
    assert extractor.sigmas["profile"] == pytest.approx(np.std(vis[np.triu_indices(len(idx), 1)]), rel=1e-5)
    assert np.all(np.isfinite(extractor.distance(f, f)))


def test_extractor_params_errors():
    with pytest.raises(ExtractorParamsError, match="bogus"):
        HandcraftedExtractor({"bogus": 1})
    with pytest.raises(ExtractorParamsError, match="at least one modality"):
        HandcraftedExtractor({"use_visual": False, "use_tactile": False})
    with pytest.raises(ExtractorParamsError, match="max_shift"):
        HandcraftedExtractor({"grid": [4, 6], "max_shift": 6})
    with pytest.raises(ExtractorParamsError, match="crop_fraction"):
        HandcraftedExtractor({"crop_fraction": 0})
    with pytest.raises(ExtractorParamsError, match="sda_mode"):
        HandcraftedExtractor({"sda_mode": "xy"})
    assert HandcraftedExtractor({"grid": [20, 32]}).params.grid == (20, 32)


def test_extractor_not_fitted_and_missing_features():
    reference, query = place_runs(places=2, visits=1)
    extractor = HandcraftedExtractor()
    f = extractor.transform(query)
    with pytest.raises(RuntimeError, match="not fitted"):
        extractor.distance(f, f)
    extractor.fit(reference)
    with pytest.raises(ValueError, match="pfh"):
        extractor.distance({"profile": f["profile"]}, f)


def test_extractor_save_load_round_trip(tmp_path):
    reference, query = place_runs(places=3, visits=2)
    extractor = HandcraftedExtractor({"max_shift": 4, "pfh_bins": 4, "sda_mode": "per_axis"})
    extractor.fit(reference)
    fq, fr = extractor.transform(query), extractor.transform(reference)
    extractor.save(tmp_path / "model")
    state = json.loads((tmp_path / "model" / "handcrafted_state.json").read_text())
    assert set(state["sigmas"]) == {"profile", "pfh", "sda"}
    loaded = HandcraftedExtractor.load(tmp_path / "model")
    assert loaded.params == extractor.params
    assert loaded.sigmas == extractor.sigmas
    lq, lr = loaded.transform(query), loaded.transform(reference)
    for key in fq:
        np.testing.assert_array_equal(lq[key], fq[key])
    np.testing.assert_array_equal(loaded.distance(lq, lr), extractor.distance(fq, fr))
    with pytest.raises(ValueError, match="no fitted state"):
        HandcraftedExtractor().load_state(tmp_path)
    # A zero sigma in a state file counts as 1 instead of dividing by zero.
    state["sigmas"]["sda"] = 0.0
    (tmp_path / "model" / "handcrafted_state.json").write_text(json.dumps(state))
    zero = HandcraftedExtractor.load(tmp_path / "model")
    terms = zero.term_distances(fq, fr)
    expected = terms["profile"] / state["sigmas"]["profile"] + terms["pfh"] / state["sigmas"]["pfh"] + terms["sda"]
    np.testing.assert_allclose(zero.distance(fq, fr), expected)


def test_plugin_registers_through_hook_and_entry_point():
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    (ep,) = [e for e in entry_points(group=hookspecs.ENTRY_POINT_GROUP) if e.name == "handcrafted"]
    assert ep.load() is handcrafted
    pm.register(handcrafted)
    registered = []
    pm.hook.vitaplace_register_features(register=registered.append)
    assert registered == [HandcraftedExtractor]
    assert HandcraftedExtractor.name == "handcrafted"
