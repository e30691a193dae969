"""Precision-weighted prediction errors of MuPNet (docs/MUPNET.md, "Precision-weighted errors").

With error precisions ``pi`` (one per channel of each edge's lower node) the energy is
``F = sum_edges sum_c pi_c E_c^2``; the backends multiply ``pi`` in where ``G`` and the row
energies are formed and into the top-down term of the latent update. Training estimates them
(``precision_weighting``): `PrecisionEstimator` sums each channel's squared errors over an
epoch on the backend's device, and `estimate_precisions` turns the sums into precisions,
``pi = 1 / max(var, floor)``, scaled so that their mean over every error channel of the
network is 1. At test time they are fixed (saved with the weights).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal, get_args

import numpy as np

from vitaplace.engine.network.backends import Backend
from vitaplace.engine.network.structure import Edge

#: ``none``: every pi = 1 (the paper's energy); ``layer``: one pi per edge; ``channel``: one per channel
PrecisionWeighting = Literal["none", "layer", "channel"]
PRECISION_WEIGHTINGS: tuple[str, ...] = get_args(PrecisionWeighting)


def estimate_precisions(squares: Mapping[str, np.ndarray], samples: int, mode: str, floor: float
                        ) -> dict[str, np.ndarray]:
    """Error precisions per edge from each channel's sum of squared errors over ``samples`` samples.

    The variance of channel c is ``var_c = squares_c / samples`` (the errors' mean square: the
    maximum-likelihood variance of a Gaussian centred on the prediction); ``layer`` pools it
    over the edge's channels (their mean). ``pi = 1 / max(var, floor)``, then every pi is
    divided by their mean over all the channels of all the edges (each channel counted once,
    so an edge weighs by its width): the mean precision is 1, as in the paper's energy.
    """
    if mode not in ("layer", "channel"):
        raise ValueError(f"unknown precision_weighting '{mode}' to estimate; valid: layer, channel")
    raw = {}
    for name, s in squares.items():
        var = np.asarray(s, np.float64) / samples
        if mode == "layer":
            var = np.full_like(var, var.mean())
        raw[name] = 1.0 / np.maximum(var, floor)
    mean = sum(float(p.sum()) for p in raw.values()) / sum(p.size for p in raw.values())
    return {name: (p / mean).astype(np.float32) for name, p in raw.items()}


class PrecisionEstimator:
    """One training run's per-channel sums of squared errors (float64, on the backend's
    device): `accumulate` adds a minibatch's errors (launches only, so it is captured with
    the minibatch), `end_epoch` returns the epoch's precisions and starts the sums afresh."""

    def __init__(self, backend: Backend, edges: Sequence[Edge], sizes: Mapping[str, int], mode: str,
                 floor: float) -> None:
        self.be, self.mode, self.floor = backend, mode, floor
        self.sums = {e.name: backend.empty((sizes[e.lower],), np.float64) for e in edges}

    def accumulate(self, errors: Mapping[str, Any]) -> None:
        """Add each edge's minibatch errors ``E`` (batch x n) to its sums."""
        for name, total in self.sums.items():
            self.be.column_squares(errors[name], total)

    def end_epoch(self, samples: int) -> dict[str, np.ndarray]:
        """The precisions of the epoch's ``samples`` samples (`estimate_precisions`); the sums restart at 0."""
        squares = {name: self.be.download(total) for name, total in self.sums.items()}
        for total in self.sums.values():
            self.be.fill(total, 0.0)
        return estimate_precisions(squares, samples, self.mode, self.floor)
