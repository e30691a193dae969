#!/usr/bin/env python
"""Markdown summary of a bench/gpu_check.sh run: ``python bench/gpu_summary.py DIR``.

Reads DIR/nvidia-smi.csv, stages.txt, sweep.json, bench.json and tests.log (whichever
exist) and prints the device, the three targets of the GPU benchmark, the tile sweep and
the CUDA test result.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _load(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def summary(dir_: Path) -> str:
    out = ["# GPU check", ""]
    smi = dir_ / "nvidia-smi.csv"
    if smi.exists():
        out += ["```", smi.read_text().strip(), "```", ""]
    stages = dir_ / "stages.txt"
    if stages.exists():
        out += ["Stages (exit status, seconds):", "", "```", stages.read_text().strip(), "```", ""]

    bench = _load(dir_ / "bench.json")
    if bench:
        d = bench["device"]
        out += [f"Device: {d['gpu']} ({d['multiprocessors']} SMs), torch {d['torch']} (CUDA {d['cuda']}), "
                f"warp {d['warp']}.", "", "## Training minibatch at the paper's shapes",
                "", f"B = 150, T = 20, {bench['gflop']:.1f} GFLOP per minibatch (2mnk per GEMM).", "",
                "| implementation | median ms | best ms | TFLOP/s | x cuBLAS |", "|---|---|---|---|---|"]
        for name, r in bench["results"].items():
            out.append(f"| {name} | {r['median_s'] * 1e3:.2f} | {r['best_s'] * 1e3:.2f} | {r['tflops']:.1f} | "
                       f"{r['ratio']:.2f} |")
        names = list(bench["results"])
        out += ["", "Agreement with the numpy backend (one small minibatch, max |diff| / max |numpy| of the updates): "
                + ", ".join(f"{k}: latents {v[0]:.1e}, weights {v[1]:.1e}" for k, v in bench["smoke"].items()), ""]
        if bench.get("breakdown_ms"):
            out += ["Warp float32, per operation (ms): "
                    + ", ".join(f"{k} {v:.3f}" for k, v in bench["breakdown_ms"].items()), ""]
        out += ["## Targets", ""]
        warp, torch = bench["results"][names[2]], bench["results"][names[1]]
        out += [f"- Warp step >= 0.8 x the cuBLAS GEMM rate of the same shapes: {warp['ratio']:.2f} x -> "
                f"**{_verdict(warp['ratio'] >= 0.8)}**",
                f"- Warp step ahead of the PyTorch-CUDA step: PyTorch takes {torch['median_s'] / warp['median_s']:.2f} x "
                f"the Warp time -> **{_verdict(warp['median_s'] < torch['median_s'])}**"]
        t = bench.get("training")
        if t:
            out.append(f"- The paper's 10000 epochs x 5550 samples projected at <= 30 min: "
                       f"{t['projected_min']:.1f} min ({t['epoch_s']:.3f} s per epoch over {t['epochs']} epochs, "
                       f"{t['tflops']:.1f} TFLOP/s; first epoch with compilation {t['first_epoch_s']:.0f} s; "
                       f"{t['speedup_vs_paper'][0]:.1f}-{t['speedup_vs_paper'][1]:.1f} x the paper's 5-6 h) -> "
                       f"**{_verdict(t['projected_min'] <= 30)}**")
            out.append(f"- Test-time inference of 300 samples x {t['inference_steps']} steps: "
                       f"{t['inference_300x3000_s']:.1f} s")
        out.append("")

    sweep = _load(dir_ / "sweep.json")
    if sweep:
        out += ["## Tile sweep", "", f"Shape B x n_l x n_below = {sweep['shape']}; median of graph replays.", "",
                "| kernel | precision | tm x tn x tk | block_dim | mathdx | splits | us | TFLOP/s | cuBLAS TFLOP/s |",
                "|---|---|---|---|---|---|---|---|---|"]
        cublas = sweep.get("cublas") or {}
        for r in sweep["rows"]:
            if "seconds" in r:
                us, tf = f"{r['seconds'] * 1e6:.0f}", f"{r['tflops']:.1f}"
            else:
                us, tf = r.get("error", "not run")[:60], "-"
            precision = r.get("precision", "float32")
            base = cublas.get(precision, {}).get(r["kernel"], {}).get("tflops")
            out.append(f"| {r['kernel']} | {precision} | {r['tm']}x{r['tn']}x{r['tk']} | {r['block_dim']} | "
                       f"{r['mathdx']} | {r['splits']} | {us} | {tf} | {'-' if base is None else f'{base:.1f}'} |")
        out.append("")

    tests = dir_ / "tests.log"
    if tests.exists():
        lines = [line for line in tests.read_text().splitlines() if line.strip()]
        out += ["## CUDA tests (`pytest -m cuda`)", "", "```", *(lines[-3:] if lines else ["(no output)"]), "```", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: gpu_summary.py DIR", file=sys.stderr)
        return 2
    print(summary(Path(args[0])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
