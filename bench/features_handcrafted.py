"""Benchmark of the hand-crafted (ViTa-SLAM) front end: profile distance, full distance, transform.

    python bench/features_handcrafted.py [--n 2000] [--threads 0]

Prints seconds for
  * ``template_distance`` on n x n random 40 x 64 templates (max_shift 5),
  * the extractor's full distance (profile + PFH + SDA) on n x n random features,
  * ``transform`` of an n-sample synthetic run (120 x 160 images, 24 whiskers, 20 samples per
    whisk cycle, 40 contacts per cycle).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vitaplace.engine.dataset import Run
from vitaplace.plugins.handcrafted import HandcraftedExtractor, template_distance


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


def timed(label: str, fn):  # type: ignore[no-untyped-def]
    start = time.perf_counter()
    result = fn()
    print(f"{label}: {time.perf_counter() - start:.2f} s", flush=True)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=2000, help="templates / samples per side (default 2000)")
    parser.add_argument("--threads", type=int, default=0, help="threads for the profile distance (0 = all cores)")
    args = parser.parse_args()
    n, threads = args.n, args.threads or None
    rng = np.random.default_rng(0)

    query = rng.random((n, 40, 64), dtype=np.float32)
    reference = rng.random((n, 40, 64), dtype=np.float32)
    timed(f"template_distance {n}x{n} (40x64, max_shift 5)", lambda: template_distance(query, reference, 5, threads=threads))

    extractor = HandcraftedExtractor({"threads": args.threads})
    extractor.fit(synthetic_run(50, rng))
    fq = {"profile": query, "pfh": rng.random((n, 27), dtype=np.float32), "sda": rng.normal(size=(n, 24)).astype(np.float32)}
    fr = {"profile": reference, "pfh": rng.random((n, 27), dtype=np.float32), "sda": rng.normal(size=(n, 24)).astype(np.float32)}
    timed(f"extractor distance {n}x{n} (profile + pfh + sda)", lambda: extractor.distance(fq, fr))

    run = synthetic_run(n, rng)
    timed(f"extractor transform of {n} samples (120x160 images, 40 contacts/cycle)", lambda: extractor.transform(run))


if __name__ == "__main__":
    main()
