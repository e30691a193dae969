"""Late fusion (`fusions:`): the fused distance and its missing terms by hand, the weight chosen
on the selection evaluation only and applied unchanged elsewhere, and a fusion's settings at
validate."""

from __future__ import annotations

import json
import os
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.config.loading import load_scenario  # noqa: E402
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve  # noqa: E402
from vitaplace.engine.evaluation.fusion import choose_weight, fused_distance, spread  # noqa: E402
from vitaplace.engine.outputs import outdir  # noqa: E402
from vitaplace.engine.pipeline.stages.fuse import chosen_weight  # noqa: E402

ENVS = Path(__file__).resolve().parents[2] / "scenarios" / "environments"


def test_the_fused_distance_by_hand():
    vision, touch = np.array([[2.0, np.inf, np.inf, 4.0]]), np.array([[3.0, 3.0, np.inf, np.inf]])
    got = fused_distance(vision, touch, 2.0, 3.0, 0.5)
    # both: 2/2 + 0.5 * 3/3 = 1.5; vision lost: 0.5 * 1, scaled to the full weight 1.5 / 0.5 -> 1.5;
    # neither: +inf; touch lost: 4/2 = 2, scaled by 1.5 / 1 -> 3
    np.testing.assert_allclose(got, [[1.5, 1.5, np.inf, 3.0]])
    # w = 0 is vision alone: a pair without vision cannot be compared
    np.testing.assert_allclose(fused_distance(vision, touch, 2.0, 3.0, 0.0), [[1.0, np.inf, np.inf, 2.0]])


def test_a_spread_is_the_standard_deviation_of_the_finite_distances_or_one():
    assert spread(np.array([[1.0, 3.0], [np.inf, np.inf]])) == pytest.approx(1.0)
    assert spread(np.full((2, 2), 0.7)) == 1.0 and spread(np.full((2, 2), np.inf)) == 1.0


def test_the_weight_with_the_best_score_is_chosen_ties_to_the_smallest():
    vision, touch = np.array([[1.0, 2.0]]), np.array([[2.0, 1.0]])
    # scored as -fused[0, 0] + fused[0, 1]: rises with w up to where touch flips the order
    w, sv, st, scores = choose_weight(vision, touch, [3.0, 0.0, 1.0], lambda d: float(d[0, 1] - d[0, 0]))
    # sigma of [1, 2] and of [2, 1]: 0.5 each; fused = 2 v + 2 w t: [[2 + 4w, 4 + 2w]] -> 2 - 2w
    assert (sv, st) == (0.5, 0.5) and scores == pytest.approx({0.0: 2.0, 1.0: 0.0, 3.0: -4.0}) and w == 0.0
    assert choose_weight(vision, touch, [0.3, 0.1, 1.0], lambda d: 1.0)[0] == 0.1


@pytest.fixture(scope="module")
def fused_run(tmp_path_factory) -> Path:
    """H-V and H-T fused, trained in E1, evaluated in E1 (the selection) and E2, both directions."""
    tmp = tmp_path_factory.mktemp("fusion")
    scenario = {
        "name": "tiny-fusion",
        "train": {"environment": str(ENVS / "e1.yaml"), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": env.upper(), "environment": str(ENVS / f"{env}.yaml"),
                         "run": {"kind": "route", "n_samples": 12}} for env in ("e1", "e2")],
        "methods": [{"name": "H-V", "plugin": "handcrafted", "params": {"use_tactile": False}},
                    {"name": "H-T", "plugin": "handcrafted", "params": {"use_visual": False}}],
        "fusions": [{"name": "H-F", "vision": "H-V", "touch": "H-T", "weights": [0, 0.3, 1, 3]}],
        "scoring": {"tau": 0.3, "direction": "both"},
    }
    path = tmp / "tiny.yaml"
    path.write_text(yaml.safe_dump(scenario))
    assert main(["run", str(path), "--out", str(tmp / "run"), "--no-progress", "-q"]) == 0
    return tmp / "run"


def matrices(run: Path, env: str, method: str, direction: str) -> dict[str, np.ndarray]:
    with np.load(run / "evaluations" / env / method / direction / "matrices.npz") as saved:
        return {k: saved[k] for k in saved.files}


def test_the_weight_is_chosen_on_the_training_world_and_applied_unchanged(fused_run):
    rows = [r for r in json.loads((fused_run / "results.json").read_text()) if r["method"] == "H-F"]
    assert {(r["environment"], r["direction"]) for r in rows} == {
        (e, d) for e in ("E1", "E2") for d in ("query-to-reference", "reference-to-query")}
    for direction in ("query-to-reference", "reference-to-query"):
        e1 = {m: matrices(fused_run, "E1", m, direction) for m in ("H-V", "H-T")}
        gtm = ground_truth_matrix(e1["H-V"]["query_poses"], e1["H-V"]["reference_poses"], 30.0)
        w, sv, st, _ = choose_weight(e1["H-V"]["tme"], e1["H-T"]["tme"], [0, 0.3, 1, 3],
                                     lambda d, gtm=gtm: pr_curve(d, gtm, 0.3).max_f1)
        for env in ("E1", "E2"):
            (row,) = [r for r in rows if r["environment"] == env and r["direction"] == direction]
            assert row["fusion"]["weight"] == w and row["fusion"]["sigma_vision"] == pytest.approx(sv)
            members = {m: matrices(fused_run, env, m, direction)["tme"] for m in ("H-V", "H-T")}
            np.testing.assert_allclose(matrices(fused_run, env, "H-F", direction)["tme"],
                                       fused_distance(members["H-V"], members["H-T"], sv, st, w))
    report = (fused_run / "report.md").read_text()
    assert "## Late fusions" in report and "| H-F | H-V + H-T | the training world |" in report


# Three queries at x = 0, 1, 2 m against three references at the same places (tau 0.3 m: each
# query's true match is its own reference). RIGHT has its least distance there, WRONG one
# place to the right (wrapping): a method whose best match is always wrong.
RIGHT = 1.0 - np.eye(3)
WRONG = 1.0 - np.roll(np.eye(3), 1, axis=1)


class SavedEvaluations:
    """What `chosen_weight` reads of the store and the simulate record: the members' saved
    distances under ``out`` and the runs' poses (three places on a line, heading 0)."""

    def __init__(self, out: Path, scenario) -> None:
        self.out, self.scenario = out, scenario
        self.runs = defaultdict(lambda: None)  # the simulate record's runs: any label

    def run(self, record: None):
        class Places:
            name = "a run"
            poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])

            def __len__(self) -> int:
                return 3
        return Places()

    def save(self, environment: str, **distances: np.ndarray) -> None:
        for method, d in distances.items():
            folder = outdir.evaluation_dir(self.out, environment, method, "query-to-reference")
            folder.mkdir(parents=True, exist_ok=True)
            np.savez(folder / outdir.MATRICES, tme=d)


def test_the_weight_is_chosen_on_the_selection_evaluation_alone(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({
        "name": "saved", "train": {"environment": str(ENVS / "e1.yaml"), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": env.upper(), "environment": str(ENVS / f"{env}.yaml"),
                         "run": {"kind": "route", "n_samples": 12}} for env in ("e1", "e2")],  # never simulated
        "methods": [{"name": "V", "plugin": "handcrafted", "params": {"use_tactile": False}},
                    {"name": "T", "plugin": "handcrafted", "params": {"use_visual": False}}],
        "fusions": [{"name": "F", "vision": "V", "touch": "T", "weights": [3, 0, 1]}],
    }))
    saved = SavedEvaluations(tmp_path / "out", load_scenario(path)[0])
    (fusion,) = saved.scenario.fusions  # select_on left out: E1, in the training world e1
    # E1: vision right, touch wrong. Both spreads sqrt(2) / 3 (three 0s, six 1s), so the fused
    # row is (RIGHT + w WRONG) * 3 / sqrt(2): w = 0 finds every match (max F1 1), w = 1 ties the
    # true match with the wrong one, w = 3 prefers the wrong one (1 against 3)
    saved.save("E1", V=RIGHT, T=WRONG)
    # E2 the other way round: chosen there, w would be 3 (1 + 0 on the true match, 0 + 3 on the
    # wrong one)
    saved.save("E2", V=WRONG, T=RIGHT)
    choice = chosen_weight(saved, saved.scenario, saved, fusion, "query-to-reference", "query")
    assert choice["weight"] == 0.0 and choice["selection_max_f1"] == 1.0
    assert choice["sigma_vision"] == pytest.approx(np.sqrt(2) / 3)
    assert choice["sigma_touch"] == pytest.approx(np.sqrt(2) / 3)
    assert chosen_weight(saved, saved.scenario, saved, fusion.model_copy(update={"select_on": "E2"}),
                         "query-to-reference", "query")["weight"] == 3.0
    # whatever E2's distances are, the weight and spreads chosen on E1 stay
    rng = np.random.default_rng(0)
    for _ in range(3):
        saved.save("E2", V=rng.random((3, 3)) * 10, T=rng.random((3, 3)))
        assert chosen_weight(saved, saved.scenario, saved, fusion, "query-to-reference", "query") == choice


@pytest.mark.parametrize("setting, message", [
    ('fusions=[{name: F, vision: L, touch: X}]', "fusions.0.touch: no method 'X'"),
    ('fusions=[{name: F, vision: L, touch: L}]', "fusions.0: vision and touch are the same method"),
    ('fusions=[{name: F, vision: L, touch: H, weights: [0, -1]}]', "fusions.0.weights"),
    ('fusions=[{name: F, vision: L, touch: H, weights: []}]', "fusions.0.weights"),
    ('fusions=[{name: F, vision: L, touch: H, select_on: E9}]', "fusions.0.select_on: no evaluation 'E9'"),
    ('fusions=[{name: H, vision: L, touch: H}]', "fusions.0.name: 'H' is already"),
])
def test_bad_fusions_are_one_line_at_validate(capsys, setting, message):
    assert main(["validate", "quickstart", "--set", setting]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
