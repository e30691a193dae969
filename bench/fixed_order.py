#!/usr/bin/env python
"""What the ``fixed`` backend costs: MuPNet's training on ``fixed`` against ``numpy``.

The study network (the touch benchmark's L: image 12 x 21, visual [200, 100], tactile [100],
joint 100, its converging training: 5 preconditioned solver steps per minibatch, momentum on
the weights, rows at their norm) trains ``--epochs`` epochs on a training run, once on each
backend per round, with one BLAS thread; the ratio of CPU seconds fixed / numpy is taken per
round (the machine is shared) and its median reported beside each backend's median CPU and
wall seconds. The convergence criterion is off, so both train the same epochs.

    vitaplace simulate touch-benchmark --out /tmp/tb
    python bench/fixed_order.py /tmp/tb/cache/datasets/train-*.h5 --epochs 20 --rounds 3
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import numpy as np

from vitaplace.engine.base.cpus import limit_blas_threads
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.data.dataset import open_run
from vitaplace.plugins.mupnet.extractor import MupnetExtractor

BACKENDS = ("numpy", "fixed")


def train(run_path: str, params: dict, backend: str) -> tuple[float, float]:
    """CPU and wall seconds of one fit on ``backend``, the held-out measurement's CPU excluded."""
    extractor = MupnetExtractor({**params, "backend": backend})
    extractor.progress = False
    run = open_run(run_path)
    wall, cpu = time.perf_counter(), time.process_time()
    extractor.fit(run)
    return time.process_time() - cpu - extractor.held_out_cpu_s, time.perf_counter() - wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", help="the touch benchmark's training run (HDF5)")
    ap.add_argument("--epochs", type=int, default=20, help="epochs per fit (default 20)")
    ap.add_argument("--rounds", type=int, default=3, help="paired rounds (default 3)")
    args = ap.parse_args(argv)
    limit_blas_threads(1)
    scenario, _ = load_scenario("touch-benchmark")
    params = {k: v for k, v in next(m for m in scenario.methods if m.name == "L").params.items() if k != "converge_tol"}
    params.update(epochs=args.epochs, converge_window=0)
    times: dict[str, list[tuple[float, float]]] = {b: [] for b in BACKENDS}
    for round_ in range(args.rounds):
        for backend in BACKENDS:
            times[backend].append(train(args.run, params, backend))
            print(f"round {round_ + 1} {backend}: {times[backend][-1][0]:.1f} s CPU", file=sys.stderr, flush=True)
    ratios = [f[0] / n[0] for f, n in zip(times["fixed"], times["numpy"], strict=True)]
    print(f"study network, {args.epochs} epochs, {platform.processor() or platform.machine()}, one BLAS thread, "
          f"{args.rounds} paired rounds")
    for backend in BACKENDS:
        cpu, wall = np.median([t[0] for t in times[backend]]), np.median([t[1] for t in times[backend]])
        print(f"{backend:<6} CPU {cpu:7.1f} s  wall {wall:7.1f} s")
    print(f"fixed / numpy CPU, per round: {', '.join(f'{r:.2f}' for r in ratios)}; median {np.median(ratios):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
