"""`vitaplace sensitivity`: scores rescored from an evaluation's saved matrices for other
revisit and heading tolerances, checked against hand-computed PR curves and against the
evaluation's own result at its own setting."""

import csv
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from conftest import reseal  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.study.sensitivity import rescore  # noqa: E402

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"

# Three references on the x axis; r2 faces the other way (yaw pi).
REFERENCES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, math.pi]])
# q0 is 0.25 m from r0, q1 0.4 m from r1, q2 0.1 m from r2 but facing 180 degrees away.
QUERIES = np.array([[0.25, 0.0, 0.0], [1.4, 0.0, 0.0], [2.0, 0.1, 0.0]])
# Each query's best match is its own reference, accepted in the order q1 (0.1), q0 (0.2), q2 (0.3).
TME = np.array([[0.2, 5.0, 5.0], [5.0, 0.1, 5.0], [5.0, 5.0, 0.3]])

# (heading tolerance, tau) -> (n_revisit, max F1, recall at 100 % precision), by hand:
# position only, tau 0.2: only q2 is correct (n 1); q1, q0 accepted first and wrong, so
#   F1 peaks when all three are accepted: P 1/3, R 1 -> 0.5; precision 1 only with nothing accepted.
# position only, tau 0.3: q0 and q2 correct (n 2), q1 wrong and first: at delta 0.3 P 2/3, R 1 -> 0.8.
# position only, tau 0.5: all correct: F1 1 at delta 0.3, every prefix has precision 1.
# heading <= 30 deg: q2's only reference within reach faces away, so q2 has no match:
#   tau 0.2: no query has a match (n 0): recall and F1 are 0 everywhere;
#   tau 0.3: only q0 (n 1); q1 wrong first: at delta 0.2 P 1/2, R 1 -> 2/3;
#   tau 0.5: q0 and q1 (n 2), accepted first: F1 1 at delta 0.2, R 1 at precision 1.
EXPECTED = {
    (None, 0.2): (1, 0.5, 0.0),
    (None, 0.3): (2, 0.8, 0.0),
    (None, 0.5): (3, 1.0, 1.0),
    (30.0, 0.2): (0, 0.0, 0.0),
    (30.0, 0.3): (1, 2 / 3, 0.0),
    (30.0, 0.5): (2, 1.0, 1.0),
}


def test_rescore_matches_hand_computed_curves():
    rows = rescore(TME, QUERIES, REFERENCES, (0.2, 0.3, 0.5), (30.0, None))
    got = {(r["heading_tolerance_deg"], r["tau"]): (r["n_revisit"], r["max_f1"], r["recall_at_100_precision"])
           for r in rows}
    assert got.keys() == EXPECTED.keys()
    for key, (n, f1, r100) in EXPECTED.items():
        assert got[key][0] == n, key
        assert got[key][1:] == pytest.approx((f1, r100)), key


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    """A finished tiny run (hand-crafted features, 5-sample runs) evaluated in both directions."""
    import yaml

    tmp = tmp_path_factory.mktemp("sensitivity")
    scenario = {
        "name": "tiny",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "H", "plugin": "handcrafted"}],
        "scoring": {"tau": 0.3, "heading_tolerance_deg": 30.0, "direction": "both"},
    }
    path = tmp / "tiny.yaml"
    path.write_text(yaml.safe_dump(scenario))
    out = tmp / "run"
    assert main(["run", str(path), "--out", str(out), "--no-progress", "-q"]) == 0
    return out


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_command_reproduces_the_evaluation_at_its_own_setting(run_folder, tmp_path):
    import json

    assert main(["sensitivity", str(run_folder), "--out", str(tmp_path)]) == 0
    rows = read_csv(tmp_path / "sensitivity.csv")
    assert len(rows) == 2 * 3 * 2  # directions x taus x heading tolerances
    assert {r["direction"] for r in rows} == {"query-to-reference", "reference-to-query"}
    for result in json.loads((run_folder / "results.json").read_text()):
        (own,) = [r for r in rows if r["direction"] == result["direction"] and float(r["tau"]) == 0.3
                  and r["heading_tolerance_deg"] == "30.0"]
        assert float(own["max_f1"]) == pytest.approx(result["max_f1"])
        assert float(own["recall_at_100_precision"]) == pytest.approx(result["recall_at_100_precision"])
        assert int(own["n_revisit"]) == result["n_revisit"]
    assert "position only" in (tmp_path / "sensitivity.md").read_text()
    record = json.loads((tmp_path / "sensitivity.json").read_text())
    assert record["seeds"] == [0] and len(record["rows"]) == len(rows)


def test_a_sweep_folder_reads_its_seed_folders(run_folder, tmp_path):
    sweep = tmp_path / "sweep"
    shutil.copytree(run_folder, sweep / "seed-0")
    assert main(["sensitivity", str(sweep)]) == 0
    assert main(["sensitivity", str(run_folder), "--out", str(tmp_path / "single")]) == 0
    assert (sweep / "sensitivity.csv").read_bytes() == (tmp_path / "single" / "sensitivity.csv").read_bytes()


def test_user_errors_are_one_line(run_folder, tmp_path, capsys):
    old = tmp_path / "old"
    shutil.copytree(run_folder, old)
    matrices = old / "evaluations" / "E1" / "H" / "query-to-reference" / "matrices.npz"
    with np.load(matrices) as saved:
        np.savez_compressed(matrices, tme=saved["tme"], gtm=saved["gtm"])  # as evaluate stage 3 saved it
    reseal(old)  # its run recorded the file as it saved it
    cases = {
        "no query_poses": ["sensitivity", str(old)],
        "expected positive distances": ["sensitivity", str(run_folder), "--tau", "0", "--out",
                                        str(tmp_path / "fresh")],
        "neither a run folder": ["sensitivity", str(tmp_path / "nothing")],
    }
    (tmp_path / "nothing").mkdir()
    for message, args in cases.items():
        assert main(args) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], lines
    assert not (old / "sensitivity.csv").exists()


def test_a_tolerance_given_twice_is_one_line_naming_the_option(run_folder, tmp_path, capsys):
    """`--tau 0.3 0.3` scored the one seed twice: sensitivity.md said 1 seed, its rows n = 2 and
    sensitivity.csv held every row twice. As `sweep --grid` and `--seeds`: each value once
    (0.3 and 0.30 are one distance)."""
    out = tmp_path / "out"
    assert main(["sensitivity", str(run_folder), "--tau", "0.3", "0.5", "0.30", "--out", str(out)]) == 2
    assert _one_line(capsys, "--tau: ").endswith("the value 0.3 is given more than once (0.3, 0.3)")
    assert not out.exists()


def test_a_tolerance_not_below_the_arena_s_diagonal_is_refused_as_the_scenario_refuses_it(run_folder, tmp_path,
                                                                                         capsys):
    """`--tau 1e9` was scored although `--set scoring.tau=1e9` is refused: every pair of poses
    would count as a revisit. E1 is 6.05 m square: its diagonal is 6.05 * sqrt(2) = 8.556 m,
    so 9 is refused, in the words scenario validation uses, and 8.55 is scored."""
    out = tmp_path / "out"
    assert main(["sensitivity", str(run_folder), "--tau", "0.3", "9", "--out", str(out)]) == 2
    line = _one_line(capsys, "--tau: 9.0 m is not below the 8.56 m diagonal of e1: every pair of poses would count "
                             "as a revisit")
    assert not out.exists()  # refused before the output folder is made
    assert main(["validate", str(run_folder / "scenario.resolved.yaml"), "--set", "scoring.tau=9"]) == 2
    assert _one_line(capsys, "scoring.tau: ").partition("scoring.tau: ")[2] == line.partition("--tau: ")[2]
    assert main(["sensitivity", str(run_folder), "--tau", "8.55", "--out", str(out)]) == 0


Q2R = Path("evaluations") / "E1" / "H" / "query-to-reference" / "matrices.npz"


def _one_line(capsys, message: str) -> str:
    """The one line of stderr, which must contain ``message`` and no traceback."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and message in lines[0], lines
    return lines[0]


def _other_scenario(run_folder: Path, folder: Path) -> Path:
    """A finished run of another scenario (tau 0.4), as its own run would have sealed it."""
    import yaml

    shutil.copytree(run_folder, folder)
    resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
    resolved["scoring"]["tau"] = 0.4
    (folder / "scenario.resolved.yaml").write_text(yaml.safe_dump(resolved))
    reseal(folder)
    return folder


def test_a_sweep_folder_holds_one_scenario_each_seed_once(run_folder, tmp_path, capsys):
    """As `aggregate`: a seed folder copied under another name is seed 0 twice; a run of
    another scenario among the seeds is refused, naming it; nothing is written."""
    twice = tmp_path / "twice"
    shutil.copytree(run_folder, twice / "seed-0")
    shutil.copytree(run_folder, twice / "seed-7")
    assert main(["sensitivity", str(twice)]) == 2
    line = _one_line(capsys, "seed 0 again")
    assert str(twice / "seed-7") in line
    mixed = tmp_path / "mixed"
    shutil.copytree(run_folder, mixed / "seed-0")
    _other_scenario(run_folder, mixed / "seed-1")
    assert main(["sensitivity", str(mixed)]) == 2
    assert str(mixed / "seed-1") in _one_line(capsys, "differs from")
    assert not list(tmp_path.rglob("sensitivity.*"))


def test_matrices_changed_since_the_run_are_refused(run_folder, tmp_path, capsys):
    """A TME replaced by another of the same keys and shape no longer has the digest
    completed.json recorded for it; nor has a truncated file."""
    for case in ("replaced", "truncated"):
        folder = tmp_path / case
        shutil.copytree(run_folder, folder)
        path = folder / Q2R
        if case == "replaced":
            with np.load(path) as saved:
                arrays = dict(saved)
            np.savez_compressed(path, **{**arrays, "tme": arrays["tme"][::-1].copy()})
        else:
            path.write_bytes(path.read_bytes()[:100])
        assert main(["sensitivity", str(folder)]) == 2
        _one_line(capsys, f"not a finished run: {Q2R} is not the file its finished run recorded")
        assert not (folder / "sensitivity.csv").exists()


def _rewrite(path: Path, **arrays) -> None:
    with np.load(path) as saved:
        np.savez_compressed(path, **{**dict(saved), **arrays})


# damaged matrices, recorded so in completed.json (as if the run itself had written them)
DAMAGED = {
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[:100]), "unreadable matrices (BadZipFile"),
    "a 3 x 3 TME": (lambda p: _rewrite(p, tme=np.zeros((3, 3))),
                    "tme of shape (3, 3) (or not finite), expected a finite 5 x 5"),
    "an all-NaN TME": (lambda p: _rewrite(p, tme=np.full((5, 5), np.nan)), "tme of shape (5, 5) (or not finite)"),
    "NaN poses": (lambda p: _rewrite(p, query_poses=np.full((5, 3), np.nan)),
                  "query_poses of shape (5, 3) (or not finite), expected finite N x 3"),
}


@pytest.mark.parametrize("case", sorted(DAMAGED))
def test_damaged_matrices_recorded_so_are_one_line(run_folder, tmp_path, capsys, case):
    damage, message = DAMAGED[case]
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    damage(folder / Q2R)
    reseal(folder)
    assert main(["sensitivity", str(folder)]) == 2
    assert str(folder / Q2R) in _one_line(capsys, message)
    assert not (folder / "sensitivity.csv").exists()


def test_a_failed_seed_is_left_out_with_one_line(run_folder, tmp_path, capsys):
    """A seed folder holding the sweep's error.txt (a failed seed) is left out, in one line,
    exit 1, as `sweep` does; the others are rescored as if it were not there."""
    sweep = tmp_path / "sweep"
    shutil.copytree(run_folder, sweep / "seed-0")
    (sweep / "seed-1").mkdir()
    (sweep / "seed-1" / "error.txt").write_text("Traceback (most recent call last):\n  ...\nValueError: injected\n")
    assert main(["sensitivity", str(sweep)]) == 1
    _one_line(capsys, "seed-1 failed, left out: ValueError: injected")
    assert main(["sensitivity", str(run_folder), "--out", str(tmp_path / "single")]) == 0
    assert (sweep / "sensitivity.csv").read_bytes() == (tmp_path / "single" / "sensitivity.csv").read_bytes()
    import json

    assert json.loads((sweep / "sensitivity.json").read_text())["failed"] == {"seed-1": "ValueError: injected"}


def test_an_out_that_cannot_be_written_is_one_line_before_reading(run_folder, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    for out in (blocker, blocker / "sub"):
        assert main(["sensitivity", str(run_folder), "--out", str(out)]) == 2
        _one_line(capsys, f"--out {out}")
    assert blocker.read_text() == ""


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_out_is_one_line(run_folder, tmp_path, capsys):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o500)
    assert main(["sensitivity", str(run_folder), "--out", str(out)]) == 2
    _one_line(capsys, f"--out {out}: cannot write there")
