"""Sequence matching (`scoring.sequence`, SeqSLAM): the local contrast and the straight-line
search against a hand-worked case and a plain-loop reference, +inf distances, length 1 being
single-sample matching bit for bit, its settings at validate, a run that matches sequences and
`vitaplace sensitivity --sequence-length` agreeing."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pydantic
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.config.scenario import ScoringSettings, SequenceSettings  # noqa: E402
from vitaplace.engine.evaluation.evaluate import evaluate, ground_truth_matrix  # noqa: E402
from vitaplace.engine.evaluation.sequence import (  # noqa: E402
    local_contrast,
    points_back,
    sequence_scores,
    travelled,
)

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"


def reference_scores(d: np.ndarray, length: int, velocities: tuple[float, float], steps: int,
                     window: int) -> np.ndarray:
    """The sequence score written as plainly as it is defined (sequence.py's docstring)."""
    n_q, n_r = d.shape
    contrast = np.full(d.shape, np.inf)
    for i in range(n_q):
        for j in range(n_r):
            if not np.isfinite(d[i, j]):
                continue
            near = d[i, max(0, j - window): j + window + 1]
            near = near[np.isfinite(near)]
            std = near.std()
            contrast[i, j] = (d[i, j] - near.mean()) / (std if std > 1e-12 * abs(near.mean()) else 1.0)
    out = np.full(d.shape, np.inf)
    for v in np.linspace(velocities[0], velocities[1], steps):
        for i in range(n_q):
            for j in range(n_r):
                terms, inside = [], True
                for k in range(max(0, i - length + 1), i + 1):
                    col = int(np.rint(j + v * (k - i)))
                    inside = inside and 0 <= col < n_r  # a line that leaves the reference run is no candidate
                    if 0 <= col < n_r and np.isfinite(contrast[k, col]):
                        terms.append(contrast[k, col])
                if terms and inside:
                    out[i, j] = min(out[i, j], float(np.mean(terms)))
    return out


def reference_odometry_scores(d: np.ndarray, length: int, window: int, metres: float, query_xy: np.ndarray,
                              reference_xy: np.ndarray) -> np.ndarray:
    """Sequences over travelled distance written as plainly as they are defined (sequence.py's
    docstring): every point's sample found by a search over the whole run."""
    contrast = _contrast(d, window)

    def path(xy: np.ndarray) -> list[float]:
        return [sum(float(np.hypot(*(xy[k + 1] - xy[k]))) for k in range(i)) for i in range(len(xy))]

    def point(t: list[float], i: int, back: float) -> int | None:
        at = t[i] - back
        if at < 0:
            return None
        gaps = [abs(t[k] - at) for k in range(i + 1)]
        return max(k for k in range(i + 1) if gaps[k] == min(gaps))  # the nearest, the later on a tie

    tq, tr = path(query_xy), path(reference_xy)
    out = np.full(d.shape, np.inf)
    for i in range(d.shape[0]):
        for j in range(d.shape[1]):
            terms, inside = [], True
            for k in range(length):
                qi, rj = point(tq, i, metres * k / (length - 1)), point(tr, j, metres * k / (length - 1))
                inside = inside and (qi is None or rj is not None)  # the reference's points run back as far
                if qi is not None and rj is not None and np.isfinite(contrast[qi, rj]):
                    terms.append(contrast[qi, rj])
            if terms and inside:
                out[i, j] = float(np.mean(terms))
    return out


def _contrast(d: np.ndarray, window: int) -> np.ndarray:
    """Local contrast written plainly: each finite entry against its row's finite entries within
    ``window`` references."""
    contrast = np.full(d.shape, np.inf)
    for i in range(d.shape[0]):
        for j in range(d.shape[1]):
            if np.isfinite(d[i, j]):
                near = d[i, max(0, j - window): j + window + 1]
                near = near[np.isfinite(near)]
                std = near.std()
                contrast[i, j] = (d[i, j] - near.mean()) / (std if std > 1e-12 * abs(near.mean()) else 1.0)
    return contrast


def test_length_one_is_the_distance_matrix_itself():
    d = np.random.default_rng(1).random((7, 9))
    assert sequence_scores(d, 1) is not None and np.array_equal(sequence_scores(d, 1), d)
    # a scenario that says length 1 scores (and keys) exactly as one that says nothing
    assert ScoringSettings(sequence={"length": 1}).model_dump() == ScoringSettings().model_dump()


# Six queries along six references (query i's true place is reference i). Every query's own
# reference is at 0.5, every other at 1.0 - except the last query, which sees reference 1 at
# 0.4 (an aliased place): alone, its best match is reference 1, wrong.
ALIASED = np.full((6, 6), 1.0)
np.fill_diagonal(ALIASED, 0.5)
ALIASED[5, 1] = 0.4


def test_a_sequence_finds_the_match_a_single_sample_misses():
    assert np.argmin(ALIASED[5]) == 1
    # window 10 covers each row: rows 0-4 have mean 0.9167 and std 0.18634, so their own
    # reference is (0.5 - 0.9167) / 0.18634 = -2.236 and the others +0.447; row 5 has mean
    # 0.8167 and std 0.2609: reference 1 is -1.597, reference 5 -1.214, the others +0.703
    contrast = local_contrast(ALIASED, 10)
    assert contrast[0, 0] == pytest.approx(-2.236, abs=1e-3) and contrast[0, 3] == pytest.approx(0.447, abs=1e-3)
    assert contrast[5, 1] == pytest.approx(-1.597, abs=1e-3) and contrast[5, 5] == pytest.approx(-1.214, abs=1e-3)
    s = sequence_scores(ALIASED, 3, velocities=(1.0, 1.0), velocity_steps=1, window=10)
    # the line of length 3 at velocity 1 through (5, 5): (3, 3), (4, 4), (5, 5) -> (-2.236 - 2.236 - 1.214) / 3
    assert s[5, 5] == pytest.approx(-1.895, abs=1e-3)
    # through (5, 1): (3, -1) is outside the reference run, so the line is no candidate (its
    # two other terms, +0.447 and -1.597, would average -0.575 on fewer terms); likewise
    # reference 0, whose line meets references -2 and -1
    assert np.isinf(s[5, 1]) and np.isinf(s[5, 0])
    # through (5, 2): (3, 0) +0.447, (4, 1) +0.447, (5, 2) +0.703 -> +0.532
    assert s[5, 2] == pytest.approx(0.532, abs=1e-3)
    assert np.argmin(s[5]) == 5
    gtm = np.abs(np.arange(6)[:, None] - np.arange(6)[None, :]).astype(float)  # metres along the loop
    assert evaluate(ALIASED, gtm, 0.1)["recall_at_k"]["1"] == pytest.approx(5 / 6)
    assert evaluate(s, gtm, 0.1)["recall_at_k"]["1"] == 1.0


@pytest.mark.parametrize("length, velocities, steps, window", [
    (2, (1.0, 1.0), 1, 3), (5, (0.8, 1.25), 5, 10), (4, (0.5, 2.0), 4, 2), (7, (1.0, 1.5), 3, 1)])
def test_sequence_scores_equal_a_plain_loop(seed, length, velocities, steps, window):
    rng = np.random.default_rng(seed)
    d = rng.random((17, 23)) * 3
    d[rng.random(d.shape) < 0.1] = np.inf  # pairs the method cannot compare
    d[4] = np.inf  # a query without the method's sensor
    d[9, 3:9] = 0.7  # a flat stretch: a window whose spread is 0
    got = sequence_scores(d, length, velocities, steps, window)
    np.testing.assert_allclose(got, reference_scores(d, length, velocities, steps, window), rtol=1e-9, atol=1e-9)


def test_a_query_the_method_cannot_compare_is_scored_by_the_sequence_that_ends_at_it():
    d = ALIASED.copy()
    d[4] = np.inf  # query 4 lost its sensor
    s = sequence_scores(d, 3, (1.0, 1.0), 1, 10)
    # its lines borrow queries 2 and 3: finite wherever the whole line is in the reference run
    # (references 2 on); references 0 and 1's lines meet references before the run's start
    assert np.isinf(s[4, :2]).all() and np.isfinite(s[4, 2:]).all() and np.argmin(s[4]) == 4
    assert np.isinf(sequence_scores(np.full((4, 4), np.inf), 2, (1.0, 1.0), 1, 3)).all()  # nothing to compare


def poses_of(xy: np.ndarray) -> np.ndarray:
    """Poses (x, y, yaw) at the points ``xy``, all facing +x."""
    return np.c_[xy, np.zeros(len(xy))]


def stop_and_go(rng: np.random.Generator, n: int) -> np.ndarray:
    """A drive of ``n`` samples that stops (a third of its steps are 0 m) and turns."""
    steps = rng.random(n - 1) * 0.2 * (rng.random(n - 1) > 0.3)
    heading = np.cumsum(rng.normal(0.0, 0.5, n - 1))
    return poses_of(np.vstack([[0.0, 0.0], np.cumsum(np.c_[steps * np.cos(heading), steps * np.sin(heading)], 0)]))


@pytest.mark.parametrize("length, metres, window", [(2, 0.3, 3), (5, 1.0, 10), (4, 0.45, 2), (3, 5.0, 1)])
def test_sequences_over_travelled_distance_equal_a_plain_loop(seed, length, metres, window):
    rng = np.random.default_rng(seed)
    d = rng.random((17, 23)) * 3
    d[rng.random(d.shape) < 0.1] = np.inf  # pairs the method cannot compare
    d[4] = np.inf  # a query without the method's sensor
    query, reference = stop_and_go(rng, 17), stop_and_go(rng, 23)
    got = sequence_scores(d, length, window=window, metres=metres, poses=(query, reference))
    want = reference_odometry_scores(d, length, window, metres, query[:, :2], reference[:, :2])
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_sequences_over_travelled_distance_in_chunks_equal_the_whole_matrix(seed):
    from vitaplace.engine.evaluation.ranking import Rows
    from vitaplace.engine.evaluation.sequence import sequence_rows

    rng = np.random.default_rng(seed)
    d = rng.random((29, 11))
    poses = (stop_and_go(rng, 29), stop_and_go(rng, 11))
    whole = sequence_scores(d, 4, window=3, metres=0.6, poses=poses)
    rows = sequence_rows(Rows.of(d), 4, window=3, metres=0.6, poses=poses)
    for size in (1, 4, 7):
        np.testing.assert_array_equal(np.vstack([block for _, block in rows.chunks(size)]), whole)


def test_a_stop_changes_no_sequence_over_travelled_distance():
    # one drive 0.25 m a sample along x, straight through (5 samples) and standing at 0.5 m for
    # two more samples (7): the samples of the stop see what sample 2 saw
    through = np.random.default_rng(3).random((5, 8))
    stopped = through[[0, 1, 2, 2, 2, 3, 4]]
    at_stop = np.array([0.0, 0.25, 0.5, 0.5, 0.5, 0.75, 1.0])
    reference = poses_of(np.c_[np.arange(8) * 0.25, np.zeros(8)])
    s_through = sequence_scores(through, 3, metres=0.5, poses=(poses_of(np.c_[at_stop[[0, 1, 2, 5, 6]], np.zeros(5)]),
                                                              reference))
    s_stopped = sequence_scores(stopped, 3, metres=0.5, poses=(poses_of(np.c_[at_stop, np.zeros(7)]), reference))
    np.testing.assert_array_equal(s_stopped, s_through[[0, 1, 2, 2, 2, 3, 4]])
    # by hand: the last sample's points are 1.0, 0.75 and 0.5 m: samples 6, 5 and 4 (the later of
    # the three at 0.5 m); a stopped sample's own point is itself, not a later one
    assert points_back(at_stop, np.array([6, 3]), np.array([0.0, 0.25, 0.5])).tolist() == [[6, 5, 4], [3, 1, 0]]
    # reference 7 (1.75 m) has 1.75, 1.5, 1.25 m: the mean of contrast entries (6, 7), (5, 6), (4, 5)
    c = local_contrast(stopped, 10)
    assert s_stopped[6, 7] == pytest.approx((c[6, 7] + c[5, 6] + c[4, 5]) / 3, rel=1e-12)
    # the first sample has no drive behind it: its one point is itself
    assert s_stopped[0, 7] == pytest.approx(c[0, 7], rel=1e-12)
    # three samples back instead: the stop puts one place three times into the line, and it differs
    assert not np.allclose(sequence_scores(stopped, 3, (1.0, 1.0), 1)[5], sequence_scores(through, 3, (1.0, 1.0), 1)[3])


def test_metres_zero_is_the_distance_matrix_itself():
    d = np.random.default_rng(1).random((7, 9))
    rng = np.random.default_rng(2)
    assert np.array_equal(sequence_scores(d, 5, metres=0.0, poses=(stop_and_go(rng, 7), stop_and_go(rng, 9))), d)
    with pytest.raises(ValueError, match="metres needs the query and reference poses"):
        sequence_scores(d, 5, metres=1.0)


def test_metres_searches_no_velocities_and_keys_nothing_when_left_out():
    with pytest.raises(pydantic.ValidationError, match="velocities: searched only by a sequence of length samples"):
        SequenceSettings(metres=1.0, velocity_steps=3)
    # a dumped setting reads back (its velocities are the defaults, named)
    settings = SequenceSettings(metres=2.0, length=5)
    assert SequenceSettings.model_validate(settings.model_dump()) == settings
    assert "metres" not in SequenceSettings(length=5).model_dump()
    assert SequenceSettings(metres=2.0, length=5).model_dump()["metres"] == 2.0


@pytest.mark.parametrize("setting, message", [
    ("scoring.sequence.length=0", "scoring.sequence.length"),
    ("scoring.sequence.velocities=[1.5, 0.8]", "scoring.sequence: velocities: expected [slowest, fastest]"),
    ("scoring.sequence.velocities=[1.0, 1.0]", "scoring.sequence: velocities: an empty range"),
    ("scoring.sequence.velocities=[0, 1]", "scoring.sequence.velocities"),
    ("scoring.sequence.window=0", "scoring.sequence.window"),
    ("scoring.sequence.length=100000", "scoring.sequence.length"),
    ("scoring.sequence.metres=-1", "scoring.sequence.metres"),
])
def test_bad_sequence_settings_are_one_line_at_validate(capsys, setting, message):
    assert main(["validate", "quickstart", "--set", setting]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_velocities_may_be_one_value_when_one_step_is_tried():
    assert SequenceSettings(velocities=(1.0, 1.0), velocity_steps=1).velocities == (1.0, 1.0)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """The same tiny scenario (hand-crafted features, 12-sample route drives) run with single
    samples, with length 1 and every other sequence setting away from its default, with
    sequences of 3, and with sequences over 0 and 0.3 m of travelled distance."""
    tmp = tmp_path_factory.mktemp("sequence")
    out = {}
    for name, sequence in (("single", {}), ("seq3", {"sequence": {"length": 3}}),
                           ("metres0", {"sequence": {"length": 5, "metres": 0}}),
                           ("metres", {"sequence": {"length": 3, "metres": 0.3}}),
                           ("one",
                            {"sequence": {"length": 1, "velocities": [0.5, 2.0], "velocity_steps": 3, "window": 2}})):
        scenario = {
            "name": "tiny",
            "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
            "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 12}}],
            "methods": [{"name": "H", "plugin": "handcrafted"}],
            "scoring": {"tau": 0.3, "direction": "both", **sequence},
        }
        path = tmp / f"{name}.yaml"
        path.write_text(yaml.safe_dump(scenario))
        out[name] = tmp / name
        assert main(["run", str(path), "--out", str(out[name]), "--no-progress", "-q"]) == 0
    return out


def test_a_run_that_matches_sequences_scores_the_sequence_of_the_methods_distances(runs):
    rows = json.loads((runs["seq3"] / "results.json").read_text())
    assert len(rows) == 2
    for row in rows:
        span = row["sequence"].pop("window_span_m")
        assert row["sequence"] == {"length": 3, "velocity_min": 0.8, "velocity_max": 1.25, "velocity_steps": 5,
                                   "window": 10}
        folder = runs["seq3"] / "evaluations" / "E1" / "H" / row["direction"]
        with np.load(folder / "matrices.npz") as m:
            # the path length of the reference drive from j - 10 to j + 10, cut at its ends, median over j
            xy = m["reference_poses"][:, :2]
            lengths = [sum(np.hypot(*(xy[k + 1] - xy[k])) for k in range(max(j - 10, 0), min(j + 10, len(xy) - 1)))
                       for j in range(len(xy))]
            assert span == pytest.approx(np.median(lengths), rel=1e-9)
            scores = sequence_scores(m["distance"], 3)
            np.testing.assert_array_equal(m["tme"], scores)
            gtm = ground_truth_matrix(m["query_poses"], m["reference_poses"], 30.0)
        assert row["max_f1"] == pytest.approx(evaluate(scores, gtm, 0.3)["max_f1"])
    assert "scored by sequences of 3 queries" in (runs["seq3"] / "report.md").read_text()
    assert "sequences of" not in (runs["single"] / "report.md").read_text()
    # the method's own distances are those of the single-sample run
    for direction in ("query-to-reference", "reference-to-query"):
        with np.load(runs["seq3"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as a, \
                np.load(runs["single"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as b:
            np.testing.assert_array_equal(a["distance"], b["tme"])
            assert "distance" not in b.files


def test_length_one_scores_a_real_evaluation_exactly_as_single_samples(runs):
    # whatever the other sequence settings say: the same rows (every number bit for bit, no
    # `sequence` field) and the same saved matrices (no `distance` beside the TME)
    assert (json.loads((runs["one"] / "results.json").read_text())
            == json.loads((runs["single"] / "results.json").read_text()))
    for direction in ("query-to-reference", "reference-to-query"):
        with np.load(runs["one"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as a, \
                np.load(runs["single"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as b:
            assert sorted(a.files) == sorted(b.files)
            for name in a.files:
                assert a[name].tobytes() == b[name].tobytes(), name


def test_metres_zero_scores_a_real_evaluation_exactly_as_single_samples(runs):
    assert (json.loads((runs["metres0"] / "results.json").read_text())
            == json.loads((runs["single"] / "results.json").read_text()))
    for direction in ("query-to-reference", "reference-to-query"):
        with np.load(runs["metres0"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as a, \
                np.load(runs["single"] / "evaluations" / "E1" / "H" / direction / "matrices.npz") as b:
            assert sorted(a.files) == sorted(b.files)
            for name in a.files:
                assert a[name].tobytes() == b[name].tobytes(), name


def test_a_run_over_travelled_distance_scores_the_sequences_of_its_poses(runs):
    for row in json.loads((runs["metres"] / "results.json").read_text()):
        assert row["sequence"]["metres"] == 0.3 and row["sequence"]["length"] == 3
        with np.load(runs["metres"] / "evaluations" / "E1" / "H" / row["direction"] / "matrices.npz") as m:
            query, reference = m["query_poses"], m["reference_poses"]
            # the route samples closer than 0.15 m: the sequences reach samples before the query's
            assert np.diff(travelled(query)).max() < 0.15 and np.diff(travelled(reference)).max() < 0.15
            want = reference_odometry_scores(m["distance"], 3, 10, 0.3, query[:, :2], reference[:, :2])
            np.testing.assert_allclose(m["tme"], want, rtol=1e-9, atol=1e-9)
            gtm = ground_truth_matrix(query, reference, 30.0)
        assert row["max_f1"] == pytest.approx(evaluate(want, gtm, 0.3)["max_f1"])
    assert "scored by sequences of 3 points over 0.3 m of travelled distance" in (
        runs["metres"] / "report.md").read_text()


def test_a_changed_sequence_length_rescores_the_evaluations_and_nothing_before_them(runs, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(runs["single"], out)

    def rerun(*overrides: str) -> set[tuple[str, str]]:
        args = ["run", str(runs["single"].parent / "single.yaml"), "--out", str(out), "--no-progress", "-q"]
        for override in overrides:
            args += ["--set", override]
        assert main(args) == 0
        stages = json.loads((out / "manifest.json").read_text())["stages"]
        return {(s["stage"], s["item"]) for s in stages if s["status"] == "ran"}

    scored = {("evaluate", f"E1 H {d}") for d in ("query-to-reference", "reference-to-query")} | {("report", "report")}
    assert rerun("scoring.sequence.length=3") == scored
    assert json.loads((out / "results.json").read_text()) == json.loads((runs["seq3"] / "results.json").read_text())
    assert rerun("scoring.sequence.length=2") == scored
    assert {row["sequence"]["length"] for row in json.loads((out / "results.json").read_text())} == {2}


@pytest.mark.parametrize("run", ["single", "seq3"])
def test_sensitivity_rescores_a_run_as_the_sequence_run_scored_it(runs, tmp_path, run):
    # from the single-sample run's distances, and from the sequence run's own (not its scores)
    assert main(["sensitivity", str(runs[run]), "--sequence-length", "3", "--tau", "0.3", "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "sensitivity.json").read_text())
    assert record["sequence_length"] == 3
    for result in json.loads((runs["seq3"] / "results.json").read_text()):
        (own,) = [r for r in record["rows"]
                  if r["direction"] == result["direction"] and r["heading_tolerance_deg"] == 30.0]
        assert own["max_f1"] == pytest.approx(result["max_f1"])


def test_sensitivity_refuses_a_sequence_length_below_one_in_one_line(runs, tmp_path, capsys):
    assert main(["sensitivity", str(runs["single"]), "--sequence-length", "0", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--sequence-length" in err


def test_the_window_span_is_the_reference_path_length_the_window_covers():
    from vitaplace.engine.evaluation.pairfiles import window_span

    # 7 references 0.1 m apart on a line: +-2 references cover 0.4 m inside, 0.2 / 0.3 m at the ends
    poses = np.c_[np.arange(7) * 0.1, np.zeros(7), np.zeros(7)]
    assert window_span(poses, 2) == pytest.approx(np.median([0.2, 0.3, 0.4, 0.4, 0.4, 0.3, 0.2]))
    # standing still covers nothing; turning on the spot neither (the heading is not path)
    assert window_span(np.c_[np.zeros(5), np.zeros(5), np.linspace(0, 3, 5)], 2) == 0.0


@pytest.mark.parametrize("span, warned", [(0.6, True), (0.61, False)])
def test_the_report_warns_when_the_contrast_window_is_no_more_than_one_place(span, warned):
    from vitaplace.engine.outputs.rows import SequenceMatching
    from vitaplace.engine.report.report import _matching

    sequence = SequenceMatching(length=5, window=10, velocity_steps=5, velocity_min=0.8, velocity_max=1.25,
                                window_span_m=span)
    text = _matching(sequence, 0.3)
    assert f"a median {span:.2f} m of the reference drive" in text
    assert ("WARNING no more than one place (2τ = 0.6 m)" in text) is warned


@pytest.mark.parametrize("metres", [None, 1.0])
def test_on_noise_the_best_matches_do_not_gather_at_the_reference_runs_start(metres):
    """Distances of pure noise carry no place: every reference a full sequence can reach is as
    likely a best match as another. Lines cut short at the reference run's start average fewer
    terms, so they are more extreme and would win the lowest score by that alone (34 % of the
    best matches in the first 3 references, 56 % in the first 10 over travelled distance, before
    such lines stopped being candidates); the first 10 references that can be matched hold
    about 10 / 190 of them."""
    d = np.random.default_rng(3).random((200, 200))
    drive = poses_of(np.c_[np.arange(200) * 0.1, np.zeros(200)])  # 0.1 m a sample: 1 m back = 10 samples
    s = sequence_scores(d, 10, (1.0, 1.0), 1, 10, metres=metres, poses=None if metres is None else (drive, drive))
    full = s[10:]  # the queries with a whole sequence behind them
    first = 9 if metres is None else 10  # the first reference with a whole sequence behind it
    assert np.isinf(full[:, :first]).all() and np.isfinite(full[:, first:]).all()
    share = float(np.mean(np.argmin(full, axis=1) < first + 10))
    assert share < 0.15, share  # 10 of the 190-191 reachable references: 5 % expected


def test_a_window_wider_than_the_run_is_the_whole_row():
    """The contrast window is cut at the run's ends: a window of 1e13 references is the row,
    computed without building a 1e13-wide view (which ran out of memory)."""
    d = np.random.default_rng(4).random((5, 7))
    np.testing.assert_array_equal(local_contrast(d, 10**13), local_contrast(d, 7))


@pytest.mark.parametrize("sets, message", [
    (["scoring.sequence.velocities=[1.0, 2.0]"],
     "scoring.sequence.velocities: the fastest, 2, spans 6 references over a sequence of 4, not below the 6 samples "
     "of run E1/reference: no line at it fits the run"),
    (["scoring.sequence.metres=1000"],
     "scoring.sequence.metres: 1000 m is not below the"),
])
def test_sequences_that_cannot_fit_the_reference_run_are_one_line(tmp_path, capsys, sets, message):
    """A line that leaves the reference run is no candidate: a velocity or a distance no
    reference can have behind it would score nothing (or, at 1e308, an overflowing index)."""
    scenario = {"name": "tiny", "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 8}},
                "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 6}}],
                "methods": [{"name": "H", "plugin": "handcrafted"}],
                "scoring": {"tau": 0.3, "recall_k": [1], "sequence": {"length": 4}}, "report": {"figures": "none"}}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario))
    argv = ["-q", "evaluate", str(path), "--out", str(tmp_path / "out"), "--no-progress"]
    assert main(argv) == 0  # velocities 0.8-1.25: the fastest spans 3.75 references of 6
    capsys.readouterr()
    assert main([*argv, *sum((["--set", s] for s in sets), [])]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vitaplace: error: {message}"), lines
