"""Sweeps: one scenario over many seeds, on a local process pool or a Ray cluster.

Each seed is one job running the whole pipeline into ``OUT/seed-<s>``; all jobs share the
stage cache ``OUT/cache`` (keys are content hashes, writes are atomic renames), so stages
common to several jobs are computed once when jobs run one after another and resumed
after an interruption. ``sweep.csv`` aggregates max-F1 and AUC (mean and standard
deviation over seeds) per environment x method x direction.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import multiprocessing
from collections import defaultdict
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.atomic import write_text_atomic

log = logging.getLogger("vitaplace")


def run_seed(scenario: str, overrides: Sequence[str], seed: int, out: str, progress: bool) -> list[dict[str, Any]]:
    """One sweep job: the full pipeline for ``seed``; returns its result rows tagged with the seed."""
    from vitaplace.engine.runner import Pipeline
    from vitaplace.engine.scenario import load_scenario

    loaded, resolved = load_scenario(scenario, [*overrides, f"seed={seed}"])
    pipeline = Pipeline(loaded, resolved, Path(out) / f"seed-{seed}", progress=progress, workers=1,
                        cache=Path(out) / "cache")
    return [{"seed": seed, **row} for row in pipeline.run()]


def aggregate(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean and standard deviation of max-F1 and AUC over seeds, per environment x method x direction."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        groups[(row["environment"], row["method"], row["direction"])].append(row)
    table = []
    for (env, method, direction), items in sorted(groups.items()):
        f1 = np.array([r["max_f1"] for r in items])
        auc = np.array([r["auc"] for r in items])
        table.append({
            "environment": env, "method": method, "direction": direction, "seeds": len(items),
            "max_f1_mean": float(f1.mean()), "max_f1_std": float(f1.std(ddof=1)) if len(f1) > 1 else 0.0,
            "auc_mean": float(auc.mean()), "auc_std": float(auc.std(ddof=1)) if len(auc) > 1 else 0.0,
        })
    return table


def run_sweep(
    scenario: str,
    overrides: Sequence[str],
    seeds: Sequence[int],
    out: Path | None,
    workers: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Run every seed, locally (process pool) or on Ray, and write sweep.json / sweep.csv."""
    from vitaplace.engine.scenario import load_scenario

    scenario_model, _ = load_scenario(scenario, overrides)  # validate once before fanning out
    out = Path(out or Path("runs") / f"{scenario_model.name}-sweep")
    out.mkdir(parents=True, exist_ok=True)
    if ray_address:
        try:
            import ray
        except ImportError:
            from vitaplace.engine.scenario import ScenarioError

            raise ScenarioError("--ray needs the optional dependency: pip install 'vitaplace[ray]'") from None
        ray.init(address=ray_address)
        remote = ray.remote(run_seed)
        results = ray.get([remote.remote(scenario, overrides, s, str(out), False) for s in seeds])
    else:
        context = multiprocessing.get_context("spawn")  # no fork: GL and Warp state are not fork-safe
        with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            futures = [pool.submit(run_seed, scenario, overrides, s, str(out), progress and len(seeds) == 1) for s in seeds]
            results = [f.result() for f in futures]
    rows = [row for result in results for row in result]
    table = aggregate(rows)
    write_text_atomic(out / "sweep.json", json.dumps({"runs": rows, "summary": table}, indent=2))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(table[0]) if table else ["environment"])
    writer.writeheader()
    writer.writerows(table)
    write_text_atomic(out / "sweep.csv", buffer.getvalue())
    for row in table:
        log.info(
            "%-6s %-12s max F1 %.2f ± %.2f %%  (%d seeds)",
            row["environment"], row["method"], 100 * row["max_f1_mean"], 100 * row["max_f1_std"], row["seeds"],
        )
    return table
