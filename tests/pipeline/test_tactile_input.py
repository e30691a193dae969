"""MuPNet's tactile input (`tactile_input`): the paper's instant, unchanged, or the whisk
cycle's deflection series at phase points plus contact flags; the training range fitted on
the training run and test values outside it counted and reported, never clipped.

Expected values are worked by hand in the comments.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import ad309c2_params
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.extension.registry import discover
from vitaplace.engine.outputs.keys import content_hash
from vitaplace.engine.pipeline.plan import params_for
from vitaplace.plugins.mupnet.extractor import MupnetParams
from vitaplace.plugins.mupnet.inputs import (
    TactileRange,
    contact_flags,
    cycle_series,
    report_out_of_range,
    tactile_values,
)

ROOT = Path(__file__).resolve().parents[2]
TINY = {"image_size": (2, 2), "visual_layers": [4], "tactile_layers": [4], "joint_size": 3, "epochs": 2,
        "batch_size": 4, "inference_steps": 3, "max_steps": 20, "backend": "numpy", "seed": 0}


def hand_run(deflection, xy=None, name="R") -> Run:
    """A run of the given (N, S, W, 2) deflection series; xy = its last sample unless given."""
    deflection = np.asarray(deflection, np.float32)
    n, _, w, _ = deflection.shape
    return Run.from_arrays(
        images=np.zeros((n, 2, 2, 3), np.uint8), theta=np.zeros((n, w)),
        xy=deflection[:, -1] if xy is None else xy, poses=np.zeros((n, 3)), deflection=deflection, name=name,
    )


# --------------------------------------------------------------------------- the cycle's values


def test_phase_points_interpolate_the_series_by_phase():
    # S = 4 samples at phases 1/4 .. 1, so phase point k of P sits at position (k + 1) * 4 / P - 1:
    # P = 8: -0.5 (held at the first sample), 0, 0.5, 1, 1.5, 2, 2.5, 3;  P = 3: 1/3, 5/3, 3.
    x = np.array([0.0, 10.0, 20.0, 40.0])
    series = np.zeros((1, 4, 1, 2))
    series[0, :, 0, 0] = x
    series[0, :, 0, 1] = 1.0
    np.testing.assert_allclose(cycle_series(series, 8)[0, :, 0, 0], [0, 0, 5, 10, 15, 20, 30, 40])
    np.testing.assert_allclose(cycle_series(series, 3)[0, :, 0, 0], [10 / 3, 10 + 10 * 2 / 3, 40], rtol=1e-6)
    np.testing.assert_allclose(cycle_series(series, 3)[0, :, 0, 1], 1.0)
    # a single-sample series (an imported run) gives P copies of the instant
    np.testing.assert_allclose(cycle_series(series[:, -1:], 4)[0, :, 0, 0], [40, 40, 40, 40])


def test_the_cycle_features_of_a_hand_built_run():
    # 2 samples, S = 4, W = 2 whiskers, P = 2 phase points: positions 1 and 3 of the series.
    d = np.zeros((2, 4, 2, 2), np.float32)
    d[0, :, 0, 0] = [0.0, 0.02, 0.0, 0.0]   # sample 0, whisker 0: a touch at s = 1 (a phase point)
    d[0, :, 1, 1] = 0.005                  # whisker 1: free-air wobble, under the 0.01 threshold
    d[1, :, 1, 0] = [0.0, 0.0, 0.03, 0.0]  # sample 1, whisker 1: a touch at s = 2, between the phase points
    run = hand_run(d)
    params = MupnetParams(tactile_input="cycle", cycle_points=2)
    values = tactile_values(run, params)
    # layout: (P, W, 2) flattened, then W flags
    expected = np.array([
        # point 1 (s = 1): w0 (x, y), w1 (x, y); point 2 (s = 3): w0, w1; flags w0, w1
        [0.02, 0, 0, 0.005, 0, 0, 0, 0.005, 1, 0],
        [0, 0, 0, 0, 0, 0, 0, 0, 0, 1],  # the touch between the points is still flagged
    ], np.float32)
    np.testing.assert_allclose(values, expected, atol=1e-7)
    assert params.tactile_size(2) == values.shape[1] == 2 * (2 * 2 + 1)
    np.testing.assert_array_equal(contact_flags(d), [[1, 0], [0, 1]])


def test_the_instant_input_is_theta_then_xy():
    rng = np.random.default_rng(5)
    d = rng.normal(0, 0.1, (3, 4, 2, 2))
    run = Run.from_arrays(images=np.zeros((3, 2, 2, 3), np.uint8), theta=[[1, 2], [3, 4], [5, 6]], xy=d[:, -1],
                          poses=np.zeros((3, 3)), deflection=d)
    values = tactile_values(run, MupnetParams())
    np.testing.assert_array_equal(values[:, :2], [[1, 2], [3, 4], [5, 6]])
    np.testing.assert_array_equal(values[:, 2:], d[:, -1].reshape(3, 4).astype(np.float32))


def test_a_single_sample_series_is_warned_about_in_cycle_mode():
    run = hand_run(np.zeros((2, 1, 2, 2)))
    tactile_values(run, MupnetParams(tactile_input="cycle"))
    assert "single deflection sample" in run.warnings["tactile cycle"]


# --------------------------------------------------------------------------- range and scaling


def test_the_scaling_spans_are_the_training_range_floored_and_flags_their_own():
    # cycle, P = 1, W = 1: channels x, y, flag. Training: x in [0, 2], y flat at 0, flag always 0.
    train = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32)
    fitted = TactileRange.fit(train, MupnetParams(tactile_input="cycle", cycle_points=1, tactile_min_range=0.05))
    offset, scale = fitted.scaler()
    np.testing.assert_array_equal(offset, [0, 0, 0])
    # spans 2, max(0, 0.05), max(0, 1): a flag never set in training scales a touch to 1, not 1 / 0.05 = 20
    np.testing.assert_allclose(scale, [0.5, 20, 1])


def test_test_values_outside_the_training_range_are_counted_and_reported_not_clipped():
    # instant, W = 1: channels theta, x, y. Training range: theta [0, 2], x and y flat at 0
    # (spans 2, 0.05, 0.05). Test sample 0: theta 3 -> 3 / 2 = 1.5, 0.5 beyond [0, 1], and y
    # 0.02 > 0 (scaled 0.4: out of range, not beyond [0, 1]); it is touched (|xy| = 0.02 > 0.01).
    # Sample 1: x -0.005 -> -0.1, 0.1 beyond; untouched (|xy| = 0.005). Sample 2 inside.
    # So 2 of 3 samples, 1 of the 1 touched, 3 values in 3 of 3 channels, up to 0.5 beyond.
    params = MupnetParams(tactile_scaling="range")  # the paper's scaling, which does not clip
    fitted = TactileRange.fit(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], np.float32), params)
    values = np.array([[3, 0, 0.02], [1, -0.005, 0], [1, 0, 0]], np.float32)
    run = hand_run(values[:, None, None, 1:], name="B")
    np.testing.assert_array_equal(fitted.outside(values), [[1, 0, 1], [0, 1, 0], [0, 0, 0]])
    report_out_of_range(run, values, fitted, params, "mupnet")
    message = run.warnings["mupnet tactile range (instant)"]
    assert message == ("mupnet (tactile_input instant): 2 of 3 samples of run 'B' (1 of its 1 touched samples) have "
                       "tactile values outside the training run's range (3 values in 3 of 3 channels, up to 0.5 scaled "
                       "units beyond [0, 1]); they are not clipped")
    inside = hand_run(np.zeros((3, 1, 1, 2)), name="C")
    report_out_of_range(inside, values[2:], fitted, params, "mupnet")
    assert inside.warnings == {}


# --------------------------------------------------------------------------- the extractor


@pytest.fixture(scope="module")
def mupnet_class():
    return discover(only="mupnet").get("mupnet")


def series_run(seed: int, touch_at: int, n: int = 12, name: str = "run") -> Run:
    """Random images and a deflection series (S = 5, W = 24) with a touch of whisker 3 at sample
    ``touch_at`` of every 4th cycle."""
    rng = np.random.default_rng(seed)
    d = rng.normal(0, 0.002, (n, 5, 24, 2))
    d[::4, touch_at, 3, 0] = 0.2
    return Run.from_arrays(images=rng.integers(0, 256, (n, 4, 4, 3), dtype=np.uint8), theta=np.zeros((n, 24)),
                           xy=d[:, -1], poses=np.zeros((n, 3)), deflection=d, name=name)


def test_instant_feeds_the_network_as_before(mupnet_class):
    """The default is the paper's input and scaling: theta + xy (72 values), each channel
    scaled by 1 / max(its training range, tactile_min_range) from its training minimum."""
    run = series_run(1, touch_at=4)
    extractor = mupnet_class({**TINY, "modalities": ["tactile"]})
    extractor.progress = False
    extractor.fit(run)
    raw = np.concatenate([run.theta, run.xy.reshape(len(run), -1)], axis=1)
    offset, scale = extractor.network.scalers["tactile"]
    np.testing.assert_array_equal(offset, raw.min(axis=0))
    np.testing.assert_allclose(scale, 1 / np.maximum(raw.max(axis=0) - raw.min(axis=0), 0.05), rtol=1e-6)
    assert extractor.network.sizes["tactile.0"] == 72


def test_the_cycle_input_reaches_the_network_and_out_of_range_tests_are_reported(mupnet_class, tmp_path):
    """Training touches whisker 3 at the cycle's last sample (s = 4 of S = 5); the test run
    mid-cycle (s = 2). Phase point k of 8 sits at position (k + 1) * 5 / 8 - 1: points 3, 4, 5
    (positions 1.5, 2.125, 2.75) weigh s = 2 by 0.5, 0.875, 0.25, so whisker 3's x there (0.1,
    0.175, 0.05) leaves its training range (noise of 0.002): every touched test sample (every
    4th of 12: 3) is reported; the flags (set in both runs) stay in range."""
    train, test = series_run(1, touch_at=4, name="train"), series_run(2, touch_at=2, name="test")
    extractor = mupnet_class({**TINY, "modalities": ["tactile"], "tactile_input": "cycle"})
    extractor.progress = False
    extractor.fit(train)
    assert extractor.network.sizes["tactile.0"] == 24 * 17
    features = extractor.transform(test)
    assert np.isfinite(features["latent"]).all()
    message = test.warnings["mupnet tactile range (cycle, 8 points)"]
    assert "of 12 samples of run 'test' (3 of its 3 touched samples)" in message
    extractor.save(tmp_path / "m")
    loaded = mupnet_class.load(tmp_path / "m")
    np.testing.assert_array_equal(loaded.tactile_range.high, extractor.tactile_range.high)
    np.testing.assert_array_equal(loaded.transform(test)["latent"], features["latent"])


#: content_hash(plugin, the parameters the pipeline hands each method's plugin) of every method
#: of every shipped scenario, recorded at commit 4d558a4, before `tactile_input` existed
METHOD_PARAMS_KEYS = {
    "coloured-cpu:L": "9daa2b704f00e44e", "coloured-cpu:L-V": "e3f7a74270751789",
    "coloured-cpu:L-T": "e4562015b8330d0f",
    "coloured-cpu:H": "072f54dc05b75ad4", "coloured-cpu:H-V": "48ef700d0a2c666a",
    "coloured-cpu:H-T": "d7284dbdd1c8cde0",
    "near-duplicate:L": "e85f49fa723cccd5", "near-duplicate:H": "072f54dc05b75ad4",
    "paper-cpu-physical:L": "9daa2b704f00e44e", "paper-cpu-physical:L-V": "e3f7a74270751789",
    "paper-cpu-physical:L-T": "e4562015b8330d0f", "paper-cpu-physical:H": "072f54dc05b75ad4",
    "paper-cpu-physical:H-V": "48ef700d0a2c666a", "paper-cpu-physical:H-T": "d7284dbdd1c8cde0",
    "paper-cpu:L": "9daa2b704f00e44e", "paper-cpu:L-V": "e3f7a74270751789", "paper-cpu:L-T": "e4562015b8330d0f",
    "paper-cpu:H": "072f54dc05b75ad4", "paper-cpu:H-V": "48ef700d0a2c666a", "paper-cpu:H-T": "d7284dbdd1c8cde0",
    "paper:L": "3a4eb71b46d8da1f", "paper:H": "072f54dc05b75ad4",
    "quickstart:L": "e85f49fa723cccd5", "quickstart:H": "072f54dc05b75ad4",
}

#: what the shipped CPU scenarios' MuPNet methods set since issue 30 (paper.yaml keeps the paper's
#: rule): the preconditioned solver at rtol 3e-6 (docs/MUPNET.md)
SETTLING = {"latent_prior": 1.0, "inference_solver": "preconditioned", "inference_rtol": 3.0e-6, "max_steps": 1000}


@pytest.mark.parametrize("name", sorted({key.split(":")[0] for key in METHOD_PARAMS_KEYS}))
def test_the_methods_of_the_shipped_scenarios_keep_their_parameter_keys(name):
    """A new parameter at its default enters no key: the pipeline hands a plugin the
    scenario's parameters (and the derived seed), not the schema's defaults. (The pins the
    committed studies were given when the defaults changed, `conftest.SINCE_AD309C2`, are
    undone first: they are the only parameters added to those files since.)"""
    scenario, _ = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    registry = discover()
    keys = {}
    for m in scenario.methods:
        params = ad309c2_params(name, m.plugin, dict(params_for(scenario, registry, m)))  # the pins since
        if name != "paper" and m.plugin == "mupnet":  # the settling solver, set since (issue 30)
            assert {k: params.pop(k) for k in SETTLING} == SETTLING
            params["max_steps"] = 300  # the cap these scenarios had at 4d558a4
        keys[f"{name}:{m.name}"] = content_hash(m.plugin, params)
    assert keys == {k: v for k, v in METHOD_PARAMS_KEYS.items() if k.startswith(f"{name}:")}


def test_the_controls_scenario_holds_the_studys_six_methods_unchanged():
    """paper-cpu-controls.yaml adds methods after paper-cpu.yaml's six: those keep their
    names, plugins, parameters and derived seeds (so their keys), and the new ones use the
    cycle input or the autoencoder."""
    keys = {}
    for name in ("paper-cpu", "paper-cpu-controls"):
        scenario, _ = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
        keys[name] = [(m.name, content_hash(m.plugin, params_for(scenario, discover(), m))) for m in scenario.methods]
    assert keys["paper-cpu-controls"][:6] == keys["paper-cpu"]
    assert [name for name, _ in keys["paper-cpu-controls"][6:]] == ["L-cycle", "L-T-cycle", "A", "A-V", "A-T",
                                                                    "A-cycle"]
