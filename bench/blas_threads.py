#!/usr/bin/env python
"""One or two BLAS threads for MuPNet's GEMM pair, idle and beside CPU-bound processes.

The pair is the first visual layer's two GEMMs of a test-time or training step at the
quickstart's shapes (image 45 x 80 x 3 = 10800 inputs, 300 latents): predict ``Y @ W``
(B x 300 by 300 x 10800) and latent ``G @ W^T`` (B x 10800 by 10800 x 300), B the batch (150,
a minibatch; the small ones are the settling solver's last samples). Rounds are paired: each
round times every batch with one thread and with two (threadpoolctl, on numpy's OpenBLAS), the
order alternating, and with ``--compete N`` the same round again while N CPU-bound processes
(busy loops this script starts and ends) run beside it. Wall and CPU seconds (this process,
all its threads: ``time.process_time``) per pair are reported as medians and as the median of
each round's two-thread / one-thread ratio. It checks that both thread counts give the same
bits (OpenBLAS splits the output, never the sum, between threads).

    python bench/blas_threads.py --rounds 7 --compete 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

#: the quickstart's first visual layer: inputs, latents
INPUTS, LATENTS = 10800, 300


def pair(W: np.ndarray, Y: np.ndarray, G: np.ndarray, P: np.ndarray, L: np.ndarray) -> None:
    np.matmul(Y, W, out=P)
    np.matmul(G, W.T, out=L)


def time_pairs(threads: int, arrays: tuple[np.ndarray, ...], repeat: int) -> tuple[float, float]:
    """Wall and CPU seconds per GEMM pair, ``repeat`` pairs on ``threads`` BLAS threads."""
    with threadpool_limits(limits=threads, user_api="blas"):
        pair(*arrays)  # wakes the pool
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(repeat):
            pair(*arrays)
        return (time.perf_counter() - wall) / repeat, (time.process_time() - cpu) / repeat


def competitors(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop(processes: list[subprocess.Popen]) -> None:
    for p in processes:
        p.terminate()
    for p in processes:
        p.wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", type=int, nargs="+", default=[150, 32, 8])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=0.5, help="about this long per timing")
    parser.add_argument("--compete", type=int, default=2, help="CPU-bound processes beside the loaded rounds")
    parser.add_argument("--json", help="write the rows here too")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    W = rng.standard_normal((LATENTS, INPUTS), dtype=np.float32)
    data = {}
    for b in args.batches:
        Y, G = rng.standard_normal((b, LATENTS), dtype=np.float32), rng.standard_normal((b, INPUTS), dtype=np.float32)
        data[b] = (W, Y, G, np.empty((b, INPUTS), np.float32), np.empty((b, LATENTS), np.float32))
        outs = []
        for threads in (1, 2):
            with threadpool_limits(limits=threads, user_api="blas"):
                pair(*data[b])
            outs.append([a.copy() for a in data[b][3:]])
        same = all(np.array_equal(x, y) for x, y in zip(*outs, strict=True))
        print(f"B={b}: one and two threads give the same bits: {same}")
    repeat = {b: max(1, int(args.seconds / time_pairs(1, data[b], 1)[0])) for b in args.batches}
    samples: dict[tuple[str, int, int], list[tuple[float, float]]] = {}
    for r in range(args.rounds):
        for load in ("idle", "loaded"):
            busy = competitors(args.compete) if load == "loaded" else []
            try:
                time.sleep(0.2 if busy else 0.0)
                for b in args.batches:
                    for threads in ((1, 2) if r % 2 == 0 else (2, 1)):
                        samples.setdefault((load, b, threads), []).append(time_pairs(threads, data[b], repeat[b]))
            finally:
                stop(busy)
    rows: list[dict[str, Any]] = []
    print(f"{'load':7} {'B':>4} | {'1 thr wall ms':>13} {'cpu ms':>7} | {'2 thr wall ms':>13} {'cpu ms':>7} | "
          f"{'2/1 wall':>8} {'2/1 cpu':>7}")
    for load in ("idle", "loaded"):
        for b in args.batches:
            one, two = samples[(load, b, 1)], samples[(load, b, 2)]
            row = {"load": load, "competitors": args.compete if load == "loaded" else 0, "batch": b,
                   "wall_ms_1": 1e3 * statistics.median(w for w, _ in one),
                   "cpu_ms_1": 1e3 * statistics.median(c for _, c in one),
                   "wall_ms_2": 1e3 * statistics.median(w for w, _ in two),
                   "cpu_ms_2": 1e3 * statistics.median(c for _, c in two),
                   "wall_ratio": statistics.median(t[0] / o[0] for o, t in zip(one, two, strict=True)),
                   "cpu_ratio": statistics.median(t[1] / o[1] for o, t in zip(one, two, strict=True))}
            rows.append(row)
            print(f"{load:7} {b:>4} | {row['wall_ms_1']:13.2f} {row['cpu_ms_1']:7.2f} | {row['wall_ms_2']:13.2f} "
                  f"{row['cpu_ms_2']:7.2f} | {row['wall_ratio']:8.2f} {row['cpu_ratio']:7.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
