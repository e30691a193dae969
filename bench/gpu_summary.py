#!/usr/bin/env python
"""Markdown summary of a bench/gpu_check.sh run: ``python bench/gpu_summary.py DIR``.

Reads DIR/nvidia-smi.csv, stages.txt, no-cuda.txt, bench.json, sweep.json, converge.json and
tests.log (whichever exist) and prints the device, the minibatch in every precision against
cuBLAS and PyTorch, the targets, the timed training per precision (seconds per epoch, energy
band against float32), the tile sweep, the convergence check at study size
(bench/gpu_converge.py: per seed, method and world the max F1, epochs run, converged, share of
samples settled before the step cap) and the CUDA test result.
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


def _bench_section(bench: dict) -> list[str]:
    d = bench["device"]
    out = [f"Device: {d['gpu']} ({d['multiprocessors']} SMs), torch {d['torch']} (CUDA {d['cuda']}), "
           f"warp {d['warp']}.", "", "## Training minibatch at the paper's shapes",
           "", f"B = 150, T = 20, {bench['gflop']:.1f} GFLOP per minibatch (2mnk per GEMM); 'x cuBLAS' is the rate "
           "over the cuBLAS GEMMs' in the same precision.", "",
           "| implementation | precision | median ms | best ms | TFLOP/s | x cuBLAS |", "|---|---|---|---|---|---|"]
    for name, r in bench["results"].items():
        out.append(f"| {name} | {r['precision']} | {r['median_s'] * 1e3:.2f} | {r['best_s'] * 1e3:.2f} | "
                   f"{r['tflops']:.1f} | {r['ratio']:.2f} |")
    out += ["", "Agreement with the numpy backend (one small minibatch, max |diff| / max |numpy| of the updates): "
            + ", ".join(f"{k}: latents {v[0]:.1e}, weights {v[1]:.1e}" for k, v in bench["smoke"].items()), ""]
    for name, ops in bench.get("breakdown_ms", {}).items():
        out += [f"{name}, per operation (ms): " + ", ".join(f"{k} {v:.3f}" for k, v in ops.items()), ""]
    for name, why in bench.get("failed", {}).items():
        out += [f"{name}: failed, left out ({why})", ""]
    out += ["## Targets", ""]
    for precision, t in bench["targets"].items():
        out += [f"- {precision}: Warp step >= 0.8 x cuBLAS GEMMs of the same precision: {t['ratio']:.2f} x -> "
                f"**{_verdict(t['ratio'] >= 0.8)}**; ahead of the PyTorch step: PyTorch takes "
                f"{t['torch_over_warp']:.2f} x the Warp time -> **{_verdict(t['torch_over_warp'] > 1)}**"]
    per_epoch = bench.get("s_per_epoch") or {}
    if per_epoch:
        best = min(per_epoch, key=per_epoch.get)
        out += [f"- Paper-shape training, best precision ({best}): {per_epoch[best]:.3f} s per epoch -> floor "
                f"<= 0.20 s **{_verdict(per_epoch[best] <= 0.20)}**, "
                f"goal <= 0.06 s **{_verdict(per_epoch[best] <= 0.06)}**"]
        out += ["", "## Training per precision (5550 random samples)", "",
                "| precision | s per epoch | epochs timed | first epoch s | TFLOP/s | 10000 epochs, min | "
                "inference 300 x 3000 s | energy band vs float32 |", "|---|---|---|---|---|---|---|---|"]
        band = bench.get("energy_band", {})
        for precision, t in bench["training"].items():
            b = f"{band[precision]:.2e}" if precision in band else "-"
            out.append(f"| {precision} | {t['epoch_s']:.3f} | {t['epochs']} | {t['first_epoch_s']:.0f} | "
                       f"{t['tflops']:.1f} | {t['projected_min']:.1f} | {t['inference_300x3000_s']:.1f} | {b} |")
    out.append("")
    return out


def _f1(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _converge_section(conv: dict) -> list[str]:
    out = ["## Convergence check at study size (issue 34)", ""]
    if "error" in conv:
        return out + [conv["error"], ""]
    tiny = " **Tiny plumbing run** (small recorded runs: the numbers mean nothing)." if conv.get("tiny_runs") else ""
    out += [f"{conv['scenario']}, methods L, L-V, L-T on the carried recorded runs (simulated at commit "
            f"{conv['runs_commit'][:10]}), epoch cap {conv['epochs_cap']} (stopped by the energy criterion: "
            f"{conv['criterion']}), test-time step cap {conv['max_steps']}, device {conv['device']}, budget "
            f"{conv['budget_s']:.0f} s.{tiny} Seeds carried: {', '.join(conv['seeds_carried'])}; max F1 from each "
            "method's own results.json, epochs and converged from its manifest's training record, settled = share "
            "of the world's query and reference samples whose inference stopped before the cap.", ""]
    for seed, result in conv.get("seeds", {}).items():
        methods = result.get("methods", {})
        detail = ", ".join(f"{m} {r['status']} ({r['seconds']:.0f} s)" for m, r in methods.items())
        out.append(f"- seed {seed}: {result.get('status', '?')}" + (f"; {detail}" if detail else ""))
    out += ["", "| seed | method | world | max F1 q->r | max F1 r->q | epochs run | converged | settled before cap |",
            "|---|---|---|---|---|---|---|---|"]
    for r in conv.get("rows", []):
        out.append(f"| {r['seed']} | {r['method']} | {r['environment']} | {_f1(r['max_f1_query_to_reference'])} | "
                   f"{_f1(r['max_f1_reference_to_query'])} | {r['epochs']} of {r['max_epochs']} | "
                   f"{'yes' if r['converged'] else 'no'} | {r['settled_share']:.1%} ({r['samples'] - r['capped']} of "
                   f"{r['samples']}) |")
    out.append("")
    return out


def summary(dir_: Path) -> str:
    out = ["# GPU check", ""]
    smi = dir_ / "nvidia-smi.csv"
    if smi.exists():
        out += ["```", smi.read_text().strip(), "```", ""]
    stages = dir_ / "stages.txt"
    if stages.exists():
        out += ["Stages (exit status, seconds):", "", "```", stages.read_text().strip(), "```", ""]

    nocuda = dir_ / "no-cuda.txt"
    if nocuda.exists():
        out += ["**No CUDA device**: " + nocuda.read_text().strip(), ""]

    bench = _load(dir_ / "bench.json")
    if bench:
        out += _bench_section(bench)

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

    conv = _load(dir_ / "converge.json")
    if conv:
        out += _converge_section(conv)

    for log, title in (("tests.log", "CUDA tests (`pytest -m cuda`)"),
                       ("cpu-tests.log", "CPU tests (tests/kernels/test_tensorcores.py, emulated tensor cores)")):
        path = dir_ / log
        if path.exists():
            lines = [line for line in path.read_text().splitlines() if line.strip()]
            out += [f"## {title}", "", "```", *(lines[-3:] if lines else ["(no output)"]), "```", ""]
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
