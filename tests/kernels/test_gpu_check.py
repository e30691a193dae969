"""The convergence stage of bench/gpu_check.sh (bench/gpu_converge.py) in its tiny CPU mode.

Recorded runs in (a tiny seed-0 pack of scenarios/paper-cpu.yaml: 40 training samples,
20-sample drives, made here with MuJoCo), the stage run as the device runs it but with
MuJoCo made unimportable (the lent GPU machines have none), an epoch cap of 1 and 5
inference steps; then every field of its results file is checked against what each
method's own pipeline folder says (results.json, manifest.json, scenario.resolved.yaml),
and the summary's table against the results file.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "bench" / "gpu_converge.py"
METHODS = ("L", "L-V", "L-T")
WORLDS = ("E1", "E2", "E3")
EPOCHS, MAX_STEPS = 1, 5


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gpu-converge")
    env = {**os.environ, "MUJOCO_GL": "egl"}
    subprocess.run([sys.executable, str(SCRIPT), "pack", "--tiny", "--seeds", "0", "--dest", str(tmp / "runs"),
                    "--sim-root", str(tmp / "sim")], check=True, cwd=ROOT, env=env)
    shim = tmp / "no-mujoco" / "mujoco"
    shim.mkdir(parents=True)
    (shim / "__init__.py").write_text("raise ImportError('no MuJoCo on the device (test shim)')\n")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(shim.parent), env.get("PYTHONPATH")]))
    proc = subprocess.run([sys.executable, str(SCRIPT), "run", "--runs", str(tmp / "runs"), "--out", str(tmp / "out"),
                           "--work", str(tmp / "work"), "--epochs", str(EPOCHS), "--max-steps", str(MAX_STEPS),
                           "--budget", "300"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr + "".join(
        p.read_text() for p in (tmp / "out").glob("*.log"))
    return tmp, json.loads((tmp / "out" / "converge.json").read_text())


def test_rows_are_the_pipelines_own(stage):
    tmp, record = stage
    assert record["tiny_runs"] is True and record["epochs_cap"] == EPOCHS and record["max_steps"] == MAX_STEPS
    assert record["seeds"]["0"]["status"] == "done"
    from vitaplace.engine.network.selection import cuda_available

    assert record["device"] == ("cuda" if cuda_available() else "cpu")  # found, not "unknown (ImportError ...)"
    rows = {(r["method"], r["environment"]): r for r in record["rows"]}
    assert sorted(rows) == sorted((m, w) for m in METHODS for w in WORLDS)
    for method in METHODS:
        folder = tmp / "work" / "seed-0" / method
        results = json.loads((folder / "results.json").read_text())
        manifest = json.loads((folder / "manifest.json").read_text())
        training = manifest["training"][method]
        assert training["max_epochs"] == EPOCHS
        for world in WORLDS:
            row = rows[method, world]
            f1 = {r["direction"]: r["max_f1"] for r in results if r["environment"] == world}
            assert row["max_f1_query_to_reference"] == f1["query-to-reference"]
            assert row["max_f1_reference_to_query"] == f1["reference-to-query"]
            assert (row["epochs"], row["max_epochs"], row["converged"]) == (
                training["epochs"], training["max_epochs"], training["converged"])
            inference = [manifest["features"][method][f"{world}/{role}"]["inference"]
                         for role in ("query", "reference")]
            assert row["samples"] == sum(i["samples"] for i in inference) == 40  # 20-sample drives, both
            assert row["capped"] == sum(i["capped"] for i in inference)
            assert row["settled_share"] == pytest.approx(1 - row["capped"] / row["samples"])
            assert row["max_steps_taken"] <= MAX_STEPS
        # the copies kept beside the results file are the pipeline's files
        kept = tmp / "out" / "converge" / "seed-0" / method
        assert json.loads((kept / "results.json").read_text()) == results


def test_runs_were_the_recorded_ones_with_the_studys_settings(stage):
    tmp, _ = stage
    carried = json.loads((tmp / "runs" / "RUNS.json").read_text())["seeds"]["0"]
    study = yaml.safe_load((ROOT / "scenarios" / "paper-cpu.yaml").read_text())
    from vitaplace.engine.pipeline.plan import seed_for

    for index, method in enumerate(METHODS):
        folder = tmp / "work" / "seed-0" / method
        manifest = json.loads((folder / "manifest.json").read_text())
        simulate = [s for s in manifest["stages"] if s["stage"] == "simulate"]
        assert len(simulate) == 7 and {s["status"] for s in simulate} == {"recorded"}
        assert sorted(manifest["recorded"]) == sorted(carried["samples"])
        assert {label: facts["samples"] for label, facts in manifest["runs"].items()} == carried["samples"]
        resolved = yaml.safe_load((folder / "scenario.resolved.yaml").read_text())
        assert resolved["seed"] == 0
        (spec,) = resolved["methods"]
        assert spec["name"] == study["methods"][index]["name"] == method
        params = spec["params"]
        assert (params["epochs"], params["max_steps"]) == (EPOCHS, MAX_STEPS)
        # the energy criterion and the network as in the study; the network seeded as the study's run seeds it
        for key in ("converge_window", "converge_tol", "image_size", "visual_layers", "joint_size"):
            assert params[key] == study["methods"][0]["params"][key]
        assert params["seed"] == seed_for(0, 1000 + index)
        assert params.get("modalities", ["visual", "tactile"]) == {
            "L": ["visual", "tactile"], "L-V": ["visual"], "L-T": ["tactile"]}[method]


def test_summary_table_lists_every_row(stage):
    tmp, record = stage
    text = subprocess.run([sys.executable, str(ROOT / "bench" / "gpu_summary.py"), str(tmp / "out")], check=True,
                          capture_output=True, text=True).stdout
    assert "## Convergence check at study size" in text and "Tiny plumbing run" in text
    table = [line for line in text.splitlines() if line.startswith("| 0 |")]
    assert len(table) == len(record["rows"]) == 9
    for line, row in zip(table, record["rows"], strict=True):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[1:3] == [row["method"], row["environment"]]
        assert float(cells[3]) == pytest.approx(row["max_f1_query_to_reference"], abs=5e-4)
        assert cells[5] == f"{row['epochs']} of {row['max_epochs']}"
