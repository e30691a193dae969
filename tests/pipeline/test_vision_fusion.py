"""The vision baselines in a scenario, through their entry points: HOG as the vision half of a
late fusion with H-T runs end to end, and a scenario naming a baseline whose library is
missing stops at validate in one line naming the extra."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402

pytest.importorskip("skimage", reason="the extra vision (scikit-image) is not installed")

ROOT = Path(__file__).resolve().parents[2]
ENVS = ROOT / "scenarios" / "environments"


def tiny_scenario(path: Path) -> Path:
    path.write_text(yaml.safe_dump({
        "name": "tiny-hog-fusion",
        "train": {"environment": str(ENVS / "e1.yaml"), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENVS / "e1.yaml"),
                         "run": {"kind": "route", "n_samples": 12}}],
        "methods": [{"name": "HOG", "plugin": "hog"},
                    {"name": "H-T", "plugin": "handcrafted", "params": {"use_visual": False}}],
        "fusions": [{"name": "HOG-F", "vision": "HOG", "touch": "H-T", "weights": [0, 1]}],
        "scoring": {"tau": 0.3},
    }))
    return path


@pytest.mark.slow
def test_hog_fused_with_h_t_runs_end_to_end(tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(tiny_scenario(tmp_path / "tiny.yaml")), "--out", str(out), "--no-progress", "-q"]) == 0
    rows = json.loads((out / "results.json").read_text())
    assert {r["method"] for r in rows} == {"HOG", "H-T", "HOG-F"}
    assert all(0.0 <= r["max_f1"] <= 1.0 for r in rows)


def test_a_baseline_without_its_library_stops_at_validate_naming_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "skimage", None)
    assert main(["validate", str(tiny_scenario(tmp_path / "tiny.yaml"))]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "methods.0.params: extractor 'hog' needs scikit-image" in err and "pip install 'vitaplace[vision]'" in err
