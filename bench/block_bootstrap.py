"""Within-seed block bootstrap benchmark: the time `write_summary` adds per evaluation.

    python bench/block_bootstrap.py [--n 300] [--evaluations 4] [--resamples 1000]

Writes ``--evaluations`` synthetic Q x Q evaluations (query run = reference run plus noise,
features = positions plus noise) into a temporary run folder the way the evaluate stage
saves them, then times, in the same process:
  * `evaluate` of one full Q x Q evaluation (the baseline: one replicate without compaction),
  * `evaluation_replicates` of each evaluation (``--resamples`` replicates),
  * the whole `write_summary` of those rows (over-seed statistics, p-values, six files).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation import resample
from vitaplace.engine.evaluation.pairfiles import evaluate_pair
from vitaplace.engine.study import summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="queries and references per evaluation")
    parser.add_argument("--evaluations", type=int, default=4)
    parser.add_argument("--resamples", type=int, default=resample.RESAMPLES)
    args = parser.parse_args()
    resample.RESAMPLES = args.resamples
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 12.0, args.n)
    ref = np.c_[np.cos(t), np.sin(t)] * 2.0
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for i in range(args.evaluations):
            seed, method = divmod(i, 2)
            query = ref + rng.normal(0.0, 0.05, ref.shape)
            tme = ev.ground_truth_matrix(query, ref) + rng.normal(0.0, 0.5, (args.n, args.n)) ** 2
            folder = Path(tmp) / f"seed-{seed}" / "evaluations" / "E1" / f"M{method}" / "q"
            folder.mkdir(parents=True)
            row = evaluate_pair(folder, tme, query, ref, 0.3)
            rows.append({"seed": seed, "environment": "E1", "method": f"M{method}", "direction": "q", **row})
        folders = {s: Path(tmp) / f"seed-{s}" for s in {r["seed"] for r in rows}}
        start = time.perf_counter()
        ev.evaluate(tme, ev.ground_truth_matrix(query, ref), 0.3)
        full = time.perf_counter() - start
        start = time.perf_counter()
        for row in rows:
            resample.evaluation_replicates(folders[row["seed"]], row)
        replicates = (time.perf_counter() - start) / len(rows)
        start = time.perf_counter()
        summary.write_summary(Path(tmp), rows, "bench", {}, folders)
        total = time.perf_counter() - start
    print(f"Q = {args.n}, {args.resamples} replicates")
    print(f"evaluate, full {args.n} x {args.n}: {full * 1e3:.1f} ms (one replicate without compaction)")
    print(f"block replicates per evaluation: {replicates:.2f} s ({replicates / args.resamples * 1e3:.2f} ms each)")
    print(f"write_summary of {len(rows)} evaluations: {total:.2f} s")


if __name__ == "__main__":
    main()
