"""The report's training section: per method, its training energy per layer (a figure),
whether it met its convergence criterion, how far its persistent latents still moved and its
held-out energy, for the methods that record them (`FeatureExtractor.training_summary`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.outputs.outdir import FIGURES, training_path
from vitaplace.engine.report import figures


def training_section(out: Path, methods: list[str], summaries: dict[str, dict[str, Any]],
                     formats: Sequence[str]) -> list[str]:
    """The training energy per layer of each method that recorded it (a figure in each of
    ``formats``; none without), whether it met its convergence criterion, how far from settled
    its persistent latents were at the end and its held-out energy (the methods that measure them)."""
    sections = []
    for name in methods:
        path = training_path(out, name)
        if path.is_file() and formats:
            figures.plot_energy(out / FIGURES / f"training-{name}", json.loads(path.read_text()),
                                title=f"{name}: training energy per layer", formats=formats)
            sections += [f"![training {name}](figures/training-{name}.png)", ""]
        summary = summaries.get(name, {})
        if "converged" in summary and "epochs" in summary:
            ended = ("met its convergence criterion" if summary["converged"] else
                     "stopped at its epoch cap without meeting its convergence criterion")
            sections += [f"{name}: training {ended} after {summary['epochs']} epochs.", ""]
        change = summary.get("latent_change")
        if change:
            sections += [f"{name}: in its last epoch, each minibatch's latent steps still moved a sample's latents "
                         f"by a median {100 * change[-1]:.2g} % (relative; {100 * change[0]:.2g} % in the first "
                         "epoch; every epoch in manifest.json's training record). Latents that had settled would "
                         "not move.", ""]
        held = summary.get("held_out")
        if held:
            best = int(np.argmin(held))
            sections += [f"{name}: held-out energy per sample (samples kept out of training, at the latents test-time "
                         f"inference settles them at) {held[-1]:.4g} after the last epoch, {held[0]:.4g} after the "
                         f"first, lowest {held[best]:.4g} after epoch {best + 1}.", ""]
    return ["## Training", "", *sections] if sections else []
