#!/usr/bin/env python
"""Benchmark one predictive-coding training minibatch at the MuPNet paper's shapes.

One minibatch is exactly what ``Network.train`` does per minibatch, minus data loading:
``predict_all``, then T x (``latent_step`` + ``predict_all``), then ``weight_step``. Shapes and
step sizes: MuPNet's settings in scenarios/paper.yaml (visual 10800 -> 1000 -> 300, tactile
72 -> 100, joint 200, B = 150, T = 20).

Measured in one run, interleaved round by round (the machine is shared and noisy; the
median over the rounds is reported, the best round too):

* ``gemm numpy``   the raw GEMMs of the step through numpy (``np.matmul(..., out=)``):
                   the same sequence of GEMMs, same shapes and transposes
                   (``Y @ W``, ``G @ W.T``, ``Y.T @ G``), no epilogue -- the baseline;
* ``gemm scipy``   the same GEMMs through ``scipy.linalg.blas.sgemm`` (scipy ships its own
                   OpenBLAS build, with its own thread pool), called as the numpy backend
                   did before it moved to ``np.matmul`` (C^T = W^T Y^T etc., beta = 1 fused);
* ``numpy backend`` the real step: ``BatchState`` with ``NumpyBackend``;
* ``legacy scipy backend`` (``--legacy``) the previous NumpyBackend (scipy ``gemm`` with the
                   step fused, numpy epilogue with a masked copy), kept here for comparison;
* ``torch``        the same step written here in PyTorch (CPU, float32, no_grad, in place);
* ``jax``          the same step written here in JAX, the whole minibatch jitted
                   (``lax.fori_loop`` over T);
* ``warp cpu``     ``BatchState`` with ``WarpBackend('cpu')``: too slow for full
                   minibatches, so each of predict_all / latent_step / weight_step is
                   timed once (T reduced to 1) and the minibatch time is scaled to T.

Between implementations the script sleeps briefly so that the spinning worker threads
of one threading runtime (OpenBLAS, OpenMP, XLA) do not steal the cores from the next.
For every timed minibatch it also reads /proc/stat and reports how many cores *other*
processes kept busy meanwhile ("other load"): with 2 cores, anything above ~0.1 means the
figure says more about the neighbours than about the code.

FLOPs count 2*m*n*k per GEMM only (the element-wise epilogue is not counted).
A smoke check first runs one small minibatch from the same state in every
implementation and prints the largest relative difference of the latent and weight
updates against the numpy backend.

    python bench/pc_step.py                 # paper shapes, 5 interleaved rounds
    python bench/pc_step.py --repeat 9
    python bench/pc_step.py --quick         # small shapes, smoke run
    python bench/pc_step.py --skip-warp --legacy
    python bench/pc_step.py --device cuda   # GPU: cuBLAS vs PyTorch vs Warp, timed training
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("JAX_PLATFORMS", "cpu")  # before any jax import: no GPU probing noise

import numpy as np

from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.network.backends import NumpyBackend
from vitaplace.engine.network.pc import LATENT_INIT, BatchState, Network, NetworkConfig
from vitaplace.engine.sim.robot import N_WHISKERS
from vitaplace.plugins.mupnet.extractor import MupnetParams

TACTILE_SIZE = 3 * N_WHISKERS  # theta and xy per whisker


@dataclass(frozen=True)
class Spec:
    """A benchmarked network: MuPNet's settings and its tactile input size."""

    params: MupnetParams
    tactile_size: int = TACTILE_SIZE

    @property
    def config(self) -> NetworkConfig:
        return self.params.network_config(self.tactile_size)

    @property
    def batch(self) -> int:
        return self.params.batch_size

    @property
    def steps(self) -> int:
        return self.params.inference_steps

    def changed(self, tactile_size: int | None = None, **params) -> Spec:
        """These settings with some replaced (and validated by the schema)."""
        merged = MupnetParams.model_validate({**self.params.model_dump(), **params})
        return Spec(merged, self.tactile_size if tactile_size is None else tactile_size)


@functools.cache
def paper_scenario() -> Scenario:
    """scenarios/paper.yaml, read and checked by the scenario loader."""
    return load_scenario("paper")[0]


def paper_spec() -> Spec:
    """The MuPNet paper's network and training settings, as scenarios/paper.yaml gives them."""
    (method,) = [m for m in paper_scenario().methods if m.plugin == "mupnet"]
    return Spec(MupnetParams.model_validate(method.params))


def quick_spec() -> Spec:
    """The paper's step sizes at small shapes (15 x 24 frames)."""
    return paper_spec().changed(
        image_size=(15, 24), visual_layers=[100, 30], tactile_layers=[10], joint_size=20, batch_size=30,
        inference_steps=3,
    )


def smoke_spec() -> Spec:
    """Small shapes, large step sizes so that one minibatch changes every array visibly (the
    comparison is on the updates, not on the arrays); B = 40 > 32: the same CUDA tile
    configurations (compiled modules) as B = 150."""
    etas = {f"eta_{kind}_{layer}": eta
            for kind, eta in (("y", 0.02), ("w", 0.01)) for layer in ("visual", "tactile", "joint")}
    return Spec(MupnetParams(
        image_size=(4, 8), visual_layers=[40, 24], tactile_layers=[8], joint_size=16, batch_size=40, inference_steps=5,
        **etas,
    ), tactile_size=12)


GAP = 0.3  # seconds of idle between implementations (thread pools stop spinning)


# ---------------------------------------------------------------------------------------
# The step, described once (from BatchState, so every implementation follows its order)
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EdgeSpec:
    name: str
    upper: str  # latent node
    lower: str  # latent node or input node ("m.0")
    eta_y: float  # of the upper node
    eta_w: float
    above: str | None  # edge whose error is the top-down term of `upper`, applied with this edge


@dataclass
class Problem:
    net: Network
    batch: int
    steps: int
    edges: list[EdgeSpec]
    sizes: dict[str, int]
    inputs: dict[str, np.ndarray]  # input node -> X
    latents: dict[str, np.ndarray]  # latent node -> Y0
    weights: dict[str, np.ndarray]  # edge -> W0

    @property
    def slope(self) -> float:
        return float(self.net.config.slope)

    def gemm_shapes(self) -> list[tuple[str, int, int, int]]:
        """(what, m, n, k) of every GEMM of one minibatch, in order."""
        b = self.batch
        pred = [("predict " + e.name, b, self.sizes[e.lower], self.sizes[e.upper]) for e in self.edges]
        lat = [("latent " + e.name, b, self.sizes[e.upper], self.sizes[e.lower]) for e in self.edges]
        wt = [("weight " + e.name, self.sizes[e.upper], self.sizes[e.lower], b) for e in self.edges]
        return pred + (lat + pred) * self.steps + wt

    def flops(self) -> float:
        return float(sum(2 * m * n * k for _, m, n, k in self.gemm_shapes()))


def make_problem(spec: Spec, seed: int = 0) -> Problem:
    net = Network(spec.config, seed=seed, backend=NumpyBackend())
    state = BatchState(net, spec.batch, net.modalities)
    edges = []
    for e in state.edges:
        above = state.edge_above.get(e.upper) if state.first_below[e.upper] == e.name else None
        edges.append(EdgeSpec(e.name, e.upper, e.lower, net.eta_y[e.upper], e.eta_w, above))
    rng = np.random.default_rng(seed + 1)
    b = spec.batch
    inputs = {net.input_node(m): rng.random((b, net.sizes[net.input_node(m)]), dtype=np.float32)
              for m in net.modalities}
    latents = {node: np.full((b, net.sizes[node]), LATENT_INIT, np.float32) for node in state.nodes}
    # latents slightly off 0.1 so that no two samples are identical
    for y in latents.values():
        y += rng.normal(0.0, 0.01, y.shape).astype(np.float32)
    weights = {name: w.copy() for name, w in net.weights.items()}
    return Problem(net, b, spec.steps, edges, dict(net.sizes), inputs, latents, weights)


class LegacyScipyBackend(NumpyBackend):
    """The numpy backend as it was before (kept for comparison, ``--legacy``): scipy's
    ``gemm`` with the step fused (beta = 1, in place), a masked copy in the epilogue and
    ``np.dot`` (numpy's BLAS) for the energy -- two OpenBLAS thread pools alternating."""

    def __init__(self) -> None:
        super().__init__(np.float32)
        from scipy.linalg import blas

        self._gemm = blas.get_blas_funcs("gemm", dtype=self.dtype)

    def predict(self, Y, W, X, A, P, E, G, activation: str, slope: float) -> None:
        assert activation == "leaky_relu"
        self._gemm(1.0, W.T, Y.T, beta=0.0, c=A.T, overwrite_c=True)
        np.multiply(A, self.dtype.type(slope), out=P)
        np.maximum(A, P, out=P)
        np.subtract(X, P, out=E)
        np.multiply(E, self.dtype.type(slope), out=G)
        np.copyto(G, E, where=A > 0)

    def latent_update(self, Y, G, W, eta: float, E_above) -> None:
        if E_above is not None:
            Y -= self.dtype.type(2.0 * eta) * E_above
        self._gemm(2.0 * eta, W.T, G.T, beta=1.0, c=Y.T, trans_a=1, overwrite_c=True)

    def weight_update(self, W, Y, G, eta: float) -> None:
        self._gemm(2.0 * eta, G.T, Y.T, beta=1.0, c=W.T, trans_b=1, overwrite_c=True)


_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _busy_seconds() -> float | None:
    """CPU seconds all processes have used so far (/proc/stat), None when unavailable."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    return (sum(v) - v[3] - v[4]) / _TICK  # minus idle and iowait


def _own_seconds() -> float:
    t = os.times()
    return t.user + t.system


# ---------------------------------------------------------------------------------------
# Implementations: each has reset() (untimed: back to the initial state), run() (one
# minibatch, timed) and result() (latents, weights as host arrays)
# ---------------------------------------------------------------------------------------


class BatchStateImpl:
    """The project's own step: Network + BatchState on a backend, one minibatch exactly as
    ``Network.train`` runs it (captured and replayed as a CUDA graph on CUDA; energies
    read back and checked once per minibatch)."""

    def __init__(self, prob: Problem, backend, steps: int | None = None) -> None:
        self.prob = prob
        self.steps = prob.steps if steps is None else steps
        self.net = Network(prob.net.config, seed=0, backend=backend)
        self.state = self.net.batch_state(prob.batch)
        self.reset()
        self._minibatch = self.net.backend.capture(self._body)

    def reset(self) -> None:
        self.net.set_weights(self.prob.weights)
        ins = {m: self.prob.inputs[self.net.input_node(m)] for m in self.net.modalities}
        self.state.load(ins, self.prob.latents)

    def _body(self) -> None:
        self.state.train_steps(self.steps)

    def run(self) -> None:
        self._minibatch()
        self.state.check_finite(self.state.energies(), "the benchmark minibatch")

    def result(self):
        be = self.net.backend
        return ({k: be.download(v) for k, v in self.state.Y.items()},
                {k: be.weights_to_host(v) for k, v in self.state.weights.items()})


class GemmImpl:
    """Only the GEMMs of the step, no epilogue: the raw BLAS rate of the same shapes.

    ``lib='numpy'``: np.matmul(Y, W), np.matmul(G, W.T), np.matmul(Y.T, G) into
    preallocated outputs (numpy's OpenBLAS). ``lib='scipy'``: scipy.linalg.blas.sgemm
    with exactly the arguments NumpyBackend passes (scipy's OpenBLAS).
    """

    def __init__(self, prob: Problem, lib: str) -> None:
        self.prob, self.lib = prob, lib
        b = prob.batch
        rng = np.random.default_rng(7)
        sz = prob.sizes
        self.W = {e.name: prob.weights[e.name].copy() for e in prob.edges}
        self.Wout = {e.name: np.zeros_like(self.W[e.name]) for e in prob.edges}
        self.Y = {n: y.copy() for n, y in prob.latents.items()}
        self.Yout = {n: np.zeros_like(y) for n, y in prob.latents.items()}
        self.A = {e.name: np.zeros((b, sz[e.lower]), np.float32) for e in prob.edges}
        self.G = {e.name: rng.normal(0, 0.1, (b, sz[e.lower])).astype(np.float32) for e in prob.edges}
        if lib == "scipy":
            from scipy.linalg import blas

            self.sgemm = blas.get_blas_funcs("gemm", dtype=np.float32)

    def reset(self) -> None:
        pass

    def run(self) -> None:
        edges, W, Y, A, G = self.prob.edges, self.W, self.Y, self.A, self.G
        if self.lib == "numpy":
            mm = np.matmul

            def predict_all():
                for e in edges:
                    mm(Y[e.upper], W[e.name], out=A[e.name])

            predict_all()
            for _ in range(self.prob.steps):
                for e in edges:
                    mm(G[e.name], W[e.name].T, out=self.Yout[e.upper])
                predict_all()
            for e in edges:
                mm(Y[e.upper].T, G[e.name], out=self.Wout[e.name])
        else:
            gemm = self.sgemm

            def predict_all():
                for e in edges:
                    gemm(1.0, W[e.name].T, Y[e.upper].T, beta=0.0, c=A[e.name].T, overwrite_c=True)

            predict_all()
            for _ in range(self.prob.steps):
                for e in edges:
                    gemm(1.0, W[e.name].T, G[e.name].T, beta=1.0, c=self.Yout[e.upper].T, trans_a=1, overwrite_c=True)
                predict_all()
            for e in edges:
                gemm(1.0, G[e.name].T, Y[e.upper].T, beta=1.0, c=self.Wout[e.name].T, trans_b=1, overwrite_c=True)


class TorchImpl:
    """The same step in PyTorch: float32, no_grad, in-place ops, fused leaky-ReLU kernels.
    On CUDA the minibatch is captured once as a CUDA graph and replayed; the energies are
    checked once per minibatch, as in the project's step. ``precision`` (CUDA): ``tf32``
    GEMMs on tensor cores, or ``bf16`` GEMM operands (bfloat16 copies of the weights kept by
    the weight step, of Y and G made per GEMM; bfloat16 products added into the float32
    arrays): the weights, latents and errors stay float32 as in the CublasBackend."""

    def __init__(self, prob: Problem, threads: int, device: str = "cpu", precision: str = "float32") -> None:
        import torch

        if device == "cpu":
            torch.set_num_threads(threads)
        self.torch, self.prob, self.device = torch, prob, device
        self.tf32, self.low = precision == "tf32", torch.bfloat16 if precision == "bf16" else None
        b, sz = prob.batch, prob.sizes
        t = lambda a: torch.from_numpy(np.array(a, np.float32)).to(device)  # noqa: E731
        self.X = {n: t(x) for n, x in prob.inputs.items()}
        self.Y = {n: t(y) for n, y in prob.latents.items()}
        self.W = {n: t(w) for n, w in prob.weights.items()}
        z = lambda e: torch.zeros((b, sz[e.lower]), dtype=torch.float32, device=device)  # noqa: E731
        self.A = {e.name: z(e) for e in prob.edges}
        self.P = {e.name: z(e) for e in prob.edges}
        self.E = {e.name: z(e) for e in prob.edges}
        self.G = {e.name: z(e) for e in prob.edges}
        self.energy = torch.zeros(len(prob.edges), dtype=torch.float32, device=device)
        self.W_low = {n: w.to(self.low) for n, w in self.W.items()} if self.low else None
        self.aten = torch.ops.aten
        self.graph = None
        self.calls = 0

    def reset(self) -> None:
        for n, y in self.prob.latents.items():
            self.Y[n].copy_(self.torch.from_numpy(y))
        for n, w in self.prob.weights.items():
            self.W[n].copy_(self.torch.from_numpy(w))
            if self.low:
                self.W_low[n].copy_(self.W[n])

    def _node(self, n):
        return self.Y[n] if n in self.Y else self.X[n]

    def predict_all(self) -> None:
        torch, aten, slope = self.torch, self.aten, self.prob.slope
        for i, e in enumerate(self.prob.edges):
            n = e.name
            A, P, E, G = self.A[n], self.P[n], self.E[n], self.G[n]
            if self.low:
                A.copy_(torch.matmul(self.Y[e.upper].to(self.low), self.W_low[n]))
            else:
                torch.matmul(self.Y[e.upper], self.W[n], out=A)
            aten.leaky_relu.out(A, slope, out=P)
            torch.sub(self._node(e.lower), P, out=E)
            aten.leaky_relu_backward.grad_input(E, A, slope, False, grad_input=G)  # G = phi'(A) * E
            flat = E.view(-1)
            torch.dot(flat, flat, out=self.energy[i])

    def latent_step(self) -> None:
        for e in self.prob.edges:
            y, two_eta = self.Y[e.upper], 2.0 * e.eta_y
            if e.above is not None:
                y.sub_(self.E[e.above], alpha=two_eta)
            if self.low:
                y.add_(self.torch.matmul(self.G[e.name].to(self.low), self.W_low[e.name].t()), alpha=two_eta)
            else:
                y.addmm_(self.G[e.name], self.W[e.name].t(), alpha=two_eta)

    def weight_step(self) -> None:
        for e in self.prob.edges:
            w, alpha = self.W[e.name], 2.0 * e.eta_w
            if self.low:
                y, g = self.Y[e.upper].to(self.low), self.G[e.name].to(self.low)
                w.add_(self.torch.matmul(y.t(), g), alpha=alpha)
                self.W_low[e.name].copy_(w)
            else:
                w.addmm_(self.Y[e.upper].t(), self.G[e.name], alpha=alpha)

    def _body(self) -> None:
        with self.torch.no_grad():
            self.predict_all()
            for _ in range(self.prob.steps):
                self.latent_step()
                self.predict_all()
            self.weight_step()

    def run(self) -> None:
        torch = self.torch
        torch.backends.cuda.matmul.allow_tf32 = self.tf32  # read when cuBLAS picks a kernel (eager, capture)
        self.calls += 1
        if self.device == "cpu" or self.calls == 1:
            self._body()
        else:
            if self.graph is None:
                self.graph = torch.cuda.CUDAGraph()
                with torch.cuda.graph(self.graph):
                    self._body()
            self.graph.replay()
        if not bool(torch.isfinite(self.energy).all()):
            raise RuntimeError("torch step diverged")

    def result(self):
        return ({k: v.cpu().numpy().copy() for k, v in self.Y.items()},
                {k: v.cpu().numpy().copy() for k, v in self.W.items()})


class JaxImpl:
    """The same step in JAX: the whole minibatch is one jitted function (fori_loop over T),
    weights and latents donated so XLA may update them in place."""

    def __init__(self, prob: Problem) -> None:
        import jax
        import jax.numpy as jnp

        self.jax, self.jnp, self.prob = jax, jnp, prob
        edges, slope, steps = prob.edges, np.float32(prob.slope), prob.steps

        def predict_all(W, Y, X):
            E, G, F = {}, {}, {}
            for e in edges:
                A = Y[e.upper] @ W[e.name]
                pos = A > 0
                P = jnp.where(pos, A, slope * A)
                Ei = (Y[e.lower] if e.lower in Y else X[e.lower]) - P
                E[e.name], G[e.name], F[e.name] = Ei, jnp.where(pos, Ei, slope * Ei), jnp.vdot(Ei, Ei)
            return E, G, F

        def latent_step(W, Y, E, G):
            Y = dict(Y)
            for e in edges:
                two_eta = np.float32(2.0 * e.eta_y)
                y = Y[e.upper]
                if e.above is not None:
                    y = y - two_eta * E[e.above]
                Y[e.upper] = y + two_eta * (G[e.name] @ W[e.name].T)
            return Y

        def minibatch(W, Y, X):
            E, G, F = predict_all(W, Y, X)

            def body(_, carry):
                Yc, Ec, Gc, _F = carry
                Yc = latent_step(W, Yc, Ec, Gc)
                Ec, Gc, Fc = predict_all(W, Yc, X)
                return Yc, Ec, Gc, Fc

            Y, E, G, F = jax.lax.fori_loop(0, steps, body, (Y, E, G, F))
            W = {e.name: W[e.name] + np.float32(2.0 * e.eta_w) * (Y[e.upper].T @ G[e.name]) for e in edges}
            return W, Y, F

        self.fn = jax.jit(minibatch, donate_argnums=(0, 1))
        self.X = {n: jnp.asarray(x) for n, x in prob.inputs.items()}
        self.reset()
        self.run()  # compile outside the timing
        self.reset()

    def reset(self) -> None:
        put = self.jax.device_put
        self.W = {n: put(np.array(w)) for n, w in self.prob.weights.items()}
        self.Y = {n: put(np.array(y)) for n, y in self.prob.latents.items()}
        self.jax.block_until_ready((self.W, self.Y))

    def run(self) -> None:
        self.W, self.Y, F = self.fn(self.W, self.Y, self.X)
        F = self.jax.block_until_ready(F)
        if not all(np.isfinite(float(v)) for v in F.values()):
            raise RuntimeError("jax step diverged")

    def result(self):
        return ({k: np.asarray(v) for k, v in self.Y.items()}, {k: np.asarray(v) for k, v in self.W.items()})


# ---------------------------------------------------------------------------------------
# Environment, smoke check, timing
# ---------------------------------------------------------------------------------------


def optional(name: str):
    try:
        return __import__(name)
    except Exception as exc:  # noqa: BLE001 - any import failure means "not available"
        print(f"  {name}: not available ({type(exc).__name__}: {exc}); skipped")
        return None


def describe_machine(torch, jax) -> dict:
    info = {"python": platform.python_version(), "cpus": os.cpu_count(), "numpy": np.__version__}
    try:
        with open("/proc/cpuinfo") as f:
            info["cpu"] = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "?")
    except OSError:
        info["cpu"] = platform.processor() or "?"
    import scipy
    import scipy.linalg.blas  # noqa: F401 - loads scipy's OpenBLAS so threadpoolctl lists it

    info["scipy"] = scipy.__version__
    try:
        import threadpoolctl

        info["blas"] = [
            {k: p.get(k) for k in ("prefix", "filepath", "version", "architecture", "num_threads", "threading_layer")}
            for p in threadpoolctl.threadpool_info()
            if p.get("user_api") == "blas"
        ]
    except ImportError:
        info["blas"] = "threadpoolctl not installed"
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OPENBLAS_CORETYPE", "MKL_NUM_THREADS"):
        info[var] = os.environ.get(var, "unset")
    if torch is not None:
        info["torch"] = (f"{torch.__version__}, {torch.get_num_threads()} threads, "
                         f"MKL {torch.backends.mkl.is_available()}")
    if jax is not None:
        info["jax"] = f"{jax.__version__}, devices {[str(d) for d in jax.devices()]}"
    return info


def print_machine(info: dict) -> None:
    print(f"machine: {info['cpu']}, {info['cpus']} logical CPUs; python {info['python']}, "
          f"numpy {info['numpy']}, scipy {info['scipy']}")
    blas = info["blas"]
    if isinstance(blas, str):
        print(f"  BLAS: {blas}")
    else:
        for p in blas:
            lib = os.path.basename(p["filepath"] or "?")
            path = p["filepath"] or ""
            owner = "numpy" if "numpy" in path else "scipy" if "scipy" in path else "?"
            print(f"  BLAS ({owner}): {lib} OpenBLAS {p['version']}, arch {p['architecture']}, "
                  f"{p['num_threads']} threads ({p['threading_layer']})")
    print("  env: " + ", ".join(f"{k}={info[k]}" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                           "OPENBLAS_CORETYPE", "MKL_NUM_THREADS")))
    for k in ("torch", "jax"):
        if k in info:
            print(f"  {k}: {info[k]}")


def relative_difference(ref: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> float:
    return max(float(np.max(np.abs(other[k] - ref[k])) / max(np.max(np.abs(ref[k])), 1e-30)) for k in ref)


def smoke_check(impls: dict[str, Callable[[Problem], object]]) -> dict[str, tuple[float, float]]:
    """One small minibatch from the same state in each implementation; max relative
    difference of the latent and weight *updates* against the numpy backend."""
    prob = make_problem(smoke_spec(), seed=3)
    deltas = {}
    for name, factory in impls.items():
        impl = factory(prob)
        impl.reset()
        impl.run()
        ys, ws = impl.result()
        deltas[name] = ({k: ys[k] - prob.latents[k] for k in ys}, {k: ws[k] - prob.weights[k] for k in ws})
    ref = deltas["numpy backend"]
    out = {}
    for name, (dy, dw) in deltas.items():
        if name != "numpy backend":
            out[name] = (relative_difference(ref[0], dy), relative_difference(ref[1], dw))
    return out


def fmt_table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    line = lambda r: "| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"  # noqa: E731
    return "\n".join([line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(line, rows)])


def timed(fn: Callable[[], object]) -> tuple[float, float]:
    """Wall time of fn() and the cores other processes kept busy meanwhile (nan if unknown)."""
    b0, o0, t0 = _busy_seconds(), _own_seconds(), time.perf_counter()
    fn()
    b1, o1, t1 = _busy_seconds(), _own_seconds(), time.perf_counter()
    dt = t1 - t0
    other = float("nan") if b0 is None or b1 is None else max(0.0, ((b1 - b0) - (o1 - o0)) / dt)
    return dt, other


def time_once(impl) -> tuple[float, float]:
    impl.reset()
    return timed(impl.run)


def measure(fn: Callable[[], object], max_other: float, retries: int) -> tuple[float, float]:
    """One timed call of fn; repeated (up to ``retries`` more times) while other processes
    kept more than ``max_other`` cores busy. Returns the least disturbed (time, other load)."""
    best = None
    for _ in range(1 + retries):
        time.sleep(GAP)
        dt, other = fn()
        if best is None or other < best[1] or (math.isnan(best[1]) and not math.isnan(other)):
            best = (dt, other)
        if not other > max_other:  # also stops when the load is unknown (nan)
            break
    return best


def per_gemm(prob: Problem, torch, repeat: int, max_other: float, retries: int):
    """GFLOP/s of the three GEMMs of the largest edge through numpy, scipy and torch,
    interleaved, each sample the mean of 5 calls; median over ``repeat`` rounds."""
    from scipy.linalg import blas

    sgemm = blas.get_blas_funcs("gemm", dtype=np.float32)
    e = max(prob.edges, key=lambda e: prob.sizes[e.upper] * prob.sizes[e.lower])
    b, nu, nd = prob.batch, prob.sizes[e.upper], prob.sizes[e.lower]
    rng = np.random.default_rng(11)
    Y = rng.random((b, nu), dtype=np.float32)
    W = prob.weights[e.name].copy()
    G = rng.normal(0, 0.1, (b, nd)).astype(np.float32)
    A, Yo, Wo = np.zeros((b, nd), np.float32), np.zeros((b, nu), np.float32), np.zeros((nu, nd), np.float32)
    cases = {
        ("predict", "numpy"): lambda: np.matmul(Y, W, out=A),
        ("predict", "scipy"): lambda: sgemm(1.0, W.T, Y.T, beta=0.0, c=A.T, overwrite_c=True),
        ("latent", "numpy"): lambda: np.matmul(G, W.T, out=Yo),
        ("latent", "scipy"): lambda: sgemm(1.0, W.T, G.T, beta=1.0, c=Yo.T, trans_a=1, overwrite_c=True),
        ("weight", "numpy"): lambda: np.matmul(Y.T, G, out=Wo),
        ("weight", "scipy"): lambda: sgemm(1.0, G.T, Y.T, beta=1.0, c=Wo.T, trans_b=1, overwrite_c=True),
    }
    if torch is not None:
        tY, tW, tG, tA, tYo, tWo = map(torch.from_numpy, (Y, W, G, A, Yo, Wo))
        cases[("predict", "torch")] = lambda: torch.matmul(tY, tW, out=tA)
        cases[("latent", "torch")] = lambda: torch.matmul(tG, tW.t(), out=tYo)
        cases[("weight", "torch")] = lambda: torch.matmul(tY.t(), tG, out=tWo)
    libs = ["numpy", "scipy"] + (["torch"] if torch is not None else [])
    whats = ("predict", "latent", "weight")
    inner = 5

    def sample(f):
        def run():
            for _ in range(inner):
                f()

        def go():
            dt, other = timed(run)
            return dt / inner, other

        return go

    times = {k: [] for k in cases}
    loads = {lib: [] for lib in libs}
    for f in cases.values():
        f()
    for r in range(repeat):
        for lib in libs[r % len(libs):] + libs[: r % len(libs)]:
            for what in whats:
                dt, other = measure(sample(cases[(what, lib)]), max_other, retries)
                times[(what, lib)].append(dt)
                loads[lib].append(other)
    shapes = {"predict": ("Y @ W", b, nd, nu), "latent": ("G @ W.T", b, nu, nd), "weight": ("Y.T @ G", nu, nd, b)}
    rows = []
    for what, (expr, m, n, k) in shapes.items():
        fl = 2 * m * n * k
        rows.append([f"{what} {e.name}: {expr}", f"{m}x{n}x{k}"]
                    + [f"{fl / statistics.median(times[(what, lib)]) / 1e9:.0f}" for lib in libs])
    rows.append(["other load (cores, median)", ""] + [f"{_median_nan(loads[lib]):.2f}" for lib in libs])
    return rows, ["GEMM (largest edge)", "m x n x k"] + [f"{lib} GFLOP/s" for lib in libs]


def _ms(seconds: float) -> str:
    ms = seconds * 1e3
    return f"{ms:.0f}" if ms >= 100 else f"{ms:.3g}"


def _median_nan(values: list[float]) -> float:
    known = [v for v in values if not math.isnan(v)]
    return statistics.median(known) if known else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds (median reported); default 5")
    ap.add_argument("--skip-warp", action="store_true", help="do not time the Warp CPU backend")
    ap.add_argument("--skip-torch", action="store_true")
    ap.add_argument("--skip-jax", action="store_true")
    ap.add_argument("--legacy", action="store_true", help="also time the previous (scipy gemm) numpy backend")
    ap.add_argument("--quick", action="store_true", help="small shapes and T=3: a smoke run")
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads (default: all CPUs)")
    ap.add_argument("--max-other", type=float, default=0.1,
                    help="retry a sample while other processes kept more cores busy than this (default 0.1)")
    ap.add_argument("--retries", type=int, default=2, help="retries per sample under --max-other (default 2)")
    ap.add_argument("--single-thread-gemms", action="store_true",
                    help="also time the per-GEMM table with BLAS and torch limited to 1 thread")
    ap.add_argument("--json", help="also write the results to this file")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                    help="cuda: cuBLAS GEMMs vs a PyTorch-CUDA step vs the Warp backend, then a timed training "
                         "(bench/pc_step_cuda.py)")
    ap.add_argument("--minibatches", type=int, default=10, help="cuda: minibatches per timed sample (default 10)")
    ap.add_argument("--epochs", type=int, default=3, help="cuda: timed training epochs after the first (default 3)")
    ap.add_argument("--tiles", help="cuda: use the fastest tile configurations of this bench/tile_sweep.py --json")
    args = ap.parse_args(argv)
    if args.device == "cuda":
        import pc_step_cuda

        if args.tiles:
            import tile_sweep

            for kernel, r in tile_sweep.apply_best(args.tiles).items():
                print(f"tiles from {args.tiles}: {kernel} {r['tm']}x{r['tn']}x{r['tk']} block_dim {r['block_dim']} "
                      f"mathdx {r['mathdx']}")

        pc_step_cuda.cuda_main(args, sys.modules[__name__])
        return 0

    spec = quick_spec() if args.quick else paper_spec()
    print("optional frameworks:")
    torch = None if args.skip_torch else optional("torch")
    jax = None if args.skip_jax else optional("jax")
    if torch is not None:
        torch.set_num_threads(args.threads)
    print()
    info = describe_machine(torch, jax)
    print_machine(info)

    # ---- numerical smoke check
    factories: dict[str, Callable[[Problem], object]] = {"numpy backend": lambda p: BatchStateImpl(p, NumpyBackend())}
    if args.legacy:
        factories["legacy"] = lambda p: BatchStateImpl(p, LegacyScipyBackend())
    if torch is not None:
        factories["torch"] = lambda p: TorchImpl(p, args.threads)
    if jax is not None:
        factories["jax"] = JaxImpl
    if not args.skip_warp:
        factories["warp cpu"] = lambda p: BatchStateImpl(p, _warp_backend())
    print("\nsmoke check (one small minibatch from the same state; max |diff| / max |numpy| of the updates):")
    agree = smoke_check(factories)
    for name, (dy, dw) in agree.items():
        print(f"  {name:10s} vs numpy backend: latents {dy:.2e}, weights {dw:.2e}")
    if not agree:
        print("  (no other implementation to compare)")

    # ---- the benchmark
    prob = make_problem(spec)
    flops = prob.flops()
    sz = prob.sizes
    mods = spec.config.modalities
    desc = (f"visual {sz['visual.0']} -> " + " -> ".join(map(str, mods["visual"].layers))
            + f", tactile {sz['tactile.0']} -> " + " -> ".join(map(str, mods["tactile"].layers))
            + f", joint {sz['joint']}, B = {prob.batch}, T = {prob.steps}")
    print(f"\nshapes: {desc}")
    print(f"GEMMs per minibatch: {len(prob.gemm_shapes())}, "
          f"FLOPs per minibatch (2mnk per GEMM): {flops / 1e9:.2f} GFLOP")

    impls: dict[str, object] = {
        "gemm numpy (baseline)": GemmImpl(prob, "numpy"),
        "gemm scipy": GemmImpl(prob, "scipy"),
        "numpy backend": BatchStateImpl(prob, NumpyBackend()),
    }
    if args.legacy:
        impls["legacy scipy backend"] = BatchStateImpl(prob, LegacyScipyBackend())
    if torch is not None:
        impls["torch"] = TorchImpl(prob, args.threads)
    if jax is not None:
        print("jax: compiling the minibatch ...", flush=True)
        impls["jax"] = JaxImpl(prob)
    names = list(impls)
    times: dict[str, list[float]] = {k: [] for k in names}
    loads: dict[str, list[float]] = {k: [] for k in names}
    for impl in impls.values():  # warm-up (allocations, thread pools, caches)
        time.sleep(GAP)
        time_once(impl)
    print(f"timing {args.repeat} interleaved rounds of {', '.join(names)} ...", flush=True)
    for r in range(args.repeat):
        for name in names[r % len(names):] + names[: r % len(names)]:  # rotate: no fixed neighbour
            dt, other = measure(lambda impl=impls[name]: time_once(impl), args.max_other, args.retries)
            times[name].append(dt)
            loads[name].append(other)
    base = statistics.median(times["gemm numpy (baseline)"])
    base_best = min(times["gemm numpy (baseline)"])

    rows = []
    results = {}
    for name in names:
        med, best, load = statistics.median(times[name]), min(times[name]), _median_nan(loads[name])
        results[name] = {"median_s": med, "best_s": best, "gflops": flops / med / 1e9, "ratio": base / med,
                         "ratio_best": base_best / best, "other_load": load}
        rows.append([name, _ms(med), _ms(best), f"{flops / med / 1e9:.1f}",
                     f"{flops / best / 1e9:.1f}", f"{base / med:.2f}", f"{base_best / best:.2f}", f"{load:.2f}"])

    if not args.skip_warp:
        rows.append(warp_row(prob, flops, base, results))

    header = ["implementation", "median ms", "best ms", "GFLOP/s (median)", "GFLOP/s (best)",
              "x baseline (median)", "x baseline (best)", "other load"]
    print(f"\nper minibatch, {args.repeat} rounds ({flops / 1e9:.2f} GFLOP); 'x baseline' = rate / raw numpy GEMM "
          f"rate; 'other load' = cores kept busy by other processes (median):")
    print(fmt_table(rows, header))

    if not args.quick:
        print(f"\nthe three GEMMs of the largest edge, median of {args.repeat} rounds x 5 calls:")
        g_rows, g_header = per_gemm(prob, torch, args.repeat, args.max_other, args.retries)
        print(fmt_table(g_rows, g_header))
        if args.single_thread_gemms:
            from threadpoolctl import threadpool_limits

            print("\nthe same, one thread each (BLAS via threadpoolctl, torch.set_num_threads(1)):")
            if torch is not None:
                torch.set_num_threads(1)
            with threadpool_limits(1, user_api="blas"):
                s_rows, _ = per_gemm(prob, torch, args.repeat, args.max_other + 1.0, args.retries)
            if torch is not None:
                torch.set_num_threads(args.threads)
            print(fmt_table(s_rows, g_header))
            g_rows = g_rows + [["1 thread: " + r[0], *r[1:]] for r in s_rows]
    else:
        g_rows, g_header = [], []

    nb = results["numpy backend"]
    print(f"\ntarget 1: numpy backend >= 0.8 x raw GEMM rate: {nb['ratio']:.2f} x (median), {nb['ratio_best']:.2f} x "
          f"(best) -> {'met' if nb['ratio'] >= 0.8 else 'NOT met'}")
    for other in ("torch", "jax"):
        if other in results:
            ahead = nb["median_s"] < results[other]["median_s"]
            print(f"target 2: numpy backend vs {other}: "
                  f"{other} takes {results[other]['median_s'] / nb['median_s']:.2f} x "
                  f"the numpy backend's time -> {'ahead' if ahead else 'NOT ahead'}")
    if max(_median_nan(v) for v in loads.values()) > args.max_other:
        print(f"note: other processes kept more than {args.max_other} cores busy during some samples; "
              "repeat when the machine is quieter before trusting the medians")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": info, "shapes": desc, "gflop": flops / 1e9, "repeat": args.repeat,
                       "results": results, "smoke": agree, "times": times, "other_load": loads,
                       "per_gemm": {"header": g_header, "rows": g_rows}}, f, indent=2)
    return 0


def _warp_backend():
    from vitaplace.engine.network.backends import WarpBackend

    return WarpBackend("cpu")


def warp_row(prob: Problem, flops: float, base: float, results: dict) -> list[str]:
    """Warp on CPU: predict_all, latent_step and weight_step timed once each (after a
    compile/warm-up call) and scaled to one minibatch with T steps."""
    label = f"warp cpu (T=1, scaled to T={prob.steps})"
    try:
        impl = BatchStateImpl(prob, _warp_backend(), steps=1)
    except Exception as exc:  # noqa: BLE001
        print(f"warp: not available ({type(exc).__name__}: {exc}); skipped")
        return [label, "-", "-", "-", "-", "-", "-", "-"]
    s = impl.state
    print("warp cpu: compiling / warm-up ...", flush=True)
    s.predict_all(), s.latent_step(), s.weight_step()
    impl.reset()
    time.sleep(GAP)
    (pred, l1), (lat, l2), (wt, l3) = timed(s.predict_all), timed(s.latent_step), timed(s.weight_step)
    load = _median_nan([l1, l2, l3])
    total = (prob.steps + 1) * pred + prob.steps * lat + wt
    print(f"warp cpu: T reduced to 1, each op timed once: predict_all {pred * 1e3:.0f} ms, latent_step "
          f"{lat * 1e3:.0f} ms, weight_step {wt * 1e3:.0f} ms; minibatch scaled to T = {prob.steps}: {total:.2f} s")
    results["warp cpu (scaled)"] = {"median_s": total, "gflops": flops / total / 1e9, "ratio": base / total,
                                    "other_load": load}
    return [label, _ms(total), "-", f"{flops / total / 1e9:.1f}", "-", f"{base / total:.3f}", "-",
            f"{load:.2f}"]


if __name__ == "__main__":
    sys.exit(main())
