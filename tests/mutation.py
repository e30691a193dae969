#!/usr/bin/env python
"""Mutation testing on demand (not part of CI): does the suite notice when the code is wrong?

Each mutant changes one snippet of the package the way a real bug would (a sign, an index,
an off-by-one, a comparison, a dropped term, a skipped step) and names the narrowest pytest
selection that should catch it. The script copies the working tree into a temporary folder,
applies each mutant there (the working tree is never written, so nothing is left mutated, not
even after Ctrl-C), runs the mutant's tests with a timeout and records the test that failed.
A mutant is *killed* when a test fails, *killed by timeout* when its tests run past the limit
(an endless loop is a detected bug, but it is reported apart), *survived* otherwise.
`EQUIVALENT` lists mutants that cannot change any result, with the reason.

    python tests/mutation.py                    # every mutant (16 min with --jobs 2 on 2 cores, 2026-12-01)
    python tests/mutation.py summary sim.model  # mutants of these modules (keys of MODULES) or names
    python tests/mutation.py --list             # mutant, file, tests
    python tests/mutation.py --check            # every snippet applies exactly once (no tests run)
    python tests/mutation.py --jobs 2 --timeout 300

A snippet that no longer occurs exactly once in its file stops the script before anything
runs (one line, exit 2): update the mutant. Exit status 0 when at least 90 % are killed.
When a module moves, edit its line in `MODULES` (the only place that names files).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET = 0.90
try:
    import tomllib
except ImportError:  # Python 3.10: the same parser from PyPI (pip install tomli)
    import tomli as tomllib

#: pyproject.toml's package-dir: package -> its source folder
PACKAGE_DIR = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
#: Folders of the package whose modules need mutants (those holding Python code); a module over
#: MIN_LINES lines needs one.
PACKAGE_DIRS = tuple(folder for folder in PACKAGE_DIR.values() if any((ROOT / folder).rglob("*.py")))
MIN_LINES = 40

#: Every mutated module by key; a mutant names its module by key, so a moved file is one line here.
MODULES = {
    "aggregate": "engine/study/aggregate.py",
    "backends": "engine/network/backends.py",
    "batch": "engine/network/batch.py",
    "solver": "engine/network/solver.py",
    "solver_kernels": "kernels/solver_kernels.py",
    "checksum": "engine/outputs/checksum.py",
    "cli": "engine/cli/main.py",
    "cli.commands": "engine/cli/commands.py",
    "completion": "engine/outputs/completion.py",
    "configfile": "engine/base/configfile.py",
    "errors": "engine/base/errors.py",
    "shipped": "engine/base/shipped.py",
    "cpus": "engine/base/cpus.py",
    "dataset": "engine/data/dataset.py",
    "evaluate": "engine/evaluation/evaluate.py",
    "features": "engine/extension/features.py",
    "figures": "engine/report/figures.py",
    "hookspecs": "engine/extension/hookspecs.py",
    "matimport": "engine/data/matimport.py",
    "outdir": "engine/outputs/outdir.py",
    "rows": "engine/outputs/rows.py",
    "pc": "engine/network/pc.py",
    "inference": "engine/network/inference.py",
    "structure": "engine/network/structure.py",
    "plausibility": "engine/sim/plausibility.py",
    "plugins": "engine/extension/registry.py",
    "provenance": "engine/pipeline/provenance.py",
    "report": "engine/report/report.py",
    "resample": "engine/evaluation/resample.py",
    "plan": "engine/pipeline/plan.py",
    "keys": "engine/pipeline/keys.py",
    "store": "engine/pipeline/store.py",
    "scoring": "engine/pipeline/scoring.py",
    "stages.simulate": "engine/pipeline/stages/simulate.py",
    "stages.fit": "engine/pipeline/stages/fit.py",
    "stages.transform": "engine/pipeline/stages/transform.py",
    "stages.evaluate": "engine/pipeline/stages/evaluate.py",
    "stages.compare": "engine/pipeline/stages/compare.py",
    "stages.report": "engine/pipeline/stages/report.py",
    "scenario": "engine/config/scenario.py",
    "schema_docs": "engine/cli/schema_docs.py",
    "slurm": "engine/cli/slurm.py",
    "installation": "engine/cli/installation.py",
    "ray_auth": "engine/cli/ray_auth.py",
    "summary": "engine/study/summary.py",
    "grid": "engine/study/grid.py",
    "sweep": "engine/cli/sweep.py",
    "video": "engine/sim/video.py",
    "sim": "engine/sim/__init__.py",
    "sim.build": "engine/sim/build.py",
    "sim.controllers": "engine/sim/controllers/__init__.py",
    "sim.controllers.common": "engine/sim/controllers/common.py",
    "sim.controllers.factory": "engine/sim/controllers/factory.py",
    "sim.controllers.foraging": "engine/sim/controllers/foraging.py",
    "sim.controllers.route": "engine/sim/controllers/route.py",
    "sim.controllers.safety": "engine/sim/controllers/safety.py",
    "sim.controllers.settings": "engine/sim/controllers/settings.py",
    "sim.controllers.teleop": "engine/sim/controllers/teleop.py",
    "sim.controllers.stations": "engine/sim/controllers/stations.py",
    "sim.clearance": "engine/sim/clearance.py",
    "sim.condition": "engine/sim/condition.py",
    "config.loading": "engine/config/loading.py",
    "config.methods": "engine/config/methods.py",
    "config.inputs": "engine/config/inputs.py",
    "config.memory": "engine/config/memory.py",
    "config.overrides": "engine/config/overrides.py",
    "manifest": "engine/pipeline/manifest.py",
    "orchestrate": "engine/pipeline/orchestrate.py",
    "output_checks": "engine/pipeline/output_checks.py",
    "processes": "engine/pipeline/processes.py",
    "records": "engine/pipeline/records.py",
    "results": "engine/pipeline/results.py",
    "simulation": "engine/pipeline/simulation.py",
    "sim.environment": "engine/sim/environment.py",
    "sim.glsetup": "engine/sim/glsetup.py",
    "sim.model": "engine/sim/model.py",
    "sim.plot": "engine/sim/plot.py",
    "sim.render": "engine/sim/render.py",
    "sim.robot": "engine/sim/robot.py",
    "sim.routegen": "engine/sim/routegen.py",
    "sim.simulate": "engine/sim/simulate.py",
    "sim.gym_env": "engine/sim/gym_env.py",
    "sim.viewer": "engine/sim/viewer.py",
    "kernels.reference": "kernels/reference.py",
    "kernels.launch": "kernels/launch.py",
    "kernels.tiles": "kernels/tiles.py",
    "kernels.predict": "kernels/predict_kernels.py",
    "kernels.update": "kernels/update_kernels.py",
    "kernels.copy": "kernels/copy_kernels.py",
    "handcrafted.extractor": "plugins/handcrafted/extractor.py",
    "handcrafted.pfh": "plugins/handcrafted/pfh.py",
    "handcrafted.profile": "plugins/handcrafted/profile.py",
    "handcrafted.sda": "plugins/handcrafted/sda.py",
    "mupnet.extractor": "plugins/mupnet/extractor.py",
    "mupnet.inputs": "plugins/mupnet/inputs.py",
    "autoencoder.extractor": "plugins/autoencoder/extractor.py",
    "autoencoder.model": "plugins/autoencoder/model.py",
    "mlflow_tracking": "plugins/mlflow_tracking.py",
    "api": "api/__init__.py",
    "testing": "api/testing.py",
    "sensitivity": "engine/study/sensitivity.py",
    "difficulty": "engine/evaluation/difficulty.py",
    "pairfiles": "engine/evaluation/pairfiles.py",
    "sequence": "engine/evaluation/sequence.py",
    "fusion": "engine/evaluation/fusion.py",
    "stages.fuse": "engine/pipeline/stages/fuse.py",
    "tensorcores": "engine/network/tensorcores.py",
    "selection": "engine/network/selection.py",
    "complementarity": "engine/evaluation/complementarity.py",
    "config.methods": "engine/config/methods.py",
    "cli.difficulty": "engine/cli/difficulty.py",
    "hypotheses": "engine/study/hypotheses.py",
}


@dataclass(frozen=True)
class Mutant:
    name: str
    module: str  # a key of MODULES
    old: str  # must occur exactly once in the module
    new: str
    tests: tuple[str, ...]  # pytest node ids that should fail

    @property
    def path(self) -> str:
        return MODULES[self.module]


def m(name: str, module: str, old: str, new: str, *tests: str) -> Mutant:
    return Mutant(name, module, old, new, tests)


#: test file key (``cli`` for test_cli.py) -> its path, in whichever tier folder of tests/ it is
TEST_FILES = {path.stem.removeprefix("test_"): path.relative_to(ROOT).as_posix()
              for path in sorted((ROOT / "tests").rglob("test_*.py"))}


def t(file: str, *names: str) -> tuple[str, ...]:
    """Node ids of tests ``names`` in the test file ``test_<file>.py`` (`TEST_FILES`)."""
    return tuple(f"{TEST_FILES[file]}::{name}" for name in names)

PFH_NORMALISE = "    return (counts * (100.0 / counts.sum())).astype(np.float32)"
PC_TRAINED = (*t("pc", *(f"{name}[numpy]" for name in (
    "test_training_lowers_reconstruction_error_of_both_modalities", "test_training_moves_every_sample_every_epoch",
    "test_energy_history_is_the_per_sample_energy_of_the_epoch", "test_inference_stops_at_threshold_or_step_cap",
    "test_each_sample_stops_on_its_own", "test_a_sample_at_the_cap_is_not_stopped", "test_joint_latents_group_samples_by_cause"))),
    *t("pc", "test_numpy_backend_matches_the_reference_on_wide_layers"))
PC_AGREE = t("pc", "test_numpy_and_warp_backends_agree[cpu]")
PC_GRADIENTS = t("pc", "test_latent_and_weight_gradients_match_finite_differences",
                 "test_inference_with_small_step_never_increases_energy[numpy]")

MUTANTS = [
    m("solver: the prior left out of the latent steps", "batch",
      "        if self.prior:\n            for node in self.nodes:", "        if False:\n            for node in self.nodes:",
      *t("solver", "test_the_long_plain_gradient_solve_is_a_stationary_point")),
    m("solver: the curvature bound without the edge above", "solver",
      "            bound[e.lower] += 2.0", "            bound[e.lower] += 0.0",
      *t("solver", "test_the_curvature_steps_are_the_gauss_newton_bound")),
    m("solver: the preconditioners without the edge above", "solver",
      "        values = np.maximum(values, 0.0) + prior + (2.0 if node in above else 0.0)",
      "        values = np.maximum(values, 0.0) + prior",
      *t("solver", "test_the_preconditioners_invert_the_gauss_newton_bound_matrix")),
    m("solver: the preconditioned restart test on the preconditioned step, not the gradient", "solver",
      "        for node, d in self.descent.items():  # dF/dY . V = -(descent . V) / eta",
      "        for node, d in self.D.items():  # dF/dY . V = -(descent . V) / eta",
      *t("solver", "test_the_preconditioned_restart_test_is_on_the_gradient")),
    m("solver: the preconditioner applied twice over", "solver",
      "            be.latent_update(self.D[node], self.descent[node], P, 0.5, None, None)",
      "            be.latent_update(self.D[node], self.descent[node], P, 1.0, None, None)",
      *t("solver", "test_the_first_step_is_one_plus_beta_times_the_preconditioned_descent[preconditioned]")),
    m("solver: the relative rule compares unsquared norms", "backends",
      "(scale * scale * gnorm < rtol2 * g0)", "(scale * gnorm < rtol2 * g0)",
      *t("solver", "test_the_relative_rule_stops_plain_steps_once_the_step_has_shrunk",
         "test_the_solver_kernels_match_the_numpy_backend")),
    m("solver: no halving after a plain step overshoots", "backends",
      "        scale[live & restart & (plain != 0)] *= 0.5", "        scale[live & restart & (plain != 0)] *= 1.0",
      *t("solver", "test_on_a_leaky_relu_network_float32_stops_where_float64_does[numpy-nesterov]",
         "test_the_restart_control_by_hand[numpy]", "test_the_solver_kernels_match_the_numpy_backend")),
    m("solver_kernels: the step after a restart not marked as one without momentum", "solver_kernels",
      "    plain[r] = wp.where(restart, 1, 0)", "    plain[r] = 0",
      *t("solver", "test_the_restart_control_by_hand[warp-cpu]", "test_the_solver_kernels_match_the_numpy_backend")),
    m("inference: a compacted batch restarts its samples' step counts", "batch",
      '            self.be.upload(carried["steps"], self.steps)', "            self.be.fill(self.steps, 0)",
      *t("solver", *(f"test_compacting_a_batch_changes_no_sample_s_steps[{b}-{c}]"
                     for b in ("numpy", "warp-cpu") for c in ("gd", "nesterov")))),
    m("inference: a compacted batch loses its samples' momentum", "solver",
      '        rows.update({f"V/{node}": v for node, v in self.V.items()})', "",
      *t("solver", "test_compacting_a_batch_changes_no_sample_s_steps[numpy-nesterov]")),
    m("inference: a compacted batch loses its samples' step scale", "solver",
      'rows = {"g0": self.g0, "scale": self.scale, "plain": self.plain}',
      'rows = {"g0": self.g0, "plain": self.plain}',
      *t("solver", "test_compacting_a_batch_changes_no_sample_s_steps[numpy-nesterov]")),
    m("solver: the factory builds nesterov for preconditioned", "solver",
      "        return Preconditioned(momentum=momentum, rtol=rtol)", "        return Nesterov(momentum=momentum, rtol=rtol)",
      *t("solver", "test_the_factory_builds_each_solver_from_its_name_and_settings")),
    m("solver: the preconditioned solver accepted without a prior", "solver",
      "    needs_prior: ClassVar[bool] = True", "    needs_prior: ClassVar[bool] = False",
      *t("mupnet_plugin", "test_the_preconditioned_solver_without_a_prior_is_one_line")),
    m("solver: gd's relative rule ignored", "solver",
      "return BatchSolver(state) if self.rtol is None else ScaledSteps(state, node_steps, rtol=self.rtol)",
      "return BatchSolver(state)",
      *t("solver", "test_the_relative_rule_stops_plain_steps_once_the_step_has_shrunk")),
    m("structure: a training configuration without the prior not the paper's energy", "structure",
      "    latent_prior: float = 0.0", "    latent_prior: float = 1.0",
      *t("mupnet_plugin", "test_the_engine_configs_hold_no_defaults_of_their_own")),
    m("inference: compacted rows not narrowed to the active samples", "inference",
      "                rows = rows[active]\n", "                rows = rows[: int(active.sum())]\n",
      *t("solver", "test_compacting_a_batch_changes_no_sample_s_steps[numpy-gd]")),
    m("pc: training's latent change measured against the sum, not the difference", "batch",
      "            be.scale_add(self.Y_start[node], y, -1.0, None)", "            be.scale_add(self.Y_start[node], y, 1.0, None)",
      *t("pc", "test_latent_change_is_how_far_each_epoch_s_steps_moved_the_latents[numpy]")),
    m("solver_kernels: momentum kept on a restart", "solver_kernels",
      "    keep = wp.where(restart[r] > wp.float64(0.0) or active[r] == 0, wp.float32(0.0), beta)",
      "    keep = wp.where(active[r] == 0, wp.float32(0.0), beta)",
      *t("solver", "test_the_solver_kernels_match_the_numpy_backend")),
    m("solver_kernels: the relative rule ignores the step scale", "solver_kernels",
      "scale[r] * scale[r] * gnorm[r] < rtol2 * g0[r]", "gnorm[r] < rtol2 * g0[r]",
      *t("solver", "test_the_solver_kernels_match_the_numpy_backend")),
    m("solver_kernels: a masked row is still added to", "solver_kernels",
      "            if mask[r] == 0:\n                return", "            if mask[r] == 2:\n                return",
      *t("solver", "test_the_solver_kernels_match_the_numpy_backend")),
    # --- the predictive-coding network and its backends
    m("pc: one sample per minibatch never trained", "pc",
      "index = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size])",
      "index = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size - 1])", *PC_TRAINED),
    m("pc: latents not written back to the store", "batch",
      "            be.scatter_rows(y, self.index, latents[node])", "            pass", *PC_TRAINED),
    m("pc: latent init 0.1 -> 0", "batch", "LATENT_INIT = 0.1", "LATENT_INIT = 0.0", *PC_TRAINED),
    m("pc: per-sample limit not scaled by the layer width", "inference",
      "self.limits = threshold * self.width", "self.limits = threshold", *PC_TRAINED),
    m("pc: inference step cap off by one", "inference",
      "todo = min(STEPS_PER_CHECK, max_steps - done)", "todo = min(STEPS_PER_CHECK, max_steps - done + 1)", *PC_TRAINED),
    m("pc: energy history not divided by the samples", "pc",
      "history.energy[name].append(total / n)", "history.energy[name].append(total)", *PC_TRAINED),
    m("pc: Glorot limit uses fan_in only", "pc",
      "limit = math.sqrt(6.0 / (fan_in + fan_out))", "limit = math.sqrt(6.0 / fan_in)", "tests/kernels/test_pc.py"),
    m("numpy backend: weight update skips the last partial chunk", "backends",
      "        for i in range(0, n_l, step):", "        for i in range(0, n_l - n_l % step if n_l > step else n_l, step):",
      *t("pc", "test_numpy_backend_matches_the_reference_on_wide_layers")),
    m("numpy backend: top-down error added instead of subtracted", "backends",
      "            np.subtract(t, E_above, out=t)", "            np.add(t, E_above, out=t)", *PC_GRADIENTS),
    m("numpy backend: inference mask ignored", "backends",
      "        np.multiply(t, self.dtype.type(2.0 * eta), out=t)\n        if mask is not None:\n            np.multiply(t, mask[:, None], out=t)",
      "        np.multiply(t, self.dtype.type(2.0 * eta), out=t)\n        if mask is not None:\n            pass", *PC_TRAINED, *PC_AGREE),
    m("numpy backend: leaky slope ignored", "backends",
      "            np.maximum(G, self.dtype.type(slope), out=G)  # G = phi'(A)",
      "            np.maximum(G, self.dtype.type(0.0), out=G)  # G = phi'(A)", *PC_GRADIENTS, *PC_AGREE),
    m("numpy backend: a stopped sample keeps counting steps", "backends",
      "        done = np.all(R < limits[:, None], axis=0)\n        active &= ~done\n        steps += active",
      "        done = np.all(R < limits[:, None], axis=0)\n        steps += active\n        active &= ~done", *PC_TRAINED),
    m("tensorcores: a write does not wait for the streams that read the buffer", "tensorcores",
      "            for reader in self._readers.get(key, ()):\n                need(reader)",
      "            for reader in ():\n                need(reader)",
      *t("tensorcores", "test_stream_order_waits_for_writers_and_for_readers_of_what_it_writes")),
    m("selection: a tensor-core precision with the numpy backend not refused", "selection",
      '    if backend == "numpy":\n        raise BackendError(', '    if False:\n        raise BackendError(',
      *t("tensorcores", "test_tensor_core_precisions_need_cuda_and_not_numpy")),
    # --- the Warp kernels
    m("kernels: stop test <= instead of <", "solver_kernels",
      "if not (row_energy[e, r] < limits[e]):", "if not (row_energy[e, r] <= limits[e]):", *t("kernels", "test_stop_converged_hand_case")),
    m("kernels: split-K sum drops the last slice", "kernels.update",
      "        for s in range(1, D.shape[0]):", "        for s in range(1, D.shape[0] - 1):", *t("kernels", "test_latent_update_matches_reference")),
    m("kernels: latent step ignores the mask", "kernels.update",
      "            if mask[r] == 0:\n                return", "            if mask[r] == 2:\n                return", *t("kernels", "test_latent_update_mask_leaves_inactive_rows_alone")),
    m("kernels: gather ignores the index", "kernels.copy",
      "    dst[r, c] = src[index[r], c]", "    dst[r, c] = src[r, c]", *t("kernels", "test_gather_and_scatter_rows")),
    m("kernels: weight kernel does not keep W transposed", "kernels.update",
      "            wp.tile_store(Wt, wp.tile_transpose(w), offset=(col, row))", "            pass", *t("kernels", "test_weight_update_keeps_the_transpose")),
    m("kernels: sigmoid padding leaks into the row energies", "kernels.predict",
      '        if wp.static(activation == "sigmoid"):', '        if wp.static(activation == "none"):',
      *t("kernels", "test_predict_matches_reference", "test_small_tiles_many_partial_edges")),
    m("kernels: latent split uses the wrong K range", "kernels.update",
      "        for k in range(s * steps, end):", "        for k in range(s * steps + 1, end):", *t("kernels", "test_latent_update_matches_reference")),
    m("kernels: weight step sign", "kernels.update",
      "        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col)) + d * two_eta",
      "        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col)) - d * two_eta",
      *t("kernels", "test_weight_update_matches_reference")),
    m("kernels: a planned tile launch still runs", "kernels.launch",
      "        _plan.append((kernel, block_dim))\n        return\n    wp.launch_tiled(",
      "        _plan.append((kernel, block_dim))\n    wp.launch_tiled(",
      *t("kernels", "test_planned_kernels_records_instead_of_launching")),
    m("kernels: the row tile rounded below a small batch", "kernels.tiles",
      "    while t < m and t < cap:", "    while t < m - 1 and t < cap:",
      *t("kernels", "test_tile_config_shrinks_rows_for_small_batches")),
    m("reference: tanh derivative", "kernels.reference", "        return one - t * t", "        return one - t",
      *t("kernels", "test_reference_derivative_vs_central_differences")),
    # --- evaluation
    m("evaluate: accept with < instead of <=", "evaluate",
      "    accepted = (best_tme <= delta) &", "    accepted = (best_tme < delta) &", "tests/components/test_evaluate.py"),
    m("evaluate: a query without an answer counted correct", "evaluate",
      "    correct = _correct(best_gtm, best_tme, tau)", "    correct = best_gtm <= tau",
      *t("evaluate", "test_a_query_that_no_reference_can_be_compared_with_has_no_answer")),
    m("simulate: every cycle a sample, whatever the controller records", "sim.simulate",
      "                if records():\n                    break", "                if True:\n                    break",
      *t("stations", "test_sampling_at_stations_records_only_the_cycles_held_whisking_a_station")),
    m("stations: held cycles not the only ones recorded", "sim.controllers.stations",
      'return self.spec.sample_at == "cycle" or self.mode == "hold"', 'return True',
      *t("stations", "test_sampling_at_stations_records_only_the_cycles_held_whisking_a_station")),
    m("evaluate: a decision without an answer counted correct", "evaluate",
      "    return (best_gtm <= tau) & np.isfinite(best_tme)", "    return best_gtm <= tau",
      *t("evaluate", "test_a_query_that_no_reference_can_be_compared_with_has_no_answer")),
    m("evaluate: recall@K counts an unanswered query", "evaluate",
      "(np.take_along_axis(g, order, axis=1) <= tau) & np.isfinite(np.take_along_axis(t, order, axis=1))",
      "(np.take_along_axis(g, order, axis=1) <= tau)",
      *t("evaluate", "test_a_query_that_no_reference_can_be_compared_with_has_no_answer")),
    m("evaluate: precision defined as 0 with nothing accepted", "evaluate",
      "    precision = _safe_div(tp, tp + fp, 1.0)", "    precision = _safe_div(tp, tp + fp, 0.0)", "tests/components/test_evaluate.py"),
    m("evaluate: recall over queries instead of revisits", "evaluate",
      "    recall = _safe_div(tp, np.full_like(tp, n_revisit), 0.0)",
      "    recall = _safe_div(tp, np.full_like(tp, int(tme_a.shape[0])), 0.0)", "tests/components/test_evaluate.py"),
    m("evaluate: revisit tolerance exclusive", "evaluate",
      "    has_revisit = gtm_a.min(axis=1) <= tau", "    has_revisit = gtm_a.min(axis=1) < tau", "tests/components/test_evaluate.py"),
    m("evaluate: ground truth ignores y", "evaluate",
      'gtm = cdist(q[:, :2], r[:, :2], metric="euclidean")', 'gtm = cdist(q[:, :1], r[:, :1], metric="euclidean")',
      "tests/components/test_evaluate.py"),
    m("evaluate: recall at 100 % precision taken at 90 %", "evaluate",
      "full = self.precision >= 1.0", "full = self.precision >= 0.9", "tests/components/test_evaluate.py"),
    m("difficulty: a stay measured step by step, not from its first sample", "difficulty",
      "        away = np.flatnonzero(np.hypot(*(xy[i:] - xy[i]).T) > radius)",
      "        away = np.flatnonzero(np.hypot(*np.diff(xy[i:], axis=0, prepend=xy[i:i + 1]).T) > radius)",
      *t("evaluate", "test_longest_stay_hand_cases")),
    m("difficulty: chance level averaged over every query, not those with a true match", "difficulty",
      '"chance_r1": float(true_match[matched].mean(axis=1).mean()),',
      '"chance_r1": float(true_match.mean(axis=1).mean()),', *t("evaluate", "test_difficulty_hand_case")),
    m("pairfiles: decisions.csv's has_revisit column holds the accepted flags", "pairfiles",
      "                        int(bool(decisions.has_revisit[i])),",
      "                        int(bool(decisions.accepted[i])),", *t("evaluate", "test_export_decisions_csv")),
    m("inputs: runs of two tactile models accepted", "config.inputs",
      "    if other is not None:\n        raise ScenarioError(f\"{path}: tactile_model:", "    if False:\n        raise ScenarioError(f\"{path}: tactile_model:",
      *t("matimport", "test_runs_of_two_tactile_models_are_refused_at_validate_naming_both",
         "test_a_recorded_training_run_and_simulated_evaluations_of_another_model_are_refused")),
    m("inputs: the simulated runs' tactile model left out of the comparison", "config.inputs",
      "        elif e.run is not None:\n            recorded.append(simulated)", "        elif False:\n            recorded.append(simulated)",
      *t("matimport", "test_a_recorded_training_run_and_simulated_evaluations_of_another_model_are_refused")),
    m("matimport: the tactile model given to import not recorded", "matimport",
      '            "robot": {"tactile_model": tactile_model},', '            "robot": {"tactile_model": "physical"},',
      *t("matimport", "test_an_imported_run_records_its_tactile_model")),
    m("simulate: a stuck drive needs 50 samples again", "stages.simulate",
      "STUCK_SHARE, STUCK_SAMPLES = 0.25, 10", "STUCK_SHARE, STUCK_SAMPLES = 0.25, 50",
      *t("teleop", "test_a_stuck_drive_is_a_quarter_of_its_run_and_ten_samples")),
    m("run settings: a hold longer than the run accepted", "sim.controllers.settings",
      "        if lo > self.n_samples:", "        if lo > 100 * self.n_samples:",
      *t("teleop", "test_holds_and_detours_no_longer_than_the_run")),
    m("run settings: more detours than samples accepted", "sim.controllers.settings",
      "        if self.off_route_fraction > 0 and self.detour_count > self.n_samples:", "        if False:",
      *t("teleop", "test_holds_and_detours_no_longer_than_the_run")),
    m("simulate: stuck runs not warned about", "stages.simulate",
      "        if is_stuck(length, len(run.poses)):",
      "        if length > len(run.poses):", *t("matimport", "test_a_run_stuck_in_one_place_reaches_the_user")),
    m("rows: a number outside its field's bounds accepted", "rows",
      "        if not self.low <= value <= self.high:", "        if False:",
      *t("result_row", "test_a_bad_row_is_refused_in_one_line_naming_the_field")),
    m("rows: a fraction of a count accepted", "rows",
      "        if self.whole and value != int(value):", "        if False:",
      *t("result_row", "test_a_bad_row_is_refused_in_one_line_naming_the_field")),
    m("rows: absent fields dumped as null", "rows",
      "        return self.model_dump(exclude_unset=True)", "        return self.model_dump()",
      *t("result_row", "test_every_committed_results_file_parses_and_dumps_to_its_own_bytes")),
    m("scoring: ground truth built reference-to-query", "scoring",
      "        folder, tme, query.poses, reference.poses, settings.tau,",
      "        folder, tme, reference.poses, query.poses, settings.tau,",
      *t("cli", "test_oracle_features_score_perfectly_end_to_end")),
    m("keys: evaluation cache key ignores the settings", "keys",
      '                        scenario.scoring.model_dump(exclude={"complementarity"}))  # pairs methods', '                        )  # pairs methods',
      *t("cli", "test_cache_redoes_exactly_what_a_change_touches")),
    # --- the hand-crafted front end
    m("pfh: upper-edge values beyond the last bin", "handcrafted.pfh",
      "    return np.clip(idx, 0, bins - 1)", "    return np.clip(idx, 0, bins)", "tests/components/test_handcrafted.py"),
    m("pfh: histogram normalised to 1 instead of 100", "handcrafted.pfh",
      PFH_NORMALISE, PFH_NORMALISE.replace("100", "1"), "tests/components/test_handcrafted.py"),
    m("sda: per_axis ignores the threshold", "handcrafted.sda",
      "        positive = d > threshold  # (N, S, W, 2)", "        positive = d > 0  # (N, S, W, 2)", "tests/components/test_handcrafted.py"),
    m("sda: magnitude slope inverted", "handcrafted.sda",
      "        return _slope(delta[..., 1], delta[..., 0]).astype(np.float32)\n    if mode",
      "        return _slope(delta[..., 0], delta[..., 1]).astype(np.float32)\n    if mode", "tests/components/test_handcrafted.py"),
    m("profile: grey is the brightest channel, not the mean of R, G, B", "handcrafted.profile",
      "grey = images[:, : self.rows].astype(np.float32).mean(axis=-1)",
      "grey = images[:, : self.rows].astype(np.float32).max(axis=-1)", "tests/components/test_handcrafted.py"),
    m("handcrafted: no warning for a run without contacts", "handcrafted.extractor",
      "if n and int(run.contact_offsets[-1]) == 0:", "if n and int(run.contact_offsets[-1]) < 0:", "tests/components/test_matimport.py"),
    # --- recorded runs: `vitaplace import`, run files and `dataset:` in scenarios
    m("matimport: v7.3 arrays not transposed back", "matimport",
      "        return data.T.astype(_CLASSES[declared], copy=False) if declared in _CLASSES else data.T",
      "        return data.astype(_CLASSES[declared], copy=False) if declared in _CLASSES else data", "tests/components/test_matimport.py"),
    m("matimport: boards and columns swapped in the whisker index", "matimport",
      "theta_run = np.transpose(theta, (2, 1, 0)).reshape(n, 24)",
      "theta_run = np.transpose(theta, (2, 0, 1)).reshape(n, 24)", "tests/components/test_matimport.py"),
    m("matimport: pose_return.mat not looked for", "matimport",
      "for f in POSE_FILES if (folder / f).is_file()", "for f in POSE_FILES[:1] if (folder / f).is_file()", "tests/components/test_matimport.py"),
    m("matimport: NaN in theta or xy not named by file and variable", "matimport",
      "        raise DatasetError(f\"{path}: variable '{name}' holds no samples; expected {_EXPECTED[kind]}\")\n"
      "    _check_finite(arr, path, name)",
      "        raise DatasetError(f\"{path}: variable '{name}' holds no samples; expected {_EXPECTED[kind]}\")",
      "tests/components/test_matimport.py"),
    m("simulate: recorded runs not checked before the stages", "stages.simulate",
      "    store.open(label, path).validate()\n", "    store.open(label, path)\n",
      *t("matimport", "test_bad_recorded_runs_in_a_scenario_are_one_line[NaN in a run file's times]")),
    m("scenario: recorded evaluation runs not relative to the scenario file", "config.loading",
      '            fix(entry.get("datasets"), ("query", "reference"))', "            pass", "tests/components/test_matimport.py"),
    m("features: unusable-data warning repeated for every method", "features",
      "    if feature in run.warnings:\n        return\n", "", "tests/components/test_matimport.py"),
    m("dataset: NaN in a float field not refused", "dataset",
      'if data.dtype.kind != "f" or data.size == 0:', 'if data.dtype.kind != "i" or data.size == 0:',
      *t("dataset", "test_nan_values_are_reported_with_field_and_sample", "test_nan_in_memory_is_rejected")),
    # --- the simulator
    m("condition: top and bottom occlusion swapped", "sim.condition",
      'rows = slice(0, k) if occlusion.side == "top" else slice(height - k, height)',
      'rows = slice(0, k) if occlusion.side == "bottom" else slice(height - k, height)',
      *t("conditions", "test_occlusion_blanks_the_stated_part_and_nothing_else")),
    m("condition: noise of half the stated std", "sim.condition",
      "out += rng.normal(0.0, camera.noise_std, size=out.shape)", "out += rng.normal(0.0, camera.noise_std / 2, size=out.shape)",
      *t("conditions", "test_noise_has_the_stated_std_and_is_reproducible_from_the_seed")),
    m("condition: blur narrower across the columns", "sim.condition",
      "sigma=(camera.blur_sigma_px, camera.blur_sigma_px, 0)", "sigma=(camera.blur_sigma_px, camera.blur_sigma_px / 2, 0)",
      *t("conditions", "test_blur_is_a_gaussian_of_the_stated_sigma")),
    m("condition: exposure ignored", "sim.condition",
      "    out *= camera.exposure\n", "",
      *t("conditions", "test_exposure_scales_intensities_and_clips_at_255")),
    m("condition: Helland's blue without its offset", "sim.condition",
      "138.5177312231 * math.log(t - 10)", "138.5177312231 * math.log(t)",
      *t("conditions", "test_kelvin_rgb_by_hand")),
    m("condition: the lights' intensity dropped", "sim.condition",
      "return [level * light.intensity * c for c in colour]", "return [level * c for c in colour]",
      *t("conditions", "test_a_light_is_its_level_times_intensity_times_colour",
         "test_the_query_drive_sees_another_frame_at_the_same_pose")),
    m("condition: the suns keep their own direction", "sim.build",
      "dir=direction or light.direction", "dir=light.direction",
      *t("conditions", "test_a_sun_along_another_direction_lights_the_scene_otherwise")),
    m("condition: frames not degraded", "sim.simulate",
      "        image[...] = degrade(image, self.condition.camera, self._noise)\n", "",
      *t("conditions", "test_a_noisy_camera_is_reproducible_per_run_seed")),
    m("condition: left out of the run's key", "sim.controllers.settings",
      "    if not is_default(run.condition):", "    if False:",
      *t("conditions", "test_the_keys_are_unchanged_without_a_condition_and_change_with_one")),
    m("condition: the reference gets the query's condition", "scenario",
      'condition = self.query_condition if role == "query" else self.reference_condition',
      "condition = self.query_condition",
      *t("conditions", "test_the_query_drive_sees_another_frame_at_the_same_pose")),
    # --- the Gymnasium environment
    m("gym: the whisk amplitude ignored", "sim.simulate",
      "self._cmd = [hi + share * (float(c) - hi) for c in", "self._cmd = [float(c) for c in",
      *t("gym", "test_whisk_amplitude_zero_holds_the_whiskers_and_a_wall_bends_them")),
    m("gym: strafe and turn swapped", "sim.gym_env",
      "        self._command = (forward, turn, strafe)", "        self._command = (forward, strafe, turn)",
      *t("gym", "test_strafe_and_turn_move_the_base_as_commanded")),
    m("gym: the command waits for the first control tick", "sim.gym_env",
      "        sim.drive(*self._command)\n", "\n",
      *t("gym", "test_pure_forward_motion_covers_speed_times_time_less_the_servo_lag")),
    m("gym: a body collision does not end the episode", "sim.gym_env",
      "        terminated = sim.body_collisions > collisions", "        terminated = False",
      *t("gym", "test_whisk_amplitude_zero_holds_the_whiskers_and_a_wall_bends_them")),
    m("gym: the reset's seed not used", "sim.gym_env",
      "        super().reset(seed=seed)", "        super().reset(seed=None)",
      *t("gym", "test_the_same_seed_gives_the_same_episode_and_another_seed_another_start")),
    m("sim: stored xy taken at the start of the cycle", "sim.simulate",
      "            xy[k] = series[-1]", "            xy[k] = series[0]",
      *t("sim", "test_stored_xy_is_the_deflection_at_maximum_protraction_and_yaw_is_wrapped")),
    m("sim: route lateral noise std doubled", "sim.controllers.route",
      "        self._lateral = _OU(self.rng, self.spec.lateral_noise, tau)",
      "        self._lateral = _OU(self.rng, 2 * self.spec.lateral_noise, tau)",
      *t("sim", "test_route_noise_processes_have_the_documented_standard_deviations")),
    m("teleop: a driver blocked on its path stands instead of finding a way round", "sim.controllers.teleop",
      "        if (key == \"k\" and d._standing()) or stalled:", "        if stalled:",
      *t("teleop", "test_a_driver_blocked_on_its_path_presses_a_safe_key_instead_of_standing",
         "test_a_drive_started_where_one_froze_moves_on")),
    m("teleop: dithering without headway never counts as blocked", "sim.controllers.teleop",
      "        if (key == \"k\" and d._standing()) or stalled:", "        if key == \"k\" and d._standing():",
      *t("teleop", "test_a_driver_without_headway_for_3_s_looks_further_along_its_path")),
    m("headway: a turn counts from the last tick, not from the anchor", "sim.controllers.safety",
      "or abs(_wrap(pose[2] - self.pose[2])) > self.TURN", "or abs(_wrap(pose[2])) > self.TURN",
      *t("sim", "test_headway_is_a_move_of_0_1_m_or_a_turn_of_0_3_rad_within_3_s")),
    m("foraging: no way out but standing when the state's turn is refused", "sim.controllers.foraging",
      "        ways_out = [(back, w), (back, 0.0), (v, 0.0), (0.0, -w), (-back, 0.0)]",
      "        ways_out = [(back, w), (back, 0.0), (v, 0.0)]",
      *t("sim", "test_a_foraging_robot_whose_turn_is_refused_turns_the_other_way_then_gives_the_state_up")),
    m("foraging: a state without headway never given up", "sim.controllers.foraging",
      "        elif self.headway.stalled(s.pose, s.time):", "        elif False:",
      *t("sim", "test_a_foraging_robot_whose_turn_is_refused_turns_the_other_way_then_gives_the_state_up")),
    m("foraging: a stall in avoid leaves no mark", "sim.controllers.foraging",
      '                self.states["avoid"].failed_at = s.pos.copy()', "                pass",
      *t("foraging", "test_a_stall_in_avoid_marks_the_place_and_the_next_avoid_there_gets_away",
         "test_the_touch_benchmark_training_drive_no_longer_stays_at_the_corner")),
    m("foraging: a retried escape still judges the head alone", "sim.controllers.foraging",
      "        if footprint:  # in the head probe's units", "        if False:  # in the head probe's units",
      *t("foraging", "test_an_avoid_that_starts_where_the_last_got_nowhere_judges_the_whole_footprint")),
    m("foraging: the mark of a failed escape is never used up", "sim.controllers.foraging",
      "        self.failed_at = None\n", "",
      *t("foraging", "test_an_avoid_that_starts_where_the_last_got_nowhere_judges_the_whole_footprint")),
    m("controllers: the package exports the foraging controller as make_controller", "sim.controllers",
      "from vitaplace.engine.sim.controllers.factory import make_controller",
      "from vitaplace.engine.sim.controllers.foraging import ForagingController as make_controller",
      *t("teleop", "test_both_controllers_use_the_one_guard")),
    m("controllers: a route run never leaves its path", "sim.controllers.factory",
      "    off_from = off_from if spec.off_route_fraction > 0 else math.inf",
      "    off_from = math.inf",
      *t("sim", "test_orbit_faces_outward_on_its_circle_and_goes_off_route_when_asked")),
    m("run settings: the key form holds the foraging gains at their defaults", "sim.controllers.settings",
      "items() if v != getattr(default, k)})", "items()})",
      *t("run_settings", "test_the_runs_of_every_shipped_scenario_keep_their_cache_keys_and_run_hashes")),
    m("run settings: old flat gains in a scenario are dropped, not moved under gains", "sim.controllers.settings",
      '    return {**rest, "gains": {**nested, **moved} if isinstance(nested, dict) else nested}',
      '    return {**rest, "gains": nested}',
      *t("run_settings", "test_a_scenario_with_the_old_flat_foraging_gains_loads_with_one_warning")),
    m("run settings: an old run file's fields of other kinds are kept (its settings do not parse)",
      "sim.controllers.settings",
      "        data = {k: v for k, v in data.items() if k in model.model_fields}", "        pass",
      *t("run_settings", "test_the_settings_stored_in_an_old_run_file_load_and_parse")),
    m("teleop: blocked on its path, the driver looks no further along it", "sim.controllers.teleop",
      "        self.s += _SKIP_AHEAD", "        self.s += 0.0",
      *t("teleop", "test_a_driver_blocked_on_its_path_presses_a_safe_key_instead_of_standing",
         "test_a_driver_without_headway_for_3_s_looks_further_along_its_path")),
    m("teleop: leaving a landmark is over at once", "sim.controllers.teleop",
      "LEAVE_TIME = 6.0", "LEAVE_TIME = 0.0",
      *t("teleop", "test_the_teleoperators_modes_switch_by_their_transition_table",
         "test_a_hold_lasts_until_its_contacts_are_recorded_and_nudges_back_onto_the_landmark")),
    m("teleop: a finished hold drives on without backing off the landmark", "sim.controllers.teleop",
      '    ("hold", "done"): "leave",', '    ("hold", "done"): "drive",',
      *t("teleop", "test_a_hold_lasts_until_its_contacts_are_recorded_and_nudges_back_onto_the_landmark")),
    m("sim: OU process variance not stationary", "sim.controllers.common",
      "self.x = a * self.x + self.sigma * math.sqrt(1 - a * a) * float(self.rng.normal())",
      "self.x = a * self.x + self.sigma * float(self.rng.normal())",
      *t("sim", "test_route_noise_processes_have_the_documented_standard_deviations")),
    m("sim: penetration signal without the 0.1 offset", "sim.model",
      "/ (np.asarray(along, dtype=float)[:, None] + 0.1)", "/ (np.asarray(along, dtype=float)[:, None] + 0.2)",
      *t("sim", "test_penetration_deflection_hand_case", "test_penetration_whiskers_pass_through_and_report_the_plugin_formula")),
    m("sim: penetration normal from the whisker's x axis", "sim.model",
      "np.add.at(out, whisker, penetration_deflection(-dist, local_normal[:, 1:], along))",
      "np.add.at(out, whisker, penetration_deflection(-dist, local_normal[:, :2], along))",
      *t("sim", "test_penetration_whiskers_pass_through_and_report_the_plugin_formula")),
    m("worlds: panels on the wrong side of the wall", "sim.build",
      "            face = np.array([cx, cy]) + inward[:2] * t / 2  # centre of the wall's inner face",
      "            face = np.array([cx, cy]) - inward[:2] * t / 2  # centre of the wall's inner face", "tests/components/test_worlds.py"),
    m("worlds: landmark height offset ignored", "sim.build",
      "shape = dict(type=_GEOM.mjGEOM_BOX, pos=(x, y, lm.z + lm.size[2] / 2)",
      "shape = dict(type=_GEOM.mjGEOM_BOX, pos=(x, y, lm.size[2] / 2)", "tests/components/test_worlds.py"),
    m("robot: camera at the base centre's side instead of cam0's", "sim.robot",
      "CAMERA_POS = (0.5166, 0.0573, 0.315)", "CAMERA_POS = (0.5166, 0.0, 0.315)",
      *t("sim", "test_camera_projects_a_known_point_where_the_whiskeye_pinhole_model_says",
         "test_compiled_robot_has_whiskeyes_body_and_whisker_poses")),
    m("routes: footprint clearance forgets the head's own radius", "sim.clearance",
      "dist[len(xy):] - HEAD_RADIUS)", "dist[len(xy):])",
      *t("sim", "test_route_keeps_body_and_head_clear_of_obstacles", "test_shipped_routes_are_what_the_route_generator_makes")),
    m("routes: the generator keeps the first clear point, not the last", "sim.routegen",
      "        out.append(xy[stop - 1])", "        out.append(xy[first])",
      *t("sim", "test_shipped_routes_are_what_the_route_generator_makes")),
    m("worlds: obstacle map ignores the arena depth", "sim.environment",
      "        self.half = np.array([env.arena.half_x, env.arena.half_y])",
      "        self.half = np.array([env.arena.half_x, env.arena.half_x])", *t("sim", "test_obstacle_map_of_a_rectangular_arena")),
    m("routes: partial revisit applied to the reference run", "scenario",
      'if role == "query" and self.query_off_route:', 'if role == "reference" and self.query_off_route:',
      *t("cli", "test_query_off_route_drives_only_the_end_of_the_query_run_off_the_route")),
    m("scenario: a renamed key's old name no longer read", "scenario",
      "    new = RENAMED_KEYS.get(name, name)", "    new = name",
      *t("cli", "test_the_old_scoring_key_is_read_with_a_warning")),
    m("aggregate: a seed folder written before a key's rename is another scenario", "aggregate",
      "{RENAMED_KEYS.get(k, k): v for k, v in resolved.items()", "{k: v for k, v in resolved.items()",
      *t("sweep", "test_a_seed_written_before_the_scoring_rename_aggregates_with_one_after")),
    m("plausibility: a teleop drive in an environment without a route passes validate", "plausibility",
      'if run.kind in ("route", "teleop") and len(env.route) < 2:', 'if run.kind == "route" and len(env.route) < 2:',
      *t("cli", "test_a_run_along_the_route_in_an_environment_without_one_is_refused_at_validate[teleop]")),
    m("plausibility: the body's radius forgotten at the arena's edge", "plausibility",
      "return np.any(np.abs(points) + BODY_RADIUS > half, axis=1)", "return np.any(np.abs(points) > half, axis=1)",
      *t("cli", "test_settings_just_inside_the_arena_are_valid")),
    m("viewer: the start heading taken as radians", "sim.viewer",
      "sim.new_data((x, y, math.radians(yaw_deg)))", "sim.new_data((x, y, yaw_deg))",
      *t("video", "test_the_viewer_shows_the_robot_at_the_environments_start")),
    m("did-you-mean: never a suggestion", "errors",
      "difflib.get_close_matches(str(word), list(choices), n=1)", "difflib.get_close_matches(str(word), list(choices), n=1, cutoff=1.0)",
      *t("api", "test_bad_arguments_are_one_line_user_errors[run-a misspelt keyword]")),
    m("api: arguments not bound before the call (Python's TypeError)", "api",
      "            signature.bind(*args, **kwargs)", "            pass",
      *t("api", "test_bad_arguments_are_one_line_user_errors[read_results-a misspelt keyword]")),
    m("api: a flag that is not True or False accepted", "api",
      "    if not isinstance(value, bool):\n        raise UserError(f\"{name}={value!r:.80}: expected True or False\")",
      "    if False:\n        raise UserError(f\"{name}={value!r:.80}: expected True or False\")",
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-progress as a number]")),
    m("api: one stage name to force read as its letters", "api",
      "    names = [force] if isinstance(force, str) else force", "    names = force",
      *t("api", "test_force_takes_one_stage_name_or_several")),
    m("api: no samples passed to the simulator", "api",
      'kind, n_samples = _choice(kind, "kind", list(RUN_KINDS)), _whole(n_samples, "n_samples", 1)',
      'kind, n_samples = _choice(kind, "kind", list(RUN_KINDS)), _whole(n_samples, "n_samples", 0)',
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-no samples]")),
    m("configfile: an unknown run kind without the nearest one", "configfile",
      "got {_quote(tag)}{did_you_mean(tag, tags)}", "got {_quote(tag)}",
      *t("api", "test_bad_arguments_are_one_line_user_errors[load_scenario-a misspelt run kind]")),
    m("shipped: scenarios listed for a missing environment", "shipped",
      'names = list(environment_files()) if what == "environments" else scenario_names()',
      'names = list(environment_files()) if what != "environments" else scenario_names()',
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-a misspelt world]")),
    m("environment: a missing file read anyway (no list of shipped worlds)", "sim.environment",
      "    if not p.exists():\n        raise EnvironmentSpecError(", "    if False:\n        raise EnvironmentSpecError(",
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-an unknown world]")),
    m("plugins: an unknown extractor without the nearest name", "plugins",
      "; available: {valid}{did_you_mean(name, self.names())}", "; available: {valid}",
      *t("api", "test_bad_arguments_are_one_line_user_errors[fit_extractor-a misspelt plugin]")),
    m("features: plugin parameters checked without the schema's key names", "features",
      "format_validation_error(f\"extractor '{cls.name}'\", exc, cls.Params)", "format_validation_error(f\"extractor '{cls.name}'\", exc, ExtractorParams)",
      *t("api", "test_bad_arguments_are_one_line_user_errors[fit_extractor-a misspelt plugin parameter]")),
    m("viewer: GLFW's reason for refusing the display dropped (its own warning handler left on)", "sim.viewer",
      "glfw.set_error_callback(", "(",
      *t("video", "test_view_on_a_display_with_no_x_server_is_one_line_without_glfws_warnings")),
    m("viewer: the window's thread not waited for before returning", "sim.viewer",
      "            thread.join(timeout=10.0)", "            pass",
      *t("video", "test_view_returns_only_once_the_viewers_window_thread_has_finished[None]")),
    m("viewer: Ctrl-C left to the command's handler (exit 130)", "sim.viewer",
      "    except KeyboardInterrupt:  # Ctrl-C", "    except RuntimeError:  # Ctrl-C",
      *t("video", "test_view_returns_only_once_the_viewers_window_thread_has_finished[3]")),
    m("viewer: the whole field of view taken as the half-angle", "sim.viewer",
      "off_axis / math.tan(math.radians(fovy_deg) / 2)", "off_axis / math.tan(math.radians(fovy_deg))",
      *t("video", "test_the_viewer_opens_looking_at_the_robot_with_every_corner_of_the_arena_on_screen")),
    m("viewer: the opening view looks across the robot's heading", "sim.viewer",
      "azimuth, elevation = math.degrees(yaw), VIEW_ELEVATION_DEG", "azimuth, elevation = math.degrees(yaw) + 90, VIEW_ELEVATION_DEG",
      *t("video", "test_the_viewer_opens_looking_at_the_robot_with_every_corner_of_the_arena_on_screen")),
    m("video: more frames than the cap", "video",
      "step = step or max(1, math.ceil(n_samples / MAX_FRAMES))", "step = step or max(1, n_samples // MAX_FRAMES)",
      *t("video", "test_frame_indices")),
    m("sim: simulate_run looked up in the wrong module", "sim",
      '"simulate_run": "simulate",', '"simulate_run": "environment",',
      *t("sim", "test_the_simulator_package_exports_its_modules_names")),
    m("glsetup: an unloadable GL library chosen", "sim.glsetup",
      "        if _loadable(backend):", "        if not _loadable(backend):",
      *t("sim", "test_without_mujoco_gl_the_first_loadable_library_is_chosen")),
    m("render: the robot's own body shown to its camera", "sim.render",
      "self._option.geomgroup[ROBOT_GROUP] = 1 if show_robot else 0", "self._option.geomgroup[ROBOT_GROUP] = 1",
      *t("sim", "test_the_eye_camera_sees_the_robot_only_when_asked")),
    m("plot: the route drawn open", "sim.plot",
      '        r = np.array([*top_view["route"], top_view["route"][0]])', '        r = np.array(top_view["route"])',
      *t("sim", "test_top_view_plot_closes_the_route")),
    m("stations: a station's point taken towards the landmark with x and y swapped", "sim.controllers.stations",
      "        towards = math.atan2(rel[1], rel[0])", "        towards = math.atan2(rel[0], rel[1])",
      *t("stations", "test_stations_are_the_loop_points_towards_their_landmarks_facing_their_nearest_points")),
    m("stations: station_count ignored", "sim.controllers.stations",
      "    return [names.index(name) for name in chosen[:count]]", "    return [names.index(name) for name in chosen]",
      *t("stations", "test_stations_and_station_count_choose_the_landmarks_in_the_order_given")),
    m("stations: the approach faces the landmark without the visit's heading offset", "sim.controllers.stations",
      "        return _wrap(super()._bearing(pose, i) + self.heading_offset)", "        return super()._bearing(pose, i)",
      *t("stations", "test_the_approach_faces_the_landmark_off_by_the_visits_heading_offset")),
    m("stations: the approach point jittered three times as far as asked", "sim.controllers.stations",
      "        radius = spec.station_jitter * math.sqrt(", "        radius = 3 * spec.station_jitter * math.sqrt(",
      *t("stations", "test_the_station_drivers_modes_switch_by_their_transition_table")),
    m("stations: a station just passed along the loop is skipped", "sim.controllers.stations",
      "            near = ahead <= ROUTE_LOOKAHEAD or ahead >= self.loop.length - _PASSED",
      "            near = ahead <= ROUTE_LOOKAHEAD",
      *t("stations", "test_the_station_drivers_modes_switch_by_their_transition_table")),
    m("factory: a stations run driven by the plain teleoperator", "sim.controllers.factory",
      "        stations = StationDriver(spec, env, rng, sample_period)", "        stations = TeleopDriver(spec, env, rng, sample_period)",
      *t("stations", "test_both_drives_visit_every_station_within_its_jitter_from_different_starts")),
    m("run settings: a landmark named twice as a station passes", "sim.controllers.settings",
      "        if self.station_landmarks is not None and len(set(self.station_landmarks)) != len(self.station_landmarks):",
      "        if False:",
      *t("stations", "test_bad_station_settings_are_refused_naming_the_key[named twice]")),
    m("plausibility: a stations run's landmarks not checked against its environment", "plausibility",
      '    if run.kind == "stations":\n        try:', '    if False:\n        try:',
      *t("stations", "test_validate_says_it_in_one_line_with_exit_status_2")),
    m("inputs: a station's jitter compared with tau itself, not half of it", "config.inputs",
      "    if 2 * run.station_jitter > tau:", "    if run.station_jitter > tau:",
      *t("stations", "test_bad_station_settings_are_refused_naming_the_key[jitter over half tau]")),
    # --- sensor drop-out at query time
    m("dropout: the whiskers' samples drawn over the camera's", "dataset",
      "        masks[sensor], start = mask, start + count", "        masks[sensor], start = mask, start",
      *t("dropout", "test_the_shares_are_as_stated_disjoint_and_drawn_from_the_seed")),
    m("dropout: a run without drop-out lacks everything", "dataset",
      "return self.missing.get(sensor, np.zeros(len(self), dtype=bool))",
      "return self.missing.get(sensor, np.ones(len(self), dtype=bool))",
      *t("dropout", "test_a_run_without_drop_out_lacks_nothing_and_a_subset_keeps_its_masks")),
    m("dropout: H's present terms not scaled to all", "handcrafted.extractor",
      "total * len(terms) / np.maximum(present, 1)", "total",
      *t("dropout", "test_handcrafted_distance_uses_only_the_present_terms_scaled_to_all_three")),
    m("dropout: H ignores the reference's masks", "handcrafted.extractor",
      "_has(reference, SENSOR_OF[key], d.shape[1])", "np.ones(d.shape[1])",
      *t("dropout", "test_handcrafted_distance_uses_only_the_present_terms_scaled_to_all_three")),
    m("dropout: H describes a lost sensor by its data", "handcrafted.extractor",
      "                features[key][run.lacks(SENSOR_OF[key])] = 0\n", "                pass\n",
      *t("dropout", "test_handcrafted_features_of_a_lost_sensor_do_not_depend_on_its_data")),
    m("dropout: MuPNet clamps the lost modality's input", "mupnet.extractor",
      "self.network.infer({m: inputs[m][index] for m in present}",
      "self.network.infer({m: inputs[m][index] for m in self.params.modalities}",
      *t("dropout", "test_mupnet_infers_a_sample_without_a_camera_from_its_whiskers_alone",
         "test_mupnet_features_of_a_lost_camera_do_not_depend_on_its_frames")),
    m("dropout: the query's transforms not keyed by its drop-out", "keys",
      "model.digest, run.key, run.digest, *dropout)", "model.digest, run.key, run.digest)",
      *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    m("dropout: results report drawn counts, not shares", "scoring",
      "float(mask.mean()) if len(mask) else 0.0", "float(mask.sum()) if len(mask) else 0.0",
      *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    m("dropout: a plugin that cannot handle it is let through", "config.methods",
      'if dropouts and not getattr(extractor, "handles_missing", False):', "if False:",
      *t("dropout", "test_a_method_that_cannot_handle_missing_modalities_is_refused")),
    m("dropout: shares summing over 1 accepted", "scenario",
      "        if self.camera + self.whiskers > 1:", "        if self.camera + self.whiskers > 2:",
      *t("dropout", "test_bad_drop_out_is_refused_at_validate_in_one_line")),
    m("dropout: the contract suite never asks an extractor that handles missing modalities", "testing",
      '    if not getattr(cls, "handles_missing", False):\n        return\n', "    return\n",
      *t("contract", "test_each_rule_bites[peeking]")),
    m("dropout: the report swaps the lost sensors", "report",
      "{_pct(shares.camera)} | {_pct(shares.whiskers)}", "{_pct(shares.whiskers)} | {_pct(shares.camera)}",
      *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    # --- configuration, plugins, reports
    m("inputs: query and reference compared by path, not content", "config.inputs",
      "if digest(datasets.query) == digest(datasets.reference):", "if datasets.query == datasets.reference:",
      *t("matimport", "test_recorded_runs_that_cannot_be_compared_are_refused_at_validate[query a copy of the reference]")),
    m("inputs: tau compared with half the arena's diagonal", "config.inputs",
      "diagonal = 2 * math.hypot(", "diagonal = math.hypot(",
      *t("cli", "test_bad_scenario_exits_2_with_one_clear_line[tau over the diagonal]")),
    m("memory: deflection series counted with one component, not two", "config.memory",
      "series = robot.deflection_samples * robot.n_whiskers * 2 * 4", "series = robot.deflection_samples * robot.n_whiskers * 4",
      *t("config", "test_run_bytes_covers_the_arrays_of_the_run_with_the_robots_whiskers[24]",
         "test_run_bytes_covers_the_arrays_of_the_run_with_the_robots_whiskers[6]")),
    m("overrides: += appends to the caller's own lists", "config.overrides",
      "data = copy.deepcopy(data)", "data = dict(data)", *t("cli", "test_set_appends_to_a_list_and_refuses_anything_else")),
    m("configfile: extends merges the base over the file", "configfile",
      "    return deep_merge(base, data)", "    return deep_merge(data, base)", *t("sim", "test_extends_deep_merges_and_replaces_lists")),
    m("schema docs: >= documented as >", "schema_docs", '("ge", ">=")', '("ge", ">")', *t("docs", "test_scenario_reference_is_current")),
    m("hookspecs: hooks declared for another project", "hookspecs",
      "hookspec = pluggy.HookspecMarker(PROJECT)", 'hookspec = pluggy.HookspecMarker("other")', *t("plugins", "test_hookspecs_found")),
    m("plugins: two extractors of one name accepted", "plugins",
      "        if name in self.extractors:\n            raise PluginError(", "        if False:\n            raise PluginError(",
      *t("plugins", "test_duplicate_names_raise_naming_both_sources", "test_duplicate_of_a_builtin_name_is_an_error")),
    m("mupnet: a sample with none of its modalities compared like any", "mupnet.extractor",
      "        d[_uninformed(query), :] = np.inf", "        pass",
      *t("dropout", "test_a_mupnet_sample_with_none_of_its_modalities_is_never_a_match")),
    m("handcrafted: a pair sharing no term at distance 0", "handcrafted.extractor",
      "total * len(terms) / np.maximum(present, 1), np.inf)", "total * len(terms) / np.maximum(present, 1), 0.0)",
      *t("dropout", "test_a_handcrafted_pair_that_shares_no_term_is_never_a_match")),
    m("mupnet: diverged latents not flagged", "mupnet.extractor", "        if diverged.any():", "        if False:",
      *t("mupnet_plugin", "test_diverging_latents_are_flagged_per_sample")),
    m("api: overrides given as a mapping not written as YAML", "api",
      'return [f"{key}={_yaml_value(key, value)}" for key, value in overrides.items()]',
      'return [f"{key}={value}" for key, value in overrides.items()]',
      *t("api", "test_overrides_as_a_mapping_or_as_set_strings_mean_the_same")),
    m("mlflow: metrics not logged", "mlflow_tracking", "        if metrics:\n", "        if not metrics:\n",
      *t("mlflow", "test_a_run_is_logged_once_and_a_rerun_that_recomputed_nothing_adds_no_run")),
    m("mlflow: a rerun that recomputed nothing logged again", "mlflow_tracking",
      "    if earlier is not None:", "    if False:",
      *t("mlflow", "test_a_run_is_logged_once_and_a_rerun_that_recomputed_nothing_adds_no_run")),
    m("mlflow: a rerun of a sweep opens a second parent run", "mlflow_tracking",
      "    parent = _logged(client, experiment_id, key)", "    parent = None",
      *t("mlflow", "test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new")),
    m("mlflow: seeds not nested under their sweep", "mlflow_tracking",
      "        tags[PARENT_TAG] = os.environ[PARENT_ENV]", "        pass",
      *t("mlflow", "test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new")),
    m("mlflow: the sweep's summary files not logged", "mlflow_tracking",
      "            client.log_artifact(parent, str(out / name))", "            pass",
      *t("mlflow", "test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new")),
    m("registry: the variables a sweep-started hook asks for dropped", "plugins",
      "        environment.update({str(k): str(v) for k, v in (asked or {}).items()})", "        pass",
      *t("mlflow", "test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new")),
    m("sweep: the plugins' variables not set for the seeds (SLURM tasks inherit the driver's)", "sweep",
      "    os.environ.update(worker_env)  # inherited", "    dict(worker_env)  # inherited",
      *t("mlflow", "test_on_slurm_the_seeds_log_into_the_sweeps_parent_run")),
    m("sweep: Ray tasks without the plugins' variables", "sweep",
      'extra = {"runtime_env": {"env_vars": dict(env)}} if env else {}', "extra = {}",
      *t("mlflow", "test_on_ray_the_mlflow_settings_reach_the_seeds_through_their_runtime_env")),
    m("sweep: the driver's environment left with the plugins' variables", "sweep",
      "                os.environ.pop(name, None)", "                pass",
      *t("mlflow", "test_a_sweep_is_one_parent_run_with_its_seeds_nested_and_a_rerun_logs_nothing_new")),
    m("figures: TME colours stretched to the outliers", "figures",
      "TME_PERCENTILES = (1.0, 90.0)", "TME_PERCENTILES = (1.0, 100.0)",
      *t("reports", "test_tme_colours_span_its_bulk_not_its_outliers_and_the_colour_bar_says_so")),
    m("report: no warning when exactly half hit the cap", "report",
      "if capped / samples >= CAP_WARNING_SHARE:", "if capped / samples > CAP_WARNING_SHARE:",
      *t("reports", "test_the_report_warns_when_most_test_time_inferences_hit_the_cap")),
    m("sequence: the contrast window one reference short on the right", "sequence",
      "near = sliding_window_view(padded[rows], 2 * window + 1, axis=1)",
      "near = sliding_window_view(padded[rows], 2 * window + 1, axis=1)[..., :-1]",
      *t("sequence", "test_sequence_scores_equal_a_plain_loop", "test_a_sequence_finds_the_match_a_single_sample_misses")),
    m("sequence: entries not divided by the window's spread", "sequence",
      "        spread = np.where(spread > FLAT * np.abs(mean), spread, 1.0)", "        spread = np.ones_like(spread)",
      *t("sequence", "test_a_sequence_finds_the_match_a_single_sample_misses")),
    m("sequence: the line runs forward from the query (queries after it)", "sequence",
      "    offsets = np.arange(-(length - 1), 1)", "    offsets = np.arange(0, length)",
      *t("sequence", "test_a_sequence_finds_the_match_a_single_sample_misses", "test_sequence_scores_equal_a_plain_loop")),
    m("sequence: the worst velocity kept instead of the best", "sequence",
      "        best = np.minimum(best, score)", "        best = score if not np.isfinite(best).any() else np.maximum(best, score)",
      *t("sequence", "test_sequence_scores_equal_a_plain_loop")),
    m("sequence: a +inf term makes the whole line +inf", "sequence",
      "            finite = np.isfinite(term)\n", "            finite = np.isfinite(term) | True\n",
      *t("sequence", "test_a_query_the_method_cannot_compare_is_scored_by_the_sequence_that_ends_at_it")),
    m("sequence: length 1 contrast-normalised like a sequence", "sequence",
      "    if length == 1:\n        return d\n", "",
      *t("sequence", "test_length_one_is_the_distance_matrix_itself")),
    m("scoring: length 1 scored through the sequence path", "scoring",
      "    if sequence.length == 1:\n        return None\n", "",
      *t("sequence", "test_length_one_scores_a_real_evaluation_exactly_as_single_samples")),
    m("keys: the evaluation cache key ignores the sequence settings", "keys",
      'scenario.scoring.model_dump(exclude={"complementarity"}))  # pairs', 'scenario.scoring.model_dump(exclude={"complementarity", "sequence"}))  # pairs',
      *t("sequence", "test_a_changed_sequence_length_rescores_the_evaluations_and_nothing_before_them")),
    m("pairfiles: the sequence setting ignored", "pairfiles",
      "        tme, extra = sequence_scores(distance, **sequence), {\"distance\": distance}", "        extra = {\"distance\": distance}",
      *t("sequence", "test_a_run_that_matches_sequences_scores_the_sequence_of_the_methods_distances")),
    m("pairfiles: the window span counts references, not metres of path", "pairfiles",
      "    return float(np.median(travelled[np.minimum(j + window, len(xy) - 1)] - travelled[np.maximum(j - window, 0)]))",
      "    return float(np.median(np.minimum(j + window, len(xy) - 1) - np.maximum(j - window, 0)))",
      *t("sequence", "test_the_window_span_is_the_reference_path_length_the_window_covers")),
    m("report: the one-place warning only below 2 tau, not at it", "report",
      "    if span <= 2 * tau:", "    if span < 2 * tau:",
      *t("sequence", "test_the_report_warns_when_the_contrast_window_is_no_more_than_one_place")),
    m("sensitivity: --sequence-length rescores the saved TME, not the method's distances", "sensitivity",
      "raw = \"distance\" if sequence_length is not None and \"distance\" in names else \"tme\"", "raw = \"tme\"",
      *t("sequence", "test_sensitivity_rescores_a_run_as_the_sequence_run_scored_it")),
    m("scenario: a sequence longer than the runs passes validate", "scenario",
      "            if e.run is not None and length > e.run.n_samples:", "            if False:",
      *t("sequence", "test_bad_sequence_settings_are_one_line_at_validate")),
    m("fusion: a missing term not made up by the other's", "fusion",
      "    return np.where(both, total, scaled)", "    return np.where(present > 0, total, np.inf)",
      *t("fusion", "test_the_fused_distance_by_hand")),
    m("fusion: the touch term unweighted", "fusion",
      "(np.asarray(touch, dtype=float) / sigma_touch, weight)]", "(np.asarray(touch, dtype=float) / sigma_touch, 1.0)]",
      *t("fusion", "test_the_fused_distance_by_hand")),
    m("fusion: ties go to the largest weight", "fusion",
      "    return min(w for w, s in scores.items() if s == best)", "    return max(w for w, s in scores.items() if s == best)",
      *t("fusion", "test_the_weight_with_the_best_score_is_chosen_ties_to_the_smallest")),
    m("fusion: the spread of every entry, +inf included", "fusion",
      "    finite = finite[np.isfinite(finite)]", "    finite = finite.ravel()",
      *t("fusion", "test_a_spread_is_the_standard_deviation_of_the_finite_distances_or_one")),
    m("fuse: each evaluation chooses its own weight", "stages.fuse",
      "            choice = chosen_weight(store, scenario, simulated, fusion, name, query)\n            for e in scenario.evaluations:\n",
      "            for e in scenario.evaluations:\n                choice = chosen_weight(store, scenario, simulated, fusion.model_copy(update={'select_on': e.name}), name, query)\n",
      *t("fusion", "test_the_weight_is_chosen_on_the_training_world_and_applied_unchanged")),
    m("fuse: the weight chosen on the last evaluation", "stages.fuse",
      "    settings, env = scenario.scoring, selection(scenario, fusion)",
      "    settings, env = scenario.scoring, scenario.evaluations[-1].name",
      *t("fusion", "test_the_weight_is_chosen_on_the_selection_evaluation_alone")),
    m("fuse: select_on ignored (always the training world's evaluation)", "stages.fuse",
      "    chosen = fusion.select_on or training_world_evaluation(scenario)[0]",
      "    chosen = training_world_evaluation(scenario)[0]",
      *t("fusion", "test_the_weight_is_chosen_on_the_selection_evaluation_alone")),
    m("scenario: a fusion may name a method the scenario lacks", "scenario",
      "                if getattr(f, role) not in methods:", "                if False:",
      *t("fusion", "test_bad_fusions_are_one_line_at_validate")),
    m("sensitivity: recall at 100 % precision reported as max F1", "sensitivity",
      '"recall_at_100_precision": curve.recall_at_full_precision})', '"recall_at_100_precision": curve.max_f1})',
      *t("sensitivity", "test_rescore_matches_hand_computed_curves")),
    m("testing: the subset check compares the rows in the wrong order", "testing",
      "    problems = _differences({key: np.asarray(value)[index] for key, value in whole.items()}, part)",
      "    problems = _differences({key: np.asarray(value)[index[::-1]] for key, value in whole.items()}, part)",
      *t("contract", "test_shipped_extractors_keep_the_contract[handcrafted-check_transform_subset]")),
    m("provenance: a changed checkout reported clean", "provenance",
      "    return bool(result.stdout.strip())", "    return False",
      *t("reports", "test_git_dirty_tells_a_changed_checkout_from_a_clean_one")),
    # --- seals, completion records, output folders, CPUs
    m("simulate: recorded runs listed with simulation seeds", "stages.simulate",
      "    return path, key, digest, None\n", "    return path, key, digest, 0\n",
      *t("matimport", "test_a_scenario_runs_end_to_end_on_imported_runs")),
    m("manifest: how training ended left out", "manifest",
      '"training": run.fit.training if run.fit is not None else {},', '"training": {},',
      *t("cli", "test_the_manifest_says_how_training_ended_for_the_methods_that_train")),
    m("run settings: an old run key read under its old name", "sim.controllers.settings",
      "    return {RENAMED_RUN_KEYS.get(k, k): v for k, v in run.items()}, found",
      "    return dict(run), found",
      *t("run_settings", "test_the_teleoperators_old_heading_tolerance_is_read_as_its_turn_threshold")),
    m("outdir: a claimed folder keeps what interrupted writes left", "outdir",
      "        for path in remove_stale_temporaries(out):\n            logging", "        for path in []:\n            logging",
      *t("seals", "test_claiming_a_folder_locks_it_logs_the_command_in_then_cleans")),
    m("compare: an evaluation without revisits not warned about", "stages.compare",
      "        if n >= MIN_REVISITS:", "        if n >= 0:",
      *t("matimport", "test_an_evaluation_with_too_few_revisits_reaches_the_user")),
    m("records: the completion record leaves out the report and what it is built from", "records",
      "        if self.report is not None:\n            files += self.report.files",
      "        if self.report is None:\n            files += self.report.files",
      *t("cli", "test_report_of_a_damaged_output_folder_is_one_line_naming_the_file")),
    m("orchestrate: until fit stops before fitting", "orchestrate",
      'if stop >= STAGES.index("fit"):', 'if stop > STAGES.index("fit"):',
      *t("cli", "test_until_runs_the_stages_up_to_and_including_the_one_named")),
    m("store: the warnings of a cached stage not restored", "store",
      "            self._restore_warnings(output)\n", "            pass\n",
      *t("store", "test_the_warnings_a_stage_raised_come_back_when_it_is_cached")),
    m("store: a stage keeps the warnings raised before it too", "store",
      "new = dict(list(warnings.items())[counts.get(label, 0):])", "new = dict(warnings)",
      *t("store", "test_the_warnings_a_stage_raised_come_back_when_it_is_cached")),
    m("store: force ignored", "store",
      "        if done and stage not in self.force:", "        if done:",
      *t("store", "test_a_stage_runs_once_then_is_cached_and_forced_runs_again")),
    m("plan: the methods' seed ignores the scenario seed", "plan",
      'params["seed"] = seed_for(scenario.seed, 1000 + index)', 'params["seed"] = seed_for(0, 1000 + index)',
      *t("plugins", "test_the_scenario_seed_reaches_the_methods_seed")),
    m("plan: the query drop-out drawn for the reference run", "plan",
      'label == f"{e.name}/query":', 'label == f"{e.name}/reference":',
      *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    m("fit: how training ended left out of the record", "stages.fit",
      '        if record["summary"]:\n', '        if not record["summary"]:\n',
      *t("cli", "test_the_manifest_says_how_training_ended_for_the_methods_that_train")),
    m("evaluate: rows give the reference run's drop-out", "stages.evaluate",
      'rows.append(result_row(e, method.name, direction, folder, simulated.runs[f"{e.name}/query"]))',
      'rows.append(result_row(e, method.name, direction, folder, simulated.runs[f"{e.name}/reference"]))',
      *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    m("output checks: features with too few rows accepted", "output_checks",
      "if not shape or shape[0] != samples:", "if not shape:", *t("cli", "test_extractor_outputs_are_checked_with_one_line")),
    m("output checks: a distance of -inf accepted", "output_checks",
      "np.where(np.isposinf(tme), 0.0, tme)", "np.where(np.isinf(tme), 0.0, tme)",
      *t("cli", "test_extractor_outputs_are_checked_with_one_line")),
    m("output checks: a distance of +inf (a pair that cannot be compared) refused", "output_checks",
      "np.where(np.isposinf(tme), 0.0, tme)", "tme", *t("dropout_run", "test_a_query_drop_out_is_drawn_recorded_used_and_keyed")),
    m("processes: the resource tracker's leak report not silenced", "processes",
      "        sys.warnoptions.append(TRACKER_REPORT)", "        pass",
      *t("cli", "test_semaphores_left_by_an_abrupt_exit_are_cleaned_up_without_a_report")),
    m("processes: a worker whose parent died while it started goes on", "processes",
      "if process_identity(parent_pid) != parent:", "if False:",
      *t("cli", "test_a_worker_whose_parent_is_not_the_one_named_exits_at_once")),
    m("results: csv rows without a fixed delta left empty", "results",
      "    if row.f1 is not None:", "    if row.f1 is None:",
      *t("cli", "test_results_csv_has_precision_recall_f1_at_max_f1_without_fixed_delta")),
    m("simulation: a long run's progress logged once per estimate, not each tenth", "simulation",
      "timeout=job.estimate / 10", "timeout=job.estimate", *t("cli", "test_a_long_simulation_in_a_worker_logs_its_progress")),
    m("checksum: a folder's digest ignores its file names", "checksum",
      '            h.update(str(file.relative_to(path)).encode() + b"\\0")', "            pass",
      *t("seals", "test_digest_of_a_folder_is_that_of_its_names_and_contents_in_order")),
    m("checksum: a damaged output passes its seal", "checksum",
      'if record.get("sha256") != digest(path):', 'if record.get("sha256") == "":',
      *t("seals", "test_check_says_why_an_output_cannot_be_used")),
    m("completion: a changed file passes the record", "completion",
      "        if _digest(folder / name) != files[name]:", "        if False:",
      *t("seals", "test_a_completion_record_notices_a_changed_file_and_scenario")),
    m("outdir: interrupted writes left behind", "outdir",
      'if path.is_file() and path.name.endswith(".part"):', 'if path.is_file() and path.name.endswith(".tmp"):',
      *t("seals", "test_stale_temporaries_are_removed_and_the_lock_is_kept")),
    m("cpus: the largest CPU count taken", "cpus",
      "    return max(1, min(counts))", "    return max(1, max(counts))",
      *t("cpus", "test_usable_cpus_is_the_smallest_of_affinity_slurm_and_override")),
    m("slurm: --time rounded down to whole minutes", "slurm",
      "    return -(-seconds // 60)", "    return seconds // 60", *t("sweep", "test_slurm_time_limits_by_hand")),
    m("slurm: sbatch's refusal escapes as a traceback", "slurm",
      "    except (submitit.core.utils.FailedJobError, submitit.core.utils.FailedSubmissionError, OSError) as exc:",
      "    except (submitit.core.utils.FailedSubmissionError, OSError) as exc:",
      *t("clusters", "test_sbatch_refusing_the_array_is_one_line_with_its_own_message_and_exit_2[partition]")),
    m("slurm: a refused submission's script and pickles left behind", "slurm",
      "        _remove_new(folder, before)\n", "",
      *t("clusters", "test_sbatch_refusing_the_array_is_one_line_with_its_own_message_and_exit_2[gres]")),
    m("slurm: --max-parallel ignored under --slurm local", "slurm",
      '    if args.max_parallel is not None and args.slurm == "local":', "    if False:",
      *t("clusters", "test_a_short_time_limit_and_a_bad_throttle_are_refused_before_anything_runs")),
    m("cli: a sweep into OUT does not look for the earlier array's queued tasks", "cli.commands",
      '        check_queue_clear(out / "slurm")  # before', '        str(out / "slurm")  # before',
      *t("clusters", "test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued")),
    m("slurm: a --time under the minimum accepted", "slurm",
      "    if minutes < MIN_TIME_MIN:", "    if minutes < 1:",
      *t("clusters", "test_a_short_time_limit_and_a_bad_throttle_are_refused_before_anything_runs")),
    m("slurm: --max-parallel not passed to the array", "slurm",
      'throttle = {"slurm_array_parallelism": settings.max_parallel} if settings.max_parallel else {}',
      "throttle = {}",
      *t("clusters", "test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued")),
    m("slurm: tasks not checked against the driver's installation", "slurm",
      "tasks = ex.map_array(CheckedTask(task, installation()), jobs)", "tasks = ex.map_array(task, jobs)",
      *t("clusters", "test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued")),
    m("slurm: a node with other code runs its seed", "slurm",
      "        if differs:\n            return {", "        if False:\n            return {",
      *t("clusters", "test_a_task_on_a_node_with_other_code_fails_its_seed_in_one_line")),
    m("slurm: a task gone from the queue waited for forever", "slurm",
      "                if now - self.gone.setdefault(task, now) >= LOST_MARGIN_S:",
      "                if False:",
      *t("clusters", "test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued")),
    m("slurm: a task running past its limit waited for forever", "slurm",
      'if state == "RUNNING" and now - self.running.setdefault(task, now) >= self.limit_s + LOST_MARGIN_S:',
      'if state == "RUNNING" and now - self.running.setdefault(task, now) >= 2 * self.limit_s + LOST_MARGIN_S:',
      *t("clusters", "test_a_task_running_past_its_limit_is_lost_and_an_interrupt_waits_for_the_queue")),
    m("slurm: a rerun ignores the earlier array's queued tasks", "slurm",
      "    if listed:\n        states =", "    if False:\n        states =",
      *t("clusters", "test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued")),
    m("slurm: an interrupt does not wait for the queue", "slurm",
      "        while listed and self.clock() < deadline:", "        while False:",
      *t("clusters", "test_a_task_running_past_its_limit_is_lost_and_an_interrupt_waits_for_the_queue")),
    m("ray auth: the GCS client's refusal on stderr not read", "ray_auth",
      " or any(sign in text for sign in AUTH_SIGNS):", ":",
      *t("clusters", "test_a_ray_cluster_that_requires_a_token_is_named_in_one_line")),
    m("ray auth: Ray's AuthenticationError not recognised", "ray_auth",
      "isinstance(failure, auth_error) or ", "", *t("clusters", "test_a_ray_cluster_that_requires_a_token_is_named_in_one_line")),
    m("installation: uncommitted changes not compared", "installation",
      "{key: theirs.get(key) for key in driver}", '{key: theirs.get(key) for key in driver if key != "dirty"}',
      *t("clusters", "test_installations_differ_by_version_commit_uncommitted_changes_or_plugins")),
    # --- sweeps and their summary
    m("resample: block length rounded down", "resample",
      "max(1, math.ceil(math.sqrt(n_queries)))", "max(1, math.floor(math.sqrt(n_queries)))",
      *t("summary", "test_block_length_and_draws")),
    m("summary: the bootstrap interval not kept within the values' range", "summary",
      "_clip(*boot.confidence_interval, inside)", "_clip(*boot.confidence_interval, limits)",
      *t("summary", "test_no_interval_of_a_proportion_leaves_0_1")),
    m("summary: standard deviation with ddof=0", "summary",
      '"std": float(x.std(ddof=1)) if n >= 2', '"std": float(x.std(ddof=0)) if n >= 2',
      *t("summary", "test_describe_matches_hand_computed_statistics")),
    m("summary: normal quantile instead of Student's t", "summary",
      'float(stats.t.ppf(0.5 + level / 2, s["n"] - 1))', "float(stats.norm.ppf(0.5 + level / 2))",
      *t("summary", "test_describe_matches_hand_computed_statistics")),
    m("summary: t with n degrees of freedom", "summary",
      'stats.t.ppf(0.5 + level / 2, s["n"] - 1)', 'stats.t.ppf(0.5 + level / 2, s["n"])',
      *t("summary", "test_describe_matches_hand_computed_statistics")),
    m("summary: interval from the std instead of the standard error", "summary",
      '* s["std"] / math.sqrt(s["n"])', '* s["std"]', *t("summary", "test_describe_matches_hand_computed_statistics")),
    m("summary: an interval made up for one seed", "summary", '    if n >= 2:\n        out["t_low"]',
      '    if n >= 1:\n        out["t_low"]',
      *t("summary", "test_one_seed_has_no_interval_over_seeds_and_says_so")),
    m("summary: differences b - a", "summary",
      "diffs = [va[s] - vb[s] for s in seeds]", "diffs = [vb[s] - va[s] for s in seeds]",
      *t("summary", "test_paired_differences_are_per_seed", "test_sign_flip_p_values_by_hand")),
    m("summary: differences over seeds only one method has", "summary",
      "seeds = [s for s in va if s in vb]", "seeds = list(va)", *t("summary", "test_paired_differences_are_per_seed")),
    m("summary: settings summarised as metrics", "summary",
      "        if key in IDENTITY or key in SETTINGS:", "        if key in IDENTITY:",
      *t("summary", "test_every_numeric_value_is_summarised_and_settings_are_not")),
    m("sweep: jobs lost with a broken pool are not run again", "sweep",
      "                rounds.append(([job], 1))", "                pass", *t("sweep", "test_a_seed_whose_worker_process_dies_fails_alone")),
    m("sweep: a failed local seed stops the sweep", "sweep",
      "                    yield job, None, describe_failure(exc)\n    except BaseException:",
      "                    raise\n    except BaseException:", *t("sweep", "test_local_sweep_keeps_going_past_a_failed_seed")),
    m("sweep: a failed Ray seed stops the sweep", "sweep",
      "                    yield job, None, describe_failure(exc)\n    finally:",
      "                    raise\n    finally:", *t("sweep", "test_ray_sweep_keeps_going_past_a_failed_seed")),
    m("sweep: colour codes kept in the failure line", "sweep",
      'text = " ".join(ANSI.sub("", text).split())', 'text = " ".join(text.split())',
      *t("sweep", "test_failures_of_ray_tasks_read_as_one_line", "test_local_sweep_keeps_going_past_a_failed_seed")),
    m("sweep: Ray's wrapped exception not unwrapped", "sweep",
      "    if isinstance(cause, BaseException):\n        exc = cause", "    if False:\n        exc = cause",
      *t("sweep", "test_failures_of_ray_tasks_read_as_one_line")),
    m("sweep: jobs read environments from the driver's paths", "sweep",
      '            entry["environment"] = str(files[entry["environment"]])', "            pass",
      *t("sweep", "test_a_job_reads_nothing_from_the_driver_s_files")),
    m("sweep: unshared storage never noticed", "sweep",
      "socket.gethostname(), not job.marker or Path(job.marker).exists()", "socket.gethostname(), True",
      *t("sweep", "test_a_job_reads_nothing_from_the_driver_s_files")),
    m("sweep: unshared storage warned for every job", "sweep",
      'if not result["sees_out"] and not outcome.unshared:', 'if not result["sees_out"]:',
      *t("sweep", "test_the_driver_warns_once_about_unshared_storage_and_reports_failures")),
    m("sweep: --force not passed to the jobs", "sweep",
      "SeedJob(data, environments, seed, str(out), tuple(force), progress, marker, point)",
      "SeedJob(data, environments, seed, str(out), (), progress, marker, point)",
      *t("sweep", "test_a_job_reads_nothing_from_the_driver_s_files", "test_local_sweep_keeps_going_past_a_failed_seed")),
    m("grid: the product loses its last axis", "grid",
      "itertools.product(*(range(len(axis.values)) for axis in axes))",
      "itertools.product(*(range(len(axis.values)) for axis in axes[:-1]))",
      *t("grid", "test_a_grid_is_the_product_of_its_axes_named_by_path_ends")),
    m("grid: a path --set also sets accepted", "grid", "        if path in fixed:", "        if False:",
      *t("grid", "test_a_bad_grid_is_one_line_naming_the_option")),
    m("grid: a value given twice accepted", "grid", "    if twice:", "    if False:",
      *t("grid", "test_a_bad_grid_is_one_line_naming_the_option")),
    m("grid: axes sharing a path end share a label", "grid",
      "name if last.count(name) == 1 else axis.path", "name",
      *t("grid", "test_a_grid_is_the_product_of_its_axes_named_by_path_ends")),
    m("grid: unsafe characters kept in folder names", "grid", "{UNSAFE.sub('_', text)}", "{text}",
      *t("grid", "test_a_grid_is_the_product_of_its_axes_named_by_path_ends")),
    m("grid: a summary's seeds the sweep lacks not refused", "grid",
      "if set(old_points) - set(names) or set(old_seeds) - set(seeds):", "if set(old_points) - set(names):",
      *t("grid", "test_a_sweep_that_would_drop_seeds_or_points_of_the_summary_is_refused_in_one_line")),
    m("grid: a plain summary left beside a grid that replaces it", "grid",
      "*(out / n for n in SUMMARY_FILES), *out.glob(\"pr-bands-*\")]", "*out.glob(\"pr-bands-*\")]",
      *t("grid", "test_more_seeds_extend_a_summary_and_replace_swaps_it_for_another")),
    m("grid: a point the scenario refuses not named", "grid",
      '            raise ScenarioError(f"--grid point {point.name}: {exc}") from None', "            raise",
      *t("grid", "test_a_grid_point_the_scenario_refuses_is_one_line_before_anything_is_written")),
    m("sweep: every grid point runs the first point's scenario", "sweep",
      "seed_jobs(point.scenario, dict(point.resolved), seeds,", "seed_jobs(points[0].scenario, dict(points[0].resolved), seeds,",
      *t("grid", "test_every_point_and_seed_runs_what_config_resolves_for_its_assignments")),
    m("sweep: grid points share one seed folder", "sweep",
      "return seed_dir(Path(self.out) / self.point, self.seed)", "return seed_dir(Path(self.out), self.seed)",
      *t("grid", "test_every_point_and_seed_runs_what_config_resolves_for_its_assignments")),
    m("sweep: Ray tasks of a grid not named by their point", "sweep",
      'name=f"{name} {job.label}"', 'name=f"{name} seed {job.seed}"',
      *t("grid", "test_a_grid_on_ray_runs_every_point_and_reports_a_failed_seed_by_its_point")),
    m("cli: config ignores --set", "cli.commands",
      "    _, resolved = load_scenario(args.scenario, args.overrides)", "    _, resolved = load_scenario(args.scenario)",
      *t("grid", "test_config_prints_the_scenario_the_api_resolves")),
    m("cli: --replace not passed to the sweep", "cli.commands", "slurm, grid, args.replace,", "slurm, grid, False,",
      *t("grid", "test_more_seeds_extend_a_summary_and_replace_swaps_it_for_another")),
    m("cli: a command left without its handler", "cli", "    p.set_defaults(handler=plugins_command)\n", "",
      *t("cli", "test_every_command_names_its_own_handler")),
    m("cli: a user error exits 1", "cli", "EXIT_USER_ERROR = 2", "EXIT_USER_ERROR = 1",
      *t("cli", "test_bad_worker_counts_are_one_line[0]")),
    m("sweep: GPU jobs keep the CPU backend", "sweep", "    if gpus_per_job > 0:", "    if gpus_per_job > 1:",
      *t("sweep", "test_gpu_jobs_select_the_gpu_backend_where_a_method_has_one")),
    m("sweep: failed seeds exit 0", "cli.commands", "        return EXIT_SEEDS_FAILED", "        return 0",
      *t("sweep", "test_local_sweep_keeps_going_past_a_failed_seed")),
    m("aggregate: other scenarios accepted", "aggregate",
      "if run.scenario != runs[0].scenario or run.identity != runs[0].identity:", "if run.scenario != runs[0].scenario:",
      *t("sweep", "test_aggregate_refuses_other_scenarios_and_unfinished_runs")),
    m("aggregate: the seed counted in the scenario's identity", "aggregate",
      'resolved.items() if k != "seed"', 'resolved.items() if k != "name"',
      *t("sweep", "test_aggregate_reproduces_the_sweep_summary")),
    m("aggregate: unfinished runs not recognised", "aggregate",
      "REQUIRED = (completion.RECORD, MANIFEST, RESULTS_JSON, completion.SCENARIO)", "REQUIRED = (completion.SCENARIO,)",
      *t("sweep", "test_aggregate_refuses_other_scenarios_and_unfinished_runs")),
    m("aggregate: a seed given twice accepted", "aggregate", "        if run.seed in seen:", "        if False:",
      *t("sweep", "test_aggregate_refuses_other_scenarios_and_unfinished_runs")),
    m("aggregate: an --out that cannot be written found only while writing", "aggregate",
      "    out = writable_dir(Path(out))\n", "    out = Path(out)\n",
      *t("sweep", "test_aggregate_out_that_cannot_be_written_is_one_line")),
    m("api: read_results reads results.json without checking the folder", "api",
      "return [row.dump() for row in validate_run_folder(folder).rows]",
      'return json.loads((folder / "results.json").read_text())',
      *t("api", "test_read_results_refuses_a_folder_whose_rerun_was_killed")),
    m("api: numpy values in overrides not converted", "api",
      '    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):', "    if False:",
      *t("api", "test_numpy_values_and_paths_in_overrides_are_their_plain_values")),
    m("api: a negative simulate seed accepted", "api",
      'environment, seed = _path(environment, "environment"), _whole(seed, "seed", 0)',
      'environment = _path(environment, "environment")',
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-a negative seed]")),
    m("api: simulate's pydantic errors raw", "api",
      "    except pydantic.ValidationError as exc:", "    except ImportError as exc:",
      *t("api", "test_bad_arguments_are_one_line_user_errors[simulate-an unknown run setting]")),
    m("api: fit_extractor given a non-Run", "api", "    if not isinstance(train, Run):", "    if False:",
      *t("api", "test_bad_arguments_are_one_line_user_errors[fit_extractor-fit on a path]")),
    m("video: no upper bound on fps (inf: a GIF without frame durations)", "video",
      "and low <= fps <= high", "and low <= fps",
      *t("video", "test_video_refuses_bad_settings_in_one_line_before_drawing[fps inf]")),
    m("video: a run without samples drawn", "video", "    if len(run) == 0:", "    if False:",
      *t("video", "test_a_run_without_samples_is_one_line")),
    m("video: the output's folder not checked before drawing", "video", "    writable_dir(path.parent)\n", "",
      *t("video", "test_video_refuses_bad_settings_in_one_line_before_drawing[out under a file]")),
    m("video: an output path that is a folder not named", "video", "    if path.is_dir():", "    if False:",
      *t("video", "test_video_refuses_bad_settings_in_one_line_before_drawing[out a folder]")),
    m("matimport: an array of no samples reaches the finiteness check", "matimport",
      '    holds NaN or inf."""\n    if arr.shape[-1] == 0:', '    holds NaN or inf."""\n    if False:',
      *t("matimport", "test_an_empty_pose_array_is_one_line")),
    m("sensitivity: the set of seed folders not checked (a seed twice, another scenario)", "sensitivity",
      "    one_scenario(runs)\n", "",
      *t("sensitivity", "test_a_sweep_folder_holds_one_scenario_each_seed_once")),
    m("sensitivity: matrices.npz not checked against completed.json", "sensitivity",
      "            check_recorded(run, [name])\n", "",
      *t("sensitivity", "test_matrices_changed_since_the_run_are_refused")),
    m("sensitivity: a failed seed folder not recognised", "sensitivity",
      "        if (path / SEED_ERROR).is_file():", "        if False:",
      *t("sensitivity", "test_a_failed_seed_is_left_out_with_one_line")),
    m("sensitivity: a failed seed left out with exit 0", "cli.commands",
      'return EXIT_SEEDS_FAILED if record["failed"] else 0', "return 0",
      *t("sensitivity", "test_a_failed_seed_is_left_out_with_one_line")),
    m("sensitivity: a TME that does not fit its poses accepted", "sensitivity",
      "if tme.shape != (len(query), len(reference)) or not", "if not",
      *t("sensitivity", "test_damaged_matrices_recorded_so_are_one_line[a 3 x 3 TME]")),
    m("sensitivity: NaN poses accepted", "sensitivity",
      "poses.shape[1] != 3 or not np.isfinite(poses).all():", "poses.shape[1] != 3:",
      *t("sensitivity", "test_damaged_matrices_recorded_so_are_one_line[NaN poses]")),
    m("sensitivity: --out checked only while writing", "sensitivity",
      "    out = writable_dir(Path(folder) if out is None else Path(out))", "    out = Path(folder) if out is None else Path(out)",
      *t("sensitivity", "test_an_out_that_cannot_be_written_is_one_line_before_reading")),
    m("tactile input: phase points one sample early", "mupnet.inputs",
      "np.arange(1, points + 1) * samples / points - 1", "np.arange(points) * samples / points - 1",
      *t("tactile_input", "test_phase_points_interpolate_the_series_by_phase")),
    m("tactile input: contact flags read at the instant only", "mupnet.inputs",
      "(np.linalg.norm(deflection, axis=3) > TOUCH_THRESHOLD).any(axis=1)",
      "(np.linalg.norm(deflection[:, -1:], axis=3) > TOUCH_THRESHOLD).any(axis=1)",
      *t("tactile_input", "test_the_cycle_features_of_a_hand_built_run")),
    m("tactile input: contact flags scaled by the measured channels' floor", "mupnet.inputs",
      "= 1.0  # the contact flags", "= params.tactile_min_range  # the contact flags",
      *t("tactile_input", "test_the_scaling_spans_are_the_training_range_floored_and_flags_their_own")),
    m("tactile input: values outside the training range not reported", "mupnet.inputs",
      "    if not outside.any():\n        return", "    if True:\n        return",
      *t("tactile_input", "test_test_values_outside_the_training_range_are_counted_and_reported_not_clipped")),
    m("mupnet: the test run's tactile range not checked", "mupnet.extractor",
      '            report_out_of_range(run, raw["tactile"], self.tactile_range, self.params, self.name)\n',
      "            pass\n",
      *t("tactile_input", "test_the_cycle_input_reaches_the_network_and_out_of_range_tests_are_reported")),
    m("autoencoder: tied weights' encoder use left out of their gradient", "autoencoder.model",
      "grads[name] = grads[name] + g.T", "grads[name] = grads[name]",
      *t("autoencoder_plugin", "test_gradients_of_a_one_layer_linear_autoencoder_are_the_closed_form")),
    m("autoencoder: activation derivative dropped in backprop", "autoencoder.model",
      "            g = grad * activation_derivative(layer.a, self.activation, self.slope)", "            g = grad",
      *t("autoencoder_plugin", "test_gradients_match_central_finite_differences[tanh-learned]")),
    m("autoencoder: the loss's gradient halved", "autoencoder.model",
      "error * (-2 / batch)", "error * (-1 / batch)",
      *t("autoencoder_plugin", "test_gradients_of_a_one_layer_linear_autoencoder_are_the_closed_form")),
    m("autoencoder: the learned encoder reads the decoder's weights", "autoencoder.model",
      'return self.weights[f"encoder.{edge}"] if self.encoder == "learned" else self.weights[edge].T',
      "return self.weights[edge].T",
      *t("autoencoder_plugin", "test_gradients_match_central_finite_differences[leaky_relu-learned]")),
    m("autoencoder: Adam without bias correction", "autoencoder.model",
      "correct1, correct2 = 1 - b1 ** self.t, 1 - b2 ** self.t", "correct1, correct2 = 1.0, 1.0",
      *t("autoencoder_plugin", "test_adam_takes_the_bias_corrected_step_and_sgd_the_plain_one")),
    m("autoencoder: converge_window ignored", "autoencoder.model",
      "            return history, True", "            pass",
      *t("autoencoder_plugin", "test_training_stops_once_converged")),
    m("autoencoder: load keeps the fresh initial weights", "autoencoder.extractor",
      "            self.model.weights = {name: saved[name] for name in saved.files}", "            pass",
      *t("contract", "test_shipped_extractors_keep_the_contract[autoencoder-check_save_load_round_trip]")),
    m("autoencoder: the test run's tactile range not checked", "autoencoder.extractor",
      '            report_out_of_range(run, raw["tactile"], self.tactile_range, self.params, self.name)\n',
      "            pass\n",
      *t("autoencoder_plugin", "test_the_test_runs_tactile_values_outside_the_training_range_are_reported")),
    # --- whether touch can matter: the touch pairs, complementarity, the difficulty command
    m("difficulty: a query paired with its nearest reference, not its nearest true match", "difficulty",
      "    position = np.where(true_match[matched], cdist(query_xy[matched], reference_xy), np.inf)",
      "    position = cdist(query_xy[matched], reference_xy)", *t("evaluate", "test_touch_at_true_matches_hand_cases")),
    m("difficulty: touched on one side counts pairs touched on both", "difficulty",
      '"touch_one_side_share": float((q_touch ^ r_touch).mean()),',
      '"touch_one_side_share": float((q_touch | r_touch).mean()),', *t("evaluate", "test_touch_at_true_matches_hand_cases")),
    m("difficulty: correspondence over every query with a true match, touched or not", "difficulty",
      "float(r_touch[q_touch].mean()) if q_touch.any() else None", "float(r_touch.mean()) if q_touch.any() else None",
      *t("evaluate", "test_touch_at_true_matches_hand_cases")),
    m("complementarity: a query without a true match counted as vision's failure", "complementarity",
      "    wrong = revisit & ~vision_right", "    wrong = ~vision_right",
      *t("complementarity", "test_complementarity_hand_case")),
    m("complementarity: the oracle right only where both are", "complementarity",
      '"oracle_r1": share(int((vision_right | touch_right).sum()), n),',
      '"oracle_r1": share(int((vision_right & touch_right).sum()), n),', *t("complementarity", "test_complementarity_hand_case")),
    m("config.methods: vision and touch methods of different plugins paired", "config.methods",
      "if v_plugin == t_plugin and v_senses == {VISUAL}", "if v_senses == {VISUAL}",
      *t("complementarity", "test_vision_and_touch_only_methods_of_one_plugin_pair_by_themselves")),
    m("features: an extractor that says nothing declares no senses instead of unknown", "features",
      'is never paired by itself."""\n        return None', 'is never paired by itself."""\n        return frozenset()',
      *t("complementarity", "test_an_extractor_that_does_not_declare_its_senses_is_unknown")),
    m("handcrafted.extractor: its senses swapped", "handcrafted.extractor",
      "return frozenset([VISUAL] * params.use_visual + [TACTILE] * params.use_tactile)",
      "return frozenset([TACTILE] * params.use_visual + [VISUAL] * params.use_tactile)",
      *t("complementarity", "test_an_extractor_that_does_not_declare_its_senses_is_unknown")),
    m("scenario: a complementarity pair of one method with itself accepted", "scenario",
      "            if pair.vision == pair.touch:", "            if False:",
      *t("cli", "test_bad_scenario_exits_2_with_one_clear_line[complementarity of one method with itself]")),
    m("compare: complementarity of the vision method with itself", "stages.compare",
      "                             for m in (vision, touch)]", "                             for m in (vision, vision)]",
      *t("difficulty_command", "test_difficulty_runs_the_handcrafted_family_alone_and_prints_gates")),
    m("results: complementarity.json left empty", "results",
      "    write_text_atomic(out / COMPLEMENTARITY, json.dumps(complementarity, indent=2))",
      "    write_text_atomic(out / COMPLEMENTARITY, json.dumps([], indent=2))",
      *t("difficulty_command", "test_difficulty_runs_the_handcrafted_family_alone_and_prints_gates")),
    m("report: vision's and touch's recall@1 swapped in the complementarity table", "report",
      '_pct(c["vision_r1"]),\n                 _pct(c["touch_r1"]),', '_pct(c["touch_r1"]),\n                 _pct(c["vision_r1"]),',
      *t("reports", "test_the_complementarity_table_and_its_absence_in_older_folders")),
    m("report: the touch pairs left out of the difficulty table", "report",
      "            _pct(d.touch_both_share), _pct(d.touch_one_side_share), _pct(d.touch_correspondence),", "",
      *t("reports", "test_the_difficulty_table_shows_the_touch_pairs_and_older_rows_without_them")),
    m("cli.difficulty: a gate at its bound missed", "cli.difficulty",
      "(value >= bound if is_min else value <= bound)", "(value > bound if is_min else value < bound)",
      *t("difficulty_command", "test_gates_by_hand")),
    m("cli.difficulty: a declared gate without a value met", "cli.difficulty",
      "            met = value is not None and", "            met = value is None or",
      *t("difficulty_command", "test_gates_by_hand")),
    m("cli.difficulty: a missed gate printed as met", "cli.difficulty",
      '    return f"{value} {bound}" if result["met"] else f"MISSED {value} {bound}"',
      '    return f"{value} {bound}"',
      *t("difficulty_command", "test_difficulty_runs_the_handcrafted_family_alone_and_prints_gates")),
    m("hypotheses: Holm's multipliers one too small", "hypotheses",
      "min(1.0, (len(p_values) - rank) * p_values[i])", "min(1.0, (len(p_values) - rank - 1) * p_values[i])",
      *t("hypotheses", "test_holm_adjusts_hand_worked_families")),
    m("hypotheses: Holm's adjusted p not made non-decreasing", "hypotheses",
      "running = max(running, min(1.0,", "running = min(running + 1.0, min(1.0,",
      *t("hypotheses", "test_holm_adjusts_hand_worked_families")),
    m("hypotheses: the endpoint against the worse comparator", "hypotheses",
      "{s: values[s] - max(c[s] for c in comparators)", "{s: values[s] - min(c[s] for c in comparators)",
      *t("hypotheses", "test_the_endpoint_is_l_minus_the_better_comparator_in_each_seed")),
    m("hypotheses: methods with different seeds paired", "hypotheses",
      "    for cell in cells[1:]:\n", "    for cell in cells[:0]:\n",
      *t("hypotheses", "test_methods_with_different_seeds_are_refused_in_one_line")),
    m("hypotheses: the interaction's H term added", "hypotheses",
      "(learned[s] - learned_vision[s]) - (handcrafted[s]", "(learned[s] - learned_vision[s]) + (handcrafted[s]",
      *t("hypotheses", "test_the_interaction_is_what_touch_adds_to_l_minus_what_it_adds_to_h")),
    m("hypotheses: the interaction's limits those of one difference", "hypotheses",
      "INTERACTION_LIMITS = (DIFFERENCE_LIMITS[0] - DIFFERENCE_LIMITS[1], DIFFERENCE_LIMITS[1] - DIFFERENCE_LIMITS[0])",
      "INTERACTION_LIMITS = DIFFERENCE_LIMITS",
      *t("hypotheses", "test_the_interaction_is_what_touch_adds_to_l_minus_what_it_adds_to_h")),
    m("hypotheses: superiority without the bootstrap interval", "hypotheses",
      '    return p < ALPHA and (stats["boot_low"] > 0 or stats["boot_high"] < 0)', "    return p < ALPHA",
      *t("hypotheses", "test_the_decision_rules_are_the_pre_registered_ones")),
    m("hypotheses: superiority at p = 0.05", "hypotheses", "    return p < ALPHA and", "    return p <= ALPHA and",
      *t("hypotheses", "test_the_decision_rules_are_the_pre_registered_ones")),
    m("hypotheses: equivalence at the margin itself", "hypotheses",
      "-EQUIVALENCE_MARGIN < tost[0] and tost[1] < EQUIVALENCE_MARGIN",
      "-EQUIVALENCE_MARGIN <= tost[0] and tost[1] <= EQUIVALENCE_MARGIN",
      *t("hypotheses", "test_the_decision_rules_are_the_pre_registered_ones")),
    m("hypotheses: the TOST read at 95 %", "hypotheses", "t_interval(differences, 1 - 2 * ALPHA)",
      "t_interval(differences, 1 - ALPHA)", *t("hypotheses", "test_the_tost_interval_is_the_90_percent_t_interval")),
    m("hypotheses: Holm over the primary too", "hypotheses",
      "*holm([p for _, _, p, _ in tested[1:]])]", "*holm([p for _, _, p, _ in tested])[1:]]",
      *t("hypotheses", "test_a_family_is_decided_on_exact_sign_flip_p_with_holm_over_the_secondaries_only")),
    m("hypotheses: a secondary decided on its unadjusted p", "hypotheses",
      "decision(stats, adjusted, tost))", "decision(stats, p, tost))",
      *t("hypotheses", "test_a_family_is_decided_on_exact_sign_flip_p_with_holm_over_the_secondaries_only")),
]

#: Mutants that cannot change a result, kept to document why they survive.
EQUIVALENT = [
    (m("pc: top-down error applied with every edge below", "batch",
       "above = self.edge_above.get(e.upper) if self.first_below[e.upper] == e.name else None",
       "above = self.edge_above.get(e.upper)", "tests/kernels/test_pc.py"),
     "only a node with several edges below and one above would see it twice; in MuPNet's tree the "
     "joint node is the only one with several edges below, and it has none above"),
    (m("pc: energies also computed on the first predict of a minibatch", "batch",
       "        self.predict_all(energy=steps == 0)", "        self.predict_all(energy=True)", "tests/kernels/test_pc.py"),
     "the row energies of that predict are overwritten by the last one before anything reads them"),
    (m("simulate: a recorded run's key ignores its content", "stages.simulate",
       '    key = recorded_key(digest)',
       '    key = recorded_key(str(path))',
       *t("matimport", "test_a_changed_run_file_reruns_what_depends_on_it")),
     "every key that depends on a run also holds the run file's digest (`dataset_digest`), so a changed "
     "file re-runs what depends on it either way; only the key the manifest records would change"),
]


def stale(mutants: list[Mutant], root: Path = ROOT) -> list[str]:
    """One message per mutant whose snippet does not occur exactly once in its module."""
    problems = []
    for mt in mutants:
        if mt.module not in MODULES:
            problems.append(f"'{mt.name}': module key '{mt.module}' is not in MODULES")
            continue
        file = root / mt.path
        count = file.read_text().count(mt.old) if file.is_file() else 0
        if count != 1:
            where = f"{mt.path} ({count} times)" if file.is_file() else f"{mt.path} (no such file)"
            problems.append(f"'{mt.name}': its snippet occurs not exactly once in {where}")
    return problems


def modules_needing_mutants(root: Path = ROOT) -> list[str]:
    """Repository paths of the package's modules longer than MIN_LINES lines."""
    return sorted(
        str(p.relative_to(root))
        for d in PACKAGE_DIRS
        for p in (root / d).rglob("*.py")
        if len(p.read_text().splitlines()) > MIN_LINES
    )


def uncovered(root: Path = ROOT) -> list[str]:
    """Modules over MIN_LINES lines that no mutant in MUTANTS changes."""
    mutated = {mt.path for mt in MUTANTS}
    return [path for path in modules_needing_mutants(root) if path not in mutated]


class Workspace:
    """A copy of the working tree in ``folder`` that imports as ``vitaplace``.

    The repository's files (tracked and untracked, not ignored) go to ``folder/repo``;
    ``folder/site`` maps the package names onto them as pyproject.toml's ``package-dir`` does,
    and comes first on PYTHONPATH, ahead of the editable install of the working tree.
    """

    def __init__(self, folder: Path):
        self.repo = folder / "repo"
        listed = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT, check=True, capture_output=True,
        ).stdout.decode().split("\0")
        for name in filter(None, listed):
            source = ROOT / name
            if source.is_file():
                (self.repo / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(source, self.repo / name)
        site = folder / "site"
        for package, directory in sorted(PACKAGE_DIR.items(), key=lambda item: item[0].count(".")):
            target = site.joinpath(*package.split("."))
            if package.count(".") == 0:  # the top package: its files, subpackages get links below
                target.mkdir(parents=True)
                for f in (self.repo / directory).iterdir():
                    (target / f.name).symlink_to(f)
            elif not target.exists():
                target.symlink_to(self.repo / directory, target_is_directory=True)
        self.env = {
            **os.environ,
            "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
            "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])),
            "PYTHONDONTWRITEBYTECODE": "1",  # a mutant of the same size and second must not reuse bytecode
        }


RUNNING: set[subprocess.Popen] = set()


def kill(proc: subprocess.Popen) -> None:
    """End ``proc``'s process group (pytest and whatever it started)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def run_pytest(ws: Workspace, tests: tuple[str, ...], timeout: float) -> tuple[str, str]:
    """(status, killer): 'passed', 'failed' (killer = the first failing node id, or why pytest
    stopped when no test ran: under a mutant whose unmutated tests pass, a broken import) or 'timeout'."""
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-rfE", "-p", "no:cacheprovider", "--no-header", *tests]
    proc = subprocess.Popen(cmd, cwd=ws.repo, env=ws.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True, text=True)
    RUNNING.add(proc)
    try:
        out, _ = proc.communicate(timeout=None if math.isinf(timeout) else timeout)
    except subprocess.TimeoutExpired:
        kill(proc)
        proc.communicate()
        return "timeout", f"over {timeout:.0f} s"
    except BaseException:  # Ctrl-C: the tests' whole process group goes too
        kill(proc)
        raise
    finally:
        RUNNING.discard(proc)
    if proc.returncode == 0:
        return "passed", ""
    failed = [line.split(" ", 1)[1].split(" - ")[0] for line in out.splitlines()
              if line.startswith(("FAILED tests", "ERROR tests"))]  # pytest's summary, not captured log lines
    if failed:
        return "failed", failed[0]
    # no test failed, yet pytest did not pass: a test module no longer imports (collection error)
    last = out.strip().splitlines()[-1] if out.strip() else ""
    return "failed", f"pytest exit {proc.returncode}: {last}"


@dataclass(frozen=True)
class Outcome:
    mutant: Mutant
    status: str  # killed, timeout, survived
    killer: str
    seconds: float


def try_mutant(ws: Workspace, mt: Mutant, timeout: float) -> Outcome:
    """Apply ``mt`` to the workspace copy, run its tests, restore the copy."""
    file = ws.repo / mt.path
    original = file.read_text()
    start = time.perf_counter()
    try:
        file.write_text(original.replace(mt.old, mt.new))
        status, killer = run_pytest(ws, mt.tests, timeout)
    finally:
        file.write_text(original)
    status = {"failed": "killed", "passed": "survived"}.get(status, status)
    return Outcome(mt, status, killer, time.perf_counter() - start)


def print_row(i: int, total: int, o: Outcome) -> None:
    label = {"killed": "killed", "timeout": "TIMEOUT", "survived": "SURVIVED"}[o.status]
    print(f"[{i:3d}/{total}] {label:8s} {o.seconds:5.0f} s  {o.mutant.name}  <- {o.killer or '-'}", flush=True)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("only", nargs="*", help="only mutants of these modules (keys of MODULES) or whose name starts so")
    ap.add_argument("--list", action="store_true", help="list the chosen mutants and exit")
    ap.add_argument("--check", action="store_true", help="check that every snippet applies and exit")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per mutant (default 600)")
    ap.add_argument("--jobs", type=int, default=1, help="mutants run at once, each in its own copy (default 1)")
    args = ap.parse_args(argv)
    chosen = [mt for mt in MUTANTS if not args.only
              or any(mt.module == p or mt.name.startswith(p) for p in args.only)]
    problems = stale(chosen + [mt for mt, _ in EQUIVALENT])
    if problems:
        print(f"mutation.py: {len(problems)} mutant(s) no longer apply: " + "; ".join(problems), file=sys.stderr)
        return 2
    if args.check:
        print(f"{len(MUTANTS)} mutants and {len(EQUIVALENT)} equivalent ones apply; "
              f"modules over {MIN_LINES} lines without a mutant: {', '.join(uncovered()) or 'none'}")
        return 0
    if args.list:
        for mt in chosen:
            print(f"{mt.name}  ({mt.path}; {' '.join(mt.tests)})")
        return 0
    if not chosen:
        print("mutation.py: no mutant matches " + " ".join(args.only), file=sys.stderr)
        return 2
    for signum in (signal.SIGINT, signal.SIGTERM):  # Ctrl-C, also when started with SIGINT ignored, and `timeout`
        signal.signal(signum, _interrupt)
    start = time.perf_counter()
    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="vitaplace-mutation-") as tmp:
        try:
            spaces: queue.Queue[Workspace] = queue.Queue()
            for j in range(max(1, args.jobs)):
                spaces.put(Workspace(Path(tmp) / str(j)))
            baseline = tuple(sorted({node for mt in chosen for node in mt.tests}))
            status, killer = run_pytest(spaces.queue[0], baseline, math.inf)
            if status != "passed":
                print(f"mutation.py: the unmutated tests fail ({status}: {killer}); fix them first", file=sys.stderr)
                return 2

            def work(mt: Mutant) -> Outcome:
                ws = spaces.get()
                try:
                    return try_mutant(ws, mt, args.timeout)
                finally:
                    spaces.put(ws)

            pool = ThreadPoolExecutor(max_workers=max(1, args.jobs))
            try:
                for i, outcome in enumerate(pool.map(work, chosen), 1):
                    outcomes.append(outcome)
                    print_row(i, len(chosen), outcome)
            finally:  # on Ctrl-C: nothing queued starts, the running tests are killed, then the copies go
                pool.shutdown(wait=False, cancel_futures=True)
                for proc in list(RUNNING):
                    kill(proc)
                pool.shutdown(wait=True)
        except KeyboardInterrupt:
            print(f"\ninterrupted after {len(outcomes)} of {len(chosen)} mutants (the working tree was never changed)",
                  file=sys.stderr)
            return 130
    killed = sum(o.status == "killed" for o in outcomes)
    timeouts = sum(o.status == "timeout" for o in outcomes)
    rate = (killed + timeouts) / len(outcomes)
    print(f"\n{'mutant':60s} {'module':28s} {'result':9s} killed by")
    for o in outcomes:
        print(f"{o.mutant.name[:60]:60s} {o.mutant.path:28s} {o.status:9s} {o.killer}")
    for mt, reason in EQUIVALENT:
        print(f"[equivalent] {mt.name}: {reason}")
    print(f"\nscore: {killed + timeouts}/{len(outcomes)} killed ({100 * rate:.1f} %; {killed} by a failing test, "
          f"{timeouts} by timeout), {len(outcomes) - killed - timeouts} survived; target {100 * TARGET:.0f} %; "
          f"{time.perf_counter() - start:.0f} s")
    return 0 if rate >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
