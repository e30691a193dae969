"""Late fusion (`fusions:`): the fused distance and its missing terms by hand, the weight chosen
on the selection evaluation only and applied unchanged elsewhere, and a fusion's settings at
validate."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix, pr_curve  # noqa: E402
from vitaplace.engine.evaluation.fusion import choose_weight, fused_distance, spread  # noqa: E402

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
    assert {(r["environment"], r["direction"]) for r in rows} == {(e, d) for e in ("E1", "E2")
                                                                   for d in ("query-to-reference", "reference-to-query")}
    for direction in ("query-to-reference", "reference-to-query"):
        e1 = {m: matrices(fused_run, "E1", m, direction) for m in ("H-V", "H-T")}
        gtm = ground_truth_matrix(e1["H-V"]["query_poses"], e1["H-V"]["reference_poses"], 30.0)
        w, sv, st, _ = choose_weight(e1["H-V"]["tme"], e1["H-T"]["tme"], [0, 0.3, 1, 3],
                                     lambda d: pr_curve(d, gtm, 0.3).max_f1)
        for env in ("E1", "E2"):
            (row,) = [r for r in rows if r["environment"] == env and r["direction"] == direction]
            assert row["fusion"]["weight"] == w and row["fusion"]["sigma_vision"] == pytest.approx(sv)
            members = {m: matrices(fused_run, env, m, direction)["tme"] for m in ("H-V", "H-T")}
            np.testing.assert_allclose(matrices(fused_run, env, "H-F", direction)["tme"],
                                       fused_distance(members["H-V"], members["H-T"], sv, st, w))
    report = (fused_run / "report.md").read_text()
    assert "## Late fusions" in report and "| H-F | H-V + H-T | the training world |" in report


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
