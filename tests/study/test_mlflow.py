"""The MLflow tracker with the real client (the `mlflow` extra: mlflow-skinny, SQLAlchemy,
Alembic) against a local SQLite store in the test's folder: a run logs its params, metrics
and artifacts once, a cached rerun adds nothing, a sweep is one parent run with its seeds
nested under it and its summary and PR bands attached, and the MLflow settings reach the
seeds on the local pool, on Ray (through the tasks' runtime_env: set in the driver after
Ray started, so its workers could not inherit them) and on SLURM (submitit's local executor).
Skipped where the extra is not installed; CI's third step installs it (.ci/run)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import yaml

pytest.importorskip("mlflow", reason="the MLflow extra is not installed (pip install 'vitaplace[mlflow]')")
pytest.importorskip("sqlalchemy", reason="MLflow's SQLite store needs SQLAlchemy (pip install 'vitaplace[mlflow]')")
pytest.importorskip("alembic", reason="MLflow's SQLite store needs Alembic (pip install 'vitaplace[mlflow]')")

os.environ.setdefault("MUJOCO_GL", "egl")

from mlflow.environment_variables import MLFLOW_HTTP_REQUEST_MAX_RETRIES, MLFLOW_HTTP_REQUEST_TIMEOUT  # noqa: E402
from mlflow.tracking import MlflowClient  # noqa: E402

import vitaplace.plugins.mlflow_tracking as tracker  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402

ENV_E1 = Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml"
EXPERIMENT = "vitaplace-test"
#: what every logged seed run holds (the run wrote all of them: it ran to the report)
RUN_ARTIFACTS = {"figures", "manifest.json", "report.md", "results.csv", "results.json", "scenario.resolved.yaml"}
SWEEP_ARTIFACTS = {"pr-bands", "sweep-diff.csv", "sweep-seeds.csv", "sweep.csv", "sweep.json", "sweep.md", "sweep.tex"}


def _scenario(folder: Path) -> Path:
    """A scenario of 5-sample runs and the handcrafted method: a seed takes seconds."""
    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump({
        "name": "tiny",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "H", "plugin": "handcrafted", "params": {"grid": [4, 8]}}],
        "scoring": {"tau": 0.3},
    }))
    return path


def _store(folder: Path) -> str:
    return f"sqlite:///{folder / 'mlflow.db'}"


def _runs(uri: str) -> list:
    """Every run of the test's experiment, oldest first."""
    client = MlflowClient(uri)
    experiment = client.get_experiment_by_name(EXPERIMENT)
    runs = client.search_runs([experiment.experiment_id]) if experiment else []
    return sorted(runs, key=lambda r: r.info.start_time)


def _artifacts(uri: str, run) -> set[str]:
    return {a.path for a in MlflowClient(uri).list_artifacts(run.info.run_id)}


@pytest.fixture
def tracking(tmp_path, monkeypatch) -> str:
    """This process logs into a SQLite store in ``tmp_path`` (artifacts beside it)."""
    uri = _store(tmp_path)
    monkeypatch.chdir(tmp_path)  # MLflow's default artifact root is ./mlruns
    monkeypatch.setenv("VITAPLACE_MLFLOW", EXPERIMENT)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.delenv("VITAPLACE_MLFLOW_PARENT", raising=False)
    return uri


def test_a_run_is_logged_once_and_a_rerun_that_recomputed_nothing_adds_no_run(tmp_path, tracking, monkeypatch):
    path, out = _scenario(tmp_path), tmp_path / "out"
    when_logged, log_run = [], tracker._log_run
    monkeypatch.setattr(tracker, "_log_run", lambda mlflow, client, run_id, *rest: (
        when_logged.append((client.get_run(run_id).info.status, (out / "completed.json").is_file())),
        log_run(mlflow, client, run_id, *rest))[1])
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress"]) == 0
    assert when_logged == [("RUNNING", True)]  # opened when the run started; its results logged once it is complete
    [run] = _runs(tracking)
    assert run.info.run_name == "tiny seed 0" and run.info.status == "FINISHED"
    params = run.data.params
    assert (params["scenario"], params["seed"], params["scoring.tau"]) == ("tiny", "0", "0.3")
    assert params["methods.H.plugin"] == "handcrafted" and params["methods.H.params.grid"] == "[4, 8]"
    # the resolved scenario, defaults included: runs that differ in a run setting differ in a param
    assert (params["train.run.n_samples"], params["train.run.speed"], params["evaluations.E1.run.kind"]) == (
        "5", "0.15", "route")
    assert params["scoring.recall_k"] == "[1, 5, 10]" and params["fusions"] == "[]"
    rows = json.loads((out / "results.json").read_text())
    expected = {f"E1/H/{row['direction']}/{name}": row[name] for row in rows
                for name in ("max_f1", "auc", "precision_at_max_f1", "recall_at_max_f1", "recall_at_100_precision")}
    assert all(list(row["recall_at_k"]) == ["1"] for row in rows)  # 5 references: recall@5 and @10 left out
    expected.update({f"E1/H/{row['direction']}/recall_at_1": row["recall_at_k"]["1"] for row in rows})
    assert run.data.metrics == pytest.approx(expected)
    manifest = json.loads((out / "manifest.json").read_text())
    tags = run.data.tags
    assert tags["git.commit"] == str(manifest["git_commit"]) and tags["vitaplace.stage"] == "report"
    assert (tags["mlflow.source.name"], tags["mlflow.source.type"]) == ("vitaplace", "LOCAL")
    assert tags.get("mlflow.source.git.commit") == manifest["git_commit"]  # absent outside a git checkout
    assert tags["vitaplace.out"] == str(out.resolve()) and "mlflow.parentRunId" not in tags
    assert _artifacts(tracking, run) == RUN_ARTIFACTS
    # every stage cached: nothing new to log (the run opened at its start is deleted)
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress"]) == 0
    assert [r.info.run_id for r in _runs(tracking)] == [run.info.run_id]
    # another tau: other results, another run
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress", "--set", "scoring.tau=0.4"]) == 0
    later = _runs(tracking)
    assert len(later) == 2 and later[1].data.params["scoring.tau"] == "0.4"


def test_training_epochs_are_logged_as_they_end_with_the_epoch_as_step(tmp_path, tracking, monkeypatch):
    """A MuPNet fitted for 3 epochs on vision (no touch needed): each epoch's numbers are in the
    run while it is RUNNING, at steps 1-3, equal to the training record the fit stage saved."""
    path, out = tmp_path / "learned.yaml", tmp_path / "out"
    path.write_text(yaml.safe_dump({
        "name": "tiny-learned",
        "train": {"environment": str(ENV_E1), "run": {"kind": "foraging", "n_samples": 8}},
        "evaluations": [{"name": "E1", "environment": str(ENV_E1), "run": {"kind": "route", "n_samples": 5}}],
        "methods": [{"name": "L", "plugin": "mupnet", "params": {
            "modalities": ["visual"], "image_size": [6, 8], "visual_layers": [8], "joint_size": 4, "epochs": 3,
            "converge_window": 0, "batch_size": 4, "held_out": 0.25}}],
        "scoring": {"tau": 0.3},
    }))
    statuses, log_batch = [], MlflowClient.log_batch

    def spy(self, run_id, metrics=(), *args, **kwargs):
        if any(m.key.startswith("training/") for m in metrics):
            statuses.append(self.get_run(run_id).info.status)
        return log_batch(self, run_id, metrics, *args, **kwargs)

    monkeypatch.setattr(MlflowClient, "log_batch", spy)
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress"]) == 0
    assert statuses == ["RUNNING"] * 3
    [run] = _runs(tracking)
    record = json.loads((out / "manifest.json").read_text())["training"]["L"]
    client = MlflowClient(tracking)
    for name, expected in (("held_out_energy", record["held_out"]), ("latent_change", record["latent_change"])):
        history = sorted(client.get_metric_history(run.info.run_id, f"training/L/{name}"), key=lambda m: m.step)
        assert [m.step for m in history] == [1, 2, 3]
        assert [m.value for m in history] == pytest.approx(expected, rel=1e-12)
    assert {"training/L/energy", "training/L/energy.joint.visual"} <= set(run.data.metrics)


def test_a_failed_run_keeps_its_mlflow_run_failed_with_its_error_and_params(tmp_path, tracking, monkeypatch):
    import vitaplace.engine.pipeline.orchestrate as orchestrate

    def broken(*args, **kwargs):
        raise RuntimeError("the fit broke\non two lines")

    monkeypatch.setattr(orchestrate, "fit", broken)
    with pytest.raises(RuntimeError, match="the fit broke"):  # an unexpected error: the CLI shows its traceback
        main(["-q", "run", str(_scenario(tmp_path)), "--out", str(tmp_path / "out"), "--no-progress"])
    [run] = _runs(tracking)
    assert run.info.status == "FAILED"
    assert run.data.tags["vitaplace.error"] == "RuntimeError: the fit broke on two lines"
    assert run.data.params["train.run.n_samples"] == "5" and run.info.run_name == "tiny seed 0"
    assert not run.data.metrics and tracker._open == {}


def test_a_param_longer_than_mlflow_takes_is_left_out_and_named_in_a_tag(tracking):
    from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH

    client = MlflowClient(tracking)
    run_id = client.create_run(client.create_experiment(EXPERIMENT)).info.run_id
    tracker._log_params(client, run_id, {"short": "x" * MAX_PARAM_VAL_LENGTH, "long": "y" * (MAX_PARAM_VAL_LENGTH + 1),
                                         **{f"p{i}": str(i) for i in range(150)}})  # two batches of at most 100
    run = client.get_run(run_id)
    assert set(run.data.params) == {"short", *(f"p{i}" for i in range(150))}
    assert run.data.tags["vitaplace.params_skipped"] == "long"


def _check_sweep(uri: str, out: Path, seeds: list[int]) -> str:
    """One parent run named for the sweep, FINISHED, with the summary files and PR bands, and
    one run per seed nested under it with the seed's results; returns the parent's id."""
    runs = _runs(uri)
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert len(parents) == 1 and len(runs) == len(seeds) + 1, [r.info.run_name for r in runs]
    parent = parents[0]
    assert parent.info.run_name == f"tiny sweep, seeds {' '.join(map(str, seeds))}" and parent.info.status == "FINISHED"
    assert parent.data.params["seeds"] == json.dumps(seeds) and "seed" not in parent.data.params
    assert _artifacts(uri, parent) == SWEEP_ARTIFACTS
    bands = {a.path for a in MlflowClient(uri).list_artifacts(parent.info.run_id, "pr-bands")}
    assert bands == {f"pr-bands/{p.name}" for p in out.glob("pr-bands-*")} and bands
    children = sorted((r for r in runs if r is not parent), key=lambda r: r.data.params["seed"])
    assert [r.data.tags["mlflow.parentRunId"] for r in children] == [parent.info.run_id] * len(seeds)
    for seed, child in zip(seeds, children, strict=True):
        assert child.info.run_name == f"tiny seed {seed}"
        assert child.data.tags["vitaplace.out"] == str(out / f"seed-{seed}")
        rows = json.loads((out / f"seed-{seed}" / "results.json").read_text())
        assert child.data.metrics["E1/H/query-to-reference/max_f1"] == pytest.approx(
            next(r["max_f1"] for r in rows if r["direction"] == "query-to-reference"))
    return parent.info.run_id


def test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new(tmp_path, tracking):
    path, out = _scenario(tmp_path), tmp_path / "sweep"
    args = ["-q", "sweep", str(path), "--seeds", "0", "1", "--workers", "2", "--out", str(out), "--no-progress"]
    assert main(args) == 0
    parent = _check_sweep(tracking, out, [0, 1])
    assert "VITAPLACE_MLFLOW_PARENT" not in os.environ  # the driver's environment as it was
    assert main(args) == 0  # every stage cached: the same three runs
    assert _check_sweep(tracking, out, [0, 1]) == parent


def test_a_grid_s_parent_carries_its_axes_and_its_children_are_named_by_point_and_seed(tmp_path, tracking):
    out = tmp_path / "grid"
    assert main(["-q", "sweep", str(_scenario(tmp_path)), "--seeds", "0", "--grid", "scoring.tau=0.3,0.4",
                 "--grid", "scoring.heading_tolerance_deg=30", "--out", str(out), "--no-progress"]) == 0
    runs = _runs(tracking)
    [parent] = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    assert parent.info.run_name == "tiny grid, seeds 0" and parent.info.status == "FINISHED"
    params = parent.data.params
    # the varied key's base value (0.3) is no point's: the parent has the axis instead
    assert "scoring.tau" not in params and params["grid.scoring.tau"] == "[0.3, 0.4]"
    assert params["grid.scoring.heading_tolerance_deg"] == "[30]" and params["scoring.heading_tolerance_deg"] == "30.0"
    assert params["seeds"] == "[0]" and "seed" not in params and params["train.run.n_samples"] == "5"
    children = {r.info.run_name: r for r in runs if r is not parent}
    names = {"tau=0.3,heading_tolerance_deg=30-seed0": "0.3", "tau=0.4,heading_tolerance_deg=30-seed0": "0.4"}
    assert set(children) == set(names)
    for name, tau in names.items():
        assert children[name].data.params["scoring.tau"] == tau
        assert children[name].data.tags["mlflow.parentRunId"] == parent.info.run_id


def _driver(args: list[str], folder: Path, prelude: str = "") -> subprocess.CompletedProcess:
    """The CLI in a fresh process in ``folder``, whose environment has no MLflow settings:
    ``prelude`` sets them (after starting Ray, for a Ray of its own)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MLFLOW_", "VITAPLACE_MLFLOW", "RAY_ADDRESS"))}
    code = f"import os, sys\n{prelude}\nfrom vitaplace.engine.cli.main import main\nsys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=400, env=env,
                          cwd=folder)


def _settings(uri: str) -> str:
    return f"os.environ['VITAPLACE_MLFLOW'] = {EXPERIMENT!r}\nos.environ['MLFLOW_TRACKING_URI'] = {uri!r}\n"


def test_on_ray_the_mlflow_settings_reach_the_seeds_through_their_runtime_env(tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'vitaplace[ray]')")
    temp = tempfile.mkdtemp(prefix="vp-ray-", dir="/tmp")
    prelude = ("import ray, uuid\n"
               f"ray.init(address='local', num_cpus=2, num_gpus=0, log_to_driver=False, _temp_dir={temp!r}, "
               "namespace='vitaplace-test-' + uuid.uuid4().hex)\n" + _settings(_store(tmp_path)))
    out = tmp_path / "sweep"
    try:
        result = _driver(["sweep", str(_scenario(tmp_path)), "--seeds", "0", "1", "--out", str(out), "--ray", "auto",
                          "--no-progress"], tmp_path, prelude)
    finally:
        shutil.rmtree(temp, ignore_errors=True)
    assert result.returncode == 0, result.stderr[-3000:]
    _check_sweep(_store(tmp_path), out, [0, 1])


def test_on_slurm_the_seeds_log_into_the_sweeps_parent_run(tmp_path):
    pytest.importorskip("submitit", reason="submitit is not installed (pip install 'vitaplace[slurm]')")
    out = tmp_path / "sweep"
    result = _driver(["sweep", str(_scenario(tmp_path)), "--seeds", "0", "1", "--out", str(out), "--slurm", "local",
                      "--time", "10", "--no-progress"], tmp_path, _settings(_store(tmp_path)))
    assert result.returncode == 0, result.stderr[-3000:]
    _check_sweep(_store(tmp_path), out, [0, 1])


def _closed_port() -> int:
    """A local port nothing listens on (bound, then closed)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_an_unreachable_tracking_server_costs_seconds_and_one_warning_after_the_run_is_complete(
        tmp_path, monkeypatch, capsys):
    """MLflow's defaults retry a refused connection 7 times with backoff (minutes); the
    tracker's calls give up after one retry, and the run that could not be opened at the
    start is not tried again at the end."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VITAPLACE_MLFLOW", EXPERIMENT)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"http://127.0.0.1:{_closed_port()}")
    for name in (*tracker.HTTP_SETTINGS, "VITAPLACE_MLFLOW_PARENT"):
        monkeypatch.delenv(name, raising=False)
    out = tmp_path / "out"
    started = time.time()
    assert main(["run", str(_scenario(tmp_path)), "--out", str(out), "--no-progress"]) == 0
    tracked = time.time() - (out / "completed.json").stat().st_mtime  # what the tracker cost after it
    assert tracked < 5 and time.time() - started < 60, tracked  # the run opened at the start is not tried again
    warnings = [line for line in capsys.readouterr().err.splitlines() if "MLflow" in line]
    assert len(warnings) == 1 and warnings[0].startswith(f"MLflow: the run in {out} not logged (tracking URI http")
    assert not set(tracker.HTTP_SETTINGS) & set(os.environ)  # set for the tracker's calls alone


def test_the_tracker_s_http_settings_are_mlflow_s_own_and_the_environment_overrides_them(monkeypatch, caplog):
    monkeypatch.delenv("MLFLOW_HTTP_REQUEST_TIMEOUT", raising=False)
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "4")
    with tracker._tracking("nothing"):  # an assert in here would be its warning: the values are checked after
        inside = (MLFLOW_HTTP_REQUEST_TIMEOUT.get(), MLFLOW_HTTP_REQUEST_MAX_RETRIES.get())
    assert inside == (5, 4)
    assert "MLFLOW_HTTP_REQUEST_TIMEOUT" not in os.environ and os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == "4"
    with tracker._tracking("this"):
        raise RuntimeError("tracking server down\nsecond line")
    assert "MLflow: this not logged (tracking URI" in caplog.text and "RuntimeError: tracking server down second line" \
        in caplog.text


def test_a_sweep_whose_tracking_server_is_unreachable_warns_once_and_writes_its_summary(tmp_path):
    out, uri = tmp_path / "sweep", f"http://127.0.0.1:{_closed_port()}"
    result = _driver(["sweep", str(_scenario(tmp_path)), "--seeds", "0", "1", "--workers", "2", "--out", str(out),
                      "--no-progress"], tmp_path, _settings(uri))
    assert result.returncode == 0, result.stderr[-3000:]
    warnings = [line for line in result.stderr.splitlines() if "MLflow" in line]
    assert len(warnings) == 1 and warnings[0].startswith(f"MLflow: the sweep in {out} (nor its seeds) not logged")
    assert json.loads((out / "sweep.json").read_text())["seeds"] == [0, 1]
    for seed in (0, 1):  # the seeds did not try: nothing about MLflow in their logs (their warnings go there)
        assert (out / f"seed-{seed}" / "completed.json").is_file()
        assert "MLflow" not in (out / f"seed-{seed}" / "log.txt").read_text()
