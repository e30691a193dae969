#!/usr/bin/env python
"""Where test-time inference is heading (issue 30): a float64 diagnosis of MuPNet's latents.

For a trained network and the first ``--samples`` samples of a run it measures, all in float64
with a model of the energy written here (independent of the backends):

* the paper's plain gradient steps (eta_y per layer, no stopping): energy per sample, the
  joint latent's median norm and the latents' median distance (relative L2 over every latent
  layer) to a long reference solve, after 100 / 300 / 1000 / 3000 / ... steps;
* the curvature of the energy in the latents at the state the steps reached, per sample by
  Lanczos on Hessian-vector products (two GEMMs per edge; the Gauss-Newton form, exact almost
  everywhere for a piecewise-linear activation such as the leaky ReLU): per latent layer the
  largest and smallest eigenvalue of its diagonal block, the stability limit 2 / lambda_max
  against eta_y, and for the whole system preconditioned by the step sizes (the matrix
  plain gradient descent iterates with) lambda_max, lambda_min and the condition number;
* the same with a Gaussian prior on the latents (``--prior``; energy + prior/2 ||y||^2).

The reference solve is the accelerated solver this diagnosis led to (Nesterov momentum with
gradient restart, step 1 / the Gauss-Newton bound of each layer's curvature) run to a
relative gradient norm of 1e-10 in float64; without a prior it has no fixed point to reach
and the script says how far it is from one.

    python bench/infer_diagnose.py --model DIR/cache/models/L-... --run DIR/cache/datasets/E1-query-....h5
    python bench/infer_diagnose.py ... --samples 30 --steps 100 300 1000 3000 --prior 0 0.1 --json d.json
    python bench/infer_diagnose.py --paper-shape --train DIR/cache/datasets/train-....h5 --run ...

``--model`` is a fitted MuPNet method's folder in a pipeline cache (``vitaplace run
quickstart --out DIR`` leaves the quickstart's L there); ``--paper-shape`` instead trains a
network of the paper's shape (visual 1000, 300; tactile 100; joint 200) on ``--train`` for
``--epochs`` epochs with the paper's other settings.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from vitaplace.engine.data.dataset import open_run
from vitaplace.engine.network.pc import LATENT_INIT, Network
from vitaplace.kernels.reference import activation, activation_derivative
from vitaplace.plugins.mupnet.extractor import MupnetExtractor

Latents = dict[str, np.ndarray]


class Energy:
    """F(Y) = sum_edges ||X_d - phi(Y_u W)||^2 + prior/2 sum_latents ||Y||^2 per sample (row),
    in float64, for fixed weights and inputs."""

    def __init__(self, net: Network, inputs: dict[str, np.ndarray], prior: float = 0.0) -> None:
        present = [m for m in net.modalities if m in inputs]
        self.net, self.prior = net, prior
        self.edges = net.active_edges(present)
        self.nodes = net.latent_nodes(present)
        self.W = {e.name: net.weights[e.name].astype(np.float64) for e in self.edges}
        self.X = {net.input_node(m): np.asarray(inputs[m], np.float64) for m in present}
        self.batch = len(next(iter(self.X.values())))
        self.eta = {node: net.eta_y[node] for node in self.nodes}
        act, slope = net.config.activation, net.config.slope
        self.phi = lambda a: activation(a, act, slope)
        self.dphi = lambda a: activation_derivative(a, act, slope)

    def start(self) -> Latents:
        return {n: np.full((self.batch, self.net.sizes[n]), LATENT_INIT) for n in self.nodes}

    def _lower(self, y: Latents, name: str) -> np.ndarray:
        return y[name] if name in y else self.X[name]

    def errors(self, y: Latents) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Per edge (E, phi'(A))."""
        out = {}
        for e in self.edges:
            a = y[e.upper] @ self.W[e.name]
            out[e.name] = (self._lower(y, e.lower) - self.phi(a), self.dphi(a))
        return out

    def energy(self, y: Latents) -> np.ndarray:
        f = sum(np.einsum("ij,ij->i", E, E) for E, _ in self.errors(y).values())
        return f + 0.5 * self.prior * sum(np.einsum("ij,ij->i", v, v) for v in y.values())

    def grad(self, y: Latents) -> Latents:
        g = {n: self.prior * y[n] for n in self.nodes}
        for e in self.edges:
            E, d = self.errors_one(y, e)
            g[e.upper] -= 2 * (d * E) @ self.W[e.name].T
            if e.lower in g:
                g[e.lower] += 2 * E
        return g

    def errors_one(self, y: Latents, e) -> tuple[np.ndarray, np.ndarray]:
        a = y[e.upper] @ self.W[e.name]
        return self._lower(y, e.lower) - self.phi(a), self.dphi(a)

    def gains(self, y: Latents) -> dict[str, np.ndarray]:
        """phi'(A) per edge at ``y`` (fixed for the Hessian-vector products there)."""
        return {e.name: self.dphi(y[e.upper] @ self.W[e.name]) for e in self.edges}

    def hvp(self, gains: dict[str, np.ndarray], v: Latents) -> Latents:
        """Gauss-Newton Hessian-vector product 2 J^T J v (+ prior v): dE = v_d - phi' * (v_u W)."""
        h = {n: self.prior * v[n] for n in v}
        for e in self.edges:
            dv_u = v.get(e.upper)
            dE = -gains[e.name] * (dv_u @ self.W[e.name]) if dv_u is not None else 0.0
            if e.lower in v:
                dE = dE + v[e.lower]
            if isinstance(dE, float):
                continue
            if e.upper in h:
                h[e.upper] -= 2 * (gains[e.name] * dE) @ self.W[e.name].T
            if e.lower in h:
                h[e.lower] += 2 * dE
        return h

    def gauss_newton_steps(self) -> dict[str, float]:
        """Per latent layer 1 / (2 sum_below ||W||_2^2 max phi'^2 + 2 [has an edge above] + prior)."""
        bound = {n: self.prior for n in self.nodes}
        gain = max(1.0, self.net.config.slope) if self.net.config.activation in ("leaky_relu", "linear") else 1.0
        for e in self.edges:
            w = self.W[e.name]
            small = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
            bound[e.upper] += 2 * gain**2 * float(np.linalg.eigvalsh(small)[-1])
            if e.lower in bound:
                bound[e.lower] += 2.0
        return {n: 1.0 / b for n, b in bound.items()}


def _rows_dot(a: Latents, b: Latents) -> np.ndarray:
    return sum(np.einsum("ij,ij->i", a[n], b[n]) for n in a)


def lanczos(op, shapes: dict[str, int], batch: int, k: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Largest and smallest Ritz values (per sample) of the symmetric operator ``op`` on latents
    restricted to ``shapes``' nodes: ``k`` Lanczos steps with full reorthogonalisation."""
    rng = np.random.default_rng(seed)
    q = {n: rng.standard_normal((batch, s)) for n, s in shapes.items()}
    norm = np.sqrt(_rows_dot(q, q))
    q = {n: v / norm[:, None] for n, v in q.items()}
    basis, alpha, beta = [q], [], []
    k = min(k, sum(shapes.values()))
    for j in range(k):
        w = op(basis[-1])
        a = _rows_dot(w, basis[-1])
        alpha.append(a)
        for prev in basis:  # full reorthogonalisation (twice is enough)
            c = _rows_dot(w, prev)
            w = {n: w[n] - c[:, None] * prev[n] for n in w}
        for prev in basis:
            c = _rows_dot(w, prev)
            w = {n: w[n] - c[:, None] * prev[n] for n in w}
        b = np.sqrt(np.maximum(_rows_dot(w, w), 0.0))
        if j == k - 1 or np.all(b < 1e-12):
            break
        beta.append(b)
        safe = np.where(b > 1e-300, b, 1.0)
        basis.append({n: w[n] / safe[:, None] for n in w})
    m = len(alpha)
    T = np.zeros((batch, m, m))
    for i in range(m):
        T[:, i, i] = alpha[i]
    for i in range(m - 1):
        T[:, i, i + 1] = T[:, i + 1, i] = beta[i]
    ritz = np.linalg.eigvalsh(T)
    return ritz[:, -1], ritz[:, 0]


def curvature(model: Energy, y: Latents, k: int) -> dict[str, object]:
    """Per layer lambda_max / lambda_min of the Hessian's diagonal block, and of the whole
    Hessian preconditioned by eta_y (D^1/2 H D^1/2, D = diag(eta_y)): medians over samples."""
    gains = model.gains(y)
    sizes = {n: y[n].shape[1] for n in model.nodes}
    layers = {}
    for node in model.nodes:
        def block(v, node=node):
            return {node: model.hvp(gains, v)[node]}
        hi, lo = lanczos(block, {node: sizes[node]}, model.batch, k)
        eta = model.eta[node]
        layers[node] = {
            "lambda_max": float(np.median(hi)), "lambda_min": float(np.median(lo)),
            "eta_y": eta, "stability_limit": float(2 / np.median(hi)),
            "condition": float(np.median(hi / np.maximum(lo, 1e-300))),
        }
    root = {n: np.sqrt(model.eta[n]) for n in model.nodes}

    def whole(v):
        h = model.hvp(gains, {n: root[n] * v[n] for n in v})
        return {n: root[n] * h[n] for n in h}

    hi, lo = lanczos(whole, sizes, model.batch, k)
    return {
        "layers": layers,
        "preconditioned": {
            "lambda_max": float(np.median(hi)), "lambda_min": float(np.median(lo)),
            "lambda_min_lowest": float(lo.min()),
            "condition": float(np.median(hi / np.maximum(lo, 1e-300))),
            # plain GD at eta_y shrinks the slowest error component by (1 - lambda_min) per step
            "gd_steps_per_decade": float(np.median(np.log(10) / np.maximum(lo, 1e-300))),
        },
    }


def reference_solve(model: Energy, rtol: float = 1e-10, max_steps: int = 200_000, momentum: float = 0.9):
    """Nesterov momentum with gradient restart, step 1 / Gauss-Newton bound per layer, float64,
    until each sample's step-scaled gradient norm is below ``rtol`` times its start."""
    eta = model.gauss_newton_steps()
    y = model.start()
    vel = {n: np.zeros_like(v) for n, v in y.items()}
    g = model.grad(y)
    d0 = np.sqrt(_rows_dot({n: eta[n] * g[n] for n in g}, {n: eta[n] * g[n] for n in g}))
    active = np.ones(model.batch, bool)
    steps = np.zeros(model.batch, int)
    for _ in range(max_steps):
        d = {n: -eta[n] * g[n] * active[:, None] for n in g}
        dn = np.sqrt(_rows_dot(d, d))
        active &= dn >= rtol * d0
        if not active.any():
            break
        steps += active
        uphill = _rows_dot(g, vel) > 0
        keep = (momentum * (active & ~uphill))[:, None]
        for n in y:
            vel[n] = keep * vel[n] + d[n] * active[:, None]
            y[n] = y[n] + d[n] * active[:, None] + momentum * vel[n]
        g = model.grad(y)
    return y, steps, ~active


def relative_distance(a: Latents, b: Latents) -> np.ndarray:
    """Per sample ||a - b|| / ||b|| over every latent layer."""
    diff = {n: a[n] - b[n] for n in b}
    return np.sqrt(_rows_dot(diff, diff) / _rows_dot(b, b))


def gd_trajectory(model: Energy, checkpoints: list[int], reference: Latents | None) -> list[dict[str, float]]:
    """The paper's plain steps (eta_y per layer, no stopping) with the state at each checkpoint."""
    y = model.start()
    rows, done = [], 0
    for cap in sorted(checkpoints):
        for _ in range(cap - done):
            g = model.grad(y)
            for n in y:
                y[n] = y[n] - model.eta[n] * g[n]
        done = cap
        row = {
            "steps": cap, "energy": float(np.median(model.energy(y))),
            "joint_norm": float(np.median(np.linalg.norm(y["joint"], axis=1))),
        }
        if reference is not None:
            row["distance"] = float(np.median(relative_distance(y, reference)))
        row["state"] = {n: v.copy() for n, v in y.items()}
        rows.append(row)
    return rows


def add_network_arguments(ap: argparse.ArgumentParser, samples: int) -> None:
    """The options `load` reads: which network, which run, how many of its samples."""
    ap.add_argument("--model", help="a fitted MuPNet method's folder (pipeline cache/models/NAME-KEY)")
    ap.add_argument("--paper-shape", action="store_true", help="train a paper-shape network on --train instead")
    ap.add_argument("--train", help="training run (.h5) for --paper-shape")
    ap.add_argument("--epochs", type=int, default=10)
    ap.add_argument("--run", required=True, help="the run (.h5) whose samples are inferred")
    ap.add_argument("--samples", type=int, default=samples)


def load(args) -> tuple[Network, dict[str, np.ndarray], str]:
    run = open_run(args.run)
    if args.paper_shape:
        from vitaplace.plugins.mupnet.extractor import MupnetParams

        ex = MupnetExtractor(MupnetParams(epochs=args.epochs, backend="numpy").model_dump())
        ex.progress = False
        ex.fit(open_run(args.train))
        label = f"paper shape, {args.epochs} epochs on {Path(args.train).name}"
    else:
        ex = MupnetExtractor.load(args.model)
        label = f"{Path(args.model).name}"
    inputs = {m: x[: args.samples] for m, x in ex.scaled_inputs(run).items()}
    return ex.network, inputs, label


def diagnose(net: Network, inputs, prior: float, steps: list[int], k: int, ref_steps_max: int) -> dict[str, object]:
    model = Energy(net, inputs, prior)
    t0 = time.perf_counter()
    ref, ref_steps, ref_done = reference_solve(model, max_steps=ref_steps_max)
    ref_grad = model.grad(ref)
    out: dict[str, object] = {
        "prior": prior,
        "reference": {
            "steps_median": int(np.median(ref_steps)), "steps_max": int(ref_steps.max()),
            "settled_share": float(ref_done.mean()), "energy": float(np.median(model.energy(ref))),
            "joint_norm": float(np.median(np.linalg.norm(ref["joint"], axis=1))),
            "grad_norm": float(np.median(np.sqrt(_rows_dot(ref_grad, ref_grad)))),
            "seconds": time.perf_counter() - t0,
        },
        "gauss_newton_steps": model.gauss_newton_steps(),
    }
    rows = gd_trajectory(model, steps, ref)
    out["curvature_at_reference"] = curvature(model, ref, k)
    out["curvature_after_gd"] = curvature(model, rows[-1]["state"], k)
    for row in rows:
        row.pop("state")
    out["gd"] = rows
    return out


def print_report(result: dict[str, object], label: str) -> None:
    print(f"== {label}: prior {result['prior']}")
    ref = result["reference"]
    print(f"reference solve: median {ref['steps_median']} steps (max {ref['steps_max']}), settled "
          f"{100 * ref['settled_share']:.0f} %, energy {ref['energy']:.5g}, |joint| {ref['joint_norm']:.4g}")
    print(f"{'gd steps':>9} {'energy':>10} {'|joint|':>8} {'dist to ref':>11}")
    for row in result["gd"]:
        print(f"{row['steps']:>9} {row['energy']:>10.5g} {row['joint_norm']:>8.4g} "
              f"{row.get('distance', float('nan')):>11.3g}")
    for where in ("curvature_after_gd", "curvature_at_reference"):
        c = result[where]
        print(f"-- {where}")
        print(f"{'layer':>13} {'lam_max':>9} {'lam_min':>9} {'2/lam_max':>9} {'eta_y':>8} {'cond':>9}")
        for node, v in c["layers"].items():
            print(f"{node:>13} {v['lambda_max']:>9.4g} {v['lambda_min']:>9.3g} {v['stability_limit']:>9.3g} "
                  f"{v['eta_y']:>8.2g} {v['condition']:>9.3g}")
        p = c["preconditioned"]
        print(f"  eta-preconditioned whole system: lam_max {p['lambda_max']:.4g} lam_min {p['lambda_min']:.3g} "
              f"(lowest sample {p['lambda_min_lowest']:.3g}) cond {p['condition']:.3g}, plain GD needs "
              f"{p['gd_steps_per_decade']:.3g} steps per decade of error")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_network_arguments(ap, samples=30)
    ap.add_argument("--steps", type=int, nargs="+", default=[100, 300, 1000, 3000])
    ap.add_argument("--prior", type=float, nargs="+", default=[0.0, 0.1])
    ap.add_argument("--lanczos", type=int, default=60, help="Lanczos steps per curvature estimate")
    ap.add_argument("--reference-steps", type=int, default=20000, help="step cap of the reference solve")
    ap.add_argument("--json", help="write the numbers here")
    args = ap.parse_args(argv)
    if not args.paper_shape and not args.model:
        ap.error("give --model DIR or --paper-shape --train RUN")
    net, inputs, label = load(args)
    results = []
    for prior in args.prior:
        result = diagnose(net, inputs, prior, args.steps, args.lanczos, args.reference_steps)
        print_report(result, label)
        results.append(result)
    if args.json:
        Path(args.json).write_text(json.dumps({"network": label, "samples": args.samples, "results": results},
                                              indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
