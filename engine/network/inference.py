"""Test-time inference of a batch of samples with frozen weights, compacting as samples stop.

Each sample stops on its own (`BatchSolver.steps`). Every `STEPS_PER_CHECK` steps
the batch is looked at; when enough samples have stopped (`COMPACT_BELOW`), their results
are taken out and the samples still active go on in a batch of their size, carrying their
latents, steps and solver state (`BatchSolver.carry`), so each sample's steps are those it
would have taken uninterrupted and a batch costs about the sum of its samples' steps rather
than its slowest sample's times its size. A batch compacted to a few samples runs on one BLAS
thread (`small_batch_threads`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from vitaplace.engine.base.cpus import small_batch_threads
from vitaplace.engine.network.batch import BatchState
from vitaplace.engine.network.solver import BatchSolver, Solver
from vitaplace.engine.network.structure import NetworkView

#: Inference steps per captured chunk between two looks at which samples are still active.
STEPS_PER_CHECK = 10
#: A batch is compacted once no more than this share of its samples is still active (a new,
#: smaller batch, and on CUDA a new graph capture, is not worth it for a sample or two).
COMPACT_BELOW = 0.9


class InferredSamples:
    """The per-sample results of one `Network.infer` call - latents, steps, settled flags and
    each edge's mean squared error - filled batch by batch (`infer`) by ``solver`` under the
    latent prior ``prior``."""

    def __init__(self, net: NetworkView, present: Sequence[str], n: int, solver: Solver, prior: float,
                 threshold: np.ndarray, sample_ids: np.ndarray) -> None:
        self.net, self.be, self.present, self.solver, self.prior = net, net.backend, present, solver, prior
        self.node_steps = solver.node_steps(net, present, prior)  # per latent node: eta_y, 1 / L, or P's handle
        self.edges = net.active_edges(present)
        self.width = np.array([net.sizes[e.lower] for e in self.edges], dtype=np.float64)
        self.limits = threshold * self.width
        self.ids = sample_ids
        self.latents = {node: np.empty((n, net.sizes[node]), np.float32) for node in net.latent_nodes(present)}
        self.steps = np.zeros(n, dtype=np.int64)
        self.settled = np.zeros(n, dtype=bool)
        self.mse = np.zeros((len(self.edges), n))
        self._full: dict[int, tuple[BatchSolver, Callable[[], None]]] = {}

    def _batch(self, size: int) -> tuple[BatchSolver, Callable[[], None]]:
        """The solver's steps on a batch of ``size`` set up for this inference, and its
        captured chunk of steps."""
        state = BatchState(self.net, size, self.present)
        state.prior = self.prior
        batch = self.solver.bind(state, self.node_steps)
        self.be.upload(self.limits, state.limits)
        return batch, self.be.capture(functools.partial(batch.steps, STEPS_PER_CHECK))

    def _record(self, state: BatchState, rows: np.ndarray) -> None:
        """The state's samples (``rows`` of the inputs) into the results; a NetworkError
        naming the layer and the samples when an energy is no longer finite."""
        row_energy = self.be.download(state.R)
        bad = ~np.isfinite(row_energy).all(axis=0)
        if bad.any():
            where = self.ids[rows[bad]]
            energy = {e.name: float(row_energy[k, bad].sum()) for k, e in enumerate(self.edges)}
            state.check_finite(energy, f"inference of samples {where.min()}-{where.max()}", self.solver.remedy)
        self.steps[rows] = self.be.download(state.steps)
        self.settled[rows] = self.be.download(state.active) == 0
        self.mse[:, rows] = row_energy / self.width[:, None]
        for node, values in state.download_latents().items():
            self.latents[node][rows] = values

    def infer(self, rows: np.ndarray, resident_x: Mapping[str, Any], max_steps: int,
              on_progress: Callable[[int], object] | None) -> None:
        """Infer the samples ``rows`` of the resident inputs, ``on_progress(k)`` as k more stop."""
        be = self.be
        if len(rows) not in self._full:  # full-size batches are reused (a call has at most two sizes)
            self._full[len(rows)] = self._batch(len(rows))
        batch, chunk = self._full[len(rows)]
        be.upload(rows.astype(np.int32), batch.state.index)
        batch.start(resident_x)
        done = reported = 0  # reported: samples of this state already passed to on_progress
        while True:
            active = be.download(batch.state.active) != 0
            left = int(active.sum())
            if on_progress is not None and len(rows) - left > reported:
                on_progress(len(rows) - left - reported)
                reported = len(rows) - left
            if done >= max_steps or left == 0:
                break
            if left <= COMPACT_BELOW * len(rows):
                reported = 0
                self._record(batch.state, rows)
                carried = batch.carry(active)
                rows = rows[active]
                batch, chunk = self._batch(len(rows))
                be.upload(rows.astype(np.int32), batch.state.index)
                batch.start(resident_x, carried)
            todo = min(STEPS_PER_CHECK, max_steps - done)
            with small_batch_threads(len(rows)):
                if todo == STEPS_PER_CHECK:
                    chunk()
                else:
                    batch.steps(todo)
            done += todo
        self._record(batch.state, rows)
        if on_progress is not None and left:
            on_progress(left)  # the rest stopped at the step cap
