"""Evaluation at scale: one pair of n queries x n references scored per shipped method, each in
its own process, with CPU seconds, wall seconds and peak memory (the process's maximum
resident set), and the exponents fitted over the sizes (time ~ n^a, memory above the
smallest size's ~ n^b).

    python bench/scale.py [--sizes 450 4500 20000] [--methods H H-T L A HOG VLAD] [--queries Q]

The pair is synthetic: both runs drive two laps of a loop with 3 cm between samples (the
quickstart's spacing; the loop grows with n, so each query has a bounded number of true
matches, about 40 at tau 0.3 m), headings along the loop; the features are random, of the
shipped methods' shapes and defaults: H the hand-crafted extractor (40 x 64 profile with 11
shifts, PFH, SDA), H-T its touch-only configuration (PFH and SDA), L MuPNet's and A the
autoencoder's 100-dimensional latents (L2), HOG and VLAD their unit-length descriptors
(3,780 and 8,192 values by default; L2). Each method's distances are computed a chunk of
queries at a time (`Rows`) and scored by `evaluate_pair` with the quickstart's scoring
(tau 0.3 m, heading tolerance 30 degrees, recall@1/5/10) into a temporary folder, a chunk of
queries at a time at every size (no matrix held whole, none written; ``--whole`` keeps the
pipeline's `FULL_MATRIX_LIMIT`, below which the matrices are held and written as
``matrices.npz``). ``--queries Q`` scores only the first Q
queries against all n references (for a method whose n x n distances take hours here: the
memory is that of the full pair, the time scales with the queries).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SPACING = 0.03  # metres between samples, as the quickstart's drives
METHODS = ("H", "H-T", "L", "A", "HOG", "VLAD")


def loop_drive(n: int, seed: int) -> np.ndarray:
    """(n, 3) poses: two laps of a circle of circumference n * SPACING / 2, with jitter."""
    rng = np.random.default_rng(seed)
    radius = n * SPACING / 2 / (2 * np.pi)
    angle = np.linspace(0, 4 * np.pi, n, endpoint=False)
    xy = radius * np.column_stack([np.cos(angle), np.sin(angle)]) + rng.normal(0, 0.05, (n, 2))
    return np.column_stack([xy, angle + np.pi / 2 + rng.normal(0, 0.2, n)])


def method(name: str, n: int, rng: np.random.Generator):  # type: ignore[no-untyped-def]  # (extractor, features)
    """A shipped extractor, ready to compare, and random features of its shape for n samples."""
    if name in ("H", "H-T"):
        from vitaplace.plugins.handcrafted import HandcraftedExtractor
        ext = HandcraftedExtractor({} if name == "H" else {"use_visual": False})
        feats = {"pfh": rng.random((n, 27), dtype=np.float32), "sda": rng.random((n, 24), dtype=np.float32)}
        if name == "H":
            feats["profile"] = rng.random((n, 40, 64), dtype=np.float32)
        ext.sigmas = {key: 1.0 for key in ext.feature_names}
        return ext, feats
    if name in ("HOG", "VLAD"):  # unit-length image descriptors of their default shape, compared by L2
        from vitaplace.plugins.hog import HogExtractor
        from vitaplace.plugins.vlad import VladExtractor
        ext = (HogExtractor if name == "HOG" else VladExtractor)()
        vectors = rng.random((n, ext.dimension), dtype=np.float32)
        return ext, {ext.feature: vectors / np.linalg.norm(vectors, axis=1, keepdims=True)}
    if name == "L":
        from vitaplace.plugins.mupnet import MupnetExtractor
        return MupnetExtractor(), {"latent": rng.normal(size=(n, 100))}
    from vitaplace.plugins.autoencoder.extractor import AutoencoderExtractor
    return AutoencoderExtractor(), {"latent": rng.normal(size=(n, 100))}


def child(name: str, n: int, queries: int, whole: bool) -> dict:
    """Score one pair in this process; the measurements as a dict."""
    from vitaplace.engine.evaluation import pairfiles
    from vitaplace.engine.evaluation.ranking import Rows

    if not whole:
        pairfiles.FULL_MATRIX_LIMIT = 0

    rng = np.random.default_rng(0)
    ext, feats = method(name, n, rng)
    ref_feats = {k: v[rng.permutation(n)] for k, v in feats.items()}  # another drive's features
    q_poses, r_poses = loop_drive(n, 1)[:queries], loop_drive(n, 2)
    q_feats = {k: v[:queries] for k, v in feats.items()}
    rows = Rows((queries, n), lambda a, b: ext.distance({k: v[a:b] for k, v in q_feats.items()}, ref_feats))
    wall, cpu = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as folder:
        summary = pairfiles.evaluate_pair(folder, rows, q_poses, r_poses, 0.3, None, (1, 5, 10),
                                          heading_tolerance_deg=30.0)
    return {"method": name, "n": n, "queries": queries, "wall_s": time.perf_counter() - wall,
            "cpu_s": time.process_time() - cpu, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "n_revisit": summary["n_revisit"], "recall_at_1": summary["recall_at_k"]["1"]}


def exponent(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of log y on log x."""
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[450, 4500, 20000], help="samples per side")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--queries", type=int, default=0, help="score only the first Q queries (0: all n)")
    parser.add_argument("--whole", action="store_true", help="hold the matrices whole below FULL_MATRIX_LIMIT")
    parser.add_argument("--child", nargs=3, metavar=("METHOD", "N", "Q"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), int(args.child[2]), args.whole)))
        return
    print(f"{'method':>6} {'n':>7} {'queries':>7} {'wall s':>9} {'CPU s':>9} {'peak MiB':>9} {'recall@1':>8}")
    for name in args.methods:
        done = []
        for n in args.sizes:
            queries = min(args.queries, n) if args.queries else n
            command = [sys.executable, str(Path(__file__).resolve()), "--child", name, str(n), str(queries)]
            out = subprocess.run(command + ["--whole"] * args.whole, check=True, capture_output=True, text=True).stdout
            row = json.loads(out.strip().splitlines()[-1])
            done.append(row)
            print(f"{name:>6} {n:>7} {queries:>7} {row['wall_s']:>9.1f} {row['cpu_s']:>9.1f} {row['peak_mib']:>9.0f} "
                  f"{row['recall_at_1']:>8.3f}", flush=True)
        if len(done) > 2:  # fitted over the sizes above the first (start-up costs dominate the smallest)
            rest = done[1:]
            above = [r["peak_mib"] - done[0]["peak_mib"] for r in rest]
            memory = exponent([r["n"] for r in rest], above) if min(above) > 0 else math.nan
            time_exp = exponent([r["n"] * r["queries"] for r in rest], [r["cpu_s"] for r in rest])
            print(f"{name:>6} CPU time ~ (queries x references)^{time_exp:.2f}, "
                  f"peak memory above n={done[0]['n']}'s ~ n^{memory:.2f}", flush=True)


if __name__ == "__main__":
    main()
