"""The tactile range gate (bench/tactile_range.py) on recorded runs whose tactile values are
set by hand, so the shares inside the training range are counted in the comments."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.data.dataset import Run, write_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SPEC = importlib.util.spec_from_file_location("tactile_range", ROOT / "bench" / "tactile_range.py")
assert SPEC is not None and SPEC.loader is not None
gate = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(gate)


def _recorded(path: Path, x0: list[float]) -> Path:
    """A recorded run of len(x0) samples, 24 whiskers: every tactile value 0 but whisker 0's x."""
    n = len(x0)
    xy = np.zeros((n, 24, 2))
    xy[:, 0, 0] = x0
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return write_run(path, Run.from_arrays(images=np.zeros((n, 8, 8, 3), np.uint8), theta=np.zeros((n, 24)), xy=xy,
                                           poses=np.c_[np.cos(t), np.sin(t), t], name=path.stem))


def scenario(tmp_path: Path, methods: list[dict], **evaluation: object) -> Path:
    # training: whisker 0's x spans [0, 1], the other 71 channels are 0 throughout; the query
    # has x = 2 in one of its 5 samples, the reference is all 0: of 2 x 5 x 72 = 720 values 719
    # lie inside (99.86 %), and whisker 0's x channel 9 of its 10 (90.0 %): FAIL
    files = {"train": _recorded(tmp_path / "train.h5", [0, 1, 0.5, 0.2, 0.3]),
             "query": _recorded(tmp_path / "query.h5", [0.5, 2, 0.5, 0.5, 0.5]),
             "reference": _recorded(tmp_path / "reference.h5", [0, 0, 0, 0, 0])}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({
        "name": "gate", "train": {"dataset": str(files["train"])},
        "evaluations": [{"name": "E1", "datasets": {"query": str(files["query"]),
                                                    "reference": str(files["reference"])}, **evaluation}],
        "methods": methods, "scoring": {"tau": 0.5}}))
    return path


TINY = {"image_size": [2, 2], "visual_layers": [4], "tactile_layers": [4], "joint_size": 3}


def test_the_gate_counts_the_values_inside_the_training_range_pooled_and_per_channel(tmp_path, capsys):
    path = scenario(tmp_path, [{"name": "L", "plugin": "mupnet", "params": TINY},
                               {"name": "L-T", "plugin": "mupnet", "params": {**TINY, "modalities": ["tactile"]}},
                               {"name": "L-V", "plugin": "mupnet", "params": {**TINY, "modalities": ["visual"]}},
                               {"name": "H", "plugin": "handcrafted"}])
    assert gate.main([str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 1
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| gate ")]
    assert rows == ["| gate | recorded | instant (L, L-T) | E1 | 720 | 99.86 | 90.0 | FAIL |"]


def test_a_query_without_whiskers_is_left_out(tmp_path, capsys):
    # every query sample loses its whiskers: only the reference's 5 x 72 values, all inside
    path = scenario(tmp_path, [{"name": "L-T", "plugin": "mupnet", "params": {**TINY, "modalities": ["tactile"]}}],
                    query_dropout={"whiskers": 1.0})
    assert gate.main([str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| gate ")]
    assert rows == ["| gate | recorded | instant (L-T) | E1 | 360 | 100.00 | 100.0 | PASS |"]


def test_a_scenario_without_a_touch_fed_mupnet_method_has_no_row_and_passes(tmp_path, capsys):
    path = scenario(tmp_path, [{"name": "L-V", "plugin": "mupnet", "params": {**TINY, "modalities": ["visual"]}}])
    assert gate.main([str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert not [line for line in capsys.readouterr().out.splitlines() if line.startswith("| gate ")]


def test_bad_input_is_one_line_and_exit_status_2(tmp_path, capsys):
    assert gate.main(["no-such-scenario", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tactile_range: ") and "no-such-scenario" in err[0], err
