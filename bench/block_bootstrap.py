"""Within-seed block bootstrap benchmark: the time `write_summary` adds per evaluation.

    python bench/block_bootstrap.py [--n 300] [--evaluations 4] [--resamples 1000]

Writes ``--evaluations`` synthetic Q x Q evaluations (query run = reference run plus noise,
features = positions plus noise) into a temporary run folder the way the evaluate stage
saves them, then times, in the same process:
  * `evaluate` of one full Q x Q evaluation (the baseline: one replicate without compaction),
  * `evaluation_replicates` of each evaluation (``--resamples`` replicates),
  * the whole `write_summary` of those rows (over-seed statistics, p-values, six files);
  * paired rounds (``--rounds``) of one evaluation's replicates, each round timing the baseline
    (scanning every replicate's rows of the compact matrices again, as before 2026-12-07) and
    `replicate_rows` (taking each drawn query's stats from one scan), wall and CPU time, the
    ratio per round and its median; both must give the same replicates.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation import resample
from vitaplace.engine.evaluation.pairfiles import evaluate_pair
from vitaplace.engine.study import summary


def rescanned(tme: np.ndarray, gtm: np.ndarray, seed: int, ks: tuple[int, ...] = (1, 5, 10)) -> list[dict]:
    """The baseline: `evaluate` of each replicate's rows of the compact matrices (a scan each)."""
    tme_c, gtm_c = resample.compact_matrices(tme, gtm, max(ks))
    return [ev.evaluate(tme_c[rows], gtm_c[rows], 0.3, None, ks) for rows in resample.block_draws(len(tme), seed)]


def paired_rounds(tme: np.ndarray, gtm: np.ndarray, rounds: int) -> None:
    """Baseline and `replicate_rows` of one evaluation in each round; the ratio per round."""
    row = {"tau": 0.3, "delta": None, "recall_at_k": {"1": 0.0, "5": 0.0, "10": 0.0}}
    if rescanned(tme, gtm, 0) != resample.replicate_rows(tme, gtm, row, 0):
        raise SystemExit("the two ways gave different replicates")
    ratios = []
    for k in range(rounds):
        took = {}
        for name, run in (("baseline", lambda: rescanned(tme, gtm, 0)),
                          ("take", lambda: resample.replicate_rows(tme, gtm, row, 0))):
            wall, cpu = time.perf_counter(), time.process_time()
            run()
            took[name] = (time.perf_counter() - wall, time.process_time() - cpu)
        ratios.append(took["take"][0] / took["baseline"][0])
        print(f"round {k}: baseline {took['baseline'][0]:.3f} s wall {took['baseline'][1]:.3f} s CPU, "
              f"take {took['take'][0]:.3f} s wall {took['take'][1]:.3f} s CPU, ratio {ratios[-1]:.3f}")
    print(f"median ratio take / baseline (wall): {statistics.median(ratios):.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=300, help="queries and references per evaluation")
    parser.add_argument("--evaluations", type=int, default=4)
    parser.add_argument("--resamples", type=int, default=resample.RESAMPLES)
    parser.add_argument("--rounds", type=int, default=5, help="paired rounds against the baseline")
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
    paired_rounds(tme, ev.ground_truth_matrix(query, ref), args.rounds)


if __name__ == "__main__":
    main()
