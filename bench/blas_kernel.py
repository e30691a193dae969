#!/usr/bin/env python
"""How far a scenario's max F1 moves when only the BLAS kernel changes.

OpenBLAS picks its SGEMM kernel for the CPU it runs on (threadpoolctl's ``architecture``); a
machine of another generation, or ``OPENBLAS_CORETYPE``, picks another, whose sums round
differently in the last bits. This runs one scenario once per kernel, one BLAS thread each,
the same seed: the first kernel runs the whole pipeline, every other one reuses its simulated
runs (a copy of its cache's datasets: MuJoCo uses no BLAS, and on one machine the same settings simulate
the same bits; on another machine they need not, docs/DESIGN.md "Rounding") and redoes fit, transform,
evaluate and report. It prints each method's max F1 per kernel and the largest move against the first.

    python bench/blas_kernel.py --out /tmp/kernels                          # quickstart, native vs Haswell
    python bench/blas_kernel.py touch-benchmark --kernels native Haswell --out /tmp/kernels-tb
    python bench/blas_kernel.py --kernels native Haswell Sandybridge --json kernels.json

``native`` leaves ``OPENBLAS_CORETYPE`` unset (the kernel OpenBLAS picks for this CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

#: the stages a kernel other than the first redoes (simulate is reused)
REDONE = ("fit", "transform", "evaluate", "report")


def kernel_env(kernel: str) -> dict[str, str]:
    """The environment of one kernel's run: one BLAS thread, ``OPENBLAS_CORETYPE`` unless native."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    env.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", VITAPLACE_BLAS_THREADS="1")
    env.setdefault("MUJOCO_GL", "egl")
    if kernel != "native":
        env["OPENBLAS_CORETYPE"] = kernel
    return env


def architecture(env: dict[str, str]) -> str:
    """The kernel numpy's OpenBLAS reports under ``env`` (`blas_libraries`' ``architecture``)."""
    code = ("from vitaplace.engine.base.cpus import blas_libraries\n"
            "print(','.join(sorted({str(lib['architecture']) for lib in blas_libraries()})))")
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def run_kernel(scenario: str, kernel: str, out: Path, first: Path | None, sets: list[str]) -> dict[str, Any]:
    """Run ``scenario`` under ``kernel`` into ``out``; reuse ``first``'s simulated runs when given."""
    env = kernel_env(kernel)
    command = [sys.executable, "-m", "vitaplace.engine.cli.main", "-q", "run", scenario, "--out", str(out), "--json"]
    command += [f"--set={s}" for s in sets]
    if first is not None:
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(first / "cache" / "datasets", out / "cache" / "datasets")
        command += [f"--force={stage}" for stage in REDONE]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{kernel}: vitaplace run failed ({done.returncode}):\n{done.stderr[-3000:]}")
    rows = json.loads(done.stdout)
    f1 = {"/".join(str(r[k]) for k in ("environment", "method", "direction") if r.get(k)): float(r["max_f1"])
          for r in rows}
    return {"kernel": kernel, "architecture": architecture(env), "max_f1": f1, "wall_s": round(wall, 1),
            "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", nargs="?", default="quickstart")
    parser.add_argument("--kernels", nargs="+", default=["native", "Haswell"],
                        help="OPENBLAS_CORETYPE values, 'native' for none (default: native Haswell)")
    parser.add_argument("--out", type=Path, required=True, help="folder for one run per kernel")
    parser.add_argument("--set", action="append", default=[], help="passed on to vitaplace run --set")
    parser.add_argument("--json", type=Path, help="write the rows here too")
    args = parser.parse_args(argv)
    rows: list[dict[str, Any]] = []
    for kernel in args.kernels:
        first = args.out / args.kernels[0] if rows else None
        rows.append(run_kernel(args.scenario, kernel, args.out / kernel, first, args.set))
        print(json.dumps(rows[-1]), flush=True)
    base = rows[0]["max_f1"]
    for row in rows[1:]:
        moves = {name: round(100 * (row["max_f1"][name] - f1), 2) for name, f1 in base.items()}
        print(f"{row['kernel']} ({row['architecture']}) against {rows[0]['kernel']} ({rows[0]['architecture']}): "
              f"max F1 moves (points) {moves}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
