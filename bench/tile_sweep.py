#!/usr/bin/env python
"""Sweep the Warp kernels' tile sizes and block_dim on one device at the paper's largest edge.

The visual input edge dominates a MuPNet minibatch (at the sizes of scenarios/paper.yaml
W is 1000 x 10800; the other edges
hold 3 % of the weights). For each kernel -- predict (M=B, N=10800, K=1000), the latent
GEMM (M=B, N=1000, K=10800, split along K) and the weight update (M=1000, N=10800, K=B)
-- every configuration is compiled (each in its own process, all at once, with a time
limit: a cuBLASDx tile GEMM takes tens of seconds to compile), checked against a float64
reference on random data, and timed as the median of several replays of a graph of
``--launches`` launches (graphs keep launch gaps out). Rows are written to ``--json`` as
they come. Where PyTorch with CUDA is installed, the same GEMMs through cuBLAS
(float32, TF32 off) are timed in the same run as the baseline.

    python bench/tile_sweep.py --device cuda --json sweep.json
    python bench/tile_sweep.py --device cpu --quick      # smoke run of the script itself
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import statistics
import sys
import time

import numpy as np
import warp as wp

import pc_step
from vitaplace.kernels import warp_kernels as wk
from vitaplace.kernels.tiles import round_rows

CANDIDATES = [
    wk.TileConfig(*c)
    for c in [
        (64, 64, 32, 128, False), (64, 64, 32, 128), (64, 128, 32, 256, False), (128, 64, 32, 256, False),
        (32, 64, 32, 128, False), (64, 64, 64, 128, False), (128, 128, 32, 256),
    ]
]
CPU_CANDIDATES = [wk.TileConfig(64, 128, 32, 1), wk.TileConfig(32, 32, 32, 1)]


def timed(fn, device: str, launches: int, repeat: int) -> float:
    """Seconds per call of ``fn``: median over ``repeat`` replays of ``launches`` calls."""
    fn()  # load the module, allocate
    wp.synchronize_device(device)
    dev = wp.get_device(device)
    if dev.is_cuda:
        with wp.ScopedCapture(device=device, force_module_load=False) as cap:
            for _ in range(launches):
                fn()
        run = lambda: wp.capture_launch(cap.graph)  # noqa: E731
    else:
        def run():
            for _ in range(launches):
                fn()
    run()
    wp.synchronize_device(device)
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        run()
        wp.synchronize_device(device)
        samples.append((time.perf_counter() - t0) / launches)
    return statistics.median(samples)


def rel_err(a, b) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def problem(b: int, n_l: int, n_below: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    Y = rng.standard_normal((b, n_l)).astype(np.float32)
    W = (rng.standard_normal((n_l, n_below)) / np.sqrt(n_l)).astype(np.float32)
    X = rng.random((b, n_below)).astype(np.float32)
    G = rng.standard_normal((b, n_below)).astype(np.float32)
    return Y, W, X, G


def _cases(device: str, shape: tuple[int, int, int], cfg: wk.TileConfig, splits_list) -> tuple[list, dict]:
    """(row, fn, output) for the three kernels of one configuration, and the references."""
    b, n_l, n_below = shape
    Y, W, X, G = problem(b, n_l, n_below)
    y64, w64, x64, g64 = (a.astype(np.float64) for a in (Y, W, X, G))
    a64 = y64 @ w64
    reference = {
        "predict": x64 - np.where(a64 > 0, a64, 0.2 * a64),
        "latent": y64 + 2 * 0.01 * (g64 @ w64.T),
        "weight": w64 + 2 * 0.01 * (y64.T @ g64),
    }
    d = lambda a: wp.array(a, dtype=wp.float32, device=device)  # noqa: E731
    wY, wW, wWt, wX, wG = d(Y), d(W), d(np.ascontiguousarray(W.T)), d(X), d(G)
    E, Gout = (wp.zeros((b, n_below), dtype=wp.float32, device=device) for _ in range(2))
    R = wp.zeros((1, b), dtype=wp.float64, device=device)
    cases = []
    for kernel in ("predict", "latent", "weight"):
        if kernel == "weight":
            tiles = cfg._replace(tk=round_rows(b, cfg.tk))
        else:
            tiles = cfg._replace(tm=round_rows(b, cfg.tm))
        for splits in splits_list if kernel == "latent" else [1]:
            row = {"kernel": kernel, "tm": tiles.tm, "tn": tiles.tn, "tk": tiles.tk, "block_dim": tiles.block_dim,
                   "mathdx": tiles.mathdx, "splits": splits}
            if kernel == "predict":
                part = wp.zeros(wk.row_partial_shape(b, n_below, tiles), dtype=wp.float32, device=device)
                out = E
                fn = lambda t=tiles, p=part: wk.predict(wY, wW, wX, E, Gout, p, R, 0, tiles=t)  # noqa: E731
            elif kernel == "latent":
                scratch = wp.zeros((splits, b, n_l), dtype=wp.float32, device=device) if splits > 1 else None
                out = wp.clone(wY)
                fn = lambda t=tiles, s=scratch, y=out: wk.latent_update(y, wG, wWt, 0.01, s, tiles=t)  # noqa: E731
            else:
                out = wp.clone(wW)
                fn = lambda t=tiles, w=out: wk.weight_update(w, wY, wG, 0.01, tiles=t)  # noqa: E731
            cases.append((row, fn, out))
    return cases, reference


def _compile(device: str, shape, cfg: tuple, splits_list) -> None:
    """Child process: compile one configuration's kernels into Warp's on-disk cache."""
    wp.config.quiet = True
    wp.init()
    cases, _ = _cases(device, shape, wk.TileConfig(*cfg), splits_list)
    with wk.planned_kernels() as plan:
        for _, fn, _ in cases:
            fn()
    wk.preload(device, plan, workers=4)


def compile_all(device: str, shape, candidates, splits_list, limit: float, log) -> set[wk.TileConfig]:
    """Compile every configuration in its own process, all at once; the ones not done
    within ``limit`` seconds are stopped. Returns the configurations that compiled."""
    ctx = multiprocessing.get_context("spawn")
    procs = {cfg: ctx.Process(target=_compile, args=(device, shape, tuple(cfg), splits_list)) for cfg in candidates}
    t0 = time.perf_counter()
    for p in procs.values():
        p.start()
    done = set()
    for cfg, p in procs.items():
        p.join(max(0.0, limit - (time.perf_counter() - t0)))
        if p.is_alive():
            p.terminate()
            p.join()
            log({"config": list(cfg), "compile": f"not done within {limit:.0f} s"})
        elif p.exitcode == 0:
            done.add(cfg)
        else:
            log({"config": list(cfg), "compile": f"failed (exit status {p.exitcode})"})
    log({"compile_all_s": round(time.perf_counter() - t0, 1), "compiled": len(done), "of": len(procs)})
    return done


def sweep(device: str, shape: tuple[int, int, int], candidates, splits_list, launches: int, repeat: int,
          log) -> list[dict]:
    """Every (kernel, configuration) checked against the float64 reference and timed; a
    configuration that does not build or run is recorded with its error."""
    b, n_l, n_below = shape
    rows = []
    for cfg in candidates:
        cases, reference = _cases(device, shape, cfg, splits_list)
        for row, fn, out in cases:
            try:
                fn()
                row["rel_err"] = rel_err(out.numpy(), reference[row["kernel"]])
                row["seconds"] = timed(fn, device, launches, repeat)
                row["tflops"] = 2 * b * n_l * n_below / row["seconds"] / 1e12
            except Exception as exc:  # noqa: BLE001 - a configuration that does not build or run is recorded
                row["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''}"
            rows.append(row)
            log(row)
    return rows


def best_tiles(rows: list[dict]) -> dict[str, dict]:
    """The fastest correct (float32-accurate) configuration of each kernel (rows of a sweep)."""
    best = {}
    for kernel in ("predict", "latent", "weight"):
        ok = [r for r in rows if r["kernel"] == kernel and "seconds" in r and r["rel_err"] < 1e-4
              and r.get("precision", "float32") == "float32"]
        if ok:
            best[kernel] = min(ok, key=lambda r: r["seconds"])
    return best


def apply_best(path: str) -> dict[str, dict]:
    """Make the kernels use the winners of the sweep saved at ``path`` (on CUDA)."""
    with open(path) as f:
        best = best_tiles(json.load(f)["rows"])
    for kernel, r in best.items():
        wk.set_tile_config(kernel, wk.TileConfig(r["tm"], r["tn"], r["tk"], r["block_dim"], r["mathdx"]))
    return best


def cublas_baseline(shape: tuple[int, int, int], repeat: int) -> dict | None:
    """The three GEMMs through torch.matmul (cuBLAS), float32 (TF32 off) and, for context, TF32."""
    try:
        import torch
    except ImportError:
        return None
    if not torch.cuda.is_available():
        return None
    b, n_l, n_below = shape
    g = torch.Generator(device="cuda").manual_seed(0)
    Y = torch.randn(b, n_l, device="cuda", generator=g)
    W = torch.randn(n_l, n_below, device="cuda", generator=g)
    G = torch.randn(b, n_below, device="cuda", generator=g)
    out = {}
    for precision in ("float32", "tf32"):
        torch.backends.cuda.matmul.allow_tf32 = precision == "tf32"
        out[precision] = {}
        for name, fn in {"predict": lambda: Y @ W, "latent": lambda: G @ W.T, "weight": lambda: Y.T @ G}.items():
            for _ in range(3):
                fn()
            torch.cuda.synchronize()
            times = []
            for _ in range(repeat):
                start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
                start.record()
                for _ in range(20):
                    fn()
                end.record()
                torch.cuda.synchronize()
                times.append(start.elapsed_time(end) / 1e3 / 20)
            t = statistics.median(times)
            out[precision][name] = {"seconds": t, "tflops": 2 * b * n_l * n_below / t / 1e12}
    torch.backends.cuda.matmul.allow_tf32 = False
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--batch", type=int, help="minibatch size (default: the paper's, scenarios/paper.yaml)")
    ap.add_argument("--quick", action="store_true", help="small shapes, two configurations")
    ap.add_argument("--launches", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--splits", type=int, nargs="*", default=[1, 4, 8],
                    help="K-slices of the latent GEMM to try (1: the fused single kernel)")
    ap.add_argument("--compile-limit", type=float, default=100.0,
                    help="seconds the configurations may take to compile (in parallel processes)")
    ap.add_argument("--json", help="write the rows to this file (rewritten after every row)")
    args = ap.parse_args(argv)
    wp.init()
    dev = wp.get_device(args.device)
    spec = pc_step.quick_spec() if args.quick else pc_step.paper_spec()
    visual = spec.config.modalities["visual"]
    shape = (args.batch or spec.batch, visual.layers[0], visual.input_size)
    candidates = CANDIDATES if dev.is_cuda else CPU_CANDIDATES
    if args.quick:
        candidates = candidates[:2]
    splits = args.splits if dev.is_cuda else [1]
    print(f"device {dev.name} ({dev.alias}), shape B x n_l x n_below = {shape}", flush=True)
    baseline = cublas_baseline(shape, args.repeat) if dev.is_cuda else None
    result = {"device": dev.name, "shape": shape, "cublas": baseline, "rows": []}

    def log(row: dict) -> None:
        print(json.dumps(row), flush=True)
        if "kernel" in row:
            result["rows"].append(row)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(result, f, indent=1)

    log({"cublas": baseline})
    if dev.is_cuda:
        compiled = compile_all(args.device, shape, candidates, splits, args.compile_limit, log)
        candidates = [c for c in candidates if c in compiled]
    sweep(args.device, shape, candidates, splits, args.launches, args.repeat, log)
    print("\nbest per kernel (median seconds per launch):")
    for kernel, r in best_tiles(result["rows"]).items():
        base = f", cuBLAS {baseline['float32'][kernel]['tflops']:.1f} TFLOP/s" if baseline else ""
        print(f"  {kernel}: {r['tm']}x{r['tn']}x{r['tk']} block_dim {r['block_dim']} mathdx {r['mathdx']} "
              f"splits {r['splits']}: {r['seconds'] * 1e6:.0f} us, {r['tflops']:.1f} TFLOP/s{base}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
