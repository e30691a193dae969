"""The evaluate stage in linear memory: with the bound on whole matrices below every pair, a
run asks each method for its distances a block of queries at a time, writes no
``matrices.npz``, and gives the same results, row for row, as the run that held them whole;
a late fusion, which needs the whole distances, then stops with one line naming the file."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.evaluation import pairfiles, ranking  # noqa: E402
from vitaplace.engine.evaluation.evaluate import f1_at_threshold_of  # noqa: E402
from vitaplace.engine.evaluation.pairfiles import load_curve  # noqa: E402
from vitaplace.plugins.handcrafted.extractor import HandcraftedExtractor  # noqa: E402

ENVS = Path(__file__).resolve().parents[2] / "scenarios" / "environments"
SAMPLES = 12  # per evaluation run
BLOCK = 5  # queries per chunk in the linear run


def scenario(path: Path, fusions: bool = False) -> Path:
    spec = {
        "name": "tiny-linear",
        "train": {"environment": str(ENVS / "e1.yaml"), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": env.upper(), "environment": str(ENVS / f"{env}.yaml"),
                         "run": {"kind": "route", "n_samples": SAMPLES}} for env in ("e1", "e2")],
        "methods": [{"name": "H-V", "plugin": "handcrafted", "params": {"use_tactile": False}},
                    {"name": "H-T", "plugin": "handcrafted", "params": {"use_visual": False}}],
        "scoring": {"tau": 0.3, "direction": "both"},
        "report": {"figures": "all"},
    }
    if fusions:
        spec["fusions"] = [{"name": "H-F", "vision": "H-V", "touch": "H-T", "weights": [0, 1]}]
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path, list[int]]:
    """(the run with whole matrices, the run in chunks, the query blocks distance was asked for)."""
    tmp = tmp_path_factory.mktemp("linear")
    path = scenario(tmp / "tiny.yaml")
    assert main(["run", str(path), "--out", str(tmp / "whole"), "--no-progress", "-q"]) == 0
    blocks: list[int] = []
    original = HandcraftedExtractor.distance

    def spy(self, query, reference):
        blocks.append(len(next(iter(query.values()))))
        return original(self, query, reference)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pairfiles, "FULL_MATRIX_LIMIT", SAMPLES * SAMPLES - 1)
        mp.setattr(ranking, "CHUNK_BYTES", 8 * SAMPLES * BLOCK)
        mp.setattr(HandcraftedExtractor, "distance", spy)
        assert main(["run", str(path), "--out", str(tmp / "chunked"), "--no-progress", "-q"]) == 0
    return tmp / "whole", tmp / "chunked", blocks


def test_a_run_in_chunks_gives_the_same_results_row_for_row(runs):
    whole, chunked, _ = runs
    rows = [json.loads((run / "results.json").read_text()) for run in (whole, chunked)]
    assert len(rows[0]) == 2 * 2 * 2 and rows[1] == rows[0]  # f1 at the training world's threshold too


def test_the_f1_at_the_training_threshold_is_that_of_the_pair_s_own_matrices(runs):
    """From the decisions in both runs; here from the whole run's saved matrices, at the
    threshold of E1 (the training world's evaluation) in the same direction."""
    whole, _, _ = runs
    for row in json.loads((whole / "results.json").read_text()):
        folder = whole / "evaluations" / row["environment"] / row["method"] / row["direction"]
        source = load_curve(whole / "evaluations" / "E1" / row["method"] / row["direction"] / "pr_curve.npz")
        with np.load(folder / "matrices.npz") as m:
            assert row["f1_at_e1_threshold"] == f1_at_threshold_of(source, m["tme"], m["gtm"], row["tau"])


def test_distances_are_asked_a_block_of_queries_at_a_time_and_no_matrices_are_written(runs):
    whole, chunked, blocks = runs
    assert blocks and max(blocks) == BLOCK and sum(blocks) == 2 * 2 * 2 * SAMPLES
    assert len(list(whole.glob("evaluations/*/*/*/matrices.npz"))) == 8
    assert not list(chunked.glob("evaluations/*/*/*/matrices.npz"))


def test_the_report_says_which_matrices_it_could_not_draw(runs):
    _, chunked, _ = runs
    report = (chunked / "report.md").read_text()
    assert report.count(f"Matrices not drawn: {SAMPLES} queries x {SAMPLES} references") == 8
    assert len(list((chunked / "figures").glob("trajectories-*.png"))) == 8


def test_a_fusion_without_the_whole_distances_stops_with_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(pairfiles, "FULL_MATRIX_LIMIT", SAMPLES * SAMPLES - 1)
    path = scenario(tmp_path / "fused.yaml", fusions=True)
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--no-progress", "-q"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("matrices.npz: missing; a late fusion reads each method's whole distances, saved only "
                            "for pairs of at most 143 queries x references (FULL_MATRIX_LIMIT)")
    assert "Traceback" not in "\n".join(err)


def test_a_run_in_chunks_aggregates_without_its_bootstrap_intervals(runs, tmp_path):
    from vitaplace.engine.study.aggregate import aggregate_runs

    _, chunked, _ = runs
    out, info = aggregate_runs([chunked], tmp_path / "summary")
    assert info["seeds"] == [0] and (out / "sweep.json").is_file() and (out / "sweep.md").is_file()
