"""Feature-extractor benchmark: transform throughput and the time of an n x n TME per method.

    python bench/features.py [--n 2000] [--threads 0] [--mupnet-steps 100]

Baseline, measured in the same run: one scipy ``cdist(cityblock)`` over the full 40 x 64
templates (the work of a single shift; shift matching does 11). Prints seconds and ratios
to the baseline for
  * ``template_distance`` on n x n random 40 x 64 templates (max_shift 5),
  * the hand-crafted extractor's full distance (profile + PFH + SDA),
  * hand-crafted ``transform`` of an n-sample synthetic run (120 x 160 images, 24 whiskers,
    20 samples per whisk cycle, 40 contacts per cycle),
  * MuPNet ``transform`` (paper layer sizes, numpy backend, a fixed number of inference
    steps) and its L2 distance.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.distance import cdist

from vitaplace.engine.data.dataset import Run
from vitaplace.plugins.handcrafted import HandcraftedExtractor, template_distance
from vitaplace.plugins.mupnet import MupnetExtractor


def synthetic_run(n: int, rng: np.random.Generator, contacts: int = 40) -> Run:
    normals = rng.normal(size=(n * contacts, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Run.from_arrays(
        images=rng.integers(0, 256, size=(n, 120, 160, 3), dtype=np.uint8),
        theta=np.zeros((n, 24)),
        xy=np.zeros((n, 24, 2)),
        poses=np.zeros((n, 3)),
        deflection=rng.normal(scale=0.02, size=(n, 20, 24, 2)),
        contact_points=rng.normal(scale=0.05, size=(n * contacts, 3)),
        contact_normals=normals,
        contact_offsets=np.arange(n + 1) * contacts,
    )


def timed(label: str, fn, baseline: float | None = None, samples: int | None = None):  # type: ignore[no-untyped-def]
    """Run ``fn`` once; print seconds, the ratio to ``baseline`` seconds, and samples/s."""
    start = time.perf_counter()
    result = fn()
    seconds = time.perf_counter() - start
    extra = f"  ({seconds / baseline:.1f}x baseline)" if baseline else ""
    extra += f"  {samples / seconds:.0f} samples/s" if samples else ""
    print(f"{label}: {seconds:.2f} s{extra}", flush=True)
    return result, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=2000, help="templates / samples per side (default 2000)")
    parser.add_argument("--threads", type=int, default=0, help="threads for the profile distance (0 = all cores)")
    parser.add_argument("--mupnet-steps", type=int, default=100, help="MuPNet test-time inference steps")
    args = parser.parse_args()
    n, threads = args.n, args.threads or None
    rng = np.random.default_rng(0)

    query = rng.random((n, 40, 64), dtype=np.float32)
    reference = rng.random((n, 40, 64), dtype=np.float32)
    _, base = timed(
        f"baseline: cdist cityblock {n}x{n} on 2560 values (one shift)",
        lambda: cdist(query.reshape(n, -1), reference.reshape(n, -1), "cityblock"),
    )
    timed(
        f"template_distance {n}x{n} (40x64, max_shift 5)",
        lambda: template_distance(query, reference, 5, threads=threads),
        base,
    )

    extractor = HandcraftedExtractor({"threads": args.threads})
    extractor.fit(synthetic_run(50, rng))
    fq = {"profile": query, "pfh": rng.random((n, 27), dtype=np.float32),
          "sda": rng.normal(size=(n, 24)).astype(np.float32)}
    fr = {"profile": reference, "pfh": rng.random((n, 27), dtype=np.float32),
          "sda": rng.normal(size=(n, 24)).astype(np.float32)}
    timed(f"handcrafted distance {n}x{n} (profile + pfh + sda)", lambda: extractor.distance(fq, fr), base)

    run = synthetic_run(n, rng)
    timed(f"handcrafted transform of {n} samples (120x160, 40 contacts/cycle)", lambda: extractor.transform(run),
          base, n)

    no_stop = {"threshold_visual": 0.0, "threshold_tactile": 0.0, "threshold_joint": 0.0}  # always max_steps
    mupnet = MupnetExtractor({"backend": "numpy", "epochs": 1, "max_steps": args.mupnet_steps, **no_stop})
    mupnet.progress = False
    mupnet.fit(synthetic_run(150, rng))
    features, _ = timed(
        f"mupnet transform of {n} samples (paper sizes, {args.mupnet_steps} inference steps)",
        lambda: mupnet.transform(run),
        base,
        n,
    )
    timed(f"mupnet distance {n}x{n} (L2 of {features['latent'].shape[1]}-d latents)",
          lambda: mupnet.distance(features, features), base)


if __name__ == "__main__":
    main()
