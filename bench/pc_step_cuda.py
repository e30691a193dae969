"""``bench/pc_step.py --device cuda``: the training minibatch at the paper's shapes on a GPU.

Measured in one run, on one GPU, interleaved round by round (median over rounds):

* ``cuBLAS GEMMs``  the GEMMs of one minibatch, same shapes and transposes, through
                    ``torch.matmul(..., out=)`` (cuBLAS, float32, TF32 off), replayed as
                    one CUDA graph: the baseline, the rate of the arithmetic alone;
* ``torch step``    the same minibatch written in PyTorch (bench/pc_step.py ``TorchImpl``),
                    captured as a CUDA graph;
* ``warp backend``  the project's step: ``BatchState`` on ``WarpBackend('cuda')``, captured
                    as a CUDA graph by the backend, exactly as ``Network.train`` runs it;
* for context, the cuBLAS GEMMs and the PyTorch step again with TF32 tensor-core GEMMs
  (inputs rounded to 10 mantissa bits): not the same arithmetic, so not a target.

Every implementation reads its energies back and checks them once per minibatch (one
host round trip), and each timed sample is a host clock around ``--minibatches``
consecutive minibatches after a device synchronisation.

Then, on the Warp backend: a timed training at the paper's shapes on 5550 random samples
(the first epoch, which compiles and captures, timed apart; then ``--epochs`` epochs),
projected to the paper's 10000 epochs, and test-time inference of 300 samples for 3000
steps (thresholds 0: every sample runs to the cap).
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable

import numpy as np

PAPER_EPOCHS = 10_000
PAPER_SAMPLES = 5550
# The paper's hardware time for that budget (GTX 1080 Ti, 5-6 hours): the anchor.
PAPER_HOURS = (5.0, 6.0)


class TorchGemms:
    """Only the GEMMs of the step (no epilogue) through cuBLAS, as one CUDA graph."""

    def __init__(self, prob, torch, tf32: bool = False) -> None:
        self.torch, self.prob, self.tf32 = torch, prob, tf32
        gen = torch.Generator(device="cuda").manual_seed(7)
        r = lambda *shape: torch.randn(*shape, device="cuda", generator=gen) * 0.1  # noqa: E731
        sz, b = prob.sizes, prob.batch
        self.W = {e.name: r(sz[e.upper], sz[e.lower]) for e in prob.edges}
        self.Wo = {e.name: torch.empty_like(self.W[e.name]) for e in prob.edges}
        self.Y = {n: r(b, sz[n]) for n in prob.latents}
        self.Yo = {n: torch.empty_like(y) for n, y in self.Y.items()}
        self.A = {e.name: r(b, sz[e.lower]) for e in prob.edges}
        self.G = {e.name: r(b, sz[e.lower]) for e in prob.edges}
        self.graph = None

    def _body(self) -> None:
        mm, edges = self.torch.matmul, self.prob.edges
        for _ in range(self.prob.steps + 1):
            for e in edges:
                mm(self.Y[e.upper], self.W[e.name], out=self.A[e.name])
        for _ in range(self.prob.steps):
            for e in edges:
                mm(self.G[e.name], self.W[e.name].t(), out=self.Yo[e.upper])
        for e in edges:
            mm(self.Y[e.upper].t(), self.G[e.name], out=self.Wo[e.name])

    def reset(self) -> None:
        pass

    def run(self) -> None:
        if self.graph is None:
            self.torch.backends.cuda.matmul.allow_tf32 = self.tf32  # fixed in the graph at capture
            self._body()  # warm-up: cuBLAS handles and workspaces
            self.torch.cuda.synchronize()
            self.graph = self.torch.cuda.CUDAGraph()
            with self.torch.cuda.graph(self.graph):
                self._body()
        self.graph.replay()


def _sync(torch, wp) -> None:
    torch.cuda.synchronize()
    wp.synchronize_device("cuda")


def time_minibatches(impl, count: int, sync: Callable[[], None]) -> float:
    """Seconds per minibatch over ``count`` consecutive minibatches (after a sync)."""
    sync()
    t0 = time.perf_counter()
    for _ in range(count):
        impl.run()
    sync()
    return (time.perf_counter() - t0) / count


def op_breakdown(impl, repeat: int, sync: Callable[[], None]) -> dict[str, float]:
    """Milliseconds of each operation of the Warp minibatch (predict_all without energies,
    latent_step, weight_step), each replayed as a graph of 20 and timed over ``repeat``."""
    s, be = impl.state, impl.net.backend
    ops = {"predict_all": lambda: s.predict_all(energy=False), "latent_step": s.latent_step, "weight_step": s.weight_step}
    out = {}
    for name, op in ops.items():
        run = be.capture(lambda op=op: [op() for _ in range(20)])
        run()
        run()
        times = []
        for _ in range(repeat):
            sync()
            t0 = time.perf_counter()
            run()
            sync()
            times.append((time.perf_counter() - t0) / 20)
        out[name] = statistics.median(times) * 1e3
    return out


def timed_training(pc, epochs: int, samples: int, log) -> dict:
    """The paper's network trained on random data: the first epoch (kernel compilation,
    graph capture) timed apart, then ``epochs`` epochs; projected to the paper's budget."""
    from vitaplace.engine.backends import WarpBackend
    from vitaplace.engine.pc import Network

    import warp as wp

    spec = pc.PAPER
    rng = np.random.default_rng(0)
    mods = spec["config"]["modalities"]
    inputs = {m: rng.random((samples, mc["input_size"]), dtype=np.float32) for m, mc in mods.items()}
    net = Network(spec["config"], seed=0, backend=WarpBackend("cuda"))
    train = {"batch_size": spec["batch"], "inference_steps": spec["steps"]}
    latents: dict[str, np.ndarray] = {}
    t0 = time.perf_counter()
    net.train(inputs, {**train, "epochs": 1}, progress=False, latents=latents)
    wp.synchronize_device("cuda")
    first = time.perf_counter() - t0
    log(f"  first epoch (compile + capture + run): {first:.1f} s")
    t0 = time.perf_counter()
    history = net.train(inputs, {**train, "epochs": epochs}, progress=False, latents=latents)
    wp.synchronize_device("cuda")
    per_epoch = (time.perf_counter() - t0) / epochs
    full = [spec["batch"]] * (samples // spec["batch"]) + ([samples % spec["batch"]] if samples % spec["batch"] else [])
    prob_flops = pc.make_problem(spec).flops() / spec["batch"]  # per sample of a minibatch
    flops_epoch = prob_flops * sum(full)
    projected = per_epoch * PAPER_EPOCHS
    log(f"  {epochs} epochs: {per_epoch:.3f} s per epoch, {flops_epoch / per_epoch / 1e12:.1f} TFLOP/s; "
        f"{PAPER_EPOCHS} epochs projected: {projected / 60:.1f} min "
        f"(paper: {PAPER_HOURS[0]:.0f}-{PAPER_HOURS[1]:.0f} h, {PAPER_HOURS[0] * 3600 / projected:.1f}-"
        f"{PAPER_HOURS[1] * 3600 / projected:.1f} x faster)")
    energy = {k: v[-1] for k, v in history.energy.items()}
    if not all(np.isfinite(list(energy.values()))):
        raise RuntimeError(f"training diverged: {energy}")
    result = {"first_epoch_s": first, "epochs": epochs, "samples": samples,
              "epoch_s": per_epoch, "tflops": flops_epoch / per_epoch / 1e12, "projected_min": projected / 60,
              "speedup_vs_paper": [h * 3600 / projected for h in PAPER_HOURS], "energy": energy}

    test = {m: x[:300] for m, x in inputs.items()}
    never = {e.name: 0.0 for e in net.edges}
    net.infer(test, max_steps=10, thresholds=never)  # compile the inference kernels
    t0 = time.perf_counter()
    inferred = net.infer(test, max_steps=3000, thresholds=never)
    infer_s = time.perf_counter() - t0
    log(f"  inference, 300 samples x {inferred.steps} steps: {infer_s:.2f} s")
    return {**result, "inference_300x3000_s": infer_s, "inference_steps": inferred.steps}


def cuda_main(args, pc) -> dict:
    """Run the CUDA benchmark; ``pc`` is the bench/pc_step.py module (problems, impls)."""
    import torch
    import warp as wp

    from vitaplace.engine.backends import WarpBackend

    if not torch.cuda.is_available():
        raise SystemExit("--device cuda: PyTorch sees no CUDA device")
    wp.init()
    dev = torch.cuda.get_device_properties(0)
    info = {"gpu": dev.name, "multiprocessors": dev.multi_processor_count, "memory_gib": dev.total_memory / 2**30,
            "torch": torch.__version__, "cuda": torch.version.cuda, "warp": wp.__version__}
    print(f"device: {info['gpu']}, {info['multiprocessors']} SMs, {info['memory_gib']:.0f} GiB; "
          f"torch {info['torch']} (CUDA {info['cuda']}), warp {info['warp']}", flush=True)
    sync = lambda: _sync(torch, wp)  # noqa: E731

    print("\nsmoke check (one small minibatch from the same state; max |diff| / max |numpy| of the updates):")
    agree = pc.smoke_check({
        "numpy backend": lambda p: pc.BatchStateImpl(p, pc.NumpyBackend()),
        "warp cuda": lambda p: pc.BatchStateImpl(p, WarpBackend("cuda")),
        "torch cuda": lambda p: pc.TorchImpl(p, 1, device="cuda"),
    })
    for name, (dy, dw) in agree.items():
        print(f"  {name:10s} vs numpy backend: latents {dy:.2e}, weights {dw:.2e}")

    spec = pc.QUICK if args.quick else pc.PAPER
    prob = pc.make_problem(spec)
    flops = prob.flops()
    print(f"\nminibatch: B = {prob.batch}, T = {prob.steps}, {flops / 1e9:.1f} GFLOP (2mnk per GEMM)", flush=True)
    impls = {
        "cuBLAS GEMMs (baseline)": TorchGemms(prob, torch),
        "torch step (CUDA graph)": pc.TorchImpl(prob, 1, device="cuda"),
        "warp backend (CUDA graph)": pc.BatchStateImpl(prob, WarpBackend("cuda")),
        "cuBLAS GEMMs, TF32 (context)": TorchGemms(prob, torch, tf32=True),
        "torch step, TF32 (context)": pc.TorchImpl(prob, 1, device="cuda", tf32=True),
    }
    for name, impl in impls.items():
        print(f"  warm-up / compile: {name} ...", flush=True)
        impl.reset()
        for _ in range(3):
            impl.run()
    times = {name: [] for name in impls}
    names = list(impls)
    for r in range(args.repeat):
        for name in names[r % len(names):] + names[: r % len(names)]:
            impls[name].reset()
            times[name].append(time_minibatches(impls[name], args.minibatches, sync))
    rows, results = [], {}
    for i, name in enumerate(names):
        base = statistics.median(times[names[0 if i < 3 else 3]])  # float32 vs float32, TF32 vs TF32
        med, best = statistics.median(times[name]), min(times[name])
        results[name] = {"median_s": med, "best_s": best, "tflops": flops / med / 1e12, "ratio": base / med}
        rows.append([name, f"{med * 1e3:.2f}", f"{best * 1e3:.2f}", f"{flops / med / 1e12:.1f}", f"{base / med:.2f}"])
    print(f"\nper minibatch, median of {args.repeat} rounds x {args.minibatches} minibatches; "
          "'x cuBLAS' = rate / the cuBLAS GEMM rate in the same precision:")
    print(pc.fmt_table(rows, ["implementation", "median ms", "best ms", "TFLOP/s", "x cuBLAS"]))
    w, t = results[names[2]], results[names[1]]
    print(f"target: warp step >= 0.8 x cuBLAS GEMM rate: {w['ratio']:.2f} x -> {'met' if w['ratio'] >= 0.8 else 'NOT met'}")
    print(f"target: warp step ahead of the torch step: torch takes {t['median_s'] / w['median_s']:.2f} x the warp "
          f"time -> {'met' if w['median_s'] < t['median_s'] else 'NOT met'}")
    breakdown = op_breakdown(impls[names[2]], args.repeat, sync)
    print("warp float32, per operation (ms): " + ", ".join(f"{k} {v:.3f}" for k, v in breakdown.items())
          + f"; minibatch = {prob.steps + 1} predict_all + {prob.steps} latent_step + 1 weight_step")

    out = {"device": info, "gflop": flops / 1e9, "smoke": agree, "results": results, "times": times,
           "breakdown_ms": breakdown, "training": None}
    _save(args.json, out)  # the comparison survives a time limit hit during the training
    if not args.quick:
        print(f"\ntimed training at the paper's shapes on the Warp backend ({PAPER_SAMPLES} random samples):", flush=True)
        training = timed_training(pc, args.epochs, PAPER_SAMPLES, lambda line: print(line, flush=True))
        print(f"target: {PAPER_EPOCHS} epochs <= 30 min: {training['projected_min']:.1f} min -> "
              f"{'met' if training['projected_min'] <= 30 else 'NOT met'}")
        print(f"target: inference of 300 samples x 3000 steps in seconds: {training['inference_300x3000_s']:.1f} s")
        out["training"] = training
        _save(args.json, out)
    return out


def _save(path: str | None, out: dict) -> None:
    if path:
        with open(path, "w") as f:
            json.dump(out, f, indent=2)
