"""How the tactile channels are scaled (`tactile_scaling`: range, the default and the paper's;
clip; robust) and how far the evaluation values sit inside the training range (the measure:
`range_measure` per sample, `feature_facts` per run, the report's table).

Expected values are worked by hand in the comments.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.base.errors import UserError  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.data.dataset import TOUCH_THRESHOLD, Run  # noqa: E402
from vitaplace.engine.extension.features import feature_facts  # noqa: E402
from vitaplace.engine.extension.registry import discover  # noqa: E402
from vitaplace.engine.report.learned import tactile_range_table  # noqa: E402
from vitaplace.plugins.mupnet.extractor import MupnetParams  # noqa: E402
from vitaplace.plugins.mupnet.inputs import RANGE_FILE, TactileRange, range_measure, report_out_of_range  # noqa: E402

#: one channel's training values: min 0, max 10; numpy's default (linear) percentiles of the
#: four sorted values sit at positions 0.75, 1.5 and 2.25: q1 = 0 + 0.75 (1 - 0) = 0.75,
#: median = 1 + 0.5 (2 - 1) = 1.5, q3 = 2 + 0.25 (10 - 2) = 4, so IQR = 4 - 0.75 = 3.25
TRAIN = np.array([[0], [1], [2], [10]], np.float32)
#: test values below, inside and above the training range
TEST = np.array([[-5], [0], [5], [20]], np.float32)


def fitted(scaling: str, values: np.ndarray = TRAIN, **params: object) -> TactileRange:
    return TactileRange.fit(values, MupnetParams(tactile_scaling=scaling, **params))


# --------------------------------------------------------------------------- the three scalings


def test_range_is_min_max_over_the_training_run_and_not_clipped():
    # (x - 0) / 10: -0.5, 0, 0.5, 2
    np.testing.assert_allclose(fitted("range").scale(TEST)[:, 0], [-0.5, 0, 0.5, 2])


def test_clip_is_the_same_clipped_to_0_1_so_values_beyond_the_range_saturate():
    # (x - 0) / 10 = -0.5, 0, 0.5, 2 -> 0, 0, 0.5, 1
    np.testing.assert_allclose(fitted("clip").scale(TEST)[:, 0], [0, 0, 0.5, 1])


def test_clip_saturates_at_the_training_range_even_where_the_span_was_floored():
    # training values 0 .. 0.02, span floored to 0.05: scaled (x - 0) / 0.05; the training
    # maximum 0.02 is 0.4 scaled, so 0.03 (0.6 scaled, beyond what training saw) is fed as 0.4
    scaling = fitted("clip", np.array([[0], [0.02]], np.float32), tactile_min_range=0.05)
    np.testing.assert_allclose(scaling.scale(np.array([[-0.01], [0.01], [0.03]], np.float32))[:, 0],
                               [0, 0.2, 0.4], rtol=1e-6)


def test_robust_is_median_and_iqr_of_the_training_run_and_not_clipped():
    # (x - 1.5) / 3.25: -6.5 / 3.25 = -2, -1.5 / 3.25, 3.5 / 3.25, 18.5 / 3.25
    scaling = fitted("robust")
    np.testing.assert_allclose(scaling.scale(TEST)[:, 0], [-2, -1.5 / 3.25, 3.5 / 3.25, 18.5 / 3.25], rtol=1e-6)
    offset, scale = scaling.scaler()
    np.testing.assert_allclose([offset[0], 1 / scale[0]], [1.5, 3.25], rtol=1e-6)


def test_robust_floors_the_iqr_and_keeps_the_contact_flags_on_their_own_scale():
    # cycle, P = 1, W = 1: channels x, y, flag. x as TRAIN (median 1.5, IQR 3.25); y flat at 0
    # (IQR 0, floored to tactile_min_range 0.05: scale 20); the flag set in 3 of 4 samples
    # (median 1, IQR 1 - 0.75 = 0.25) is fed as it is: offset 0, scale 1.
    train = np.array([[0, 0, 0], [1, 0, 1], [2, 0, 1], [10, 0, 1]], np.float32)
    scaling = fitted("robust", train, tactile_input="cycle", cycle_points=1, tactile_min_range=0.05)
    offset, scale = scaling.scaler()
    np.testing.assert_allclose(offset, [1.5, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(scale, [1 / 3.25, 20, 1], rtol=1e-6)
    np.testing.assert_allclose(scaling.scale(np.array([[1.5, 0.1, 1]], np.float32)), [[0, 2, 1]], rtol=1e-6)


def test_the_default_scales_as_before_the_option():
    """range (the paper's, the default before clip) feeds (x - low) * (1 / max(high - low, floor)),
    bit for bit the expression the scaling had before tactile_scaling, and returns the scaled
    array itself; the default is now clip."""
    rng = np.random.default_rng(3)
    train, test = rng.normal(0, 0.3, (40, 9)).astype(np.float32), rng.normal(0, 0.6, (30, 9)).astype(np.float32)
    train[:, 4] = 0.01  # a flat channel: the floor
    assert MupnetParams().tactile_scaling == "clip"
    default = TactileRange.fit(train, MupnetParams(tactile_scaling="range"))
    assert default.scaling == "range" and default.center is None
    low, high = train.min(axis=0), train.max(axis=0)
    span = np.maximum(high - low, np.float32(0.05))
    before = (test - low) * np.where(span > 0, 1 / np.where(span > 0, span, 1), 0).astype(np.float32)
    np.testing.assert_array_equal(default.scale(test), before)
    scaled = (test - low) * default.scaler()[1]
    assert default.saturate(scaled) is scaled


@pytest.mark.parametrize("scaling", ["range", "clip", "robust"])
def test_a_saved_range_loads_back_scaling_alike(tmp_path, scaling):
    train = np.array([[0, 0, 0], [1, 0, 1], [2, 0, 1], [10, 0, 1]], np.float32)
    saved = fitted(scaling, train, tactile_input="cycle", cycle_points=1)
    saved.save(tmp_path)
    loaded = TactileRange.load(tmp_path)
    assert loaded.scaling == scaling
    test = np.array([[-5, 0.3, 1], [20, -0.2, 0]], np.float32)
    np.testing.assert_array_equal(loaded.scale(test), saved.scale(test))
    data = json.loads((tmp_path / RANGE_FILE).read_text())
    assert ("center" in data and "spread" in data) == (scaling == "robust")  # what each mode needs


def test_a_range_saved_before_the_option_loads_as_range(tmp_path):
    (tmp_path / RANGE_FILE).write_text(json.dumps({"low": [0.0], "high": [10.0], "floor": [0.05]}))
    loaded = TactileRange.load(tmp_path)
    assert loaded.scaling == "range"
    np.testing.assert_allclose(loaded.scale(TEST)[:, 0], [-0.5, 0, 0.5, 2])


def test_an_unknown_scaling_is_one_line_naming_the_parameter(capsys):
    assert main(["validate", "quickstart", "--set", "methods.0.params.tactile_scaling=minmax"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vitaplace: error: "), lines
    assert "methods.0.params: extractor 'mupnet': tactile_scaling: Input should be 'range', 'clip' or 'robust'" \
        in lines[0], lines


# --------------------------------------------------------------------------- the extractors


def places_run(seed: int, n: int = 12, name: str = "run", push: float = 0.0) -> Run:
    """Random images and whiskers (W = 24): ``push`` added to whisker 3's x in every 4th sample."""
    rng = np.random.default_rng(seed)
    xy = rng.normal(0, 0.05, (n, 24, 2))
    xy[::4, 3, 0] += push
    return Run.from_arrays(images=rng.integers(0, 256, (n, 4, 4, 3), dtype=np.uint8),
                           theta=rng.normal(0, 0.1, (n, 24)), xy=xy, poses=np.zeros((n, 3)), name=name)


TINY = {"image_size": (2, 2), "visual_layers": [4], "tactile_layers": [4], "joint_size": 3, "epochs": 2,
        "batch_size": 4, "inference_steps": 3, "max_steps": 20, "backend": "numpy", "seed": 0}


@pytest.mark.parametrize("plugin", ["mupnet", "autoencoder"])
def test_clip_feeds_the_network_saturated_values_and_the_features_measure_the_range(tmp_path, plugin):
    """Whisker 3's x pushed by 5 in 3 of 12 test samples: 3 of 12 x 72 values leave the training
    range; under clip the network is fed them at 1 (the range's top), so a push of 5 and one of
    50 give the same features; the measure is saved with the features and loads back."""
    extractor_class = discover(only=plugin).get(plugin)
    params = TINY if plugin == "mupnet" else {k: v for k, v in TINY.items()
                                              if k not in ("inference_steps", "max_steps", "backend")}
    extractor = extractor_class({**params, "modalities": ["tactile"], "tactile_scaling": "clip"})
    extractor.progress = False
    extractor.fit(places_run(1))
    test, far = places_run(1, name="test", push=5.0), places_run(1, name="far", push=50.0)
    features = extractor.transform(test)
    np.testing.assert_array_equal(features["latent"], extractor.transform(far)["latent"])
    assert int((~features["tactile_inside"]).sum()) == 3 and features["tactile_inside"].shape == (12, 72)
    assert "they are clipped to the training range" in test.warnings[f"{plugin} tactile range (instant)"]
    extractor.save(tmp_path / "m")
    loaded = extractor_class.load(tmp_path / "m")
    assert loaded.tactile_range.scaling == "clip"
    np.testing.assert_array_equal(loaded.transform(far)["latent"], features["latent"])


# --------------------------------------------------------------------------- the measure


def measure_case() -> tuple[np.ndarray, TactileRange]:
    # instant, W = 1: channels theta, x, y. Training range: theta [0, 2], x and y flat at 0
    # (spans 2, 0.05, 0.05). Sample 0: theta 3 (3 / 2 = 1.5: 0.5 beyond [0, 1]) and y 0.02
    # (scaled 0.4: outside the range, not beyond [0, 1]); sample 1: x -0.005 (-0.1: 0.1 beyond);
    # sample 2 inside.
    train = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32)
    values = np.array([[3, 0, 0.02], [1, -0.005, 0], [1, 0, 0]], np.float32)
    return values, TactileRange.fit(train, MupnetParams())


def test_the_measure_of_a_hand_built_run():
    values, fit = measure_case()
    measure = range_measure(values, fit)
    np.testing.assert_array_equal(measure["tactile_inside"], [[0, 1, 0], [1, 0, 1], [1, 1, 1]])
    np.testing.assert_allclose(measure["tactile_beyond"], [0.5, 0.1, 0], rtol=1e-5)
    # 6 of 9 values inside; every channel 2 of 3 (66.7 % < 99 %); largest excess 0.5
    facts = feature_facts({"latent": np.zeros((3, 2), np.float32), **measure})["tactile_range"]
    assert facts | {"beyond": round(facts["beyond"], 5), "channel_min": round(facts["channel_min"], 5)} == {
        "values": 9, "inside": 6, "channels": 3, "channel_min": 0.66667, "channels_under": 3, "beyond": 0.5,
        "samples": 3}
    # sample 0 without whiskers (not fed): 5 of 6 values inside; theta 2/2, x 1/2, y 2/2; excess 0.1
    unfed = range_measure(values, fit, np.array([False, True, True]))
    assert unfed["tactile_beyond"][0] == 0 and unfed["tactile_measured"].tolist() == [False, True, True]
    facts = feature_facts({"latent": np.zeros((3, 2), np.float32), **unfed})["tactile_range"]
    assert facts | {"beyond": round(facts["beyond"], 5)} == {
        "values": 6, "inside": 5, "channels": 3, "channel_min": 0.5, "channels_under": 1, "beyond": 0.1,
        "samples": 2}
    assert "tactile_range" not in feature_facts({"latent": np.zeros((3, 2), np.float32)})


def test_the_measure_is_in_range_units_and_the_warning_quotes_its_maximum():
    values, _ = measure_case()
    train = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32)
    for scaling in ("clip", "robust"):
        fit = TactileRange.fit(train, MupnetParams(tactile_scaling=scaling))
        np.testing.assert_allclose(range_measure(values, fit)["tactile_beyond"], [0.5, 0.1, 0], rtol=1e-5)
    # only y's 0.02 (scaled 0.4) outside: outside the range, 0 beyond [0, 1] (not -0.4)
    run = Run.from_arrays(images=np.zeros((1, 2, 2, 3), np.uint8), theta=np.zeros((1, 1)), xy=np.zeros((1, 1, 2)),
                          poses=np.zeros((1, 3)), name="Y")
    paper = MupnetParams(tactile_scaling="range")
    report_out_of_range(run, values[:1] * [0, 0, 1], TactileRange.fit(train, paper), paper, "m")
    assert "up to 0 scaled units beyond [0, 1]); they are not clipped" in run.warnings["m tactile range (instant)"]


def test_the_report_tabulates_the_measure_per_method_and_run():
    facts = {"values": 6, "inside": 5, "channels": 3, "channel_min": 0.5, "channels_under": 1, "beyond": 0.1,
             "samples": 2}  # the hand-built run with sample 0 unfed: 5 / 6 = 83.3 %
    table = tactile_range_table({"L": {"E1/query": {"tactile_range": facts}}, "H": {"E1/query": {}}})
    assert table.splitlines()[0].startswith("| method | run | % of values in range | lowest channel % | "
                                            "channels under 99 % |")
    assert table.splitlines()[2:] == ["| L | E1/query | 83.3 | 50.0 | 1 of 3 | 0.1 |"]
    assert tactile_range_table({"H": {"E1/query": {}}}) == ""


@pytest.mark.parametrize("plugin", ["mupnet", "autoencoder"])
def test_a_training_run_that_touches_nothing_is_refused_when_touch_is_fed(plugin):
    """Every whisker at rest (xy 0, below the touch threshold) in every training sample: the
    tactile range would be the rest position's, so fitting is refused naming the modalities;
    one sample pushed past the threshold is enough to fit, and vision alone needs no touch."""
    extractor_class = discover(only=plugin).get(plugin)
    params = TINY if plugin == "mupnet" else {k: v for k, v in TINY.items()
                                              if k not in ("inference_steps", "max_steps", "backend")}
    still = places_run(2)
    still.xy[...] = 0.0
    with pytest.raises(UserError, match=r"modalities include 'tactile' but no sample of the training run 'run' "
                                        r"touches anything"):
        extractor_class({**params, "modalities": ["visual", "tactile"]}).fit(still)
    visual = extractor_class({**params, "modalities": ["visual"]})
    visual.progress = False
    visual.fit(still)
    one_touch = places_run(2)
    one_touch.xy[...] = 0.0
    one_touch.xy[5, 7] = [2 * TOUCH_THRESHOLD, 0.0]
    extractor = extractor_class({**params, "modalities": ["tactile"]})
    extractor.progress = False
    extractor.fit(one_touch)
    assert extractor.tactile_range is not None
