"""Keys that follow outputs: a plugin edited between two runs is never served from the cache,
``--force`` of a stage reaches every stage downstream whose input changed, and a forced stage
that reproduces its output leaves the downstream work cached."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from conftest import install_plugin

os.environ.setdefault("MUJOCO_GL", "egl")

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"

#: Test-only extractor: the true positions as features; with ``ORACLE_ORDER=reversed`` (read at
#: transform time) the query run's in reverse order, which pairs each query with the wrong place.
PLUGIN = '''
import os
import numpy as np
from scipy.spatial.distance import cdist
from vitaplace.engine.extension.features import FeatureExtractor
from vitaplace.engine.extension.hookspecs import hookimpl


class Oracle(FeatureExtractor):
    """Test-only: positions as features."""
    name = "oracle"
    def fit(self, train): pass
    def transform(self, run):
        xy = np.asarray(run.poses[:, :2], dtype=np.float64)
        if os.environ.get("ORACLE_ORDER") == "reversed" and run.name.endswith("query"):
            xy = xy[::-1].copy()
        return {"xy": xy}
    def distance(self, query, reference): return cdist(query["xy"], reference["xy"])
    def save_state(self, directory): pass
    def load_state(self, directory): pass


@hookimpl
def vitaplace_register_features(register):
    register(Oracle)
'''


@pytest.fixture
def setup(tmp_path):
    """A site folder with the plugin installed as a distribution (version 1.0), and a scenario."""
    site = tmp_path / "site"
    site.mkdir()
    install_plugin(site, "vitaplace_oracle", PLUGIN, "vitaplace-oracle", "1.0", "oracle")
    scenario = tmp_path / "oracle.yaml"
    scenario.write_text(yaml.safe_dump({
        "name": "oracle",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 8}}],
        "methods": [{"name": "O", "plugin": "oracle"}],
        "scoring": {"tau": 0.3},
    }))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]),
           "PYTHONDONTWRITEBYTECODE": "1", "VITAPLACE_PLUGINS": "oracle"}
    return site / "vitaplace_oracle.py", scenario, tmp_path / "out", env


def run(scenario: Path, out: Path, env: dict, *extra: str, order: str = "") -> tuple[float, dict[str, str]]:
    """`vitaplace evaluate` in a fresh process: (max F1, stage -> statuses of its items)."""
    result = subprocess.run(
        [sys.executable, "-m", "vitaplace.engine.cli.main", "evaluate", str(scenario), "--out", str(out),
         "--no-progress",
         *extra], capture_output=True, text=True, timeout=600, env={**env, "ORACLE_ORDER": order},
    )
    assert result.returncode == 0, result.stderr[-2000:]
    stages: dict[str, set[str]] = {}
    for record in json.loads((out / "manifest.json").read_text())["stages"]:
        stages.setdefault(record["stage"], set()).add(record["status"])
    (row,) = json.loads((out / "results.json").read_text())
    return row["max_f1"], {stage: "/".join(sorted(s)) for stage, s in stages.items()}


def test_an_edited_plugin_is_not_served_from_the_cache(setup):
    """The plugin's transform changes, its version does not: without --force the run redoes
    fit, transform and evaluate and reports the new numbers."""
    plugin, scenario, out, env = setup
    first, _ = run(scenario, out, env)
    assert first == 1.0  # true positions: every query finds its place
    plugin.write_text(PLUGIN.replace('== "reversed"', '!= "anything"'))  # always reversed now
    edited, stages = run(scenario, out, env)
    assert edited < 1.0
    assert stages == {"simulate": "cached", "fit": "ran", "transform": "ran", "evaluate": "ran"}
    plugin.write_text(PLUGIN)  # back to the first code: its cached model and features serve again
    again, stages = run(scenario, out, env)
    assert again == first and stages == {"simulate": "cached", "fit": "cached", "transform": "cached",
                                         "evaluate": "ran"}


def test_force_reaches_every_stage_whose_input_changed(setup):
    """--force transform with a transform whose output changed re-runs evaluate too; forced
    again with the same output, evaluate stays cached."""
    _, scenario, out, env = setup
    first, _ = run(scenario, out, env)
    forced, stages = run(scenario, out, env, "--force", "transform", order="reversed")
    assert forced < 1.0 and stages["transform"] == "ran" and stages["evaluate"] == "ran"
    same, stages = run(scenario, out, env, "--force", "transform", order="reversed")
    assert same == forced and stages["transform"] == "ran" and stages["evaluate"] == "cached"
    back, stages = run(scenario, out, env, "--force", "transform")
    assert back == first == 1.0 and stages["evaluate"] == "ran"
