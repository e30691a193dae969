"""Plain numpy reference for one predictive-coding layer step.

This module is the *specification* that the Warp kernels (``predict_kernels.py``,
``update_kernels.py``) and the numpy backend are tested against. Every function is
dtype-preserving: float32 inputs give float32 outputs, float64 inputs give float64 outputs.

For a layer with latent ``Y`` (B x n_l), weights ``W`` (n_l x n_below) and the layer
below (or the sensory input) ``X`` (B x n_below)::

    A = Y @ W                   prediction pre-activation
    P = phi(A)                  prediction of the layer below
    E = X - P                   prediction error
    G = phi'(A) * E             gain-weighted error
    dF/dY = -2 G @ W.T + 2 E_above      (E_above absent for the top / joint layer)
    dF/dW = -2 Y.T @ G

with the energy ``F = sum_l ||E_l||^2`` (no 1/2). With error precisions (one ``pi`` per
channel of the layer below, per edge) the energy is ``F = sum_l sum_c pi_c E_lc^2``, ``G``
carries the edge's own ``pi`` (``G = pi * phi'(A) * E``) and the top-down term the edge
above's: ``dF/dY = -2 G @ W.T + 2 pi_above * E_above``; ``dF/dW = -2 Y.T @ G`` unchanged in form.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "ACTIVATIONS",
    "activation",
    "activation_derivative",
    "predict",
    "energy",
    "latent_step",
    "weight_step",
    "momentum_weight_step",
    "adam_weight_step",
    "project_rows",
]

#: Names accepted by :func:`activation` and :func:`activation_derivative`.
ACTIVATIONS: tuple[str, ...] = ("leaky_relu", "tanh", "sigmoid", "linear")


def _check_name(name: str) -> None:
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation {name!r}; valid activations: {', '.join(ACTIVATIONS)}")


def _sigmoid(a: np.ndarray) -> np.ndarray:
    # Numerically stable logistic function, no overflow warnings for large |a|.
    a = np.asarray(a)
    e = np.exp(-np.abs(a))
    return np.where(a >= 0, 1 / (1 + e), e / (1 + e)).astype(a.dtype, copy=False)


def activation(a: np.ndarray, name: str, slope: float = 0.2) -> np.ndarray:
    """phi(a), element-wise (P = phi(A)).

    ``leaky_relu``: a if a > 0 else slope * a; ``tanh``; ``sigmoid``: 1 / (1 + exp(-a));
    ``linear``: a.
    """
    _check_name(name)
    a = np.asarray(a)
    if name == "leaky_relu":
        return np.where(a > 0, a, a * a.dtype.type(slope))
    if name == "tanh":
        return np.tanh(a)
    if name == "sigmoid":
        return _sigmoid(a)
    return a.copy()  # linear


def activation_derivative(a: np.ndarray, name: str, slope: float = 0.2) -> np.ndarray:
    """phi'(a), element-wise (the gain in G = phi'(A) * E).

    ``leaky_relu``: 1 if a > 0 else slope; ``tanh``: 1 - tanh(a)^2;
    ``sigmoid``: s(a) (1 - s(a)); ``linear``: 1.
    """
    _check_name(name)
    a = np.asarray(a)
    one = a.dtype.type(1)
    if name == "leaky_relu":
        return np.where(a > 0, one, a.dtype.type(slope)).astype(a.dtype, copy=False)
    if name == "tanh":
        t = np.tanh(a)
        return one - t * t
    if name == "sigmoid":
        s = _sigmoid(a)
        return s * (one - s)
    return np.ones_like(a)  # linear


def predict(
    Y: np.ndarray,
    W: np.ndarray,
    X: np.ndarray,
    name: str = "leaky_relu",
    slope: float = 0.2,
    precision: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Prediction, error and gain of one layer.

    Returns ``(A, P, E, G)`` with ``A = Y @ W``, ``P = phi(A)``, ``E = X - P`` and
    ``G = phi'(A) * E``, times ``precision`` (the edge's error precisions, one per column) when given.
    """
    A = Y @ W
    P = activation(A, name, slope)
    E = X - P
    G = activation_derivative(A, name, slope) * E
    if precision is not None:
        G = G * np.asarray(precision, G.dtype)
    return A, P, E, G


def energy(E: np.ndarray, precision: np.ndarray | None = None) -> np.ndarray:
    """Each row's energy ``sum_c pi_c E[r, c]^2`` (``pi`` 1 when ``precision`` is None), in float64."""
    E = np.asarray(E, np.float64)
    pi = np.ones(E.shape[1]) if precision is None else np.asarray(precision, np.float64)
    return (E * E) @ pi


def latent_step(
    Y: np.ndarray,
    G: np.ndarray,
    W: np.ndarray,
    eta: float,
    E_above: np.ndarray | None = None,
    precision_above: np.ndarray | None = None,
) -> np.ndarray:
    """One gradient step on the latent; returns the new ``Y``.

    ``Y - eta * dF/dY`` with ``dF/dY = -2 G @ W.T + 2 pi_above E_above``, i.e.
    ``Y + 2 eta G @ W.T - 2 eta pi_above E_above``. ``E_above`` is the error of the layer above
    (whose target is ``Y``); pass ``None`` for the top / joint layer. ``precision_above``:
    that edge's error precisions (one per column of ``Y``; None: 1).
    """
    two_eta = Y.dtype.type(2 * eta)
    out = Y + two_eta * (G @ W.T)
    if E_above is not None:
        if precision_above is not None:
            E_above = np.asarray(precision_above, E_above.dtype) * E_above
        out = out - two_eta * E_above
    return out


def weight_step(W: np.ndarray, Y: np.ndarray, G: np.ndarray, eta: float) -> np.ndarray:
    """One gradient step on the weights; returns the new ``W``.

    ``W - eta * dF/dW`` with ``dF/dW = -2 Y.T @ G``, i.e. ``W + 2 eta Y.T @ G``.
    """
    return W + W.dtype.type(2 * eta) * (Y.T @ G)


def momentum_weight_step(W: np.ndarray, V: np.ndarray, D: np.ndarray, eta: float, beta: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Heavy-ball weight step from the step direction ``D = 2 Y.T @ G`` (= -dF/dW); returns
    the new ``(W, V)``: ``V' = beta V + D``, ``W' = W + eta V'``."""
    t = W.dtype.type
    V = t(beta) * V + D
    return W + t(eta) * V, V


def adam_weight_step(W: np.ndarray, M: np.ndarray, S: np.ndarray, D: np.ndarray, step: int, eta: float, beta1: float,
                     beta2: float, eps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Adam's weight step from the step direction ``D`` (= -dF/dW) at step count ``step``
    (from 1); returns the new ``(W, M, S)``: ``M' = b1 M + (1 - b1) D``,
    ``S' = b2 S + (1 - b2) D^2``, ``W' = W + eta (M' / (1 - b1^step)) / (sqrt(S' / (1 - b2^step)) + eps)``
    (the bias corrections in float64)."""
    t = W.dtype.type
    M = t(beta1) * M + t(1.0 - beta1) * D
    S = t(beta2) * S + t(1.0 - beta2) * (D * D)
    c1, c2 = t(1.0 - beta1**step), t(1.0 - beta2**step)
    return W + t(eta) * (M / c1) / (np.sqrt(S / c2) + t(eps)), M, S


def project_rows(W: np.ndarray, norms: np.ndarray) -> np.ndarray:
    """``W`` with each row rescaled to ``norms`` (``weight_norm: rows``): row r times
    ``float32(norms[r] / |W[r]|)``, the norm taken in float64; a zero row is kept."""
    current = np.sqrt(np.einsum("ij,ij->i", W.astype(np.float64), W.astype(np.float64)))
    factor = np.where(current > 0, norms / np.where(current > 0, current, 1.0), 1.0).astype(W.dtype)
    return W * factor[:, None]
