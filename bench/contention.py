#!/usr/bin/env python
"""A scenario's CPU and wall time alone and beside CPU-bound processes, per BLAS thread count.

For each ``VITAPLACE_BLAS_THREADS`` value (``--threads``, default 1 and 2: today's default and
the former one, a thread per core), the scenario's learning stages (fit, transform, evaluate,
report; the simulated runs are made once, first, and reused) run once on the machine as it is
("idle") and once while ``--compete`` CPU-bound processes (busy loops this script starts and
ends) run beside them, in paired rounds. Reported: the CPU seconds (the run's process and its
children) and wall seconds of each, and per thread count the loaded / idle ratios, the medians
over ``--rounds``. The target of issue 50: CPU ratio <= 1.2 and wall ratio <= 3 with two
competitors.

    python bench/contention.py --out /tmp/contention --rounds 2
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blas_threads import competitors, stop  # noqa: E402 - the same busy loops as the GEMM benchmark

#: the stages every timed run redoes
REDONE = ("fit", "transform", "evaluate", "report")


def vitaplace(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Run ``vitaplace ARGS`` in a process of its own: (wall, CPU) seconds, CPU of it and its children."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "vitaplace.engine.cli.main", "-q", *args], env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"vitaplace {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", nargs="?", default="quickstart")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="VITAPLACE_BLAS_THREADS values")
    parser.add_argument("--compete", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                             "MKL_NUM_THREADS", "VITAPLACE_BLAS_THREADS")}
    base.setdefault("MUJOCO_GL", "egl")
    sim = args.out / "simulated"
    vitaplace(["simulate", args.scenario, "--out", str(sim)], base)
    times: dict[tuple[int, str], list[tuple[float, float]]] = {}
    for r in range(args.rounds):
        for threads in args.threads if r % 2 == 0 else args.threads[::-1]:
            for load in ("idle", "loaded"):
                out = args.out / f"t{threads}-{load}"
                shutil.rmtree(out, ignore_errors=True)
                shutil.copytree(sim / "cache" / "datasets", out / "cache" / "datasets")
                busy = competitors(args.compete) if load == "loaded" else []
                try:
                    timed = vitaplace(["run", args.scenario, "--out", str(out), *[f"--force={s}" for s in REDONE]],
                                      {**base, "VITAPLACE_BLAS_THREADS": str(threads)})
                finally:
                    stop(busy)
                times.setdefault((threads, load), []).append(timed)
                print(f"round {r}, {threads} BLAS thread(s), {load}: wall {timed[0]:.1f} s, CPU {timed[1]:.1f} s",
                      flush=True)
    rows: list[dict[str, Any]] = []
    for threads in args.threads:
        idle, loaded = times[(threads, "idle")], times[(threads, "loaded")]
        row = {"threads": threads, "competitors": args.compete,
               "idle_wall_s": statistics.median(w for w, _ in idle),
               "idle_cpu_s": statistics.median(c for _, c in idle),
               "loaded_wall_s": statistics.median(w for w, _ in loaded),
               "loaded_cpu_s": statistics.median(c for _, c in loaded),
               "wall_ratio": statistics.median(b[0] / a[0] for a, b in zip(idle, loaded, strict=True)),
               "cpu_ratio": statistics.median(b[1] / a[1] for a, b in zip(idle, loaded, strict=True))}
        rows.append(row)
        print(f"{threads} BLAS thread(s): idle {row['idle_wall_s']:.1f} s wall / {row['idle_cpu_s']:.1f} s CPU, "
              f"{args.compete} competitors {row['loaded_wall_s']:.1f} s / {row['loaded_cpu_s']:.1f} s: "
              f"wall x{row['wall_ratio']:.2f}, CPU x{row['cpu_ratio']:.2f}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
