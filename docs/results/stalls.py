"""Where the evaluation drives of a sweep stall: per seed, world and drive, the longest stretch
of consecutive samples that stays within 0.25 m of its first pose (`longest_stay`, also in
every evaluation's difficulty as a share), and where it starts.

    python docs/results/stalls.py runs/paper-cpu-sweep docs/results/paper-cpu-sweep/stalls.csv

Reads the poses each evaluation saved (``seed-*/evaluations/WORLD/METHOD/query-to-reference/
matrices.npz``, the first method's; the drives are the same for every method) and writes one
CSV row per seed x world x drive. A teleoperated drive stops at landmarks for a few whisk
cycles; a stretch of hundreds of samples in one place is a drive that got stuck.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from vitaplace.engine.evaluation.evaluate import longest_stay


def main(sweep: Path, out: Path) -> int:
    rows = []
    for seed_dir in sorted(sweep.glob("seed-*"), key=lambda p: int(p.name.split("-")[1])):
        for world_dir in sorted((seed_dir / "evaluations").iterdir()):
            method_dir = sorted(p for p in world_dir.iterdir() if p.is_dir())[0]
            matrices = np.load(method_dir / "query-to-reference" / "matrices.npz")
            for drive in ("query", "reference"):
                poses = matrices[f"{drive}_poses"]
                length, start = longest_stay(poses[:, :2])
                rows.append({"seed": seed_dir.name.split("-")[1], "environment": world_dir.name, "drive": drive,
                             "samples": len(poses), "longest_stay": length, "stay_start": start,
                             "stay_x": f"{poses[start, 0]:.2f}", "stay_y": f"{poses[start, 1]:.2f}"})
    with open(out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
