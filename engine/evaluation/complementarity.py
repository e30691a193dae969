"""Whether touch can rescue vision: the queries a vision-only method gets wrong at its best
match that a touch-only method of the same family gets right, on one evaluation direction.

The conventions are `vitaplace.engine.evaluation.evaluate`'s: single best match per query,
*right* when it is a true match (``gtm <= tau`` at the best match), recall@1 over the
queries that have a true match. The oracle takes, per query, whichever of the two methods
is right: its recall@1 is the ceiling of any fusion of the two that picks one of their
matches.

Ties follow evaluate's rule: a method's best match is right with probability ``p`` (its
``correct_share``, the share of true matches among the references tied at its best
distance; 0 or 1 untied), the two methods' ties drawn independently. Each count is the
expected count over the queries with a true match: a query is vision's failure ``1 - p_V``
of a time, rescued ``(1 - p_V) p_T``, and the oracle is right ``p_V + p_T - p_V p_T``; counts
are ints unless a tie splits one (`count_value`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vitaplace.engine.evaluation.evaluate import Decisions, count_value

__all__ = ["COMPLEMENTARITY_KEYS", "complementarity", "count_text"]

#: the measures of `complementarity`'s result, in order
COMPLEMENTARITY_KEYS = ("n_revisit", "vision_r1", "touch_r1", "vision_wrong", "rescued", "rescue", "oracle_r1")


def complementarity(vision: Decisions, touch: Decisions) -> dict[str, Any]:
    """The complementarity of a vision-only and a touch-only method scored on the same
    queries and references (`COMPLEMENTARITY_KEYS`, plain numbers):

    ``n_revisit`` the queries with a true match; ``vision_r1`` and ``touch_r1`` each
    method's recall@1 over them; ``vision_wrong`` the queries with a true match whose vision
    best match is not one; ``rescued`` how many of those the touch method gets right (both
    expected counts under the tie rule, module docstring), and
    ``rescue`` their share (None when vision is never wrong); ``oracle_r1`` the recall@1 of
    taking whichever method is right. The recalls are None when no query has a true match.
    """
    if vision.n_queries != touch.n_queries or not np.array_equal(vision.has_revisit, touch.has_revisit):
        raise ValueError("the vision and touch decisions must be of the same queries and ground truth")
    revisit = np.asarray(vision.has_revisit, dtype=bool)
    vision_right = np.where(revisit, vision.correct_share, 0.0)
    touch_right = np.where(revisit, touch.correct_share, 0.0)
    wrong = np.where(revisit, 1.0 - vision_right, 0.0)
    n, n_wrong, rescued = int(revisit.sum()), float(wrong.sum()), float((wrong * touch_right).sum())

    def share(count: float, of: float) -> float | None:
        return count / of if of else None

    return {
        "n_revisit": n,
        "vision_r1": share(float(vision_right.sum()), n),
        "touch_r1": share(float(touch_right.sum()), n),
        "vision_wrong": count_value(n_wrong),
        "rescued": count_value(rescued),
        "rescue": share(rescued, n_wrong),
        "oracle_r1": share(float((vision_right + touch_right - vision_right * touch_right).sum()), n),
    }


def count_text(count: float) -> str:
    """A complementarity count as the tables print it: ``34``, or ``3.50`` where a tie split it."""
    return str(int(count)) if float(count).is_integer() else f"{count:.2f}"
