"""MuPNet's configurations, its edges, and `NetworkView`: what a batch and a solver read of a network.

The configurations are plain containers: the MuPNet plugin's parameter schema
(``MupnetParams``) holds the settings, their defaults and their checks and builds these.
`NetworkView` is the typed handle `vitaplace.engine.network.batch`,
`vitaplace.engine.network.solver` and `vitaplace.engine.network.inference` hold of the
`vitaplace.engine.network.pc.Network` (which builds them, so they cannot import it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vitaplace.engine.network.backends import Backend


@dataclass(frozen=True)
class ModalityConfig:
    """One sensory modality: its input size, the latent layer sizes above it (bottom first),
    and the latent step size, weight step size and test-time stop threshold of its layers."""

    input_size: int
    layers: list[int]
    eta_y: float
    eta_w: float
    threshold: float


@dataclass(frozen=True)
class JointConfig:
    """The joint layer: its size, step sizes and the test-time threshold of its edges."""

    size: int
    eta_y: float
    eta_w: float
    threshold: float


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture and step sizes. The settings and their defaults and checks are the MuPNet
    plugin's parameter schema (``MupnetParams.network_config``); these are plain containers."""

    modalities: dict[str, ModalityConfig]
    joint: JointConfig
    activation: str
    slope: float

    @classmethod
    def from_dict(cls, data: Mapping) -> NetworkConfig:
        """The configuration from its `asdict` form (every key required)."""
        return cls(
            modalities={m: ModalityConfig(**mc) for m, mc in data["modalities"].items()},
            joint=JointConfig(**data["joint"]),
            activation=data["activation"],
            slope=data["slope"],
        )


@dataclass(frozen=True)
class TrainingConfig:
    """Passes over the data (the maximum when converging: stop once the epoch energy fell by
    less than ``converge_tol`` over ``converge_window`` epochs, 0: off), minibatch size, T
    latent steps per minibatch, and the seed of the random minibatch order. Settings and
    defaults: ``MupnetParams.training_config``.

    ``latent_prior`` and the weight optimiser's settings have defaults (the paper's energy
    and plain SGD, the plugin's defaults), so that code written before they existed builds
    the same configuration. ``weight_optimizer``: ``sgd`` (the paper's), ``momentum`` (heavy
    ball, ``weight_momentum``) or ``adam`` (``adam_beta1``, ``adam_beta2``, ``adam_eps``);
    `vitaplace.engine.network.optimizer`. ``precision_weighting`` (default ``none``, the
    paper's energy): how training estimates the error precisions after each epoch
    (`vitaplace.engine.network.precision`); the precisions themselves belong to the network
    and are saved with it. ``weight_norm`` (default ``none``, the paper's): ``rows`` keeps
    each row of every edge's W (a unit's projective field) at its norm at the start of
    training, projecting it back after every weight step."""

    epochs: int
    batch_size: int
    inference_steps: int
    seed: int
    converge_window: int
    converge_tol: float
    #: lambda of the Gaussian prior on the latents in the inference steps (0: the paper's energy)
    latent_prior: float = 0.0
    #: the weight optimiser: sgd (the paper's plain step), momentum or adam
    weight_optimizer: str = "sgd"
    #: beta of the heavy-ball momentum (weight_optimizer momentum)
    weight_momentum: float = 0.9
    #: Adam's moment decays and epsilon (weight_optimizer adam)
    adam_beta1: float = 0.9
    adam_beta2: float = 0.999
    adam_eps: float = 1e-8
    #: error precisions estimated after each epoch: none (all 1), layer (one per edge) or channel
    precision_weighting: str = "none"
    #: the floor of an error variance in that estimate (pi <= 1 / floor before the normalisation)
    precision_floor: float = 1e-3
    #: none, or rows: every row of W held at its norm at the start of training
    weight_norm: str = "none"


@dataclass
class Edge:
    """A prediction from node ``upper`` to node ``lower``; named by the error it produces."""

    name: str
    upper: str
    lower: str
    modality: str
    eta_w: float
    threshold: float


class NetworkView(Protocol):
    """What a batch's buffers and steps, a solver and the settling of a batch read of the
    network: its backend, configuration, node sizes, latent step sizes and weights."""

    backend: Backend
    config: NetworkConfig
    sizes: dict[str, int]
    eta_y: dict[str, float]
    #: host error precisions per edge (one per channel of its lower node), and whether they are in use
    precisions: dict[str, np.ndarray]
    weighted: bool

    def input_node(self, modality: str) -> str: ...
    def latent_nodes(self, modalities: Sequence[str]) -> list[str]: ...
    def active_edges(self, modalities: Sequence[str]) -> list[Edge]: ...
    def device_weights(self) -> dict[str, object]: ...
    def host_weights(self) -> dict[str, np.ndarray]: ...
    def device_precisions(self) -> dict[str, object] | None: ...
