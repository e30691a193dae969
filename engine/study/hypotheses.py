"""The pre-registered tests of the studies (docs/RESULTS.md, "Pre-registration" and "Second
study: pre-registration"), on per-seed values of max F1.

An **endpoint** is a mean paired difference over seeds: per seed, L minus its comparator, or
minus the better of several in that seed (`versus_best`: the second study's "L − max(L-V,
L-F)"). Each endpoint gets (`endpoint_tests`):

* its statistics over seeds (`paired`: `describe` inside [-1, 1], the range of a difference
  of proportions) and the exact two-sided sign-flip p (`sign_flip_p`);
* the TOST of equivalence at ±`EQUIVALENCE_MARGIN` (5 points): two one-sided paired t-tests,
  each at `ALPHA`, which both reject exactly when the (1 - 2 `ALPHA`) = 90 % Student-t
  interval of the mean (`tost_interval`) lies inside (-margin, +margin).

The decision rules, fixed before any number was run (`decision`):

* **superiority** (`superiority`): the 95 % percentile-bootstrap interval over seeds
  excludes 0 and the sign-flip p < `ALPHA`; L better when the mean is positive, worse when
  negative. The first study's primary endpoint is decided by this rule alone;
* **equivalence** (`equivalence`): the TOST interval inside (-5, +5) points;
* both can hold (L better, by less than 5 points); neither: the study did not show a
  difference nor equivalence.

The family: the primary endpoint is decided on its own p; the numbered secondaries' sign-flip
p values are adjusted by Holm's step-down procedure (`holm`) for a family-wise `ALPHA` over
the secondaries; the equivalence tests are reported beside them, unadjusted.

The decomposition L − H = (L-V − H-V) + [(L − L-V) − (H − H-V)] (exploratory, unadjusted):
`interaction` is its second term per seed, tested by `paired` inside `INTERACTION_LIMITS`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.study.summary import describe, difference_bounds, sign_flip_p, t_interval

#: the significance level of every test: superiority's sign-flip p, each one-sided test of the TOST, Holm's family
ALPHA = 0.05
#: the TOST's margin, max F1 (5 points)
EQUIVALENCE_MARGIN = 0.05
#: the range of a paired difference of max F1, and of a difference of two such differences
DIFFERENCE_LIMITS = difference_bounds("max_f1")
INTERACTION_LIMITS = (DIFFERENCE_LIMITS[0] - DIFFERENCE_LIMITS[1], DIFFERENCE_LIMITS[1] - DIFFERENCE_LIMITS[0])

#: seed -> a method's value in that seed
PerSeed = Mapping[int, float]


def _seeds(cells: Sequence[PerSeed]) -> list[int]:
    """The seeds every cell has, sorted; one line naming them when the cells differ."""
    seeds = sorted(cells[0])
    for cell in cells[1:]:
        if set(cell) != set(seeds):
            raise UserError(f"per-seed values of seeds {sorted(cell)} paired with seeds {seeds}, "
                            "expected the same seeds for every method")
    return seeds


def versus_best(values: PerSeed, comparators: Sequence[PerSeed]) -> dict[int, float]:
    """Seed -> ``values`` minus the best (largest) of ``comparators`` in that seed, in seed
    order: the paired difference against one comparator, against the per-seed better one of
    several."""
    return {s: values[s] - max(c[s] for c in comparators) for s in _seeds([values, *comparators])}


def interaction(learned: PerSeed, learned_vision: PerSeed, handcrafted: PerSeed,
                handcrafted_vision: PerSeed) -> dict[int, float]:
    """Seed -> (L - L-V) - (H - H-V), given L, L-V, H and H-V per seed: what touch adds to L
    minus what it adds to H, the decomposition's second term."""
    cells = [learned, learned_vision, handcrafted, handcrafted_vision]
    return {s: (learned[s] - learned_vision[s]) - (handcrafted[s] - handcrafted_vision[s]) for s in _seeds(cells)}


def paired(differences: Sequence[float],
           limits: tuple[float, float] = DIFFERENCE_LIMITS) -> tuple[dict[str, float], float]:
    """`describe` of per-seed paired differences inside ``limits``, and their sign-flip p."""
    return describe(differences, limits), sign_flip_p(differences)


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p values, in the order given: the i-th smallest of m times
    (m - i + 1), made non-decreasing, at most 1."""
    order = sorted(range(len(p_values)), key=lambda i: p_values[i])
    adjusted, running = [0.0] * len(p_values), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p_values) - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


def tost_interval(differences: Sequence[float]) -> tuple[float, float]:
    """The TOST's interval: the (1 - 2 `ALPHA`) Student-t interval of the mean difference."""
    return t_interval(differences, 1 - 2 * ALPHA)


def superiority(stats: Mapping[str, float], p: float) -> bool:
    """The bootstrap interval (``boot_low``, ``boot_high``) excludes 0 and p < `ALPHA`."""
    return p < ALPHA and (stats["boot_low"] > 0 or stats["boot_high"] < 0)


def equivalence(tost: tuple[float, float]) -> bool:
    """The TOST interval lies inside (-`EQUIVALENCE_MARGIN`, +`EQUIVALENCE_MARGIN`)."""
    return -EQUIVALENCE_MARGIN < tost[0] and tost[1] < EQUIVALENCE_MARGIN


def decision(stats: Mapping[str, float], p: float, tost: tuple[float, float]) -> str:
    """The pre-registered verdict on one endpoint from its statistics (``mean``, bootstrap
    interval), its p (Holm-adjusted for a secondary) and its TOST interval."""
    points = f"{100 * EQUIVALENCE_MARGIN:g} points"
    direction = "L better" if stats["mean"] > 0 else "L worse"
    superior, equivalent = superiority(stats, p), equivalence(tost)
    if superior and equivalent:
        return f"{direction}, by < {points}"
    if superior:
        return direction
    return f"equivalent (±{points})" if equivalent else "neither shown"


@dataclass(frozen=True)
class Endpoint:
    """One endpoint, tested: its per-seed values, `paired` statistics and sign-flip p, the p
    its decision reads (Holm-adjusted for a secondary), the TOST interval and the verdict."""

    values: tuple[float, ...]
    stats: dict[str, float]
    p: float
    p_holm: float
    tost: tuple[float, float]
    decision: str


def endpoint_tests(primary: Sequence[float], secondaries: Sequence[Sequence[float]]) -> list[Endpoint]:
    """The primary endpoint and the secondaries (per-seed values each), tested and decided:
    Holm over the secondaries' p values only; the primary keeps its own p."""
    tested = [(tuple(values), *paired(values), tost_interval(values)) for values in (primary, *secondaries)]
    p_holm = [tested[0][2], *holm([p for _, _, p, _ in tested[1:]])]
    return [Endpoint(values, stats, p, adjusted, tost, decision(stats, adjusted, tost))
            for (values, stats, p, tost), adjusted in zip(tested, p_holm, strict=True)]
