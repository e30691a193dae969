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
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli import main  # noqa: E402

E1 = str(Path(__file__).resolve().parent.parent / "scenarios" / "environments" / "e1.yaml")
VALID = {
    "name": "t",
    "train": {"environment": E1, "run": {"kind": "foraging", "n_samples": 5}},
    "evaluations": [{"name": "E1", "environment": E1, "run": {"kind": "route", "n_samples": 5}}],
    "methods": [{"name": "H", "plugin": "handcrafted"}, {"name": "L", "plugin": "mupnet", "params": {"epochs": 2}}],
    "evaluation": {"tau": 0.3},
    "robot": {"whisk_hz": 2.0},
}

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10**12), max_value=10**12),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=40),
    st.sampled_from([math.inf, -math.inf, math.nan, 0, -1, 1e308, "", "..", "../x", "e1.yaml", "relu6"]),
)
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                      max_leaves=12)
# a path into the valid scenario, and what to put there (or delete it)
paths = st.lists(st.sampled_from(["name", "train", "run", "n_samples", "kind", "environment", "evaluations", 0,
                                   "methods", 1, "params", "epochs", "image_size", "evaluation", "tau", "delta",
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


@settings(max_examples=int(os.environ.get("FUZZ_EXAMPLES", 60)), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
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
