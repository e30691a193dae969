"""Importing MultiPredNet/WhiskEye MATLAB recordings (images/theta/xy/poses .mat files)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from vitaplace.engine.data.dataset import DatasetError, open_run, write_run
from vitaplace.engine.data.matimport import import_mat


def write_layout(folder, n=7, seed=0, images_as_cell=False, float_images=False):
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, size=(45, 80, 3, n), dtype=np.uint8)
    theta = rng.normal(size=(4, 6, n))
    xy = rng.normal(size=(2, 4, 6, n))
    poses = rng.normal(size=(n, 3))
    if images_as_cell:
        cell = np.empty((1, n), dtype=object)
        for i in range(n):
            cell[0, i] = images[..., i]
        scipy.io.savemat(folder / "images.mat", {"images": cell})
    elif float_images:
        scipy.io.savemat(folder / "images.mat", {"images": images / 255.0})
    else:
        scipy.io.savemat(folder / "images.mat", {"images": images})
    scipy.io.savemat(folder / "theta.mat", {"theta": theta})
    scipy.io.savemat(folder / "xy.mat", {"xy": xy})
    scipy.io.savemat(folder / "poses.mat", {"pose_return": poses})  # named as in extract_poses.m
    return images, theta, xy, poses


@pytest.mark.parametrize("variant", ["array", "cell", "float"])
def test_import_shapes_and_values(tmp_path, variant):
    images, theta, xy, poses = write_layout(
        tmp_path, images_as_cell=variant == "cell", float_images=variant == "float"
    )
    run = import_mat(tmp_path)
    n = 7
    assert len(run) == n
    assert run.images.shape == (n, 45, 80, 3) and run.images.dtype == np.uint8
    assert run.theta.shape == (n, 24) and run.xy.shape == (n, 24, 2) and run.poses.shape == (n, 3)
    assert np.array_equal(run.images[3], images[..., 3])
    # whisker (column c, board r) -> index r * 4 + c
    for c, r, i in [(0, 0, 0), (3, 0, 3), (0, 1, 4), (2, 5, 22), (3, 5, 23)]:
        assert run.theta[4, r * 4 + c] == pytest.approx(theta[c, r, 4], rel=1e-6)
        assert run.xy[4, r * 4 + c, 0] == pytest.approx(xy[0, c, r, 4], rel=1e-6)
        assert run.xy[4, r * 4 + c, 1] == pytest.approx(xy[1, c, r, 4], rel=1e-6)
        del i
    assert np.allclose(run.poses, poses)
    assert run.deflection.shape == (n, 1, 24, 2)
    assert run.contact_offsets.tolist() == [0] * (n + 1)
    # and it can be stored like a simulated run
    back = open_run(write_run(tmp_path / "out" / "real.h5", run))
    assert np.array_equal(back.theta, run.theta)


def test_poses_as_3_by_n_and_plain_name(tmp_path):
    _, _, _, poses = write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "poses.mat", {"poses": poses.T})
    assert np.allclose(import_mat(tmp_path).poses, poses)


def test_missing_file(tmp_path):
    write_layout(tmp_path)
    (tmp_path / "xy.mat").unlink()
    with pytest.raises(DatasetError, match=r"xy\.mat: missing MATLAB file"):
        import_mat(tmp_path)


def test_misshaped_theta(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "theta.mat", {"theta": np.zeros((6, 4, 7))})
    with pytest.raises(DatasetError, match=r"theta\.mat: variable 'theta' has shape \(6, 4, 7\), expected 4 x 6 x N"):
        import_mat(tmp_path)


def test_sample_count_mismatch(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "poses.mat", {"poses": np.zeros((5, 3))})
    with pytest.raises(DatasetError, match="different numbers of samples.*poses.mat 5"):
        import_mat(tmp_path)


def test_an_empty_pose_array_is_one_line(tmp_path, capsys):
    from vitaplace.engine.cli.main import main

    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "poses.mat", {"poses": np.zeros((0, 3))})
    assert main(["import", str(tmp_path), "--out", str(tmp_path / "run.h5")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"vitaplace: error: {tmp_path / 'poses.mat'}: variable 'poses' holds no samples; "
                           "expected at least one")
    assert not (tmp_path / "run.h5").exists()


def test_ambiguous_and_garbage_files(tmp_path):
    write_layout(tmp_path)
    scipy.io.savemat(tmp_path / "xy.mat", {"a": np.zeros((2, 4, 6, 7)), "b": np.zeros(3)})
    with pytest.raises(DatasetError, match=r"xy\.mat: cannot tell which variable holds xy"):
        import_mat(tmp_path)
    (tmp_path / "xy.mat").write_text("garbage")
    with pytest.raises(DatasetError, match=r"xy\.mat: not a readable MATLAB \.mat file"):
        import_mat(tmp_path)
    with pytest.raises(DatasetError, match="not a folder"):
        import_mat(tmp_path / "nowhere")


# --------------------------------------------------------------------------- `vitaplace import`
# Every accepted layout is written here the way MATLAB writes it and imported through the CLI;
# the expected arrays are the ones written, indexed by hand (whisker (column c, board r) -> r * 4 + c).

import json  # noqa: E402

import h5py  # noqa: E402
import yaml  # noqa: E402

from vitaplace.engine.cli.main import main  # noqa: E402

N = 7
#: MATLAB's class names of the numpy dtypes written below.
MATLAB_CLASS = {np.dtype(np.uint8): "uint8", np.dtype(np.float64): "double"}


def recording(seed=0, n=N):
    """Arrays as MATLAB holds them: images 45 x 80 x 3 x N, theta 4 x 6 x N, xy 2 x 4 x 6 x N,
    poses N x 3. Floats are float32-exact, so the float32 run file stores them unchanged."""
    rng = np.random.default_rng(seed)
    f32 = lambda shape: rng.normal(size=shape).astype(np.float32).astype(np.float64)  # noqa: E731
    images = rng.integers(0, 256, size=(45, 80, 3, n), dtype=np.uint8)
    return images, f32((4, 6, n)), f32((2, 4, 6, n)), rng.normal(size=(n, 3))


def as_cell(images):
    """A 1 x N MATLAB cell array of the 45 x 80 x 3 frames."""
    cell = np.empty((1, images.shape[-1]), dtype=object)
    for i in range(images.shape[-1]):
        cell[0, i] = images[..., i]
    return cell


def savemat73(path, name, value):
    """A MATLAB v7.3 file as MATLAB writes one: HDF5 after a 512-byte MAT header, every array
    stored with its dimensions reversed and a ``MATLAB_class`` attribute, a cell array as an
    array of object references to its elements under ``#refs#``."""
    with h5py.File(path, "w", userblock_size=512) as f:
        if value.dtype == object:
            refs = f.create_group("#refs#")
            table = np.empty(value.shape[::-1], dtype=h5py.ref_dtype)
            for index, element in np.ndenumerate(value):
                element = np.asarray(element)
                target = refs.create_dataset(f"r{len(refs)}", data=element.T)
                target.attrs["MATLAB_class"] = np.bytes_(MATLAB_CLASS[element.dtype])
                table[index[::-1]] = target.ref
            f.create_dataset(name, data=table).attrs["MATLAB_class"] = np.bytes_("cell")
        else:
            f.create_dataset(name, data=value.T).attrs["MATLAB_class"] = np.bytes_(MATLAB_CLASS[value.dtype])
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with open(path, "r+b") as f:
        f.write(header.ljust(116) + b"\0" * 8 + b"\x00\x02IM")


def save(folder, file, name, value, version):
    if version == "v7.3":
        savemat73(folder / file, name, value)
    else:
        scipy.io.savemat(folder / file, {name: value})


def write_recording(folder, version="v5", cell=False, pose_return=False, seed=0, n=N):
    folder.mkdir(parents=True, exist_ok=True)
    images, theta, xy, poses = recording(seed, n)
    save(folder, "images.mat", "images", as_cell(images) if cell else images, version)
    save(folder, "theta.mat", "theta", theta, version)
    save(folder, "xy.mat", "xy", xy, version)
    if pose_return:  # extract_poses.m's output saved as it is named
        save(folder, "pose_return.mat", "pose_return", poses, version)
    else:
        save(folder, "poses.mat", "poses", poses, version)
    return images, theta, xy, poses


LAYOUTS = [(v, cell, pose_return) for v in ("v5", "v7.3") for cell in (False, True) for pose_return in (False, True)]


@pytest.mark.parametrize("version,cell,pose_return", LAYOUTS)
def test_import_every_layout_through_the_cli(tmp_path, capsys, version, cell, pose_return):
    images, theta, xy, poses = write_recording(tmp_path / "rec", version, cell, pose_return)
    out = tmp_path / "runs" / "real.h5"
    assert main(["import", str(tmp_path / "rec"), "--out", str(out)]) == 0
    assert f"imported {N} samples" in capsys.readouterr().out
    assert [p.name for p in out.parent.iterdir()] == ["real.h5"]  # no temporary left behind
    run = open_run(out)
    assert len(run) == N and run.name == "rec"
    for i in range(N):
        assert np.array_equal(run.images[i], images[:, :, :, i])
        for r in range(6):
            for c in range(4):
                assert run.theta[i, r * 4 + c] == theta[c, r, i]
                assert run.xy[i, r * 4 + c, 0] == xy[0, c, r, i] and run.xy[i, r * 4 + c, 1] == xy[1, c, r, i]
    assert np.array_equal(run.poses, poses)
    assert run.deflection.shape == (N, 1, 24, 2) and np.array_equal(run.deflection[:, 0], run.xy)
    assert run.contact_offsets.tolist() == [0] * (N + 1)


def test_v73_single_frame_and_float_images(tmp_path):
    """MATLAB drops a trailing singleton dimension (N = 1); double images in [0, 1] scale to 0..255."""
    folder = tmp_path / "one"
    images, theta, xy, poses = write_recording(folder, "v7.3", n=1)
    savemat73(folder / "images.mat", "images", images[..., 0] / 255.0)
    savemat73(folder / "theta.mat", "theta", theta[..., 0])
    savemat73(folder / "xy.mat", "xy", xy[..., 0])
    run = import_mat(folder)
    assert np.array_equal(run.images[0], images[..., 0])
    assert run.theta[0, 5 * 4 + 3] == theta[3, 5, 0] and run.xy[0, 1 * 4 + 2, 1] == xy[1, 2, 1, 0]


def _nan_theta(folder):
    _, theta, _, _ = recording()
    theta[1, 2, 4] = np.nan
    scipy.io.savemat(folder / "theta.mat", {"theta": theta})


def _cell_of_wrong_frames(folder):
    cell = as_cell(recording()[0])
    cell[0, 3] = np.zeros((45, 80), dtype=np.uint8)
    savemat73(folder / "images.mat", "images", cell)


def _nan_in_float_images(folder):
    images = recording()[0] / 255.0
    images[0, 0, 0, 5] = np.inf
    savemat73(folder / "images.mat", "images", images)


BAD_RECORDINGS = {
    "missing theta": (lambda f: (f / "theta.mat").unlink(),
                      r"theta\.mat: missing MATLAB file; expected variable 'theta' \(4 x 6 x N\)"),
    "no poses file": (lambda f: (f / "poses.mat").unlink(),
                      r"poses\.mat: missing MATLAB file \(nor is there pose_return\.mat\)"),
    "xy boards and columns swapped": (
        lambda f: scipy.io.savemat(f / "xy.mat", {"xy": np.zeros((2, 6, 4, N))}),
        r"xy\.mat: variable 'xy' has shape \(2, 6, 4, 7\), expected 2 x 4 x 6 x N",
    ),
    "theta as a cell": (
        lambda f: savemat73(f / "theta.mat", "theta", as_cell(np.zeros((4, 6, 1, 2)))),
        r"theta\.mat: variable 'theta' is not a numeric array; expected 4 x 6 x N",
    ),
    "pose_return N x 2": (
        lambda f: ((f / "poses.mat").unlink(),
                   scipy.io.savemat(f / "pose_return.mat", {"pose_return": np.zeros((N, 2))})),
        r"pose_return\.mat: variable 'pose_return' has shape \(7, 2\), expected N x 3",
    ),
    "fewer poses": (
        lambda f: scipy.io.savemat(f / "poses.mat", {"poses": np.zeros((5, 3))}),
        r"different numbers of samples: images\.mat 7, theta\.mat 7, xy\.mat 7, poses\.mat 5",
    ),
    "NaN in theta": (_nan_theta,
                     r"theta\.mat: variable 'theta' has NaN or infinite values in 1 sample\(s\) \(first: sample 4"),
    "inf in images": (_nan_in_float_images,
                      r"images\.mat: variable 'images' has NaN or infinite values .*first: sample 5"),
    "v7.3 cell with a 2-D frame": (_cell_of_wrong_frames,
                                   r"images\.mat: variable 'images' is a cell array of frames of shape"),
    "garbage": (lambda f: (f / "xy.mat").write_bytes(b"\x89HDF\r\n\x1a\nnot really"),
                r"xy\.mat: not a readable MATLAB"),
}


@pytest.mark.parametrize("case", sorted(BAD_RECORDINGS))
def test_bad_recordings_are_one_line_exit_2(tmp_path, capsys, case):
    folder = tmp_path / "rec"
    write_recording(folder)
    BAD_RECORDINGS[case][0](folder)
    out = tmp_path / "out" / "run.h5"
    assert main(["import", str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    import re

    assert lines[0].startswith(f"vitaplace: error: {folder}") and re.search(BAD_RECORDINGS[case][1], lines[0]), lines[0]
    assert not out.exists()


def test_import_into_a_folder_is_one_line(tmp_path, capsys):
    write_recording(tmp_path / "rec")
    assert main(["import", str(tmp_path / "rec"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vitaplace: error: --out {tmp_path}: is a folder") and "\n" not in err


def test_import_over_an_existing_file_needs_replace(tmp_path, capsys):
    """An existing --out (a scenario, another run) is not written over unless --replace says
    so, as `vitaplace simulate ENV.yaml`'s run file."""
    write_recording(tmp_path / "rec")
    kept = tmp_path / "keep.yaml"
    kept.write_text("name: mine\n")
    assert main(["import", str(tmp_path / "rec"), "--out", str(kept)]) == 2
    assert capsys.readouterr().err.strip() == (f"vitaplace: error: --out {kept}: exists; --replace writes the run "
                                               "file over it, or give another --out")
    assert kept.read_text() == "name: mine\n"
    assert main(["import", str(tmp_path / "rec"), "--out", str(kept), "--replace"]) == 0
    assert len(open_run(kept)) == N


# --------------------------------------------------------------------------- scenarios with recorded runs


def import_run(tmp_path, name, poses, seed, *options):
    """Import a v5 recording with the given poses into ``tmp_path/<name>.h5``."""
    folder = tmp_path / "mat" / name
    write_recording(folder, seed=seed, n=len(poses))
    scipy.io.savemat(folder / "poses.mat", {"poses": poses})
    assert main(["import", str(folder), "--out", str(tmp_path / f"{name}.h5"), *options]) == 0
    return tmp_path / f"{name}.h5"


def test_an_imported_run_records_its_tactile_model(tmp_path):
    from vitaplace.engine.data.dataset import recorded_tactile_model

    route = np.zeros((8, 3))
    assert recorded_tactile_model(open_run(import_run(tmp_path, "a", route, 1))) == "physical"  # the default
    penetration = import_run(tmp_path, "b", route, 1, "--tactile-model", "penetration")
    assert recorded_tactile_model(open_run(penetration)) == "penetration"


def _set_tactile_model(path, model):
    run = open_run(path)
    attrs = {k: v for k, v in run.attrs.items() if k != "robot"}
    _rewrite_run(path, attrs=attrs if model is None else {**attrs, "robot": {"tactile_model": model}})


def test_runs_of_two_tactile_models_are_refused_at_validate_naming_both(tmp_path, capsys):
    scenario = recorded_scenario(tmp_path)
    _set_tactile_model(tmp_path / "query.h5", "penetration")
    assert main(["validate", str(scenario)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "tactile_model" in err
    assert f"the training run {tmp_path / 'train.h5'} has physical" in err
    assert f"evaluations.0.datasets.query {tmp_path / 'query.h5'} has penetration" in err


def test_a_recorded_training_run_and_simulated_evaluations_of_another_model_are_refused(tmp_path, capsys):
    scenario = recorded_scenario(tmp_path)
    data = yaml.safe_load(scenario.read_text())
    data["evaluations"] = [{"name": "E1", "environment": "e1", "run": {"kind": "route", "n_samples": 8}}]
    data["robot"] = {"tactile_model": "penetration", "camera_width": 16, "camera_height": 12}
    scenario.write_text(yaml.safe_dump(data))
    assert main(["validate", str(scenario)]) == 2
    err = capsys.readouterr().err.strip()
    assert "the simulated runs (robot.tactile_model) has penetration" in err and "has physical" in err, err


def test_files_that_do_not_say_are_not_compared_and_a_setting_without_effect_is_warned_about(tmp_path, caplog):
    scenario = recorded_scenario(tmp_path)
    _set_tactile_model(tmp_path / "query.h5", None)  # written before run files said
    assert main(["validate", str(scenario)]) == 0
    data = yaml.safe_load(scenario.read_text())
    scenario.write_text(yaml.safe_dump({**data, "robot": {"tactile_model": "penetration"}}))
    with caplog.at_level("WARNING", logger="vitaplace"):  # every run is recorded: the files say physical
        assert main(["validate", str(scenario)]) == 0
    assert "robot.tactile_model (penetration) has no effect: every run is recorded" in caplog.text


def recorded_scenario(tmp_path):
    """Train, query and reference all imported; two hand-crafted methods read the same runs."""
    route = np.stack([np.linspace(0, 2, 8), np.zeros(8), np.zeros(8)], axis=1)
    import_run(tmp_path, "train", route, 1)
    import_run(tmp_path, "ref", route, 2)
    import_run(tmp_path, "query", route + [0.05, 0.0, 0.0], 3)
    small = {"grid": [6, 8], "max_shift": 1}
    data = {
        "name": "recorded",
        "train": {"dataset": "train.h5"},
        "evaluations": [{"name": "E1", "datasets": {"query": "query.h5", "reference": "ref.h5"}}],
        "methods": [{"name": "H", "plugin": "handcrafted", "params": small},
                    {"name": "H2", "plugin": "handcrafted", "params": {"use_visual": False}}],
    }
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_scenario_runs_end_to_end_on_imported_runs(tmp_path, capsys):
    scenario = recorded_scenario(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--no-progress"]) == 0
    rows = json.loads((out / "results.json").read_text())
    assert {(r["environment"], r["method"]) for r in rows} == {("E1", "H"), ("E1", "H2")}
    assert all(r["n_queries"] == 8 for r in rows)
    manifest = json.loads((out / "manifest.json").read_text())
    simulate = {r["item"]: r for r in manifest["stages"] if r["stage"] == "simulate"}
    assert {item: r["status"] for item, r in simulate.items()} == dict.fromkeys(("train", "E1/query", "E1/reference"),
                                                                                "recorded")
    assert simulate["E1/query"]["output"] == str(tmp_path / "query.h5")
    assert not (out / "cache" / "datasets").exists()  # nothing simulated
    assert manifest["recorded"]["E1/reference"] == str(tmp_path / "ref.h5") and manifest["run_seeds"] == {}
    # each run without contacts and with one deflection sample warns once per feature, whatever the methods
    log_text = (out / "log.txt").read_text()
    for label in ("train", "E1/query", "E1/reference"):
        assert log_text.count(f"run {label} has no contacts: PFH features are all zero") == 1, log_text
        assert log_text.count(f"run {label} has a single deflection sample per whisk cycle: SDA features") == 1
    assert manifest["warnings"]["E1/query"]["PFH"] == "run E1/query has no contacts: PFH features are all zero"
    assert "H" in (out / "report.md").read_text()


def test_a_changed_run_file_reruns_what_depends_on_it(tmp_path):
    scenario = recorded_scenario(tmp_path)
    out = tmp_path / "out"

    def statuses() -> dict:
        assert main(["evaluate", str(scenario), "--out", str(out), "--no-progress"]) == 0
        return {(r["stage"], r["item"]): r["status"] for r in json.loads((out / "manifest.json").read_text())["stages"]}

    statuses()
    assert {s for (stage, _), s in statuses().items() if stage != "simulate"} == {"cached"}
    route = np.stack([np.linspace(0, 2, 8), np.zeros(8), np.zeros(8)], axis=1)
    import_run(tmp_path, "query", route + [0.05, 0.0, 0.0], 4, "--replace")  # same path, other content
    ran = {key for key, s in statuses().items() if s == "ran"}
    assert ran == {("transform", "H E1/query"), ("transform", "H2 E1/query"),
                   ("evaluate", "E1 H query-to-reference"), ("evaluate", "E1 H2 query-to-reference")}, ran


def _nan_in_run_file(tmp_path, data, field="poses"):
    with h5py.File(tmp_path / "query.h5", "r+") as f:
        f[field][2, ...] = np.nan


BAD_RECORDED_SCENARIOS = {
    "missing dataset": (lambda t, d: d["train"].update(dataset="nope.h5"),
                        r"train\.dataset: no such file .*nope\.h5.*vitaplace import"),
    "dataset and run": (
        lambda t, d: d["train"].update(run={"kind": "foraging", "n_samples": 5}),
        r"train: give either 'dataset' \(recorded runs\) or 'environment' and 'run' \(simulated\), "
        r"not both: remove 'run'",
    ),
    "neither": (lambda t, d: d["evaluations"][0].pop("datasets"), r"evaluations\.0: 'environment' and 'run' missing"),
    "a v7.3 .mat file, not a run file": (
        lambda t, d: (savemat73(t / "theta.mat", "theta", np.zeros((4, 6, 7))),
                      d["evaluations"][0]["datasets"].update(query="theta.mat")),
        r"evaluations\.0\.datasets\.query: .*theta\.mat: not a vitaplace dataset",
    ),
    "too few samples": (
        lambda t, d: d["evaluations"][0]["datasets"].update(reference=str(import_run(t, "short", np.zeros((4, 3)), 5))),
        r"evaluations\.0\.datasets\.reference: an evaluation run needs at least 5 samples, .*short\.h5 has 4",
    ),
    "NaN in a run file": (_nan_in_run_file,
                          r"query\.h5: field 'poses' has NaN or infinite values \(1 rows, first at index 2\)"),
    # no stage reads a run's times: only the check of a recorded run before the stages finds this
    "NaN in a run file's times": (lambda t, d: _nan_in_run_file(t, d, "times"),
                                  r"query\.h5: field 'times' has NaN or infinite values \(1 rows, first at index 2\)"),
}


@pytest.mark.parametrize("case", sorted(BAD_RECORDED_SCENARIOS))
def test_bad_recorded_runs_in_a_scenario_are_one_line(tmp_path, capsys, case):
    path = recorded_scenario(tmp_path)
    data = yaml.safe_load(path.read_text())
    BAD_RECORDED_SCENARIOS[case][0](tmp_path, data)
    path.write_text(yaml.safe_dump(data))
    capsys.readouterr()
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and last.startswith("vitaplace: error: "), err
    import re

    assert re.search(BAD_RECORDED_SCENARIOS[case][1], last), last
    assert not (tmp_path / "out" / "cache" / "models").exists()  # refused before any method was fitted


def _rewrite_run(path, **changes) -> None:
    """Rewrite the run file ``path`` with some of its fields (images, poses, xy, attrs, ...) replaced."""
    from vitaplace.engine.data.dataset import Run

    run = open_run(path)
    fields = dict(images=run.images, theta=run.theta, xy=run.xy, poses=run.poses, times=run.times,
                  deflection=run.deflection, name=run.name, attrs=run.attrs)
    write_run(path, Run.from_arrays(**{**fields, **changes}))


def test_a_run_stuck_in_one_place_reaches_the_user(tmp_path, monkeypatch):
    """A query that stands at one pose for samples 2-6 (5 of its 8; the route's samples are
    0.29 m apart, beyond the 0.25 m radius) warns in the log, manifest.json and report.md, and
    its longest-stay share (5/8) is in the difficulty; the reference is not warned about. The
    runs are tiny, so the sample floor is lowered to 4 (the share, 1/4, is the shipped one)."""
    from vitaplace.engine.pipeline.stages import simulate

    monkeypatch.setattr(simulate, "STUCK_SAMPLES", 4)
    scenario = recorded_scenario(tmp_path)
    poses = open_run(tmp_path / "query.h5").poses.copy()
    poses[2:7] = poses[2]
    _rewrite_run(tmp_path / "query.h5", poses=poses)
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--no-progress"]) == 0
    message = ("run E1/query: the robot stayed within 0.25 m of one place for 5 of its 8 samples, from sample 2 "
               "(longest_stay)")
    assert message in (out / "log.txt").read_text()
    warnings = json.loads((out / "manifest.json").read_text())["warnings"]
    assert warnings["E1/query"]["longest_stay"].startswith(message)
    assert "longest_stay" not in warnings.get("E1/reference", {}) and "longest_stay" not in warnings.get("train", {})
    assert message in (out / "report.md").read_text().split("## Warnings", 1)[1]
    for row in json.loads((out / "results.json").read_text()):
        assert row["difficulty"]["query_longest_stay_share"] == pytest.approx(5 / 8)
        assert row["difficulty"]["reference_longest_stay_share"] == pytest.approx(1 / 8)


@pytest.mark.parametrize("tau, expected", [
    (0.01, "none of its 8 queries has a true match within tau = 0.01 m"),  # the query runs 5 cm beside the reference
    (0.3, "only 8 of its 8 queries have a true match within tau = 0.3 m"),  # all 8, still fewer than 10
])
def test_an_evaluation_with_too_few_revisits_reaches_the_user(tmp_path, tau, expected):
    """An evaluation direction whose queries have fewer than MIN_REVISITS (10) true matches
    warns in the log, manifest.json (on the run whose samples are the queries) and report.md:
    with none, "max F1 0.00 %" said nothing with exit 0."""
    scenario = recorded_scenario(tmp_path)
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--no-progress", "--set", f"scoring.tau={tau}"]) == 0
    message = f"evaluation E1 query-to-reference: {expected} (n_revisit < 10)"
    assert message in (out / "log.txt").read_text()
    warnings = json.loads((out / "manifest.json").read_text())["warnings"]
    assert warnings["E1/query"]["revisits query-to-reference"].startswith(message)
    assert message in (out / "report.md").read_text().split("## Warnings", 1)[1]
    assert {row["n_revisit"] for row in json.loads((out / "results.json").read_text())} == {0 if tau < 0.05 else 8}


def test_collisions_and_a_training_run_in_no_world_reach_the_user(tmp_path):
    """A run whose robot touched the world (``body_collision_instants`` > 0) warns in the log,
    manifest.json and report.md; a recorded training run is in no known world, so no
    threshold transfers (``f1_at_e1_threshold`` null, the report says why). The query run is
    the reference route shifted 5 cm sideways, facing the same way: each query's nearest
    reference is 5 cm and 0 degrees away. Touch: whisker 0 of query samples 0 and 1 deflected,
    nothing in the reference run (touch shares 2/8 and 0)."""
    scenario = recorded_scenario(tmp_path)
    for name, touched, collisions in (("query", [0, 1], 3), ("ref", [], 0)):
        run = open_run(tmp_path / f"{name}.h5")
        xy = np.zeros_like(run.xy)
        xy[touched, 0, 0] = 0.5
        _rewrite_run(tmp_path / f"{name}.h5", xy=xy, attrs={**run.attrs, "body_collision_instants": collisions})
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--no-progress"]) == 0
    message = ("run E1/query: the robot's body or head touched a landmark or wall at 3 whisk-series instant(s) "
               "(body_collision_instants)")
    assert message in (out / "log.txt").read_text()
    warnings = json.loads((out / "manifest.json").read_text())["warnings"]
    assert warnings["E1/query"]["body_collision_instants"].startswith(message)
    assert "body_collision_instants" not in warnings.get("E1/reference", {})
    report = (out / "report.md").read_text()
    assert message in report.split("## Warnings", 1)[1]
    assert "none: the training run is a recorded file" in report
    for row in json.loads((out / "results.json").read_text()):
        assert row["f1_at_e1_threshold"] is None and row["e1_threshold"] is None
        assert row["difficulty"]["nearest_ref_median_m"] == pytest.approx(0.05)
        assert row["difficulty"]["nearest_ref_heading_median_deg"] == pytest.approx(0.0)
        assert (row["difficulty"]["query_touch_share"], row["difficulty"]["reference_touch_share"]) == (0.25, 0.0)


# --------------------------------------------------------------------------- imports that refuse to guess


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_float_frames_that_overshoot_1_are_refused_not_blackened(tmp_path, capsys):
    """Bicubic resizing of [0, 1] frames overshoots: one pixel at 1.004 must not turn the
    recording into 0..255 values (every pixel 0 or 1)."""
    folder = tmp_path / "rec"
    images = write_recording(folder)[0] / 255.0
    images[10, 20, 1, 3] = 1.004
    scipy.io.savemat(folder / "images.mat", {"images": images})
    out = tmp_path / "run.h5"
    line = _one_line_error(capsys, ["import", str(folder), "--out", str(out)])
    assert f"{folder / 'images.mat'}: variable 'images'" in line and "1 value(s) above 1 (largest 1.004)" in line
    assert "--image-range" in line and not out.exists()
    # stated: [0, 1] frames, the overshoot saturates as MATLAB's im2uint8 does
    assert main(["import", str(folder), "--out", str(out), "--image-range", "0-1"]) == 0
    run = open_run(out)
    expected = np.rint(np.clip(images, 0, 1) * 255).astype(np.uint8)
    assert np.array_equal(run.images, np.moveaxis(expected, 3, 0)) and run.images[3, 10, 20, 1] == 255


@pytest.mark.parametrize("bad,count", [((-0.5,), 1), ((300.0, 256.5), 2)])
def test_values_outside_both_ranges_are_refused_with_their_count(tmp_path, capsys, bad, count):
    folder = tmp_path / "rec"
    images = write_recording(folder)[0].astype(np.float64)
    images.reshape(-1)[: len(bad)] = bad
    scipy.io.savemat(folder / "images.mat", {"images": images})
    for extra in ([], ["--image-range", "0-255"]):
        line = _one_line_error(capsys, ["import", str(folder), "--out", str(tmp_path / "run.h5"), *extra])
        assert f"{folder / 'images.mat'}" in line and f"has {count} value(s) outside both [0, 1] and [0, 255]" in line


def test_whole_numbers_in_a_double_array_are_0_to_255(tmp_path):
    """``double(uint8_image)`` in MATLAB: whole numbers up to 255, read as they are."""
    folder = tmp_path / "rec"
    images = write_recording(folder)[0]
    scipy.io.savemat(folder / "images.mat", {"images": images.astype(np.float64)})
    assert np.array_equal(import_mat(folder).images, np.moveaxis(images, 3, 0))


def test_the_declared_matlab_class_decides_not_the_storage_type(tmp_path):
    """MATLAB stores a double array of whole numbers in a smaller integer type: a binary
    frame (0.0 and 1.0, class double) stored as uint8 is [0, 1], i.e. black and white."""
    folder = tmp_path / "rec"
    write_recording(folder, "v7.3")
    binary = (np.random.default_rng(3).random((45, 80, 3, N)) > 0.5).astype(np.uint8)
    with h5py.File(folder / "images.mat", "w", userblock_size=512) as f:
        f.create_dataset("images", data=binary.T).attrs["MATLAB_class"] = np.bytes_("double")
    run = import_mat(folder)
    assert np.array_equal(run.images, np.moveaxis(binary, 3, 0) * 255)


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_complex_arrays_are_refused(tmp_path, capsys, version):
    folder = tmp_path / "rec"
    theta = write_recording(folder, version)[1] * (1 + 0.5j)
    if version == "v7.3":  # MATLAB stores a complex array as a compound of real and imaginary parts
        with h5py.File(folder / "theta.mat", "w", userblock_size=512) as f:
            data = np.empty(theta.T.shape, dtype=[("real", "<f8"), ("imag", "<f8")])
            data["real"], data["imag"] = theta.T.real, theta.T.imag
            f.create_dataset("theta", data=data).attrs["MATLAB_class"] = np.bytes_("double")
    else:
        scipy.io.savemat(folder / "theta.mat", {"theta": theta})
    line = _one_line_error(capsys, ["import", str(folder), "--out", str(tmp_path / "run.h5")])
    assert f"{folder / 'theta.mat'}: variable 'theta' is complex; expected real values" in line


def test_three_poses_are_ambiguous_unless_the_layout_is_stated(tmp_path, capsys):
    folder = tmp_path / "rec"
    write_recording(folder, n=3)
    poses = np.arange(9.0).reshape(3, 3)  # rows: (0, 1, 2), (3, 4, 5), (6, 7, 8)
    scipy.io.savemat(folder / "poses.mat", {"poses": poses})
    out = tmp_path / "run.h5"
    line = _one_line_error(capsys, ["import", str(folder), "--out", str(out)])
    assert f"{folder / 'poses.mat'}: variable 'poses' is 3 x 3" in line and "--pose-layout" in line
    assert main(["import", str(folder), "--out", str(out), "--pose-layout", "Nx3"]) == 0
    assert open_run(out).poses.tolist() == [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    assert main(["import", str(folder), "--out", str(out), "--pose-layout", "3xN", "--replace"]) == 0
    assert open_run(out).poses.tolist() == [[0, 3, 6], [1, 4, 7], [2, 5, 8]]


# --------------------------------------------------------------------------- recorded runs checked at validate


def _twelve_whiskers(tmp_path, data):
    from vitaplace.engine.data.dataset import Run

    rng = np.random.default_rng(0)
    run = Run.from_arrays(images=rng.integers(0, 256, (8, 45, 80, 3), dtype=np.uint8), theta=np.zeros((8, 12)),
                          xy=np.zeros((8, 12, 2)), poses=np.stack([np.linspace(0, 2, 8), np.zeros(8), np.zeros(8)], 1))
    write_run(tmp_path / "q12.h5", run)
    data["evaluations"][0]["datasets"]["query"] = "q12.h5"


def _smaller_images(tmp_path, data):
    run = open_run(tmp_path / "query.h5")
    small = run.subset(slice(None))
    small._source["images"] = np.ascontiguousarray(run.images[:, :40])
    write_run(tmp_path / "q40.h5", small)
    data["evaluations"][0]["datasets"]["query"] = "q40.h5"


def _copy_of_the_reference(tmp_path, data):
    (tmp_path / "copy.h5").write_bytes((tmp_path / "ref.h5").read_bytes())
    data["evaluations"][0]["datasets"]["query"] = "copy.h5"


def _symlink_loop(tmp_path, data):
    (tmp_path / "loop.h5").symlink_to(tmp_path / "loop.h5")
    data["evaluations"][0]["datasets"]["query"] = "loop.h5"


INCONSISTENT_RECORDINGS = {
    "a query with 12 whiskers": (_twelve_whiskers,
                                 r"evaluations\.0\.datasets\.query: .*q12\.h5 has 12 whiskers, the training run 24"),
    "a query with smaller images": (_smaller_images, r"evaluations\.0\.datasets\.query: .*q40\.h5 has 40x80x3 images, "
                                                     r"the training run 45x80x3"),
    "query = reference": (lambda t, d: d["evaluations"][0]["datasets"].update(query="ref.h5"),
                          r"evaluations\.0\.datasets: query .*ref\.h5 and reference .*ref\.h5 are the same recording"),
    "query a copy of the reference": (_copy_of_the_reference, r"evaluations\.0\.datasets: query .*copy\.h5 and "
                                                              r"reference .*ref\.h5 are the same recording"),
    "a symlink loop": (_symlink_loop, r"evaluations\.0\.datasets\.query: no such file .*loop\.h5"),
}


@pytest.mark.parametrize("case", sorted(INCONSISTENT_RECORDINGS))
def test_recorded_runs_that_cannot_be_compared_are_refused_at_validate(tmp_path, capsys, case):
    import re

    path = recorded_scenario(tmp_path)
    data = yaml.safe_load(path.read_text())
    INCONSISTENT_RECORDINGS[case][0](tmp_path, data)
    path.write_text(yaml.safe_dump(data))
    capsys.readouterr()
    line = _one_line_error(capsys, ["validate", str(path)])
    assert line.startswith(f"vitaplace: error: {path}: ") and re.search(INCONSISTENT_RECORDINGS[case][1], line), line


def _logical_images(folder, layout):
    """images.mat as MATLAB saves a logical (true/false) array: v5 (an array or a cell of
    frames) or v7.3 (uint8 0/1 with class logical); read as 0/1 they would be black frames."""
    write_recording(folder)
    binary = np.random.default_rng(5).random((45, 80, 3, N)) > 0.5
    if layout == "v7.3":
        with h5py.File(folder / "images.mat", "w", userblock_size=512) as f:
            f.create_dataset("images", data=binary.astype(np.uint8).T).attrs["MATLAB_class"] = np.bytes_("logical")
    else:
        scipy.io.savemat(folder / "images.mat", {"images": as_cell(binary) if layout == "cell" else binary})


@pytest.mark.parametrize("layout", ["v5", "cell", "v7.3"])
def test_logical_images_are_refused_not_imported_as_black_frames(tmp_path, capsys, layout):
    folder, out = tmp_path / "rec", tmp_path / "run.h5"
    _logical_images(folder, layout)
    line = _one_line_error(capsys, ["import", str(folder), "--out", str(out)])
    assert f"{folder / 'images.mat'}: variable 'images' is of MATLAB class logical" in line
    assert "expected uint8 (0..255), or double or single in [0, 1]" in line and not out.exists()


@pytest.mark.parametrize("file", ["theta", "xy"])
def test_theta_or_xy_beyond_float32_is_refused_naming_file_and_variable(tmp_path, capsys, file):
    """1e39 is a finite double but no float32 (largest 3.40282e+38): a run file would hold inf."""
    folder, out = tmp_path / "rec", tmp_path / "run.h5"
    arrays = dict(zip(("images", "theta", "xy", "poses"), write_recording(folder), strict=True))
    bad = arrays[file].copy()
    bad[(0,) * bad.ndim], bad[(1,) * bad.ndim] = 1e39, -2e39
    scipy.io.savemat(folder / f"{file}.mat", {file: bad})
    line = _one_line_error(capsys, ["import", str(folder), "--out", str(out)])
    assert line == (f"vitaplace: error: {folder / f'{file}.mat'}: variable '{file}' has 2 value(s) beyond float32's "
                    f"range (largest magnitude 2e+39); expected values within +-3.40282e+38, as a run file stores "
                    f"{file} as float32") and not out.exists()
    bad[(0,) * bad.ndim], bad[(1,) * bad.ndim] = 3.4e38, -3.4e38  # within float32: imported
    scipy.io.savemat(folder / f"{file}.mat", {file: bad})
    assert main(["import", str(folder), "--out", str(out)]) == 0
