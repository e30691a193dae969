"""Hostile scenario files, generated: whatever a file holds, `vitaplace validate` answers with
exit 0, or exit 2 and one line naming the file — never a traceback, never a hang."""

from __future__ import annotations

import copy
import math
import os
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402

E1 = str(Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml")
VALID = {
    "name": "t",
    "train": {"environment": E1, "run": {"kind": "foraging", "n_samples": 5}},
    "evaluations": [{"name": "E1", "environment": E1, "run": {"kind": "route", "n_samples": 5}}],
    "methods": [{"name": "H", "plugin": "handcrafted"}, {"name": "L", "plugin": "mupnet", "params": {"epochs": 2}}],
    "scoring": {"tau": 0.3},
    "robot": {"whisk_hz": 2.0},
}

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10**12), max_value=10**12),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=40),
    st.sampled_from([math.inf, -math.inf, math.nan, 0, -1, 1e308, "", "..", "../x", "e1.yaml", "relu6"]),
)
values = st.recursive(scalars,
                      lambda inner: st.lists(inner, max_size=4)
                      | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                      max_leaves=12)
# a path into the valid scenario, and what to put there (or delete it)
paths = st.lists(st.sampled_from(["name", "train", "run", "n_samples", "kind", "environment", "evaluations", 0,
                                   "methods", 1, "params", "epochs", "image_size", "scoring", "evaluation", "tau",
                                   "delta",
                                   "robot", "whisk_hz", "spring_stiffness", "seed", "extends", "plugin"]),
                 min_size=1, max_size=4)


def mutate(data: dict, path: list, value, delete: bool) -> dict:
    out = copy.deepcopy(data)
    node = out
    for part in path[:-1]:
        if isinstance(node, dict) and part in node:
            node = node[part]
        elif isinstance(node, list) and isinstance(part, int) and part < len(node):
            node = node[part]
        else:
            break
    last = path[-1]
    if isinstance(node, dict) and isinstance(last, str):
        if delete:
            node.pop(last, None)
        else:
            node[last] = value
    elif isinstance(node, list) and isinstance(last, int) and last < len(node):
        node[last] = value
    return out


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 60)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=paths, value=values, delete=st.booleans())
def test_any_mutated_scenario_gets_a_clean_answer(tmp_path, capsys, path, value, delete):
    scenario = tmp_path / "fuzz.yaml"
    scenario.write_text(yaml.safe_dump(mutate(VALID, path, value, delete), allow_unicode=True))
    start = time.perf_counter()
    code = main(["validate", str(scenario)])
    err = capsys.readouterr().err.strip().splitlines()
    assert time.perf_counter() - start < 30
    assert code in (0, 2)
    if code == 2:
        assert len(err) == 1 and err[0].startswith("vitaplace: error:"), err
        assert len(err[0]) < 2000


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.binary(max_size=400) | st.text(max_size=400).map(str.encode))
def test_arbitrary_bytes_get_a_clean_answer(tmp_path, capsys, text):
    scenario = tmp_path / "bytes.yaml"
    scenario.write_bytes(text)
    code = main(["validate", str(scenario)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("vitaplace: error:"), err


@pytest.mark.parametrize("value", [[1, 2], {"a": 1}, None, "x" * 5000])
def test_wrong_shapes_at_the_top_level(tmp_path, capsys, value):
    scenario = tmp_path / "top.yaml"
    scenario.write_text(yaml.safe_dump(value))
    assert main(["validate", str(scenario)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- recorded run files
# Whatever a run file holds, opening and checking it ends in a clean state or one DatasetError
# line naming the file: never another exception.

import shutil  # noqa: E402
import tempfile  # noqa: E402

import h5py  # noqa: E402
import numpy as np  # noqa: E402

from vitaplace.engine.data.dataset import FIELDS, DatasetError, Run, open_run, write_run  # noqa: E402


def _base_run_file(folder: Path) -> Path:
    rng = np.random.default_rng(0)
    n = 6
    run = Run.from_arrays(images=rng.integers(0, 256, (n, 4, 5, 3), dtype=np.uint8), theta=rng.normal(size=(n, 24)),
                          xy=rng.normal(size=(n, 24, 2)), poses=rng.normal(size=(n, 3)), attrs={"seed": 1})
    return write_run(folder / "run.h5", run)


def _array(dtype: str, shape: tuple, fill) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):  # NaN or 1e9 cast to small integers: whatever comes
        return np.full(shape, fill).astype(dtype)


arrays = st.builds(
    _array,
    st.sampled_from(["u1", "i8", "f4", "f8", "S3", "c16", "?"]),
    st.lists(st.integers(0, 7), min_size=0, max_size=4).map(tuple),
    st.sampled_from([0, 1, -1, 255, 1e9, math.nan, math.inf]),
)
run_values = st.one_of(arrays, scalars.filter(lambda v: v is not None), st.lists(st.integers(-5, 5), max_size=5))


def _store(group, name: str, value) -> bool:
    """Put ``value`` under ``name`` as a dataset; False (and nothing left under ``name``) when
    HDF5 cannot hold it at all: h5py creates the dataset before it finds, for example, a NUL
    in a string it cannot write."""
    try:
        group.create_dataset(name, data=value)
    except (TypeError, ValueError):
        if name in group:
            del group[name]
        return False
    return True


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 60)), deadline=None)
@given(target=st.sampled_from([*FIELDS, "schema_version", "seed", "name", "params", "run_key", "bytes"]),
       value=run_values, delete=st.booleans(), offset=st.integers(0, 10**6))
@example(target="images", value="\x00", delete=False, offset=0)  # HDF5 cannot store a NUL in a string
@example(target="schema_version", value="\x00", delete=False, offset=0)
@example(target="bytes", value=False, delete=False, offset=184)  # h5py: RuntimeError, bad symbol table node
def test_any_mutated_run_file_gets_a_clean_answer(target, value, delete, offset):
    folder = Path(tempfile.mkdtemp())
    try:
        path = _base_run_file(folder)
        if target == "bytes":  # a flipped byte somewhere in the file
            data = bytearray(path.read_bytes())
            data[offset % len(data)] ^= 0xFF
            path.write_bytes(bytes(data))
        else:
            with h5py.File(path, "a") as f:
                if target in FIELDS:
                    del f[target]
                    if not delete and not _store(f, target, value):
                        f.create_group(target)
                elif delete:
                    del f.attrs[target]
                else:
                    try:
                        f.attrs[target] = value
                    except (TypeError, ValueError):
                        f.attrs[target] = str(value).replace("\x00", "\\x00")  # HDF5 text holds no NUL
        try:
            run = open_run(path)
            run.validate()
            len(run), run.n_whiskers, run.image_shape  # noqa: B018 - what a scenario check reads
        except DatasetError as exc:
            message = str(exc)
            assert message.startswith(str(path)) and "\n" not in message, message
    finally:
        shutil.rmtree(folder, ignore_errors=True)


# --------------------------------------------------------------------------- aggregate folders
# Whatever two run folders hold, `vitaplace aggregate` exits 0 with a summary, or 2 with one line
# and nothing written.


def _finished_folder(folder: Path, seed: int) -> None:
    """A finished run folder as the runner leaves one: scenario, manifest, results, PR curve
    and the completion record written last."""
    import json

    from vitaplace.engine.evaluation.pairfiles import evaluate_pair
    from vitaplace.engine.outputs import completion

    poses = np.stack([np.linspace(0, 2, 6), np.zeros(6), np.zeros(6)], axis=1)
    tme = np.abs(np.subtract.outer(np.arange(6.0), np.arange(6.0))) + 0.1 * seed
    evaluation = folder / "evaluations" / "E1" / "M" / "query-to-reference"
    summary = evaluate_pair(evaluation, tme, poses, poses, 0.3)
    (folder / "scenario.resolved.yaml").write_text(yaml.safe_dump({"name": "fuzz", "seed": seed,
                                                                   "scoring": {"tau": 0.3}}))
    (folder / "manifest.json").write_text(json.dumps({"scenario": "fuzz", "seed": seed}))
    rows = [{"environment": "E1", "method": "M", "direction": "query-to-reference", **summary}]
    (folder / "results.json").write_text(json.dumps(rows))
    completion.write(folder, [folder / "manifest.json", folder / "results.json", evaluation / "pr_curve.npz"])


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 60)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file=st.sampled_from(["results.json", "manifest.json", "completed.json", "scenario.resolved.yaml"]),
       key=st.sampled_from(["max_f1", "auc", "recall_at_k", "environment", "seed", "scenario", "files", "name",
                            "n_queries"]),
       value=values, whole=st.booleans(), reseal=st.booleans())
# found by this test: a row's own null seed overrode the folder's; a null recall_at_k
@example(file="results.json", key="seed", value=None, whole=False, reseal=True)
@example(file="results.json", key="recall_at_k", value=None, whole=False, reseal=True)
# a line break in a field's name
@example(file="results.json", key="auc", value={"\r": False}, whole=False, reseal=True)
@example(file="results.json", key="n_queries", value=None, whole=False, reseal=True)  # sized the block bootstrap
@example(file="results.json", key="recall_at_k", value={"": None}, whole=False, reseal=True)  # K not a number
@example(file="results.json", key="recall_at_k", value=1, whole=False, reseal=True)  # not a mapping
# overflowed the bootstrap
@example(file="results.json", key="max_f1", value=4.752060766250472e+161, whole=False, reseal=True)
def test_any_mutated_aggregate_folder_gets_a_clean_answer(capsys, file, key, value, whole, reseal):
    import json

    from vitaplace.engine.outputs import completion
    root = Path(tempfile.mkdtemp())
    try:
        for seed in (0, 1):
            _finished_folder(root / f"seed-{seed}", seed)
        victim = root / "seed-1" / file
        loads = yaml.safe_load if file.endswith(".yaml") else json.loads
        data = loads(victim.read_text())
        if whole:
            data = value
        elif file == "results.json":
            data[0][key] = value
        elif isinstance(data, dict):
            data[key] = value
        victim.write_text(yaml.safe_dump(data) if file.endswith(".yaml") else json.dumps(data))
        if reseal and file != "completed.json":
            names = json.loads((root / "seed-1" / "completed.json").read_text())["files"]
            completion.write(root / "seed-1", [root / "seed-1" / n for n in names])
        out = root / "summary"
        code = main(["aggregate", str(root / "seed-0"), str(root / "seed-1"), "--out", str(out)])
        captured = capsys.readouterr()
        assert code in (0, 2), captured.err
        if code == 2:
            lines = captured.err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith("vitaplace: error:"), captured.err
            assert not out.exists()
        else:
            assert (out / "sweep.csv").is_file() and "summary of 2 seeds" in captured.out
    finally:
        shutil.rmtree(root, ignore_errors=True)
