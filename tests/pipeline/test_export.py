"""`vitaplace export`: a scenario's evaluations in the layout VPR tools read, and its runs as a
checksummed package read back by `read_package`. The touch benchmark is exported at a small
size and every file is checked against the stage cache's runs and the ground truth worked out
here from the poses."""

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.config.loading import load_scenario  # noqa: E402
from vitaplace.engine.data.dataset import FIELDS, open_run  # noqa: E402
from vitaplace.engine.export import read_package  # noqa: E402
from vitaplace.engine.export.common import ExportError, ground_truth  # noqa: E402
from vitaplace.engine.export.vpr import image_name  # noqa: E402

#: the touch benchmark's heading tolerance, and a tau that finds true matches in drives this short
TAU, HEADING = 1.5, 30.0
EVALUATIONS = ["alike-boxes", "alike-shapes", "distinct-boxes", "distinct-shapes", "distinct-shapes-dusk",
               "distinct-shapes-dropout"]
#: the touch benchmark at a small size: a few samples a run, one whisk cycle's sample each
SMALL = ["train.run.n_samples=5", f"scoring.tau={TAU}", *(f"evaluations.{i}.run.{key}" for i in range(len(EVALUATIONS))
                                   for key in ("n_samples=6", "hold_cycles=[1,1]", "sample_at=cycle"))]
SETS = [arg for assignment in SMALL for arg in ("--set", assignment)]


def true_matches_by_hand(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(Q, R) bool: within TAU metres and headings within HEADING degrees (wrapped), a loop per pair."""
    true = np.zeros((len(query), len(reference)), dtype=bool)
    for i, (qx, qy, qyaw) in enumerate(query):
        for j, (rx, ry, ryaw) in enumerate(reference):
            turn = abs(math.degrees(math.remainder(qyaw - ryaw, 2 * math.pi)))
            true[i, j] = math.hypot(qx - rx, qy - ry) <= TAU and turn <= HEADING
    return true


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The small touch benchmark exported in both formats: (export folder, stage folder)."""
    root = tmp_path_factory.mktemp("export")
    out, runs = root / "out", root / "runs"
    assert main(["-q", "export", "touch-benchmark", *SETS, "--out", str(out), "--runs", str(runs)]) == 0
    return out, runs


def cached_run(runs: Path, label: str):
    """The run file of ``label`` that the simulate stage recorded into the stage folder ``runs``."""
    (path,) = (runs / "cache" / "datasets").glob(f"{label.replace('/', '-')}-*.h5")
    return open_run(path)


def test_a_file_name_holds_position_index_heading_and_time_by_hand():
    name = image_name(3, np.array([1.2345678, -0.25, -math.pi / 2]), 1.5)
    assert name == "@1.234568@-0.250000@@@@@00003@@270.0000@@@@1.500@@.png"
    fields = name.split("@")  # as VPR-methods-evaluation splits a path: east [1], north [2]
    assert (float(fields[1]), float(fields[2]), fields[-1]) == (1.234568, -0.25, ".png")


def test_the_ground_truth_is_the_benchmarks_rule_by_hand():
    scenario, _ = load_scenario("touch-benchmark", [])
    query = np.array([[0.0, 0.0, 0.0]])
    reference = np.array([[0.2, 0.0, 0.0],  # near, same heading: a true match
                          [0.2, 0.0, math.pi],  # near, facing away
                          [0.0, 0.4, 0.0],  # same heading, too far
                          [0.3, 0.0, math.radians(30)],  # both bounds themselves: a true match
                          [0.0, 0.1, math.radians(-31)]])  # just past the heading tolerance
    gtm, true = ground_truth(scenario, query, reference)
    assert true.tolist() == [[True, False, False, True, False]]
    assert gtm[0, 0] == pytest.approx(0.2) and gtm[0, 1] == np.inf and gtm[0, 2] == pytest.approx(0.4)


@pytest.mark.slow
def test_the_package_reads_back_the_runs_and_ground_truth(exported):
    out, runs = exported
    package = read_package(out / "package")
    labels = ["train", *(f"{e}/{side}" for e in EVALUATIONS for side in ("query", "reference"))]
    assert list(package.runs) == labels
    for label in labels:
        cached, read = cached_run(runs, label), package.runs[label]
        for key in FIELDS:
            assert np.array_equal(read._get(key), cached._get(key)), (label, key)
        assert read.attrs == cached.attrs
    manifest = json.loads((runs / "manifest.json").read_text())
    sheet = package.datasheet
    assert sheet["format_version"] == 1 and sheet["scenario"] == "touch-benchmark"
    assert sheet["ground_truth_rule"] == {"tau_m": TAU, "heading_tolerance_deg": HEADING}
    assert {label: run["seed"] for label, run in sheet["runs"].items()} == manifest["run_seeds"]
    assert {label: run["samples"] for label, run in sheet["runs"].items()} == {
        label: 5 if label == "train" else 6 for label in labels}
    assert sheet["settings"]["evaluations"][0]["run"]["n_samples"] == 6  # the resolved scenario, --set applied
    assert (out / "package" / "datasheet.md").read_text().startswith("# touch-benchmark: a vitaplace benchmark")
    dropped = manifest["dropout"]["distinct-shapes-dropout/query"]["camera"]
    matches, near = 0, 0
    for e in EVALUATIONS:
        q, r = package.runs[f"{e}/query"].poses, package.runs[f"{e}/reference"].poses
        truth = package.ground_truth[e]
        assert np.array_equal(truth["true_match"], true_matches_by_hand(q, r)), e
        finite = np.isfinite(truth["gtm"])
        assert np.allclose(truth["gtm"][finite], np.linalg.norm(q[:, None, :2] - r[None, :, :2], axis=2)[finite])
        lacks = np.flatnonzero(truth["query_lacks_camera"]).tolist()
        assert lacks == (dropped if e == "distinct-shapes-dropout" else []), e
        assert not truth["query_lacks_whiskers"].any()
        assert sheet["evaluations"][e]["true_matches"] == int(truth["true_match"].sum())
        matches += int(truth["true_match"].sum())
        near += int((np.linalg.norm(q[:, None, :2] - r[None, :, :2], axis=2) <= TAU).sum())
    assert 0 < matches < near  # true matches, and pairs within tau that face apart
    assert dropped  # a quarter of 6 queries lack the camera


@pytest.mark.slow
def test_the_ground_truth_is_the_evaluations(exported, tmp_path):
    """The package's ground truth is what the evaluate stage scores with, run on the same cached
    runs (a copy of the export's cache: evaluating in the export's own runs folder would make
    the next export carry on to the evaluate stage there)."""
    out, runs = exported
    evaluated = tmp_path / "evaluated"
    shutil.copytree(runs / "cache", evaluated / "cache")
    method = ["--set", "methods=[{name: H, plugin: handcrafted}]", "--set", "fusions=[]"]
    assert main(["-q", "evaluate", "touch-benchmark", *SETS, *method, "--out", str(evaluated), "--no-progress"]) == 0
    package = read_package(out / "package")
    for e in EVALUATIONS:
        with np.load(evaluated / "evaluations" / e / "H" / "query-to-reference" / "matrices.npz") as matrices:
            assert np.array_equal(package.ground_truth[e]["gtm"], matrices["gtm"]), e


@pytest.mark.slow
def test_the_vpr_layout_parses_back_to_the_poses_images_and_positives(exported):
    out, runs = exported
    for e in EVALUATIONS:
        folder = out / "vpr" / e
        poses = {}
        for side, role in (("database", "reference"), ("queries", "query")):
            run = cached_run(runs, f"{e}/{role}")
            names = (folder / "images" / "test" / f"{side}_images_paths.txt").read_text().splitlines()
            assert len(names) == len(run) == len(list((folder / "images" / "test" / side).iterdir()))
            for i, name in enumerate(names):
                fields = name.split("@")
                x, y, heading = float(fields[1]), float(fields[2]), float(fields[9])
                assert abs(x - run.poses[i, 0]) <= 5e-7 and abs(y - run.poses[i, 1]) <= 5e-7
                turn = math.remainder(math.radians(heading) - run.poses[i, 2], 2 * math.pi)
                assert abs(turn) <= math.radians(5e-5) and 0 <= heading < 360
                assert int(fields[7]) == i and float(fields[13]) == pytest.approx(run.times[i], abs=5e-4)
                with Image.open(folder / "images" / "test" / side / name) as image:
                    assert np.array_equal(np.asarray(image), run.images[i])  # lossless
            poses[role] = run.poses
        true = true_matches_by_hand(poses["query"], poses["reference"])
        positives = json.loads((folder / "positives.json").read_text())
        assert positives["positives"] == [np.flatnonzero(row).tolist() for row in true]
        assert (positives["tau_m"], positives["heading_tolerance_deg"]) == (TAU, HEADING)
        with np.load(folder / "ground_truth.npz") as gt:
            assert np.array_equal(gt["GThard"], true.T) and np.array_equal(gt["GTsoft"], true.T)
            lacks = gt["query_lacks_camera"]
        assert np.flatnonzero(lacks).tolist() == positives["queries_lacking_camera"]


@pytest.mark.slow
def test_a_changed_missing_or_unlisted_file_is_refused_naming_it(exported, tmp_path):
    out, _ = exported
    package = tmp_path / "package"
    shutil.copytree(out / "package", package)
    run = package / "runs" / "alike-boxes" / "query.h5"
    data = bytearray(run.read_bytes())
    data[len(data) // 2] ^= 0xFF
    run.write_bytes(bytes(data))
    with pytest.raises(ExportError, match=rf"^{run}: its SHA-256 differs from SHA256SUMS"):
        read_package(package)
    shutil.copy(out / "package" / "runs" / "alike-boxes" / "query.h5", run)
    truth = package / "ground_truth" / "alike-shapes.npz"
    truth.unlink()
    with pytest.raises(ExportError, match=rf"^{truth}: listed in SHA256SUMS but missing$"):
        read_package(package)
    shutil.copy(out / "package" / "ground_truth" / "alike-shapes.npz", truth)
    sums = package / "SHA256SUMS"
    sums.write_text("".join(line + "\n" for line in sums.read_text().splitlines() if "alike-shapes.npz" not in line))
    with pytest.raises(ExportError, match=rf"^{truth}: not listed in {sums}$"):
        read_package(package)
    sums.write_text(f"{'0' * 64}  ../outside.h5\n")  # a file outside the package
    with pytest.raises(ExportError, match=rf"^{sums}: line 1 is not '<sha256>  <file in the package>'$"):
        read_package(package)
    sums.unlink()
    with pytest.raises(ExportError, match=rf"^{sums}: missing"):
        read_package(package)


@pytest.mark.slow
def test_out_must_be_empty_or_an_export_of_the_same_format(exported, tmp_path, capsys):
    out, runs = exported
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    for folder, fmt in ((foreign, "both"), (out, "vpr")):  # not an export; an export of another format
        capsys.readouterr()
        assert main(["-q", "export", "touch-benchmark", *SETS, "--out", str(folder), "--runs", str(runs),
                     "--format", fmt]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"vitaplace: error: --out {folder}: not empty and not a vitaplace "
                                                   f"export of format {'vpr+package' if fmt == 'both' else fmt}")
    assert (foreign / "notes.txt").read_text() == "mine"
    assert main(["-q", "export", "touch-benchmark", *SETS, "--out", str(runs), "--runs", str(runs)]) == 2
    assert "--runs" in capsys.readouterr().err
    # an export of the same format is replaced, from the cached runs
    stale = out / "vpr" / "alike-boxes" / "stale.txt"
    stale.write_text("old")
    assert main(["-q", "export", "touch-benchmark", *SETS, "--out", str(out), "--runs", str(runs)]) == 0
    assert not stale.exists()
    read_package(out / "package")


@pytest.mark.parametrize("runs, out", [("", "exp2"), (".", "/elsewhere"), ("exp1/sub", "exp1"),
                                       ("exprun", "exprun/sub"), ("same", "same")])
def test_runs_must_be_a_folder_of_its_own_apart_from_out(tmp_path, monkeypatch, capsys, runs, out):
    """An empty --runs is the current folder, which the runs would be written into; --runs
    inside --out makes --out a folder the export refuses, --out inside --runs puts the export
    in a run folder whose claim cleans it: each refused in one line before anything is written."""
    monkeypatch.chdir(tmp_path)
    out = str(tmp_path / "elsewhere") if out == "/elsewhere" else out
    assert main(["-q", "export", "touch-benchmark", *SETS, "--out", out, "--runs", runs]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    if runs in ("", "."):
        assert err[0].startswith("vitaplace: error: --runs .: an empty path or the current folder; expected a folder")
    else:
        assert err[0] == (f"vitaplace: error: --runs {runs}, --out {out}: the folder the runs are recorded into must "
                          "lie apart from --out, neither inside the other")
    assert list(tmp_path.iterdir()) == []


def test_a_package_file_the_checksums_do_not_list_is_refused_naming_it(tmp_path):
    """SHA256SUMS holds every other file (docs/DATA.md): a datasheet.md it lacks, or a run or
    ground truth added beside the listed ones, is refused naming the file."""
    import hashlib

    package = tmp_path / "package"
    package.mkdir()
    (package / "datasheet.json").write_text(json.dumps({"format_version": 1, "runs": {}, "evaluations": {}}))
    sums = package / "SHA256SUMS"
    sums.write_text(f"{hashlib.sha256((package / 'datasheet.json').read_bytes()).hexdigest()}  datasheet.json\n")
    assert read_package(package).runs == {}  # every file listed
    for extra in ("datasheet.md", "runs/E1/extra.h5", "ground_truth/E2.npz"):
        (package / extra).parent.mkdir(parents=True, exist_ok=True)
        (package / extra).write_text("unlisted")
        with pytest.raises(ExportError, match=rf"^{package / extra}: not listed in {sums}$"):
            read_package(package)
        (package / extra).unlink()
    sheet = {"format_version": 1, "runs": {"train": {"file": "runs/train.h5"}}, "evaluations": {}}
    (package / "datasheet.json").write_text(json.dumps(sheet))  # names a run neither there nor listed
    sums.write_text(f"{hashlib.sha256((package / 'datasheet.json').read_bytes()).hexdigest()}  datasheet.json\n")
    with pytest.raises(ExportError, match=rf"^{package / 'runs' / 'train.h5'}: not listed in {sums}$"):
        read_package(package)


@pytest.mark.parametrize("folder", [3, None, ["package"]])
def test_read_package_of_something_that_is_no_path_is_one_line(folder):
    with pytest.raises(ExportError, match=r"^folder=.*: expected the path of a package folder \(text or a Path\)$"):
        read_package(folder)


def test_runs_holding_a_runs_results_are_refused_untouched(tmp_path, capsys):
    """Recording the runs into a finished run folder would prune its results as stale: --runs
    there is refused in one line before anything is written."""
    finished = tmp_path / "R"
    finished.mkdir()
    (finished / ".vitaplace.lock").write_text("1")
    (finished / "results.json").write_text("[]")
    assert main(["-q", "export", "touch-benchmark", *SETS, "--out", str(tmp_path / "X"), "--runs", str(finished)]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"vitaplace: error: --runs {finished}: holds a run's results (results.json); expected a folder for the "
        "recorded runs alone (default: runs/<scenario name>-export)"]
    assert sorted(p.name for p in finished.iterdir()) == [".vitaplace.lock", "results.json"]
    assert not (tmp_path / "X").exists()
