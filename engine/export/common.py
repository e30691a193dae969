"""What both export layouts share: the runs an export is made from, the benchmark's ground
truth of an evaluation, and files written atomically."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.atomic import atomic_path
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.evaluation.evaluate import ground_truth_matrix

#: the version of both layouts; `read_package` reads packages of this version
FORMAT_VERSION = 1


class ExportError(UserError):
    """An export folder or package that cannot be written or read; one line naming the file."""


@dataclass(frozen=True)
class ExportRun:
    """One run of the scenario as the export reads it: its run file, the seed it was simulated
    with (None for a recorded run), and for a query run with a drop-out the samples that lack
    each sensor and the seed that drew them."""

    label: str  # ``train``, ``E1/query``
    path: Path
    seed: int | None
    missing: dict[str, np.ndarray] = field(default_factory=dict)
    dropout_seed: int | None = None

    def lacks(self, sensor: str, samples: int) -> np.ndarray:
        """(samples,) bool: True where the sample lacks ``sensor`` (all False without drop-out)."""
        return np.asarray(self.missing.get(sensor, np.zeros(samples, dtype=bool)), dtype=bool)


def ground_truth(scenario: Scenario, query_poses: np.ndarray,
                 reference_poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The evaluation's ground truth as the benchmark scores it: ``gtm`` (queries x references,
    metres; +inf where the headings differ by more than the heading tolerance,
    `ground_truth_matrix`) and the true matches ``gtm <= tau``."""
    gtm = ground_truth_matrix(query_poses, reference_poses, scenario.scoring.heading_tolerance_deg)
    return gtm, gtm <= scenario.scoring.tau


def write_npz(path: Path, **arrays: Any) -> Path:
    """``arrays`` in an uncompressed ``.npz`` at ``path``, written atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: numpy would add '.npz' to a name
        named: dict[str, Any] = {name: np.asarray(value) for name, value in arrays.items()}  # Any: not allow_pickle's
        np.savez(fh, **named)
    return path


def copy_file(source: Path, path: Path) -> Path:
    """``source``'s bytes at ``path``, written atomically."""
    with atomic_path(path) as tmp:
        shutil.copyfile(source, tmp)
    return path
