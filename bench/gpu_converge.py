#!/usr/bin/env python
"""The converged-network check of issue 34: MuPNet (L, L-V, L-T) at study size, trained until
the energy criterion stops it, inferred with the paper's step cap, on recorded runs.

The study (scenarios/paper-cpu.yaml, docs/RESULTS.md) capped training at 90 epochs and
test-time inference at 300 steps; no network converged and every inference hit the cap.
This check reruns its three MuPNet methods on the same runs of a seed with the epoch cap
raised (default 1000; the criterion, converge_window 20 / converge_tol 0.01, unchanged)
and max_steps 3000, through the project's own pipeline (``vitaplace evaluate``), and
records per method and world the max F1, the epochs run, whether training converged and
the share of samples that settled before the step cap.

MuJoCo is not on the lent GPU machines, so the runs are simulated here and carried:

    python bench/gpu_converge.py pack --seeds 0 1 --dest .gpu-carry-runs    # (bench/gpu_runs.sh)
    python bench/gpu_converge.py run --runs .gpu-carry-runs --out DIR --budget 200

``pack`` simulates each seed's seven runs of paper-cpu.yaml (``vitaplace simulate``; cached in
runs/gpu-runs/seed-N) and packs them into DEST/seed-N.tar.xz with DEST/RUNS.json (checksums,
sizes, sample counts, the commit). ``--tiny`` simulates a 40-sample training run and 20-sample
drives instead (the CPU test of the plumbing).

``run`` unpacks each seed's archive (checksum checked), and runs the three methods as three
``vitaplace evaluate`` processes side by side, each with the scenario's methods cut to one and
the seed the study would have derived for it at its index (so that every network starts as in
the study), the runs switched to the recorded files and query_off_route set to 0 (the detours
are in the recorded query runs already; scoring does not read it). Seeds run in RUNS.json's
order while the budget (seconds) leaves time for another seed as long as the last one took;
the first always starts. DIR/converge.json is rewritten after every seed (so a stage killed
by its time limit still leaves the finished seeds); each method's pipeline folder is under
--work (default: a temporary folder), its results.json, manifest.json and log.txt copied to
DIR/converge/seed-N/METHOD/.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "paper-cpu.yaml"
#: the study's MuPNet methods, in the scenario's order (their index derives their seed)
METHODS = ("L", "L-V", "L-T")
WORLDS = ("E1", "E2", "E3")
LABELS = ("train", *(f"{w}/{role}" for w in WORLDS for role in ("query", "reference")))
TINY = {"train.run.n_samples": 40, **{f"evaluations.{i}.run.n_samples": 20 for i in range(len(WORLDS))}}


def _member(label: str) -> str:
    return label.replace("/", "-") + ".h5"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _write_json(path: Path, data: object) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, path)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "vitaplace.engine.cli.main", "-q", *args]


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def pack(seeds: list[int], dest: Path, sim_root: Path, tiny: bool) -> dict:
    """Simulate each seed's runs of paper-cpu.yaml and pack them into DEST/seed-N.tar.xz."""
    dest.mkdir(parents=True, exist_ok=True)
    for old in dest.glob("seed-*.tar.xz"):
        old.unlink()
    record: dict = {"scenario": "scenarios/paper-cpu.yaml", "tiny": tiny, "git_commit": _git_commit(), "seeds": {}}
    for seed in seeds:
        out = sim_root / (f"seed-{seed}" + ("-tiny" if tiny else ""))
        sets = [f"seed={seed}", *(f"{k}={v}" for k, v in (TINY.items() if tiny else ()))]
        t0 = time.perf_counter()
        subprocess.run(_cli("simulate", str(SCENARIO), *(a for s in sets for a in ("--set", s)), "--out", str(out),
                            "--no-progress"), check=True, cwd=ROOT)
        simulate_s = time.perf_counter() - t0
        manifest = json.loads((out / "manifest.json").read_text())
        archive = dest / f"seed-{seed}.tar.xz"
        raw = 0
        with tarfile.open(archive, "w:xz", preset=6) as tar:
            for label in LABELS:
                path = out / "cache" / "datasets" / f"{label.replace('/', '-')}-{manifest['datasets'][label]}.h5"
                raw += path.stat().st_size
                tar.add(path, arcname=_member(label))
        record["seeds"][str(seed)] = {
            "file": archive.name, "sha256": _sha256(archive), "bytes": archive.stat().st_size, "raw_bytes": raw,
            "samples": {label: manifest["runs"][label]["samples"] for label in LABELS},
            "dataset_keys": manifest["datasets"], "simulate_s": round(simulate_s, 1), "overrides": sets,
        }
        _write_json(dest / "RUNS.json", record)
        print(f"seed {seed}: {archive} {archive.stat().st_size / 2**20:.2f} MiB (run files {raw / 2**20:.1f} MiB), "
              f"simulated in {simulate_s:.0f} s", flush=True)
    return record


def _method_overrides(scenario_seed: int, runs_dir: Path, method: str, epochs: int, max_steps: int) -> list[str]:
    """--set assignments: the recorded runs of ``runs_dir``, one method with the study's seed for it."""
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.pipeline.plan import seed_for

    scenario, _ = load_scenario(SCENARIO, [f"seed={scenario_seed}"])
    index = [m.name for m in scenario.methods].index(method)
    spec = scenario.methods[index].model_dump(mode="json")
    params = dict(spec.get("params") or {})
    params.setdefault("seed", seed_for(scenario_seed, 1000 + index))  # what the study's run derived for it
    params.update(epochs=epochs, max_steps=max_steps)
    one = {"name": spec["name"], "plugin": spec["plugin"], "params": params}
    sets = [f"seed={scenario_seed}", "train.environment=null", "train.run=null",
            f"train.dataset={json.dumps(str(runs_dir / _member('train')))}", f"methods={json.dumps([one])}"]
    for i, world in enumerate(WORLDS):
        assert scenario.evaluations[i].name == world
        files = {role: str(runs_dir / _member(f"{world}/{role}")) for role in ("query", "reference")}
        sets += [f"evaluations.{i}.run=null", f"evaluations.{i}.query_off_route=0",
                 f"evaluations.{i}.datasets={json.dumps(files)}"]
    return sets


def _rows(seed: int, method: str, out: Path) -> list[dict]:
    """The table's rows of one method's pipeline folder: read from its results.json and manifest.json."""
    results = json.loads((out / "results.json").read_text())
    manifest = json.loads((out / "manifest.json").read_text())
    training = manifest["training"][method]
    features = manifest["features"][method]
    rows = []
    for world in WORLDS:
        f1 = {r["direction"]: r["max_f1"] for r in results if r["environment"] == world and r["method"] == method}
        inference = {role: features[f"{world}/{role}"]["inference"] for role in ("query", "reference")}
        samples = sum(i["samples"] for i in inference.values())
        capped = sum(i["capped"] for i in inference.values())
        rows.append({
            "seed": seed, "method": method, "environment": world,
            "max_f1_query_to_reference": f1.get("query-to-reference"),
            "max_f1_reference_to_query": f1.get("reference-to-query"),
            "epochs": training["epochs"], "max_epochs": training["max_epochs"], "converged": training["converged"],
            "samples": samples, "capped": capped, "settled_share": (samples - capped) / samples,
            "max_steps_taken": max(i["max"] for i in inference.values()),
            "median_steps": {role: i["median"] for role, i in inference.items()},
        })
    return rows


def _unpack(runs: Path, seed: str, entry: dict, where: Path) -> Path:
    archive = runs / entry["file"]
    if _sha256(archive) != entry["sha256"]:
        raise RuntimeError(f"{archive}: checksum differs from RUNS.json (incomplete carry?)")
    target = where / f"runs-{seed}"
    shutil.rmtree(target, ignore_errors=True)
    target.mkdir(parents=True)
    with tarfile.open(archive, "r:xz") as tar:
        names = tar.getnames()
        if sorted(names) != sorted(_member(label) for label in LABELS):
            raise RuntimeError(f"{archive}: unexpected members {names}")
        tar.extractall(target)
    return target


#: the running pipeline processes, stopped (whole process groups) if this script is terminated
_RUNNING: list[subprocess.Popen] = []


def _stop_running(signum: int, frame: object) -> None:
    for proc in _RUNNING:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    sys.exit(128 + signum)


def _run_seed(seed: str, runs_dir: Path, work: Path, out_dir: Path, epochs: int, max_steps: int,
              deadline: float) -> dict:
    """The three methods of one seed as three side-by-side ``vitaplace evaluate`` processes."""
    procs = {}
    t0 = time.perf_counter()
    for method in METHODS:
        folder = work / f"seed-{seed}" / method
        shutil.rmtree(folder, ignore_errors=True)
        folder.parent.mkdir(parents=True, exist_ok=True)
        sets = _method_overrides(int(seed), runs_dir, method, epochs, max_steps)
        log = (out_dir / f"seed-{seed}-{method}.log").open("w")
        cmd = _cli("evaluate", str(SCENARIO), *(a for s in sets for a in ("--set", s)), "--out", str(folder),
                   "--no-progress")
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        _RUNNING.append(proc)
        procs[method] = (proc, folder, log)
    methods = {}
    for method, (proc, folder, log) in procs.items():
        try:
            rc = proc.wait(timeout=max(1.0, deadline - time.monotonic()))
            status = "done" if rc == 0 else "failed"
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            rc, status = proc.wait(), "timed out"
        log.close()
        entry = {"status": status, "rc": rc, "seconds": round(time.perf_counter() - t0, 1), "work": str(folder)}
        if status == "done":
            keep = out_dir / "converge" / f"seed-{seed}" / method
            keep.mkdir(parents=True, exist_ok=True)
            for name in ("results.json", "manifest.json", "log.txt"):
                shutil.copy2(folder / name, keep / name)
            entry["rows"] = _rows(int(seed), method, folder)
        methods[method] = entry
    return {"seconds": round(time.perf_counter() - t0, 1), "methods": methods}


def run(runs: Path, out_dir: Path, budget: float, epochs: int, max_steps: int, work: Path | None,
        seeds: list[str] | None) -> int:
    start = time.monotonic()
    deadline = start + budget
    signal.signal(signal.SIGTERM, _stop_running)
    out_dir.mkdir(parents=True, exist_ok=True)
    work = work or Path(tempfile.mkdtemp(prefix="vitaplace-converge-"))
    record_path = out_dir / "converge.json"
    try:
        carried = json.loads((runs / "RUNS.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        _write_json(record_path, {"error": f"no recorded runs: {exc} (bench/gpu_runs.sh, then carry {runs})"})
        print(f"no recorded runs in {runs}: {exc}", file=sys.stderr)
        return 1
    try:
        from vitaplace.engine.network.selection import cuda_available
        device = "cuda" if cuda_available() else "cpu"
    except Exception as exc:  # noqa: BLE001 - recorded, not fatal: the pipeline says what is missing
        device = f"unknown ({type(exc).__name__}: {exc})"
    missing = []
    for module in ("h5py", "matplotlib", "pluggy", "pydantic", "scipy", "threadpoolctl", "tqdm", "warp", "yaml"):
        try:
            __import__(module)
        except ImportError:
            missing.append(module)
    if missing:
        _write_json(record_path, {"error": f"the pipeline cannot run here: no module {', '.join(missing)} "
                                           "(bench/gpu_wheels.sh carries their wheels in deps/; scipy is not carried)"})
        print(f"missing modules: {', '.join(missing)}", file=sys.stderr)
        return 1
    record = {"scenario": carried["scenario"], "runs_commit": carried["git_commit"], "tiny_runs": carried["tiny"],
              "epochs_cap": epochs, "max_steps": max_steps, "budget_s": budget, "device": device,
              "criterion": "converge_window 20, converge_tol 0.01 (paper-cpu.yaml)",
              "seeds_carried": sorted(carried["seeds"], key=int), "seeds": {}, "rows": []}
    _write_json(record_path, record)
    status = 0
    last = 0.0
    for seed in seeds or sorted(carried["seeds"], key=int):
        left = deadline - time.monotonic()
        if record["seeds"] and left < 1.2 * last:
            record["seeds"][seed] = {"status": f"not started: {left:.0f} s left, the last seed took {last:.0f} s"}
            _write_json(record_path, record)
            continue
        try:
            runs_dir = _unpack(runs, seed, carried["seeds"][seed], work)
            result = _run_seed(seed, runs_dir, work, out_dir, epochs, max_steps, deadline)
        except Exception as exc:  # noqa: BLE001 - recorded in the results file
            result = {"status": f"failed: {type(exc).__name__}: {exc}", "methods": {}}
            status = 1
        last = result.get("seconds", 0.0)
        states = {m["status"] for m in result["methods"].values()}
        result.setdefault("status", "done" if states == {"done"} else ", ".join(sorted(states)) or "failed")
        if states != {"done"}:
            status = 1
        record["seeds"][seed] = result
        record["rows"] += [row for m in result["methods"].values() for row in m.get("rows", [])]
        record["seconds"] = round(time.monotonic() - start, 1)
        _write_json(record_path, record)
        print(f"seed {seed}: {result['status']} in {last:.0f} s", flush=True)
    return status


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="simulate the seeds' runs here and pack them for the device")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--dest", type=Path, default=ROOT / ".gpu-carry-runs")
    p.add_argument("--sim-root", type=Path, default=ROOT / "runs" / "gpu-runs")
    p.add_argument("--tiny", action="store_true", help="40-sample training run, 20-sample drives")
    r = sub.add_parser("run", help="train, infer and score L, L-V, L-T on the carried runs")
    r.add_argument("--runs", type=Path, default=ROOT / ".gpu-carry-runs")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--budget", type=float, default=240.0, help="seconds for all seeds")
    r.add_argument("--epochs", type=int, default=1000, help="epoch cap (the energy criterion stops earlier)")
    r.add_argument("--max-steps", type=int, default=3000, help="test-time inference step cap")
    r.add_argument("--work", type=Path, default=None, help="the pipeline folders (default: a temporary folder)")
    r.add_argument("--seeds", nargs="+", default=None, help="default: every carried seed, in order")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    if args.command == "pack":
        pack(args.seeds, args.dest, args.sim_root, args.tiny)
        return 0
    return run(args.runs, args.out, args.budget, args.epochs, args.max_steps, args.work, args.seeds)


if __name__ == "__main__":
    sys.exit(main())
