"""The HDF5 dataset contract: round trip, corrupt/foreign files, schema version, atomic writes."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from vitaplace.engine.data import dataset as ds
from vitaplace.engine.data.dataset import SCHEMA_VERSION, DatasetError, Run, open_run, write_run


def make_run(n: int = 5, s: int = 3, seed: int = 0) -> Run:
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 4, size=n)
    m = int(counts.sum())
    normals = rng.normal(size=(m, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Run.from_arrays(
        images=rng.integers(0, 256, size=(n, 12, 16, 3), dtype=np.uint8),
        theta=rng.normal(size=(n, 24)),
        xy=rng.normal(size=(n, 24, 2)),
        poses=rng.normal(size=(n, 3)),
        times=np.arange(n) * 0.5,
        deflection=rng.normal(size=(n, s, 24, 2)),
        contact_points=rng.normal(size=(m, 3)),
        contact_normals=normals,
        contact_offsets=np.concatenate([[0], np.cumsum(counts)]),
        name="unit",
        attrs={"seed": 7, "run_key": "abc123", "robot": {"whisk_hz": 2.0}, "camera": {"width": 16}},
    )


def test_a_file_from_before_the_engine_split_gives_its_scenario_hash_as_run_key(tmp_path):
    """Run files written before the rename hold the key as ``scenario_hash``: it is read as ``run_key``."""
    import h5py

    path = write_run(tmp_path / "old.h5", make_run())
    with h5py.File(path, "r+") as f:
        f.attrs["scenario_hash"] = f.attrs["run_key"]
        del f.attrs["run_key"]
    assert open_run(path).attrs["run_key"] == "abc123"


def test_round_trip(tmp_path):
    run = make_run()
    path = write_run(tmp_path / "run.h5", run)
    back = open_run(path)
    assert back.name == "unit" and len(back) == len(run) and back.path == path
    for key in ds.FIELDS:
        a, b = run._get(key), back._get(key)
        assert a.dtype == b.dtype, key
        assert np.array_equal(a, b), key
    assert back.attrs["seed"] == 7
    assert back.attrs["run_key"] == "abc123"
    assert back.attrs["robot"] == {"whisk_hz": 2.0}
    assert back.n_whiskers == 24 and back.image_shape == (12, 16, 3)
    for i in range(len(run)):
        p, n = back.contacts(i)
        p0, n0 = run.contacts(i)
        assert np.array_equal(p, p0) and np.array_equal(n, n0)
    assert np.array_equal(back.image_batch(1, 3), run.images[1:3])
    sub = back.subset(np.array([4, 0]))
    assert np.array_equal(sub.poses, run.poses[[4, 0]])
    assert np.array_equal(sub.contacts(0)[0], run.contacts(4)[0])
    with h5py.File(path) as f:
        assert int(f.attrs["schema_version"]) == SCHEMA_VERSION


def test_in_memory_shape_errors_are_dataset_errors():
    run = make_run()
    with pytest.raises(DatasetError, match="'xy'"):
        Run.from_arrays(images=run.images, theta=run.theta, xy=run.xy[:, :3], poses=run.poses)
    with pytest.raises(DatasetError, match="contact_offsets"):
        Run.from_arrays(
            images=run.images,
            theta=run.theta,
            xy=run.xy,
            poses=run.poses,
            contact_points=np.zeros((2, 3)),
            contact_normals=np.zeros((2, 3)),
            contact_offsets=np.array([0, 1, 1, 1, 1, 1]),
        )


def test_truncated_file(tmp_path):
    path = write_run(tmp_path / "run.h5", make_run(n=20))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"run\.h5: not a readable HDF5 file \(truncated or foreign\?\)"):
        open_run(path)


def test_foreign_hdf5_file(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["images"] = np.zeros((2, 4, 4, 3), np.uint8)
    with pytest.raises(DatasetError, match=r"other\.h5: not a vitaplace dataset"):
        open_run(path)


def test_non_hdf5_file(tmp_path):
    path = tmp_path / "notes.h5"
    path.write_text("this is not HDF5\n" * 100)
    with pytest.raises(DatasetError, match=r"notes\.h5: not a readable HDF5 file"):
        open_run(path)


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match="no such dataset file"):
        open_run(tmp_path / "nope.h5")


def test_other_schema_version(tmp_path):
    path = write_run(tmp_path / "run.h5", make_run())
    with h5py.File(path, "a") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(DatasetError, match=rf"schema version {SCHEMA_VERSION + 1}.*reads version {SCHEMA_VERSION}"):
        open_run(path)


def test_missing_field(tmp_path):
    path = write_run(tmp_path / "run.h5", make_run())
    with h5py.File(path, "a") as f:
        del f["deflection"]
    with pytest.raises(DatasetError, match="lacks field.*deflection"):
        open_run(path)


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    target = tmp_path / "run.h5"
    run = make_run()
    real_get = Run._get

    def failing_get(self, key):
        if key == "deflection":  # after images/theta/xy were written
            raise KeyboardInterrupt("simulated crash mid-write")
        return real_get(self, key)

    monkeypatch.setattr(Run, "_get", failing_get)
    with pytest.raises(KeyboardInterrupt):
        write_run(target, run)
    assert not target.exists()
    assert list(tmp_path.iterdir()) == [], "the temporary file must be removed too"
    monkeypatch.undo()
    # an existing complete file is not damaged by a failed overwrite
    write_run(target, run)
    monkeypatch.setattr(Run, "_get", failing_get)
    with pytest.raises(KeyboardInterrupt):
        write_run(target, make_run(seed=1))
    monkeypatch.undo()
    assert np.array_equal(open_run(target).poses, run.poses)


def test_nan_values_are_reported_with_field_and_sample(tmp_path):
    run = make_run()
    path = write_run(tmp_path / "run.h5", run)
    with h5py.File(path, "r+") as f:
        f["theta"][3, 5] = np.nan
        f["poses"][1, 0] = np.inf
    back = open_run(path)
    with pytest.raises(DatasetError,
                       match=r"run\.h5: field 'theta' has NaN or infinite values \(1 rows, first at index 3\)"):
        _ = back.theta
    with pytest.raises(DatasetError, match=r"field 'poses' .* first at index 1"):
        _ = back.poses
    np.testing.assert_array_equal(back.xy, run.xy)  # the other fields stay readable


def test_nan_in_memory_is_rejected():
    with pytest.raises(DatasetError, match=r"field 'xy' has NaN"):
        Run.from_arrays(
            images=np.zeros((2, 4, 4, 3), np.uint8),
            theta=np.zeros((2, 24)),
            xy=np.full((2, 24, 2), np.nan),
            poses=np.zeros((2, 3)),
        )


# --------------------------------------------------------------------------- hostile run files
# Each file below is what a damaged or forged recording looks like; `open_run` must answer
# with one DatasetError naming the file (never a traceback, never gigabytes read).


def _set_attr(key, value):
    def change(f):
        f.attrs[key] = value
    return change


def _field_as_group(f):
    del f["theta"]
    f.create_group("theta")


def _forged_size(f):
    """A small file declaring 10^7 samples: chunked datasets whose chunks were never written."""
    n = 10**7
    for key in list(f):
        del f[key]
    for key, shape in {"images": (n, 2, 2, 3), "theta": (n, 24), "xy": (n, 24, 2), "deflection": (n, 1, 24, 2),
                       "poses": (n, 3), "times": (n,), "contact_offsets": (n + 1,)}.items():
        f.create_dataset(key, shape=shape, dtype=ds.FIELDS[key], chunks=(1000,) + shape[1:])
    for key in ("contact_points", "contact_normals"):
        f.create_dataset(key, shape=(0, 3), dtype=np.float32)


HOSTILE_FILES = {
    "schema_version as text": (_set_attr("schema_version", "one"), r"schema version 'one' \(not an integer\)"),
    "schema_version as an array": (_set_attr("schema_version", np.array([1, 1])), r"schema version .*not an integer"),
    "seed as text": (_set_attr("seed", "seven"), r"attribute 'seed' is .*seven.*expected an integer"),
    "params not JSON": (_set_attr("params", "{not json"), r"attribute 'params' is not valid JSON"),
    "params a JSON list": (_set_attr("params", "[1, 2]"), r"attribute 'params' is list JSON, expected a JSON object"),
    "name as a number": (_set_attr("name", 3.5), r"attribute 'name' is .*3\.5.*expected text"),
    "a field stored as a group": (_field_as_group, r"field 'theta' is a group, expected a dataset"),
    "images as floats": (lambda f: (f.__delitem__("images"), f.create_dataset("images", data=np.zeros((5, 12, 16, 3)))),
                         r"field 'images' has dtype float64, expected uint8"),
    "theta as text": (lambda f: (f.__delitem__("theta"), f.create_dataset("theta", data=np.full((5, 24), b"x"))),
                      r"field 'theta' has dtype \|S1, expected float32"),
    "10^7 samples declared, none stored": (_forged_size,
                                           r"field 'images' declares shape \(10000000, 2, 2, 3\) but the file "
                                                         r"does not hold its data"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE_FILES))
def test_hostile_run_files_are_one_dataset_error(tmp_path, case):
    import re
    import tracemalloc

    path = write_run(tmp_path / "run.h5", make_run())
    with h5py.File(path, "a") as f:
        HOSTILE_FILES[case][0](f)
    tracemalloc.start()
    with pytest.raises(DatasetError) as info:
        open_run(path).validate()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message, message
    assert re.search(HOSTILE_FILES[case][1], message), message
    assert peak < 50e6, f"read {peak / 1e6:.0f} MB to refuse the file"

