#!/usr/bin/env python
"""Benchmark MuPNet's test-time inference: the paper's plain steps against the solvers that settle.

For a fitted network and the first ``--samples`` samples of a run, each configuration
(solver, latent prior, relative stopping rule, step cap) is timed through the public
``Network.infer`` on the numpy backend, interleaved round by round (the machine is shared and
noisy): each round times every configuration and the first (``gd`` with 300 steps, the
baseline) back to back, each configuration's ratio to the baseline is taken *within* the round,
and the median of those paired ratios over ``--repeat`` rounds is reported and judged (with
the CPU time beside the wall time), never a ratio of medians from different rounds. Beside it,
in the same rounds:

* ``raw GEMMs``: the GEMMs those steps need (per edge ``Y_u @ W`` and ``G @ Wt``, Wt the
  contiguous transpose the backend keeps, at the batch's shape, ``np.matmul(..., out=)``),
  timed for 20 steps and scaled to the sample-steps the configuration took (the batch is
  compacted as samples stop) -- the baseline;
* ``settled``: the share of samples whose latents (every latent layer, relative L2) are within
  ``--tolerance`` (1e-3) of a long reference solve of the same energy (same prior) in float64:
  the same solver (``--solver``: nesterov, preconditioned; gd rows against nesterov's) with the
  thresholds off, stopped at a relative step of 1e-9 or ``--reference-steps``. The energy is
  not convex (leaky ReLU), so each solver is measured against the point its own path reaches.
  The reference's own share stopped by that rule is printed: where it is under 100 %,
  "settled" is measured against a point that is not one. References are solved for the
  priors of ``--prior`` only: without 0 there, the paper's row is timed (it is the baseline)
  and its settled share is "n/a" (0 % on the quickstart, docs/MUPNET.md).

BLAS threads as vitaplace's own commands set them: one, unless ``VITAPLACE_BLAS_THREADS`` asks
for more (the header line prints the count).

The target of issue 30: >= 95 % settled at <= 1/3 of the wall time of ``gd`` with 300 steps.

    python bench/infer.py --model DIR/cache/models/L-... --run DIR/cache/datasets/E1-query-....h5
    python bench/infer.py ... --samples 450 --solver preconditioned --prior 1 --rtol 1e-5 --repeat 3 --json infer.json
    python bench/infer.py --paper-shape --train DIR/cache/datasets/train-....h5 --run ... --samples 150

``vitaplace run quickstart --out DIR`` leaves the quickstart's L and its runs in DIR/cache;
``--paper-shape`` trains a network of the paper's shape (visual 1000, 300; tactile 100; joint 200)
on ``--train`` for ``--epochs`` epochs (bench/infer_diagnose.py's loader).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np

from infer_diagnose import add_network_arguments, load, relative_distance
from vitaplace.engine.base.cpus import configure_blas_threads
from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.pc import Network
from vitaplace.engine.network.solver import Solver, make_solver


@dataclass(frozen=True)
class Setting:
    label: str
    name: str  # the solver's name (`make_solver`)
    solver: Solver
    prior: float
    cap: int


def settings(solvers: list[str], priors: list[float], rtols: list[float], cap: int) -> list[Setting]:
    out = [Setting("gd, paper's rule", "gd", make_solver("gd"), 0.0, 300)]
    for prior in priors:
        if prior:
            out.append(Setting(f"gd, prior {prior:g}", "gd", make_solver("gd"), prior, 300))
        for name in solvers:
            if make_solver(name).needs_prior and not prior:
                continue  # its preconditioners need the prior (docs/MUPNET.md)
            for rtol in rtols:
                out.append(Setting(f"{name}, prior {prior:g}, rtol {rtol:g}, cap {cap}", name,
                                   make_solver(name, rtol=rtol), prior, cap))
    return out


def float64_copy(net: Network) -> Network:
    copy = Network(net.config, seed=net.seed, backend=NumpyBackend(np.float64))
    copy.set_weights({name: w.astype(np.float64) for name, w in net.weights.items()})
    copy.scalers = net.scalers
    return copy


def reference(net64: Network, inputs, name: str, prior: float, cap: int):
    off = {e.name: 0.0 for e in net64.edges}
    x = {m: v.astype(np.float64) for m, v in inputs.items()}
    return net64.infer(x, cap, thresholds=off, batch_size=len(next(iter(x.values()))),
                       solver=make_solver(name, rtol=1e-9), latent_prior=prior)


def gemm_seconds_per_step(net: Network, inputs, batch: int) -> float:
    """Raw float32 GEMMs of one inference step at ``batch`` rows: per edge Y_u @ W and G @ W.T."""
    present = [m for m in net.modalities if m in inputs]
    rng = np.random.default_rng(0)
    work = []
    for e in net.active_edges(present):
        w = net.weights[e.name].astype(np.float32)
        y = rng.random((batch, w.shape[0]), dtype=np.float32)
        g = rng.random((batch, w.shape[1]), dtype=np.float32)
        work.append((y, w, np.ascontiguousarray(w.T), g, np.empty((batch, w.shape[1]), np.float32),
                     np.empty((batch, w.shape[0]), np.float32)))
    steps = 20
    t0 = time.perf_counter()
    for _ in range(steps):
        for y, w, wt, g, pred, back in work:  # as NumpyBackend: G @ Wt with Wt the contiguous transpose
            np.matmul(y, w, out=pred)
            np.matmul(g, wt, out=back)
    return (time.perf_counter() - t0) / steps


def settled(share: float | None) -> str:
    return "n/a" if share is None else f"{100 * share:.1f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_network_arguments(ap, samples=450)
    ap.add_argument("--batch-size", type=int, default=500, help="Network.infer's batch (the plugin's default)")
    ap.add_argument("--solver", nargs="+", default=["nesterov", "preconditioned"],
                    choices=["nesterov", "preconditioned"])
    ap.add_argument("--prior", type=float, nargs="+", default=[0.0, 1.0])
    ap.add_argument("--rtol", type=float, nargs="+", default=[1e-4, 3e-5, 1e-5, 3e-6])
    ap.add_argument("--cap", type=int, default=1000, help="the solvers' step cap (gd: 300, today's)")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved rounds (median reported)")
    ap.add_argument("--reference-steps", type=int, default=20000)
    ap.add_argument("--tolerance", type=float, default=1e-3)
    ap.add_argument("--json", help="write the numbers here")
    args = ap.parse_args(argv)
    if not args.model and not (args.paper_shape and args.train):
        ap.error("give --model, or --paper-shape with --train")
    threads = configure_blas_threads()

    net, inputs, label = load(args)
    n = len(next(iter(inputs.values())))
    nodes = net.latent_nodes([m for m in net.modalities if m in inputs])
    batch = min(args.batch_size, n)
    todo = settings(args.solver, args.prior, args.rtol, args.cap)

    net64 = float64_copy(net)
    refs = {}  # per (solver, prior): a point of the same energy that the same solver reaches
    for key in sorted({(s.name, s.prior) for s in todo if s.name != "gd"}):
        t0 = time.perf_counter()
        refs[key] = reference(net64, inputs, *key, args.reference_steps)
        print(f"reference, {key[0]}, prior {key[1]:g}: {time.perf_counter() - t0:.0f} s, median "
              f"{np.median(refs[key].steps_per_sample):.0f} steps, stopped by its rule "
              f"{100 * refs[key].settled.mean():.1f} %", file=sys.stderr, flush=True)
    # gd is measured against nesterov's solve of its energy, else preconditioned's (without 0 in
    # --prior the paper's row is timed, not measured)
    for prior in {p for _, p in refs}:
        nesterov = refs.get(("nesterov", prior))
        refs[("gd", prior)] = nesterov if nesterov is not None else refs[("preconditioned", prior)]

    walls: dict[str, list[float]] = {s.label: [] for s in todo}
    cpus: dict[str, list[float]] = {s.label: [] for s in todo}
    gemm: list[float] = []
    results = {}
    for _ in range(args.repeat):
        gemm.append(gemm_seconds_per_step(net, inputs, batch))
        for s in todo:
            t0, c0 = time.perf_counter(), time.process_time()
            results[s.label] = net.infer(inputs, s.cap, batch_size=args.batch_size, solver=s.solver,
                                         latent_prior=s.prior)
            walls[s.label].append(time.perf_counter() - t0)
            cpus[s.label].append(time.process_time() - c0)
    gemm_step = float(np.median(gemm))
    base_label = todo[0].label
    # per round, each setting's wall over the baseline's wall of the same round
    paired = {s.label: np.array(walls[s.label]) / np.array(walls[base_label]) for s in todo}

    rows = []
    for s in todo:
        r = results[s.label]
        wall = float(np.median(walls[s.label]))
        ref = refs.get((s.name, s.prior))
        dist = (relative_distance({n: r.latents[n].astype(np.float64) for n in nodes},
                                  {n: ref.latents[n] for n in nodes}) if ref is not None else np.full(n, np.nan))
        rows.append({
            "setting": s.label, "solver": s.name, "prior": s.prior, "rtol": s.solver.rtol,
            "cap": s.cap, "wall_s": wall, "cpu_s": float(np.median(cpus[s.label])),
            "ratio_median": float(np.median(paired[s.label])), "ratio_min": float(paired[s.label].min()),
            "ratio_max": float(paired[s.label].max()), "steps_median": float(np.median(r.steps_per_sample)),
            "steps_max": int(r.steps_per_sample.max()),
            "sample_steps_per_s": float(r.steps_per_sample.sum() / wall),
            "wall_over_raw_gemms": wall / (gemm_step * r.steps_per_sample.sum() / batch),
            "settled_share": float((dist < args.tolerance).mean()) if ref is not None else None,
            "stopped_by_a_rule_share": float(r.settled.mean()),
            "distance_median": float(np.median(dist)),
        })
    print(f"{label}: {n} samples, numpy backend, {platform.processor() or platform.machine()}, "
          f"{threads} BLAS thread{'s' if threads > 1 else ''}, median of {args.repeat} interleaved rounds; "
          "x gd300: the median of the per-round paired ratios (their range)")
    print(f"{'setting':<34} {'wall s':>7} {'cpu s':>7} {'x gd300':>7} {'range':>11} {'steps med/max':>13} "
          f"{'sample-steps/s':>14} {'x raw GEMMs':>11} {'settled %':>9} {'dist med':>9}")
    for row in rows:
        spread = f"{row['ratio_min']:.2f}-{row['ratio_max']:.2f}"
        print(f"{row['setting']:<34} {row['wall_s']:>7.2f} {row['cpu_s']:>7.2f} {row['ratio_median']:>7.2f} "
              f"{spread:>11} {row['steps_median']:>6.0f}/{row['steps_max']:<6d} {row['sample_steps_per_s']:>14.0f} "
              f"{row['wall_over_raw_gemms']:>11.2f} {settled(row['settled_share']):>9} {row['distance_median']:>9.2g}")
    met = [r["setting"] for r in rows if (r["settled_share"] or 0) >= 0.95 and r["ratio_median"] <= 1 / 3]
    print("target (>= 95 % settled at <= 1/3 of gd300's wall, median paired ratio):",
          ", ".join(met) if met else "not met")
    if args.json:
        payload = {"label": label, "samples": n, "blas_threads": threads, "rows": rows,
                   "gemm_seconds_per_step": gemm_step,
                   "reference": {f"{solver}, prior {p:g}": {"steps_median": float(np.median(r.steps_per_sample)),
                                                            "stopped_share": float(r.settled.mean())}
                                 for (solver, p), r in refs.items()}}
        with open(args.json, "w") as fh:
            json.dump(payload, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
