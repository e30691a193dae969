"""A scenario with a query drop-out end to end: the drop-out drawn, recorded in manifest.json
and results.json, handed to the methods, and keyed (another share re-runs the query's
transforms and what follows, nothing else)."""

from __future__ import annotations

import json
import os

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from test_cli import TINY  # noqa: E402

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.data.dataset import dropout_masks  # noqa: E402
from vitaplace.engine.extension.features import load_features  # noqa: E402

#: vision alone: a query without its camera shares no term with any reference (distance +inf)
VISION_ONLY = "methods+={name: H-V, plugin: handcrafted, params: {use_tactile: false}}"


def run(out, dropout: str) -> dict:
    argv = ["run", "quickstart", "--out", str(out), "--no-progress"]
    for override in [*TINY, VISION_ONLY, f"evaluations.0.query_dropout={dropout}"]:
        argv += ["--set", override]
    assert main(argv) == 0
    return json.loads((out / "manifest.json").read_text())


def test_a_query_drop_out_is_drawn_recorded_used_and_keyed(tmp_path):
    out = tmp_path / "out"
    manifest = run(out, "{camera: 0.3, whiskers: 0.2}")
    record = manifest["dropout"]["E1/query"]
    masks = dropout_masks(10, {"camera": 0.3, "whiskers": 0.2}, record["seed"])  # 10 query samples (TINY)
    assert record["camera"] == np.flatnonzero(masks["camera"]).tolist() and len(record["camera"]) == 3
    assert record["whiskers"] == np.flatnonzero(masks["whiskers"]).tolist() and len(record["whiskers"]) == 2
    rows = json.loads((out / "results.json").read_text())
    assert {row["method"] for row in rows} == {"L", "H", "H-V"}
    assert all(row["query_dropout"] == {"camera": 0.3, "whiskers": 0.2} for row in rows)
    report = (out / "report.md").read_text()
    assert "## Query drop-out" in report and "| E1 | 30.00 | 20.00 |" in report
    (query,) = (out / "cache" / "features").glob("H-E1-query-*.npz")
    features = load_features(query)
    assert np.flatnonzero(features["missing_camera"]).tolist() == record["camera"]
    assert np.flatnonzero(features["missing_whiskers"]).tolist() == record["whiskers"]
    # H-V cannot compare its 3 camera-less queries with anything: their rows are +inf, and
    # they are never accepted, so they are counted among the 10 queries as missed, not matched
    tme = np.load(out / "evaluations" / "E1" / "H-V" / "query-to-reference" / "matrices.npz")["tme"]
    assert np.flatnonzero(np.isposinf(tme).all(axis=1)).tolist() == record["camera"]

    again = run(out, "{camera: 0.5}")
    status = {(r["stage"], r["item"]): r["status"] for r in again["stages"]}
    assert (status[("simulate", "E1/query")] == status[("fit", "L")] == status[("transform", "L E1/reference")]
            == "cached")
    assert status[("transform", "L E1/query")] == status[("transform", "H E1/query")] == "ran"
    assert len(again["dropout"]["E1/query"]["camera"]) == 5 and again["dropout"]["E1/query"]["whiskers"] == []
