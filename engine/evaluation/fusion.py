"""Late fusion of a vision-only and a touch-only method (a scenario's ``fusions:``): the
control that tells a joint code from a better weighting of two separate ones.

Each method's distance matrix is divided by its spread σ (the standard deviation of its
finite distances in the selection evaluation, the training world's; 1 when that is 0 or
undefined), as H divides each of its terms by the spread of that term's distances, and the
two are summed with the touch term weighted::

    d = (d_V / σ_V + w · d_T / σ_T) · (1 + w) / (present weight)

A pair only one of the methods can compare (+inf there: a query that lost that sensor) keeps
the other's term, scaled up to the full weight ``1 + w`` as H scales its present terms (a
weighted Gower distance); a pair neither can compare is +inf; with both present the factor is
1 and ``d`` is the plain sum. ``w`` is chosen from a stated grid on the selection evaluation
alone — the largest max F1, ties to the smallest ``w`` — and applied unchanged to every
evaluation (`choose_weight`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["choose_weight", "fused_distance", "spread"]


def spread(distances: np.ndarray) -> float:
    """Standard deviation of the finite entries of ``distances``; 1 if it is 0 or undefined."""
    finite = np.asarray(distances, dtype=float)
    finite = finite[np.isfinite(finite)]
    sigma = float(finite.std()) if finite.size else 0.0
    return sigma if np.isfinite(sigma) and sigma > 0 else 1.0


def fused_distance(vision: np.ndarray, touch: np.ndarray, sigma_vision: float, sigma_touch: float,
                   weight: float) -> np.ndarray:
    """``(d_V / σ_V + w d_T / σ_T)``, each term's absence (+inf) made up by the other's scaled to
    the full weight (module docstring)."""
    terms = [(np.asarray(vision, dtype=float) / sigma_vision, 1.0),
             (np.asarray(touch, dtype=float) / sigma_touch, weight)]
    total = np.zeros(np.shape(vision))
    present = np.zeros(np.shape(vision))
    for term, w in terms:
        here = np.isfinite(term)
        total += w * np.where(here, term, 0.0)
        present += w * here
    full = 1.0 + weight
    both = present == full
    scaled = np.divide(total * full, present, out=np.full(total.shape, np.inf), where=present > 0)
    return np.where(both, total, scaled)


def choose_weight(
    vision: np.ndarray, touch: np.ndarray, weights: Sequence[float], score: Callable[[np.ndarray], float],
) -> tuple[float, float, float, dict[float, float]]:
    """(w, σ_V, σ_T, score per weight) on the selection evaluation: ``score(fused)`` (its max
    F1) for each weight of the grid, the best kept, ties to the smallest weight."""
    sigma_v, sigma_t = spread(vision), spread(touch)
    scores = {float(w): float(score(fused_distance(vision, touch, sigma_v, sigma_t, float(w))))
              for w in sorted(weights)}
    best = max(scores.values())
    return min(w for w, s in scores.items() if s == best), sigma_v, sigma_t, scores
