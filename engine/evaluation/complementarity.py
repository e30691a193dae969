"""Whether touch can rescue vision: the queries a vision-only method gets wrong at its best
match that a touch-only method of the same family gets right, on one evaluation direction.

The conventions are `vitaplace.engine.evaluation.evaluate`'s: single best match per query,
*right* when it is a true match (``gtm <= tau`` at the best match), recall@1 over the
queries that have a true match. The oracle takes, per query, whichever of the two methods
is right: its recall@1 is the ceiling of any fusion of the two that picks one of their
matches.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vitaplace.engine.evaluation.evaluate import Decisions

__all__ = ["COMPLEMENTARITY_KEYS", "complementarity"]

#: the measures of `complementarity`'s result, in order
COMPLEMENTARITY_KEYS = ("n_revisit", "vision_r1", "touch_r1", "vision_wrong", "rescued", "rescue", "oracle_r1")


def complementarity(vision: Decisions, touch: Decisions) -> dict[str, Any]:
    """The complementarity of a vision-only and a touch-only method scored on the same
    queries and references (`COMPLEMENTARITY_KEYS`, plain numbers):

    ``n_revisit`` the queries with a true match; ``vision_r1`` and ``touch_r1`` each
    method's recall@1 over them; ``vision_wrong`` the queries with a true match whose vision
    best match is not one; ``rescued`` how many of those the touch method gets right, and
    ``rescue`` their share (None when vision is never wrong); ``oracle_r1`` the recall@1 of
    taking whichever method is right. The recalls are None when no query has a true match.
    """
    if vision.n_queries != touch.n_queries or not np.array_equal(vision.has_revisit, touch.has_revisit):
        raise ValueError("the vision and touch decisions must be of the same queries and ground truth")
    revisit = np.asarray(vision.has_revisit, dtype=bool)
    vision_right = revisit & vision.correct
    touch_right = revisit & touch.correct
    wrong = revisit & ~vision_right
    n, n_wrong, rescued = int(revisit.sum()), int(wrong.sum()), int((wrong & touch_right).sum())

    def share(count: int, of: int) -> float | None:
        return count / of if of else None

    return {
        "n_revisit": n,
        "vision_r1": share(int(vision_right.sum()), n),
        "touch_r1": share(int(touch_right.sum()), n),
        "vision_wrong": n_wrong,
        "rescued": rescued,
        "rescue": share(rescued, n_wrong),
        "oracle_r1": share(int((vision_right | touch_right).sum()), n),
    }
