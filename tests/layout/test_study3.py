"""The third study's scenario files against its pre-registration (docs/RESULTS.md, "Third
study: pre-registration"): the registered conditions, gates, methods, late fusions and
matching, the fusion-weight calibration at every grid weight, and the text's commands over
the registered seeds, so that neither the files nor the text can drift from the other; and the
sizes' design change recorded before the first scored run ("Design change before the first
scored run"), which the files now follow."""

import re
from pathlib import Path

import pytest

from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.sim.environment import load_environment

ROOT = Path(__file__).resolve().parents[2]
TEXT = (ROOT / "docs" / "RESULTS.md").read_text()
PREREG = TEXT[TEXT.index("## Third study: pre-registration"):TEXT.index("## Third study: calibration")]
PREREG = " ".join(PREREG.split())
_START = TEXT.index("### Design change before the first scored run")
_END = TEXT.find("\n### ", _START + 1)
CHANGE = " ".join(TEXT[_START:_END if _END > 0 else None].split())
GATES = {"touch_correspondence_min": 0.7, "rescue_min": 0.25, "hv_max_f1_max": 0.85, "headroom_min": 0.10}
STATION = ["L", "L-V", "L-T", "L-paper", "A", "H", "H-V", "H-T", "HOG", "VLAD"]
FUSIONS = {"L-F": ("L-V", "L-T"), "H-F": ("H-V", "H-T"), "HOG-F": ("HOG", "H-T"), "VLAD-F": ("VLAD", "H-T")}
#: the faithful and drop-out arms after the design change's cuts (2), (7) and (8)
REDUCED = ["L", "H", "H-V", "H-T"]
GRID = [0.0, 0.03, 0.1, 0.3, 1.0, 3.0]
#: the fair-chance defaults of 2026-12-07 as registered, beside the study network
FAIR = {"image_size": [12, 21], "visual_layers": [200, 100], "tactile_layers": [100], "joint_size": 100,
        "epochs": 3000, "converge_window": 20, "converge_tol": 0.01, "training_inference": "solver",
        "inference_steps": 5, "weight_optimizer": "momentum", "weight_norm": "rows", "latent_prior": 0.1,
        "precision_weighting": "none", "tactile_scaling": "clip", "held_out": 0.1,
        "inference_solver": "preconditioned", "inference_rtol": 3.0e-6, "max_steps": 1000}
#: the paper's algorithm (PAPER_ALGORITHM) on the same network, trained to the same criterion
PAPER = {**FAIR, "training_inference": "plain", "inference_steps": 20, "weight_optimizer": "sgd", "weight_norm": "none",
         "latent_prior": 0.0, "tactile_scaling": "range", "held_out": 0.0, "inference_solver": "gd",
         "inference_rtol": None, "max_steps": 3000,
         "epochs": 1226}  # the design change's cut (5): the registered floor


def scenario(name: str):
    return load_scenario(ROOT / "scenarios" / f"{name}.yaml")[0]


def test_the_arms_hold_the_registered_methods_and_fusions():
    arms = {name: scenario(name) for name in ("study3", "study3-dropout", "study3-faithful")}
    assert [m.name for m in arms["study3"].methods] == STATION
    assert [m.name for m in arms["study3-faithful"].methods] == REDUCED
    assert [m.name for m in arms["study3-dropout"].methods] == REDUCED
    for name, arm in arms.items():
        fusions = FUSIONS if name == "study3" else {"H-F": FUSIONS["H-F"]}
        assert {f.name: (f.vision, f.touch) for f in arm.fusions} == fusions, name
        assert {f.select_on for f in arm.fusions} == {"E1" if name == "study3-faithful" else "alike-shapes"}
        params = {m.name: dict(m.params) for m in arm.methods}
        assert params["L"] == FAIR, name
        if name == "study3":
            assert params["L-V"] == {**FAIR, "modalities": ["visual"]}
            assert params["L-T"] == {**FAIR, "modalities": ["tactile"]}
            assert params["L-paper"] == PAPER
            assert {k: params["A"][k] for k in ("image_size", "visual_layers", "tactile_layers", "joint_size",
                                                "tactile_scaling", "epochs", "converge_window", "converge_tol")} == {
                k: FAIR[k] for k in ("image_size", "visual_layers", "tactile_layers", "joint_size", "tactile_scaling",
                                     "epochs", "converge_window", "converge_tol")}


def test_the_paper_arm_is_the_paper_s_algorithm():
    from vitaplace.plugins.mupnet.extractor import PAPER_ALGORITHM

    assert {k: PAPER[k] for k in PAPER_ALGORITHM if k not in ("epochs", "converge_window")} == {
        k: v for k, v in PAPER_ALGORITHM.items() if k not in ("epochs", "converge_window")}


def test_the_conditions_and_their_gates_are_the_registered_ones():
    station = {e.name: e for e in scenario("study3").evaluations}
    assert list(station) == ["alike-shapes", "crossed-opposite", "dusk", "fog", "night"]
    horizon = station["crossed-opposite"]
    assert horizon.query_condition == horizon.reference_condition
    assert horizon.query_condition.camera.occlusion.model_dump() == {"share": 0.5, "side": "bottom"}
    dropout = {e.name: e for e in scenario("study3-dropout").evaluations}
    assert list(dropout) == ["alike-shapes", "dropout"]
    for e in [*station.values(), *dropout.values()]:
        assert e.gates.model_dump() == GATES, e.name
        assert e.run.kind == "stations" and e.run.n_samples == 200
    benchmark = {e.name: e for e in scenario("touch-benchmark").evaluations}
    assert station["dusk"].query_condition == benchmark["distinct-shapes-dusk"].query_condition
    tau = scenario("study3").scoring.tau
    fog = station["fog"].query_condition.fog
    assert (fog.start_m, fog.end_m * 0.95) == (0.0, pytest.approx(2 * tau, abs=1e-3))  # visibility 2 tau
    night, dusk = station["night"].query_condition, station["dusk"].query_condition
    assert night.light.intensity == pytest.approx(0.1) and night.light.colour_temperature_k == 2700
    assert (night.camera.exposure, night.camera.noise_std, night.camera.blur_sigma_px) == (
        2 * dusk.camera.exposure, 2 * dusk.camera.noise_std, 2 * dusk.camera.blur_sigma_px)
    assert dropout["dropout"].query_dropout.camera == 0.25
    worlds = {name: e.environment for name, e in station.items()}
    assert [Path(str(w)).stem for w in worlds.values()] == [
        "touch-alike-shapes", "touch-crossed-opposite", "touch-distinct-shapes", "touch-distinct-shapes",
        "touch-distinct-shapes"]


def test_crossed_pairs_cross_what_each_sense_aliases():
    """East and north look alike and west and south too (panel and landmark of one colour per
    pair); east and west feel alike and north and south too (one shape per pair); each
    landmark's nearest point as in touch-alike-boxes, whose route it drives."""
    crossed, boxes = load_environment("touch-crossed-pairs"), load_environment("touch-alike-boxes")
    marks = {lm.name: lm for lm in crossed.landmarks}
    panels = {side: crossed.arena.walls[side].panel.rgba for side in ("east", "north", "west", "south")}
    looks = {side: (panels[side], marks[side].rgba) for side in panels}
    feels = {side: {k: v for k, v in marks[side].model_dump().items() if k not in ("name", "pos", "rgba", "material")}
             for side in panels}
    assert looks["east"] == looks["north"] != looks["west"] == looks["south"]
    assert feels["east"] == feels["west"] != feels["north"] == feels["south"]
    assert looks["east"][0] == looks["east"][1] and looks["west"][0] == looks["west"][1]
    for lm in crossed.landmarks:  # every nearest point 1.638 m from the centre
        reach = lm.size[0] / 2 if lm.type == "box" else lm.radius  # type: ignore[union-attr]
        assert abs(max(abs(lm.pos[0]), abs(lm.pos[1])) - reach - 1.638) < 1e-9, lm.name
    assert crossed.route == boxes.route


def test_crossed_clear_is_crossed_pairs_with_clear_landmarks():
    """Redesign 2: touch-crossed-pairs' panels and landmark shapes, each landmark in
    touch-clear-shapes' acrylic, so vision keeps only the panels' pairs."""
    crossed, clear = load_environment("touch-crossed-pairs"), load_environment("touch-crossed-clear")
    shape = [{k: v for k, v in lm.model_dump().items() if k not in ("rgba", "material")} for lm in crossed.landmarks]
    assert shape == [{k: v for k, v in lm.model_dump().items() if k not in ("rgba", "material")}
                     for lm in clear.landmarks]
    assert {lm.material for lm in clear.landmarks} == {"acrylic"}
    assert clear.materials["acrylic"] == load_environment("touch-clear-shapes").materials["acrylic"]
    assert clear.arena == crossed.arena and clear.route == crossed.route


def test_crossed_edges_is_crossed_clear_with_edges_for_cylinders():
    """Redesign 3: north and south are touch-alike-shapes' box turned 45 degrees (an edge, its
    corner 1.638 m from the centre), east and west keep their flat faces; panels, material and
    route are touch-crossed-clear's."""
    edges, clear = load_environment("touch-crossed-edges"), load_environment("touch-crossed-clear")
    shapes = load_environment("touch-alike-shapes")
    marks = {lm.name: lm.model_dump() for lm in edges.landmarks}
    turned = next(lm.model_dump() for lm in shapes.landmarks if lm.name == "north")
    for side, y in (("north", 2.204), ("south", -2.204)):
        assert {**marks[side], "pos": None, "material": None, "name": None} == {
            **turned, "pos": None, "material": None, "name": None}
        assert tuple(marks[side]["pos"]) == (0.0, y)
    assert marks["east"] == next(lm.model_dump() for lm in clear.landmarks if lm.name == "east")
    assert abs(2.204 - 0.4 * 2 ** 0.5 - 1.638) < 1e-3
    assert {lm.material for lm in edges.landmarks} == {"acrylic"}
    assert edges.arena == clear.arena and edges.route == clear.route and edges.materials == clear.materials


def test_crossed_opposite_pairs_opposite_views_and_adjacent_shapes():
    """Redesign 5: the panels of opposite walls alike (a half turn maps the arena, its walls and
    its straight-down sun onto themselves, so partners see the same at every heading), the
    shapes alike at adjacent stations (flat faces east and north, turned boxes west and south,
    every nearest point 1.638 m from the centre)."""
    world = load_environment("touch-crossed-opposite")
    panels = {side: world.arena.walls[side].panel.rgba for side in ("east", "north", "west", "south")}
    assert panels["east"] == panels["west"] != panels["north"] == panels["south"]
    marks = {lm.name: lm.model_dump() for lm in world.landmarks}
    shape = {side: {k: v for k, v in marks[side].items() if k not in ("name", "pos")} for side in marks}
    assert shape["east"] == shape["north"] != shape["west"] == shape["south"]
    assert [tuple(marks[s]["pos"]) for s in ("east", "north", "west", "south")] == [
        (2.138, 0.0), (0.0, 2.138), (-2.204, 0.0), (0.0, -2.204)]
    lights = world.lighting.lights
    assert len(lights) == 1 and tuple(lights[0].direction) == (0.0, 0.0, -1.0)


def test_clear_shapes_is_alike_shapes_in_clear_acrylic():
    """The first design, not scored (docs/RESULTS.md, "Third study: calibration"): the same
    landmarks, walls and route; each landmark drawn in a material of alpha 0.08 (clear PMMA
    transmits about 92 % of visible light) in the floor's grey."""
    clear, alike = load_environment("touch-clear-shapes"), load_environment("touch-alike-shapes")
    geometry = [{k: v for k, v in lm.model_dump().items() if k != "material"} for lm in clear.landmarks]
    assert geometry == [{k: v for k, v in lm.model_dump().items() if k != "material"} for lm in alike.landmarks]
    assert {lm.material for lm in clear.landmarks} == {"acrylic"}
    assert clear.materials["acrylic"].rgba == (*alike.materials["grey"].rgba[:3], 0.08)
    assert clear.route == alike.route and clear.arena == alike.arena


def test_the_weight_calibration_runs_every_fusion_at_every_grid_weight():
    weights = scenario("study3-weights")
    station = {m.name: m for m in scenario("study3").methods}
    assert [m.name for m in weights.methods] == ["L-V", "L-T", "H-V", "H-T", "HOG", "VLAD"]
    for m in weights.methods:
        assert (m.plugin, dict(m.params)) == (station[m.name].plugin, dict(station[m.name].params))
    found = {f.name: (f.vision, f.touch, f.weights, f.select_on) for f in weights.fusions}
    assert found == {f"{name}-{w:g}": (*pair, [w], "alike-shapes") for name, pair in FUSIONS.items() for w in GRID}
    assert [e.name for e in weights.evaluations] == [e.name for e in scenario("study3").evaluations]


def test_matching_single_samples_and_sequences_over_2_8_metres():
    for name, window in (("study3", 24), ("study3-dropout", 24), ("study3-faithful", 50)):
        sequence = scenario(name).scoring.sequence
        assert (sequence.length, sequence.metres, sequence.window) == (3, 0, window), name


def test_the_commands_run_the_registered_seeds():
    commands = re.findall(r"vitaplace sweep scenarios/(study3[\w-]*|study2-budget)\.yaml --seeds ([\d ]+)", PREREG)
    seeds = {}
    for name, listed in commands:
        seeds.setdefault(name, []).append([int(s) for s in listed.split()])
    assert list(range(20, 30)) in seeds["study3"] and list(range(20, 30)) in seeds["study3-faithful"]
    assert list(range(1000, 1010)) in seeds["study3-dropout"] and list(range(10)) in seeds["study2-budget"]
    assert seeds["study3-weights"] == [list(range(100, 108))]
    calibration = re.findall(r"for s in ([\d ]+); do vitaplace difficulty scenarios/(study3[\w-]*)\.yaml", PREREG)
    assert sorted((name, [int(s) for s in listed.split()]) for listed, name in calibration) == [
        ("study3", list(range(100, 108))), ("study3-dropout", list(range(1100, 1108)))]
    scored = {s for name in ("study3", "study3-faithful", "study3-dropout") for run in seeds[name][1:] for s in run}
    assert not scored & (set(range(100, 108)) | set(range(1100, 1108)))  # calibration seeds are never scored


def test_the_design_change_s_commands_run_its_seeds_and_sizes():
    sweep = r"vitaplace sweep scenarios/(study3[\w-]*|study2-budget)\.yaml --seeds ([\d ]+)(.*?)--out"
    commands = re.findall(sweep, CHANGE)
    runs = [(name, [int(s) for s in listed.split()], "--grid" in rest) for name, listed, rest in commands]
    assert runs == [("study3", list(range(20, 30)), True), ("study2-budget", list(range(8)), False),
                    ("study2-budget", list(range(8)), False), ("study3-faithful", list(range(20, 30)), False),
                    ("study3-dropout", list(range(1000, 1010)), False)]
    assert "python bench/blas_kernel.py study3 --set seed=20 --kernels Haswell" in CHANGE
    assert "**1226**" in CHANGE and "**1000–1009**" in CHANGE
