"""The Warp kernels' operations in one namespace: what the Warp backend calls, on CPU or CUDA.

(a) ``predict``, ``predict_epilogue``: prediction, error, gain, row energies (predict_kernels)
(b) ``latent_update``, ``latent_apply``: the latent step (update_kernels)
(c) ``weight_update``: the weight step, keeping ``W.T`` (update_kernels)
(c') ``momentum_weight_step``, ``adam_weight_step``, ``count_step``: the weight optimisers'
     element-wise steps, from the direction ``weight_update`` writes into zeroed weights (update_kernels)
(c'') ``column_squares``: per-channel sums of squared errors (the error precisions' estimate) (update_kernels)
(c''') ``project_rows``: each row of ``W`` rescaled to a given norm, keeping ``W.T`` (update_kernels)
(d) ``gather_rows``, ``scatter_rows``, ``to_bfloat16``: copies on the device (copy_kernels)
(e) ``stop_converged``: per-sample stopping of inference (solver_kernels)

Tile sizes live in ``tiles``; the checks, launches and the plan of kernels to preload in
``launch``. ``kernels/reference.py`` is the numpy specification all are tested against.
"""

from vitaplace.kernels.copy_kernels import gather_rows, scatter_rows, to_bfloat16
from vitaplace.kernels.launch import planned_kernels, planning, preload
from vitaplace.kernels.predict_kernels import predict, predict_epilogue, row_partial_shape
from vitaplace.kernels.reference import ACTIVATIONS
from vitaplace.kernels.solver_kernels import stop_converged
from vitaplace.kernels.tiles import TileConfig, latent_splits, set_tile_config, tile_config
from vitaplace.kernels.update_kernels import (
    adam_weight_step,
    column_squares,
    count_step,
    latent_apply,
    latent_scratch_shape,
    latent_update,
    momentum_weight_step,
    project_rows,
    weight_update,
)

__all__ = [
    "ACTIVATIONS", "TileConfig", "adam_weight_step", "column_squares", "count_step", "gather_rows", "latent_apply",
    "latent_scratch_shape", "latent_splits", "latent_update", "momentum_weight_step", "planned_kernels", "planning",
    "predict", "predict_epilogue", "preload", "project_rows", "row_partial_shape", "scatter_rows", "set_tile_config",
    "stop_converged", "tile_config", "to_bfloat16", "weight_update",
]
