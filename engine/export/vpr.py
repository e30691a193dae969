"""The VPR layout: each evaluation as the image folders that visual place recognition tools
read, so that a method outside vitaplace is scored on the same drives.

Per evaluation ``vpr/EVALUATION/`` holds, as VPR-methods-evaluation and the VPR datasets
downloader lay a dataset out, ``images/test/database/`` (the reference run's camera frames)
and ``images/test/queries/`` (the query run's), each frame a lossless PNG named with the
fields of that convention, ``@east@north@zone@letter@lat@lon@id@tile@heading@pitch@roll@height@time@note@.png``:
east and north the position in metres (6 decimals), id the sample's index, heading the yaw in
degrees counter-clockwise from the x axis in [0, 360) (4 decimals), time the sample's time in
seconds; the others are empty. ``database_images_paths.txt`` and ``queries_images_paths.txt``
beside the folders list the names in drive order (VPR-methods-evaluation reads that order,
and the sample index of an image is its line), ``positives.json`` the true matches of each
query (reference indices) by the benchmark's own rule, and ``ground_truth.npz`` the same as
VPR_Tutorial's ``GThard``/``GTsoft`` (references x queries, bool).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from PIL import Image

from vitaplace.engine.base.atomic import atomic_path, write_text_atomic
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.data.dataset import Run, open_run
from vitaplace.engine.export.common import ExportRun, ground_truth, write_npz

VPR = "vpr"
#: below an evaluation's folder: the split VPR-methods-evaluation's datasets keep their test images in
IMAGES = Path("images") / "test"
DATABASE, QUERIES = "database", "queries"
POSITIVES = "positives.json"
GROUND_TRUTH = "ground_truth.npz"


def image_name(index: int, pose: np.ndarray, time: float) -> str:
    """The file name of sample ``index`` at ``pose`` (x [m], y [m], yaw [rad]) and ``time`` [s]
    (module docstring: the fields of the VPR datasets' convention)."""
    heading = float(np.degrees(pose[2])) % 360.0
    fields = [f"{pose[0]:.6f}", f"{pose[1]:.6f}", "", "", "", "", f"{index:05d}", "", f"{heading:.4f}", "", "", "",
              f"{time:.3f}", ""]
    return "@" + "@".join(fields) + "@.png"


def write_images(folder: Path, run: Run) -> list[str]:
    """Every camera frame of ``run`` as a PNG in ``folder`` and the names, in drive order, in
    ``<folder>_images_paths.txt``; returns the names."""
    names = [image_name(i, run.poses[i], float(run.times[i])) for i in range(len(run))]
    images = run.images
    for name, image in zip(names, images, strict=True):
        with atomic_path(folder / name) as tmp:
            Image.fromarray(np.ascontiguousarray(image)).save(tmp, format="PNG")
    write_text_atomic(folder.with_name(f"{folder.name}_images_paths.txt"), "\n".join(names) + "\n")
    return names


def write_vpr(out: Path, scenario: Scenario, runs: Mapping[str, ExportRun]) -> list[Path]:
    """Every evaluation of ``scenario`` in the VPR layout under ``out/vpr`` (module docstring);
    returns the evaluation folders."""
    folders = []
    for evaluation in scenario.evaluations:
        folder = out / VPR / evaluation.name
        query, reference = runs[f"{evaluation.name}/query"], runs[f"{evaluation.name}/reference"]
        q, r = open_run(query.path), open_run(reference.path)
        database = write_images(folder / IMAGES / DATABASE, r)
        queries = write_images(folder / IMAGES / QUERIES, q)
        _, true = ground_truth(scenario, q.poses, r.poses)
        lacks_camera = query.lacks("camera", len(q))
        write_npz(folder / GROUND_TRUTH, GThard=true.T, GTsoft=true.T, query_lacks_camera=lacks_camera)
        positives = {
            "tau_m": scenario.scoring.tau, "heading_tolerance_deg": scenario.scoring.heading_tolerance_deg,
            "database": database, "queries": queries,
            "positives": [np.flatnonzero(row).tolist() for row in true],
            "queries_lacking_camera": np.flatnonzero(lacks_camera).tolist(),
        }
        write_text_atomic(folder / POSITIVES, json.dumps(positives, indent=1))
        folders.append(folder)
    return folders
