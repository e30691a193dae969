"""The tables of docs/RESULTS.md, computed from the study's committed summaries.

    python docs/results/tables.py            # every table, each under its name
    python docs/results/tables.py six-penetration

Each table in RESULTS.md sits between ``<!-- table NAME -->`` and ``<!-- /table -->`` and is
exactly what this script prints for NAME (`tests/layout/test_results_doc.py` checks it), so no
number in the text can drift from the files `vitaplace sweep` and `vitaplace sensitivity`
wrote: ``sweep.csv`` (statistics over seeds per world x method x direction x value),
``sweep-diff.csv`` (paired differences between methods, with the sign-flip p),
``sweep-seeds.csv`` (every value per seed; ``sweep-seeds.csv.gz`` where large) and
``sensitivity.csv`` (per seed, max F1 rescored under other ground truths), and each seed's
``manifest.json`` and ``report.md`` (copied into ``seeds/seed-N/``), in
``paper-cpu-sweep/`` (penetration touch model) and ``paper-cpu-physical-sweep/`` (physical
whiskers). The second study's tables (``study2-*``) read the same files of its three arms'
sweeps, one folder per grid point (`ARMS`, `POINTS`), seed 0's `vitaplace difficulty` runs
(``study2-difficulty/``) and the budget trend (``study2-budget/epochs=E/``). This script reads
and formats: the statistics and the pre-registered tests (the endpoints against the per-seed
better comparator, Holm over the secondaries, the TOST at ±5 points, the decision rules, the
decomposition's interaction) are `vitaplace.engine.study.hypotheses`'s. Proportions are
printed in percent, intervals are the percentile bootstrap over seeds unless a column says
otherwise.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import gzip
import json
import math
import re
import statistics
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.study import hypotheses
from vitaplace.engine.study.hypotheses import INTERACTION_LIMITS, endpoint_tests, paired, versus_best
from vitaplace.engine.study.summary import LEVEL

HERE = Path(__file__).resolve().parent
#: touch model -> the sweep folder of its scenario
STUDIES = {"penetration": HERE / "paper-cpu-sweep", "physical": HERE / "paper-cpu-physical-sweep"}
WORLDS = ("E1", "E2", "E3")
METHODS = ("L", "L-V", "L-T", "H", "H-V", "H-T")
Q2R, R2Q = "query-to-reference", "reference-to-query"
DIRECTIONS = {Q2R: "q→r", R2Q: "r→q"}
#: the paper's reading of each world, L (learned) vs H (hand-crafted), F1
PAPER = {"E1": "similar F1", "E2": "L: higher precision", "E3": "L 72.94 %, H 62.34 %"}


#: the second study's arms -> (sweep folder, scenario file, evaluations, grid points as run)
ARMS = {
    "touch": (HERE / "study2-sweep", "study2.yaml",
              ("alike-boxes", "alike-shapes", "distinct-boxes", "distinct-shapes", "distinct-shapes-dusk"),
              ("length=1", "length=16")),
    "drop-out": (HERE / "study2-dropout-sweep", "study2-dropout.yaml", ("alike-shapes", "distinct-shapes-dropout"),
                 ("length=1", "length=16")),
    "faithful": (HERE / "study2-faithful-sweep", "study2-faithful.yaml", WORLDS, ("length=1",)),
}
#: grid point -> how its evaluations match
MATCHING = {"length=1": "single", "length=16": "seq. 16"}
#: the second study's methods and fusions (the drop-out arm has no A: it cannot describe a sample without a camera)
METHODS2 = ("L", "L-V", "L-T", "L-cycle", "A", "H", "H-V", "H-T", "L-F", "H-F")
LEARNED = ("L", "L-V", "L-T", "L-cycle")
#: second study: "arm/point" -> its summaries' folder
POINTS = {f"{arm}/{point}": folder / point for arm, (folder, _, _, points) in ARMS.items() for point in points}
BUDGET2 = HERE / "study2-budget"
BUDGET_EPOCHS = (30, 70, 270)
#: the second study's budget trend: "budget/epochs=E" -> its summaries' folder (seed 0 only)
BUDGET_POINTS = {f"budget/epochs={e}": BUDGET2 / f"epochs={e}" for e in BUDGET_EPOCHS}
#: the third study's arms (the design change's sizes) -> (sweep summaries by matching, evaluations, methods)
ARMS3 = {
    "station": ({"single": HERE / "study3-sweep" / "metres=0", "seq. 2.8 m": HERE / "study3-sequences" / "metres=2.8"},
                ("alike-shapes", "crossed-opposite", "dusk", "fog", "night"),
                ("L", "L-V", "L-T", "L-paper", "A", "H", "H-V", "H-T", "HOG", "VLAD",
                 "L-F", "H-F", "HOG-F", "VLAD-F")),
    "faithful": ({"single": HERE / "study3-faithful-sweep"}, WORLDS, ("L", "H", "H-V", "H-T", "H-F")),
    "drop-out": ({"single": HERE / "study3-dropout-sweep"}, ("alike-shapes", "dropout"),
                 ("L", "H", "H-V", "H-T", "H-F")),
}
#: third study: "arm/matching" -> its summaries' folder
POINTS3 = {f"{arm}/{matching}": folder
           for arm, (folders, _, _) in ARMS3.items() for matching, folder in folders.items()}
#: the sequence rerun's single-sample point (docs/RESULTS.md, the third study's correction of
#: the sequence scores): the registered station sweep run again, beside its sequence point
SEQUENCE_RERUN3 = HERE / "study3-sequences" / "metres=0"
SURVIVAL_EPOCHS = (70, 3000)
#: the survival comparison: "survival/epochs=E" -> its summaries' folder
SURVIVAL_POINTS = {f"survival/epochs={e}": HERE / "study3-survival" / f"epochs={e}" for e in SURVIVAL_EPOCHS}
#: the survival comparison's 70-epoch half as first run, on the first machine (docs/RESULTS.md,
#: "Third study: results"): the same command and simulated runs as "survival/epochs=70"
FIRST_MACHINE3 = {"survival/first-machine": HERE / "study3-survival" / "first-machine" / "epochs=70"}
#: every summaries' folder tables read from: the first study's by touch model, the second's and
#: the third's by arm/point
SUMMARIES = {**STUDIES, **POINTS, **BUDGET_POINTS, **POINTS3, **SURVIVAL_POINTS, **FIRST_MACHINE3}


def read_csv(path: Path) -> list[dict[str, str]]:
    """The rows of a committed CSV summary, or of its gzipped copy ``path.gz`` (the large
    per-seed tables are committed compressed)."""
    if path.exists():
        with open(path, newline="") as handle:
            return list(csv.DictReader(handle))
    with gzip.open(path.with_name(path.name + ".gz"), "rt", newline="") as handle:
        return list(csv.DictReader(handle))


@functools.cache  # each file is read once, however many tables use it (callers do not mutate rows)
def read(study: str, name: str) -> list[dict[str, str]]:
    return read_csv(SUMMARIES[study] / name)


def _index(rows: Iterable[dict[str, str]], *keys: str) -> dict[tuple[str, ...], dict[str, str]]:
    return {tuple(row[k] for k in keys): row for row in rows}


def pct(value: str | float) -> str:
    return f"{100 * float(value):.1f}"


def pct_interval(row: dict[str, str], name: str = "boot") -> str:
    return f"[{pct(row[f'{name}_low'])}, {pct(row[f'{name}_high'])}]"


def p_value(p: str | float) -> str:
    return f"{float(p):.3f}"


def markdown(header: Sequence[str], body: Iterable[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return "\n".join(lines)


def difficulty() -> str:
    """Each world's drive pair, query to reference: mean over seeds (min-max)."""
    measures = [("difficulty.nearest_ref_median_m", "nearest ref. median, cm", 100, 1),
                ("difficulty.nearest_ref_p90_m", "nearest ref. 90th pct., cm", 100, 1),
                ("difficulty.nearest_ref_heading_median_deg", "heading to it, median °", 1, 1),
                ("difficulty.chance_r1", "chance R@1, %", 100, 1),
                ("difficulty.query_touch_share", "query touch, %", 100, 1),
                ("difficulty.reference_touch_share", "reference touch, %", 100, 1)]
    body = []
    for study in STUDIES:
        rows = _index(read(study, "sweep.csv"), "environment", "method", "direction", "metric")
        for world in WORLDS:
            cells = [world, study]
            for metric, _, scale, digits in measures:
                r = rows[(world, "L", Q2R, metric)]
                cells.append(f"{scale * float(r['mean']):.{digits}f} "
                             f"({scale * float(r['min']):.{digits}f}–{scale * float(r['max']):.{digits}f})")
            body.append([*cells, PAPER[world]])
    return markdown(["world", "touch model", *(label for _, label, _, _ in measures), "paper (L vs H)"], body)


def six_methods(study: str) -> str:
    """Max F1 of the six methods, mean [bootstrap 95 %] over seeds, both directions."""
    rows = _index(read(study, "sweep.csv"), "environment", "method", "direction", "metric")
    body = []
    for direction, arrow in DIRECTIONS.items():
        for method in METHODS:
            cells = []
            for world in WORLDS:
                r = rows[(world, method, direction, "max_f1")]
                cells.append(f"{pct(r['mean'])} {pct_interval(r)}")
            body.append([method, arrow, *cells])
    n = rows[("E1", "L", Q2R, "max_f1")]["n"]
    return markdown(["method", "direction", *(f"{w} max F1 % (n={n})" for w in WORLDS)], body)


def _difference(study: str, world: str, direction: str, a: str, b: str, metric: str = "max_f1") -> dict[str, str]:
    rows = _index(read(study, "sweep-diff.csv"), "environment", "direction", "metric", "method_a", "method_b")
    if (world, direction, metric, a, b) in rows:
        return rows[(world, direction, metric, a, b)]
    flipped = dict(rows[(world, direction, metric, b, a)])  # the file holds each pair once
    for name in ("mean", "min", "max"):
        flipped[name] = str(-float(flipped[name]))
    flipped["min"], flipped["max"] = flipped["max"], flipped["min"]
    for name in ("t", "boot", "block"):
        flipped[f"{name}_low"], flipped[f"{name}_high"] = (str(-float(flipped[f"{name}_high"])),
                                                           str(-float(flipped[f"{name}_low"])))
    return flipped


def _difference_cells(r: dict[str, str]) -> list[str]:
    return [f"{pct(r['mean'])} ± {pct(r['std'])}", pct_interval(r, "t"), pct_interval(r, "boot"),
            pct_interval(r, "block"), p_value(r["p_sign_flip"])]


DIFFERENCE_HEADER = ["mean ± std, points", "t 95 %", "bootstrap 95 %", "block 95 %", "sign-flip p"]


def primary() -> str:
    """E3 max F1, L - H: the pre-registered endpoint (first row) and its secondary variants."""
    body = []
    for study, direction, role in (("penetration", Q2R, "**primary**"), ("penetration", R2Q, "secondary"),
                                   ("physical", Q2R, "secondary"), ("physical", R2Q, "secondary")):
        r = _difference(study, "E3", direction, "L", "H")
        body.append([role, study, DIRECTIONS[direction], r["n"], *_difference_cells(r)])
    return markdown(["endpoint", "touch model", "direction", "n", *DIFFERENCE_HEADER], body)


@functools.cache
def _means(study: str) -> dict[tuple[str, str, str], float]:
    rows = read(study, "sweep.csv")
    return {(r["environment"], r["method"], r["direction"]): float(r["mean"]) for r in rows if r["metric"] == "max_f1"}


def _best_cells(study: str, world: str, direction: str, methods: Sequence[str]) -> list[str]:
    """The method of ``methods`` with the highest mean max F1 in one cell, the runner-up, and
    their paired difference [bootstrap 95 %] with its sign-flip p."""
    means = _means(study)
    first, second = sorted(methods, key=lambda m: -means[(world, m, direction)])[:2]
    r = _difference(study, world, direction, first, second)
    return [f"{first} ({pct(means[(world, first, direction)])})",
            f"{second} ({pct(means[(world, second, direction)])})",
            f"{pct(r['mean'])} {pct_interval(r)}", p_value(r["p_sign_flip"])]


BEST_HEADER = ["best (mean max F1 %)", "runner-up", "best − runner-up, points [bootstrap 95 %]", "sign-flip p"]


def best() -> str:
    """Per world, direction and touch model: the method with the highest mean max F1, the
    runner-up, and their paired difference."""
    body = [[world, study, arrow, *_best_cells(study, world, direction, METHODS)]
            for study in STUDIES for world in WORLDS for direction, arrow in DIRECTIONS.items()]
    return markdown(["world", "touch model", "direction", *BEST_HEADER], body)


def overall() -> str:
    """Each method's mean max F1 over the three worlds and both directions (a ranking only;
    the per-world differences above carry the intervals)."""
    body = []
    for study in STUDIES:
        means = _means(study)
        average = {m: sum(means[(w, m, d)] for w in WORLDS for d in DIRECTIONS) / (len(WORLDS) * len(DIRECTIONS))
                   for m in METHODS}
        ranked = sorted(METHODS, key=lambda m: -average[m])
        body.append([study, *(f"{m} {pct(average[m])}" for m in ranked)])
    return markdown(["touch model", *(f"rank {i}" for i in range(1, len(METHODS) + 1))], body)


def pairs(comparisons: Sequence[tuple[str, str]]) -> Callable[[], str]:
    def table() -> str:
        body = []
        for study in STUDIES:
            for a, b in comparisons:
                for world in WORLDS:
                    r = _difference(study, world, Q2R, a, b)
                    body.append([f"{a} − {b}", study, world, *_difference_cells(r)])
        return markdown(["difference (q→r)", "touch model", "world", *DIFFERENCE_HEADER], body)
    table.__doc__ = "Paired max-F1 differences, query to reference: " + ", ".join(f"{a} - {b}" for a, b in comparisons)
    return table


@functools.cache  # callers do not mutate it
def _per_seed(study: str, metric: str = "max_f1") -> dict[tuple[str, str, str], dict[int, float]]:
    """``{(world, method, direction): {seed: value}}`` of ``metric`` from ``sweep-seeds.csv``."""
    values: dict[tuple[str, str, str], dict[int, float]] = {}
    for r in read(study, "sweep-seeds.csv"):
        if r["metric"] == metric:
            values.setdefault((r["environment"], r["method"], r["direction"]), {})[int(r["seed"])] = float(r["value"])
    return values


def interaction(study: str, world: str, direction: str) -> tuple[list[float], dict[str, float], float]:
    """What touch costs L less than H, (L - L-V) - (H - H-V), max F1, per seed from
    ``sweep-seeds.csv`` (the summaries hold no paired statistics of it): the per-seed values
    (`hypotheses.interaction`), their `describe` (mean, std, t and bootstrap intervals; no
    block interval, the block replicates are not committed) and their sign-flip p."""
    values = _per_seed(study)
    d = list(hypotheses.interaction(*(values[(world, m, direction)] for m in ("L", "L-V", "H", "H-V"))).values())
    return (d, *paired(d, INTERACTION_LIMITS))


def _paired_cell(r: dict[str, str], p: str | float) -> str:
    return f"{pct(r['mean'])} {pct_interval(r)}, t {pct_interval(r, 't')}, p={p_value(p)}"


def _decomposition_cells(study: str, world: str, direction: str) -> list[str]:
    """L - H, L-V - H-V (both from ``sweep-diff.csv``) and the interaction (`interaction`) of one cell."""
    cells = []
    for a, b in (("L", "H"), ("L-V", "H-V")):
        r = _difference(study, world, direction, a, b)
        cells.append(_paired_cell(r, r["p_sign_flip"]))
    _, stats, p = interaction(study, world, direction)
    return [*cells, _paired_cell({k: str(v) for k, v in stats.items()}, p)]


DECOMPOSITION_HEADER = ["L − H, points", "= L-V − H-V (vision)", "+ (L − L-V) − (H − H-V) (touch)"]


def decomposition() -> str:
    """L - H = (L-V - H-V) + [(L - L-V) - (H - H-V)], max F1, per world, direction and touch
    model: what vision contributes and what touch costs L less than H (negative: more). Each
    term's mean over seeds [bootstrap 95 %], its t 95 % interval and sign-flip p; the first
    two from ``sweep-diff.csv``, the third computed per seed (`interaction`). The means add
    up exactly; their rounded values may differ by 0.1."""
    body = [[world, study, arrow, *_decomposition_cells(study, world, direction)]
            for study in STUDIES for direction, arrow in DIRECTIONS.items() for world in WORLDS]
    return markdown(["world", "touch model", "direction", *DECOMPOSITION_HEADER], body)


def transfer() -> str:
    """Max F1 against the F1 at the threshold that maximises F1 on E1 (the same method's E1
    evaluation), E2 and E3, query to reference, penetration: does E1's threshold carry over?"""
    rows = _index(read("penetration", "sweep.csv"), "environment", "method", "direction", "metric")
    body = []
    for method in METHODS:
        cells = [method]
        for world in ("E2", "E3"):
            best_f1 = rows[(world, method, Q2R, "max_f1")]
            at_e1 = rows[(world, method, Q2R, "f1_at_e1_threshold")]
            cells += [f"{pct(best_f1['mean'])}", f"{pct(at_e1['mean'])} {pct_interval(at_e1)}"]
        body.append(cells)
    return markdown(["method", "E2 max F1 %", "E2 F1 at E1's threshold %", "E3 max F1 %", "E3 F1 at E1's threshold %"],
                    body)


def transfer_differences() -> str:
    """Paired differences of the F1 at E1's threshold, query to reference, both touch models."""
    body = []
    for study in STUDIES:
        for a, b in (("L", "H"), ("L", "H-V"), ("L-V", "H-V")):
            for world in ("E2", "E3"):
                r = _difference(study, world, Q2R, a, b, "f1_at_e1_threshold")
                body.append([f"{a} − {b}", study, world, *_difference_cells(r)])
    return markdown(["F1 at E1's threshold (q→r)", "touch model", "world", *DIFFERENCE_HEADER], body)


def recall_at_full_precision() -> str:
    """Recall at 100 % precision (the share of revisits found before the first false match),
    query to reference, both touch models."""
    body = []
    for study in STUDIES:
        rows = _index(read(study, "sweep.csv"), "environment", "method", "direction", "metric")
        for method in METHODS:
            body.append([method, study, *(f"{pct(r['mean'])} {pct_interval(r)}" for r in
                                          (rows[(w, method, Q2R, "recall_at_100_precision")] for w in WORLDS))])
    return markdown(["method", "touch model", *(f"{w} R at 100 % P, %" for w in WORLDS)], body)


def sensitivity() -> str:
    """L - H and L - H-V max F1 under other ground truths (revisit tolerance tau, with and
    without the 30 degree heading tolerance), query to reference, rescored from the saved
    matrices: mean [bootstrap 95 %] over seeds and the sign-flip p."""
    body = []
    for study in STUDIES:
        values: dict[tuple[str, str, str, str], dict[int, float]] = {}
        for r in read(study, "sensitivity.csv"):
            if r["direction"] == Q2R:
                key = (r["environment"], r["method"], r["tau"], r["heading_tolerance_deg"] or "none")
                values.setdefault(key, {})[int(r["seed"])] = float(r["max_f1"])
        settings = sorted({(k[2], k[3]) for k in values}, key=lambda s: (s[1] == "none", float(s[0])))
        for tau, heading in settings:
            cells = [study, f"{float(tau):g}", "position only" if heading == "none" else f"{float(heading):g}°"]
            for world in WORLDS:
                for b in ("H", "H-V"):
                    d = versus_best(values[(world, "L", tau, heading)], [values[(world, b, tau, heading)]])
                    stats, p = paired(list(d.values()))
                    cells.append(f"{pct(stats['mean'])} [{pct(stats['boot_low'])}, {pct(stats['boot_high'])}] "
                                 f"p={p_value(p)}")
            body.append(cells)
    header = ["touch model", "τ, m", "heading"] + [f"{w}: L − {b}, points" for w in WORLDS for b in ("H", "H-V")]
    return markdown(header, body)


#: a drive that stays this many samples within 0.25 m is stuck (the pipeline warns from a
#: quarter of a run, 150 of these 600 samples)
STALL_SAMPLES = 100


def _longest_stay(rows: dict[tuple[str, ...], dict[str, str]], seed: str, world: str, drive: str) -> int:
    """Samples of the longest stay of ``drive`` ("query" or "reference") in ``world`` at ``seed``."""
    key = (seed, world, "L", "query-to-reference")
    count = "n_queries" if drive == "query" else "n_references"
    share = float(rows[(*key, f"difficulty.{drive}_longest_stay_share")]["value"])
    return round(share * float(rows[(*key, count)]["value"]))


def stalls() -> str:
    """Per world and touch model: how many of the 12 evaluation drives (6 seeds x query and
    reference) stay within 0.25 m for at least `STALL_SAMPLES` consecutive samples, and the
    longest stay: each evaluation's ``difficulty.query_longest_stay_share`` and
    ``difficulty.reference_longest_stay_share`` (``sweep-seeds.csv``, method L, query to
    reference; the drives are the same for every method) times its sample counts."""
    body = []
    for study in STUDIES:
        rows = _index(read(study, "sweep-seeds.csv"), "seed", "environment", "method", "direction", "metric")
        for world in WORLDS:
            seeds = sorted({key[0] for key in rows}, key=int)
            stays = [(_longest_stay(rows, seed, world, drive), seed, drive)
                     for seed in seeds for drive in ("query", "reference")]
            stuck = sorted((s for s in stays if s[0] >= STALL_SAMPLES), key=lambda s: (int(s[1]), s[2]))
            body.append([world, study, f"{len(stuck)} of {len(stays)}", str(max(s[0] for s in stays)),
                         ", ".join(f"{seed}{drive[0]} ({n})" for n, seed, drive in stuck) or "–"])
    return markdown(["world", "touch model", f"drives stuck ≥ {STALL_SAMPLES} samples", "longest stay, samples",
                     "stuck drives: seed, q/r (samples)"], body)


def budget() -> str:
    """The learned methods' budget as run, from each seed's manifest.json: epochs trained (of
    the cap; converged seeds: the training energy improved by less than 1 % over 20 epochs)
    and the share of test samples whose inference stopped at the step cap."""
    body = []
    for study, folder in STUDIES.items():
        manifests = [json.loads(path.read_text()) for path in sorted(folder.glob("seeds/seed-*/manifest.json"))]
        for method in ("L", "L-V", "L-T"):
            epochs = [m["training"][method]["epochs"] for m in manifests]
            cap = {m["training"][method]["max_epochs"] for m in manifests}
            converged = sum(bool(m["training"][method]["converged"]) for m in manifests)
            runs = [run["inference"] for m in manifests for run in m["features"][method].values()]
            capped, samples = sum(r["capped"] for r in runs), sum(r["samples"] for r in runs)
            body.append([method, study, str(len(manifests)),
                         f"{min(epochs)}–{max(epochs)} of {'/'.join(map(str, cap))}",
                         f"{converged} of {len(manifests)}", f"{100 * capped / samples:.1f} ({capped} of {samples})"])
    return markdown(["method", "touch model", "seeds", "epochs trained", "converged",
                     "test samples at the step cap, %"],
                    body)


def warnings() -> str:
    """Every warning in each seed's manifest.json (``warnings``: run -> check -> message; the
    same lines are under Warnings in its report.md)."""
    body = []
    for study, folder in STUDIES.items():
        found = []
        for path in sorted(folder.glob("seeds/seed-*/manifest.json"), key=lambda p: int(p.parent.name.split("-")[1])):
            for run, checks in json.loads(path.read_text())["warnings"].items():
                for check, message in checks.items():
                    found.append([study, path.parent.name.split("-")[1], run, f"`{check}`", message])
        body += found or [[study, "–", "–", "–", "none"]]
    return markdown(["touch model", "seed", "run", "check", "warning"], body)


# ---------------------------------------------------------------------------------------------
# The second study (RESULTS.md, "Second study"): three arms, each a sweep with one folder per
# grid point (``length=1``: single samples, ``length=16``: sequences of 16), summaries keyed
# "arm/point" in `POINTS`; seed 0's validity gates from `vitaplace difficulty` (study2-difficulty/),
# the budget trend from study2-budget/epochs=E/.

DIFFICULTY2 = HERE / "study2-difficulty"


def methods_of(arm: str) -> tuple[str, ...]:
    return tuple(m for m in METHODS2 if not (arm == "drop-out" and m == "A"))


def cells2(points: Iterable[str] = tuple(POINTS)) -> list[tuple[str, str, str]]:
    """Every (arm/point, evaluation, direction) cell of the second study, in arm, point,
    evaluation, direction order."""
    return [(key, world, direction)
            for key in points for world in ARMS[key.split("/")[0]][2] for direction in DIRECTIONS]


@functools.cache  # each manifest is read once (callers do not mutate them)
def _seed_manifests(arm: str) -> dict[int, dict]:
    """Seed -> the single-sample point's manifest.json of that seed (the features, inference
    and training of a seed are those of every grid point)."""
    folder = ARMS[arm][0] / "length=1" / "seeds"
    return {int(path.parent.name.split("-")[1]): json.loads(path.read_text())
            for path in folder.glob("seed-*/manifest.json")}


#: (label, arm/point, evaluation, direction, minuend, comparators): the minuend (L) minus the
#: per-seed best of the comparators
Endpoints = Sequence[tuple[str, str, str, str, str | tuple[str, ...], tuple[str, ...]]]
ENDPOINTS: Endpoints = (
    ("**primary**", "touch/length=1", "alike-shapes", Q2R, "L", ("L-V", "L-F")),
    ("1", "touch/length=1", "alike-shapes", R2Q, "L", ("L-V", "L-F")),
    ("2", "touch/length=1", "distinct-shapes-dusk", Q2R, "L", ("L-V", "L-F")),
    ("3", "drop-out/length=1", "distinct-shapes-dropout", Q2R, "L", ("L-V", "L-F")),
    ("4", "touch/length=16", "alike-shapes", Q2R, "L", ("L-V", "L-F")),
    ("5", "touch/length=1", "alike-shapes", Q2R, "L", ("A",)),
    ("6", "faithful/length=1", "E3", Q2R, "L", ("H",)),
)


def best_by_mean(key: str, world: str, direction: str, methods: Sequence[str]) -> str:
    """The one of ``methods`` with the highest mean max F1 over seeds in a cell (the first named on a tie)."""
    values = _per_seed(key)
    return max(methods, key=lambda m: statistics.fmean(values[(world, m, direction)].values()))


def endpoint_values(key: str, world: str, direction: str, minuend: str | tuple[str, ...],
                    comparators: Sequence[str]) -> tuple[str, dict[int, float]]:
    """The comparison's name and, per seed, ``minuend`` minus the best of ``comparators`` in
    that seed, max F1 (`_per_seed`, `versus_best`). A tuple ``minuend`` is a family: its best
    method by mean over seeds (`best_by_mean`) minus the comparators' best by mean."""
    values = _per_seed(key)
    if isinstance(minuend, tuple):
        minuend, comparators = (best_by_mean(key, world, direction, family) for family in (minuend, comparators))
        comparators = (comparators,)
    name = f"{minuend} − {comparators[0]}" if len(comparators) == 1 else f"{minuend} − max({', '.join(comparators)})"
    return name, versus_best(values[(world, minuend, direction)], [values[(world, m, direction)] for m in comparators])


def endpoints(spec: Endpoints = ENDPOINTS) -> list[dict]:
    """The primary endpoint and the secondaries of ``spec``, each with its comparison, per-seed
    values, `describe`, sign-flip p, Holm-adjusted p (over the secondaries; the primary keeps
    its own), 90 % t interval and decision (`hypotheses.endpoint_tests`)."""
    compared = [endpoint_values(key, world, direction, minuend, comparators)
                for _, key, world, direction, minuend, comparators in spec]
    tested = endpoint_tests(list(compared[0][1].values()), [list(v.values()) for _, v in compared[1:]])
    return [{"label": label, "key": key, "world": world, "direction": direction, "comparison": comparison,
             **dataclasses.asdict(endpoint)}
            for (label, key, world, direction, _, _), (comparison, _), endpoint in zip(spec, compared, tested,
                                                                                       strict=True)]


def endpoints_table(spec: Endpoints, matching: Mapping[str, str]) -> str:
    """The endpoints of ``spec`` (max F1, points): n, mean ± std, bootstrap 95 %, the sign-flip
    p and its Holm adjustment over the secondaries, the TOST's 90 % t interval against ±5
    points, and the pre-registered decision."""
    body = []
    for e in endpoints(spec):
        arm, point = e["key"].split("/")
        s = e["stats"]
        body.append([e["label"], e["comparison"], arm, e["world"], DIRECTIONS[e["direction"]], matching[point],
                     str(s["n"]), f"{pct(s['mean'])} ± {pct(s['std'])}",
                     f"[{pct(s['boot_low'])}, {pct(s['boot_high'])}]",
                     p_value(e["p"]), p_value(e["p_holm"]), f"[{pct(e['tost'][0])}, {pct(e['tost'][1])}]",
                     e["decision"]])
    return markdown(["endpoint", "comparison", "arm", "evaluation", "direction", "matching", "n", "mean ± std, points",
                     "bootstrap 95 %", "sign-flip p", "Holm p", "t 90 % (TOST ±5)", "decision"], body)


def study2_endpoints() -> str:
    """The second study's primary endpoint and its six secondaries (`endpoints_table`)."""
    return endpoints_table(ENDPOINTS, MATCHING)


def study2_comparator() -> str:
    """The primary's comparator per seed: L-V's and L-F's max F1 in alike-shapes, query to
    reference, single samples, the fusion weight w chosen there, the better of the two, and L
    minus it."""
    values, weights = _per_seed("touch/length=1"), _per_seed("touch/length=1", "fusion.weight")
    cell = ("alike-shapes", Q2R)
    body = []
    for seed, d in endpoint_values("touch/length=1", *cell, "L", ("L-V", "L-F"))[1].items():
        lv, lf, l_value = (values[(cell[0], m, cell[1])][seed] for m in ("L-V", "L-F", "L"))
        body.append([str(seed), pct(l_value), pct(lv), pct(lf), f"{weights[(cell[0], 'L-F', cell[1])][seed]:g}",
                     "L-F" if lf > lv else ("L-V = L-F" if lf == lv else "L-V"), pct(d)])
    return markdown(["seed", "L max F1 %", "L-V", "L-F", "w", "comparator", "L − comparator, points"], body)


def seed_difficulty_rows(scenario: Scenario, folder: Path) -> list[dict]:
    """`difficulty_rows` of one seed's run folder: its results and complementarity, as
    `vitaplace difficulty` would report them."""
    from vitaplace.engine.cli.difficulty import difficulty_rows
    from vitaplace.engine.outputs.rows import parse_row

    results = folder / "results.json"
    parsed = [parse_row(row, f"{results}: row {i}") for i, row in enumerate(json.loads(results.read_text()))]
    return difficulty_rows(scenario, parsed, json.loads((folder / "complementarity.json").read_text()))


@functools.cache
def _gate_rows(arm: str) -> dict[int, list[dict]]:
    """Seed -> `difficulty_rows` of that seed: seed 0 from the committed `vitaplace difficulty`
    run, the others from the sweep's own H-family evaluations (the same measures; the test
    checks that seed 0's agree)."""
    from vitaplace.engine.config.loading import load_scenario

    scenario, _ = load_scenario(HERE.parents[1] / "scenarios" / ARMS[arm][1])
    seeds = ARMS[arm][0] / "length=1" / "seeds"
    rows = {}
    for folder in sorted(seeds.glob("seed-*"), key=lambda f: int(f.name.split("-")[1])):
        seed = int(folder.name.split("-")[1])
        difficulty_json = DIFFICULTY2 / f"{ARMS[arm][1].removesuffix('.yaml')}-seed-{seed}.json"
        if difficulty_json.exists():
            rows[seed] = json.loads(difficulty_json.read_text())
        else:
            rows[seed] = seed_difficulty_rows(scenario, folder)
    return rows


def _gate_cell(results: list[dict], scale: float = 100) -> str:
    """Median (min–max) of a gated measure over seeds and in how many seeds its gate is met."""
    values = [r["value"] for r in results if r["value"] is not None]
    if not values:
        return "none"
    cell = f"{scale * statistics.median(values):.1f} ({scale * min(values):.1f}–{scale * max(values):.1f})"
    if results[0]["gate"] is None:
        return f"{cell}, no gate"
    return f"{cell}, met {sum(bool(r['met']) for r in results)} of {len(results)}"


def study2_gates() -> str:
    """The validity gates of the two touch arms per evaluation and direction, over the eight
    seeds: touch correspondence (gate >= 70 %), H-T's rescues of H-V's recall@1 failures
    (summed over seeds; the share's median (min–max), gate >= 25 %) beside the chance
    recall@1, and H-V's max F1 (gate <= 85 % where declared), each with the number of seeds
    that meet it."""
    body = []
    for arm in ("touch", "drop-out"):
        per_seed = _gate_rows(arm)
        for world in ARMS[arm][2]:
            for direction, arrow in DIRECTIONS.items():
                rows = [next(r for r in seed_rows if (r["environment"], r["direction"]) == (world, direction))
                        for seed_rows in per_seed.values()]
                rescued = sum(r["complementarity"]["rescued"] for r in rows)
                wrong = sum(r["complementarity"]["vision_wrong"] for r in rows)
                chance = statistics.median(r["difficulty"]["chance_r1"] for r in rows)
                body.append([arm, world, arrow, str(len(rows)),
                             _gate_cell([r["gates"]["touch_correspondence_min"] for r in rows]),
                             f"{rescued} of {wrong}; {_gate_cell([r['gates']['rescue_min'] for r in rows])}",
                             pct(chance), _gate_cell([r["gates"]["hv_max_f1_max"] for r in rows])])
    return markdown(["arm", "evaluation", "direction", "seeds", "touch correspondence %",
                     "H-T rescues of H-V's failures, %",
                     "chance R@1 %", "H-V max F1 %"], body)


#: the third study's gate calibration (docs/RESULTS.md, "Third study: calibration"): per arm (and
#: redesign) the folder of its `vitaplace difficulty --json` outputs, one ``seed-N.json`` per
#: calibration seed, and the conditions the table shows from it (None: all; a redesign's
#: folder repeats the unchanged conditions, cached, and shows only the redesigned one)
CALIBRATION3: dict[str, tuple[Path, tuple[str, ...] | None]] = {
    "station": (HERE / "study3-calibration" / "station", None),
    "station, redesign 1": (HERE / "study3-calibration" / "station-crossed", ("crossed-pairs",)),
    "station, redesign 2": (HERE / "study3-calibration" / "station-crossed-clear", ("crossed-clear",)),
    "station, redesign 3": (HERE / "study3-calibration" / "station-crossed-edges", ("crossed-edges",)),
    "station, redesign 4": (HERE / "study3-calibration" / "station-crossed-horizon", ("crossed-horizon",)),
    "station, redesign 5": (HERE / "study3-calibration" / "station-crossed-opposite", ("crossed-opposite",)),
    "drop-out": (HERE / "study3-calibration" / "dropout", None),
}
#: the gates in the order the table prints them
GATES3 = ("touch_correspondence_min", "hv_max_f1_max", "rescue_min", "headroom_min")
#: a condition has headroom when all four gates are met, query -> reference, in this many of 8 seeds
HEADROOM_SEEDS = 7


def calibration3(arm: str) -> dict[int, list[dict]]:
    """Seed -> the `vitaplace difficulty` rows of one arm's calibration seed."""
    files = sorted(CALIBRATION3[arm][0].glob("seed-*.json"), key=lambda f: int(f.stem.split("-")[1]))
    return {int(f.stem.split("-")[1]): json.loads(f.read_text()) for f in files}


def all_gates_met(rows: Sequence[dict]) -> int:
    """In how many of ``rows`` (one evaluation and direction, one row per seed) every gate of
    `GATES3` is met."""
    return sum(all(r["gates"][g]["met"] for g in GATES3) for r in rows)


GATE_TABLE_HEADER = ["arm", "condition", "direction", "seeds", "touch correspondence %", "H-V max F1 %",
                     "H-T rescues of H-V's failures, %", "headroom, points", "all four met", "has headroom"]


def _gate_table_rows(arm: str, per_seed: Mapping[int, list[dict]], shown: Sequence[str] | None) -> list[list[str]]:
    """One arm's rows of a gate table: per condition (those in ``shown``, or all) and
    direction, each gated measure's median (min–max) and the seeds meeting it, the seeds
    meeting all four, and (query → reference) whether the condition has headroom (the
    calibration's rule, for its eight seeds)."""
    body = []
    conditions = dict.fromkeys(r["environment"] for rows in per_seed.values() for r in rows)
    for condition in (c for c in conditions if shown is None or c in shown):
        for direction, arrow in DIRECTIONS.items():
            rows = [next(r for r in seed_rows if (r["environment"], r["direction"]) == (condition, direction))
                    for seed_rows in per_seed.values()]
            met = all_gates_met(rows)
            verdict = ("yes" if met >= HEADROOM_SEEDS else "no") if direction == Q2R else "–"
            body.append([arm, condition, arrow, str(len(rows)),
                         *(_gate_cell([r["gates"][g] for r in rows]) for g in GATES3),
                         f"{met} of {len(rows)}", verdict])
    return body


def study3_calibration_gates() -> str:
    """The third study's gates over its calibration seeds, per arm, condition and direction
    (`_gate_table_rows`): a condition has headroom when all four are met in >= 7 of 8 seeds."""
    body = [row for arm, (_, shown) in CALIBRATION3.items() for row in _gate_table_rows(arm, calibration3(arm), shown)]
    return markdown(GATE_TABLE_HEADER, body)


#: the third study's calibration of the fusion weights: `vitaplace sweep scenarios/study3-weights.yaml`
#: over the calibration seeds (its summary ``sweep.csv``), each fusion at each grid weight as a
#: method ``NAME-w``
WEIGHTS3 = HERE / "study3-weights"
FUSIONS3 = ("L-F", "H-F", "HOG-F", "VLAD-F")
GRID3 = ("0", "0.03", "0.1", "0.3", "1", "3")
#: the primary condition the calibration of the gates picked (docs/RESULTS.md, "Third study: calibration")
PRIMARY3 = "crossed-opposite"


def fusion_weights3(summary: Path = WEIGHTS3 / "sweep.csv") -> dict[str, dict[str, float]]:
    """Fusion -> grid weight -> max F1 in the primary condition: the mean over the calibration
    seeds, averaged over the two directions."""
    means = {(r["method"], r["direction"]): float(r["mean"]) for r in read_csv(summary)
             if r["environment"] == PRIMARY3 and r["metric"] == "max_f1"}
    return {fusion: {w: (means[(f"{fusion}-{w}", Q2R)] + means[(f"{fusion}-{w}", R2Q)]) / 2 for w in GRID3}
            for fusion in FUSIONS3}


def chosen_weights3(scores: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """Per fusion the grid weight of the highest score (`fusion_weights3`), ties to the smaller."""
    chosen = {}
    for fusion, by_weight in scores.items():
        best = max(by_weight.values())
        chosen[fusion] = min(float(w) for w, score in by_weight.items() if score == best)
    return chosen


def study3_weights() -> str:
    """Max F1 % of every fusion at every grid weight in the primary condition (mean over the
    calibration seeds, averaged over both directions) and the weight the study fixes."""
    scores = fusion_weights3()
    chosen = chosen_weights3(scores)
    body = [[fusion, *(f"{100 * scores[fusion][w]:.1f}" for w in GRID3), f"{chosen[fusion]:g}"] for fusion in FUSIONS3]
    return markdown(["fusion", *(f"w = {w}" for w in GRID3), "fixed w"], body)


#: the third study's families for secondary 4: the best touch-using method minus the best vision-only one
TOUCH_USING3 = ("L", "L-paper", "A", "L-F", "H", "H-F", "HOG-F", "VLAD-F")
VISION_ONLY3 = ("L-V", "H-V", "HOG", "VLAD")
#: the third study's primary endpoint and secondaries as registered (numbered as registered;
#: secondary 2 has no member: no condition but the primary has headroom, and 3 has two)
ENDPOINTS3: Endpoints = (
    ("**primary**", "station/single", PRIMARY3, Q2R, "L", ("L-V", "L-F")),
    ("1", "station/single", PRIMARY3, R2Q, "L", ("L-V", "L-F")),
    ("3", "station/single", PRIMARY3, Q2R, "L", ("H",)),
    ("3", "faithful/single", "E3", Q2R, "L", ("H",)),
    ("4", "station/single", PRIMARY3, Q2R, TOUCH_USING3, VISION_ONLY3),
    ("5", "station/single", PRIMARY3, Q2R, "L", ("L-paper",)),
    ("6", "station/single", PRIMARY3, Q2R, "L", ("A",)),
    ("7", "station/seq. 2.8 m", PRIMARY3, Q2R, "L", ("L-V", "L-F")),
)


def study3_endpoints() -> str:
    """The third study's primary endpoint and its secondaries (`endpoints_table`)."""
    return endpoints_table(ENDPOINTS3, {matching: matching for matching in ("single", "seq. 2.8 m")})


def study3_methods(arm: str) -> str:
    """Max F1 %, mean [bootstrap 95 %] over seeds, of every method and fusion of one arm of the
    third study, per direction and matching (columns: its evaluations)."""
    folders, worlds, methods = ARMS3[arm]
    body = []
    for matching in folders:
        rows = _index(read(f"{arm}/{matching}", "sweep.csv"), "environment", "method", "direction", "metric")
        for direction, arrow in DIRECTIONS.items():
            for method in methods:
                body.append([method, arrow, matching, *(f"{pct(r['mean'])} {pct_interval(r)}" for r in
                                                        (rows[(w, method, direction, "max_f1")] for w in worlds))])
    n = _index(read(f"{arm}/single", "sweep.csv"), "environment", "method", "direction", "metric")[
        (worlds[0], "L", Q2R, "max_f1")]["n"]
    return markdown(["method", "direction", "matching", *(f"{w} (n={n})" for w in worlds)], body)


@functools.cache  # each manifest is read once (callers do not mutate them)
def _seed_manifests3(arm: str) -> dict[int, dict]:
    """Seed -> the single-sample point's manifest.json of one arm of the third study."""
    folder = ARMS3[arm][0]["single"] / "seeds"
    return {int(path.parent.name.split("-")[1]): json.loads(path.read_text())
            for path in folder.glob("seed-*/manifest.json")}


def _median_range(values: Sequence[float], scale: float = 100, digits: int = 1) -> str:
    return (f"{scale * statistics.median(values):.{digits}f} "
            f"({scale * min(values):.{digits}f}–{scale * max(values):.{digits}f})")


def study3_learned(arm: str) -> str:
    """Each learned network of one arm of the third study, over its seeds: epochs trained of the
    cap, how many met the criterion, the held-out energy at the last epoch; in the arm's
    primary or degraded evaluation (both drives): the share of test-time samples settled
    before the cap, the share of tactile values inside the training range, and vision's share
    of the drive on the joint latent; median (min–max) over seeds."""
    focus = {"station": PRIMARY3, "faithful": "E3", "drop-out": "dropout"}
    body = []
    manifests = list(_seed_manifests3(arm).values())
    for method in (m for m in ARMS3[arm][2] if m in manifests[0]["training"]):
        trained = [m["training"][method] for m in manifests]
        runs = [m["features"][method][f"{focus[arm]}/{drive}"]
                for m in manifests for drive in ("query", "reference")]
        settled = [(r["inference"]["samples"] - r["inference"]["capped"]) / r["inference"]["samples"]
                   for r in runs if "inference" in r]
        inside = [r["tactile_range"]["inside"] / r["tactile_range"]["values"] for r in runs if "tactile_range" in r]
        drive = [r["drive"]["median"] for r in runs if "drive" in r]
        epochs, caps = [t["epochs"] for t in trained], sorted({t["max_epochs"] for t in trained})
        held_out = [t["held_out"][-1] for t in trained if t.get("held_out")]
        body.append([arm, method, focus[arm], str(len(trained)),
                     f"{min(epochs)}–{max(epochs)} of {'/'.join(str(c) for c in caps)}",
                     f"{sum(bool(t['converged']) for t in trained)} of {len(trained)}",
                     _median_range(held_out, scale=1, digits=3) if held_out else "–",
                     _median_range(settled) if settled else "–", _median_range(inside) if inside else "–",
                     _median_range(drive, digits=2, scale=1) if drive else "–"])
    return markdown(["arm", "method", "evaluation", "seeds", "epochs trained", "met the criterion",
                     "held-out energy, last epoch", "settled %", "tactile values in range %", "vision's drive share"],
                    body)


#: the third study's arms -> their scenario file (the faithful arm's E1-E3 declare no gates)
GATED3 = {"station": "study3.yaml", "faithful": "study3-faithful.yaml", "drop-out": "study3-dropout.yaml"}


def study3_gates(arm: str) -> str:
    """The gates on the study's own seeds of one arm (the hand-crafted family's evaluations in
    its sweep, the measures `vitaplace difficulty` reports), per condition and direction, as
    the calibration table prints them. A condition that declares no gates (the faithful arm's
    E1-E3, the paper's protocol) is measured against the registered ones, the primary's."""
    from vitaplace.engine.config.loading import load_scenario

    scenarios = HERE.parents[1] / "scenarios"
    station, _ = load_scenario(scenarios / GATED3["station"])
    registered = next(e.gates for e in station.evaluations if e.name == PRIMARY3)
    scenario, _ = load_scenario(scenarios / GATED3[arm])
    gated = [e if any(getattr(e.gates, g) is not None for g in GATES3) else e.model_copy(update={"gates": registered})
             for e in scenario.evaluations]
    scenario = scenario.model_copy(update={"evaluations": gated})
    per_seed = {int(folder.name.split("-")[1]): seed_difficulty_rows(scenario, folder)
                for folder in (ARMS3[arm][0]["single"] / "seeds").glob("seed-*")}
    body = [row[:-1] for row in _gate_table_rows(arm, dict(sorted(per_seed.items())), None)]
    return markdown(GATE_TABLE_HEADER[:-1], body)


def study3_survival() -> str:
    """Does the second study's answer survive training? L − L-V, max F1 points, mean [bootstrap
    95 %] and sign-flip p over seeds 0–7, at the second study's 70-epoch cap and at
    convergence (cap 3000), per evaluation and direction, single samples."""
    body = []
    for world in ARMS["touch"][2]:
        for direction, arrow in DIRECTIONS.items():
            cells = []
            for key in SURVIVAL_POINTS:
                r = _difference(key, world, direction, "L", "L-V")
                cells.append(f"{pct(r['mean'])} {pct_interval(r)}, p={p_value(r['p_sign_flip'])}")
            body.append([world, arrow, *cells])
    return markdown(["evaluation", "direction", *(f"L − L-V, {e} epochs" for e in SURVIVAL_EPOCHS)], body)


def study3_survival_training() -> str:
    """The survival comparison's networks per half: epochs trained of the cap and how many met
    the convergence criterion, over seeds 0-7 (each seed's manifest)."""
    body = []
    for key, folder in SURVIVAL_POINTS.items():
        manifests = sorted((folder / "seeds").glob("seed-*/manifest.json"))
        trained = [json.loads(path.read_text())["training"] for path in manifests]
        for method in ("L", "L-V"):
            runs = [t[method] for t in trained]
            epochs = [r["epochs"] for r in runs]
            body.append([key.split("=")[1], method, str(len(runs)),
                         f"{min(epochs)}–{max(epochs)} of {runs[0]['max_epochs']}", f"{statistics.median(epochs):g}",
                         f"{sum(bool(r['converged']) for r in runs)} of {len(runs)}"])
    return markdown(["epoch cap", "method", "seeds", "epochs trained", "median", "met the criterion"], body)


def study3_machines() -> str:
    """What the machine alone moves: the survival comparison's 70-epoch half on the first
    machine and on the second (same command; the simulation and the BLAS kernel differ), per method over every
    condition, direction and seed: the |max F1 difference| (median, largest), the largest
    |mean difference over seeds| of a cell, and the seed-to-seed std of the cells (median)."""
    first, second = _per_seed("survival/first-machine"), _per_seed("survival/epochs=70")
    body = []
    for method in ("L", "L-V"):
        cells = [(w, method, d) for w in ARMS["touch"][2] for d in DIRECTIONS]
        moves = [second[c][seed] - first[c][seed] for c in cells for seed in first[c]]
        cell_means = [statistics.mean(second[c][seed] - first[c][seed] for seed in first[c]) for c in cells]
        spread = [statistics.stdev(second[c].values()) for c in cells]
        body.append([method, str(len(moves)), f"{100 * statistics.median(map(abs, moves)):.1f}",
                     f"{100 * max(map(abs, moves)):.1f}", f"{100 * max(map(abs, cell_means)):.1f}",
                     f"{100 * statistics.median(spread):.1f}"])
    return markdown(["method", "cells × seeds", "size of the move, median", "largest",
                     "largest size of a cell's mean move", "seed-to-seed std, median"], body)


def survival_held() -> bool:
    """The registered reading: in alike-shapes, query → reference, L − L-V at convergence has
    its sign at 70 epochs and its bootstrap interval does not reach 5 points the other way."""
    before, after = (_difference(key, "alike-shapes", Q2R, "L", "L-V") for key in SURVIVAL_POINTS)
    sign = math.copysign(1.0, float(before["mean"]))
    same_sign = math.copysign(1.0, float(after["mean"])) == sign
    far_end = float(after["boot_high"]) if sign < 0 else -float(after["boot_low"])
    return same_sign and far_end < 0.05


def study3_rank(arm: str) -> str:
    """The best method of one arm of the third study, single samples: each method's rank by
    mean max F1 over seeds in each condition (both directions) and over all of them, each with
    its 95 % interval over `RANK_RESAMPLES` resamples of the seeds, paired across methods and
    conditions (`rank_replicates`), and the share of resamples in which it ranks first overall."""
    _, worlds, methods = ARMS3[arm]
    values = _per_seed(f"{arm}/single")
    seeds = sorted(values[(worlds[0], "L", Q2R)])

    def scores(cells: Sequence[tuple[str, str]]) -> dict[str, np.ndarray]:
        return {m: np.array([[values[(w, m, d)][s] for w, d in cells] for s in seeds]) for m in methods}

    points = {w: scores([(w, d) for d in DIRECTIONS]) for w in worlds}
    points["overall"] = scores([(w, d) for w in worlds for d in DIRECTIONS])
    ranks = rank_replicates(points)
    estimate = {key: {m: i + 1 for i, m in enumerate(sorted(methods, key=lambda m: -a[m].mean()))}
                for key, a in points.items()}
    first = {m: float((ranks["overall"][m] == 1).mean()) for m in methods}
    body = [[m, *(f"{estimate[k][m]} {_interval(ranks[k][m])}" for k in points), f"{100 * first[m]:.1f}"]
            for m in sorted(methods, key=lambda m: estimate["overall"][m])]
    return markdown(["method", *(f"{k}, rank [95 %]" for k in points), "first overall, % of resamples"], body)


#: the third study's kernel rerun: `bench/blas_kernel.py`'s ``--json`` rows for the second kernel
KERNEL3 = HERE / "study3-kernel" / "kernels.json"
#: its exploratory complement: Haswell, then Sandybridge on the same simulated runs, one machine
KERNEL3_ALONE = HERE / "study3-kernel" / "same-machine" / "kernels.json"
KERNEL_SEED = 20


def _kernel_moves(before: Callable[[tuple[str, str, str]], float], after: dict[str, float], header: str) -> str:
    """Per station-arm method, the size of the move of max F1 from ``before`` to ``after`` over
    every condition and direction (median, largest, points), beside the median seed-to-seed
    standard deviation of the arm's max F1 in those cells."""
    values = _per_seed("station/single")
    body = []
    for method in ARMS3["station"][2]:
        cells = [(w, method, d) for w in ARMS3["station"][1] for d in DIRECTIONS]
        moves = [abs(after["/".join(cell)] - before(cell)) for cell in cells]
        spread = [statistics.stdev(values[cell].values()) for cell in cells]
        body.append([method, f"{100 * statistics.median(moves):.1f}", f"{100 * max(moves):.1f}",
                     f"{100 * statistics.median(spread):.1f}"])
    return markdown(["method", f"{header}, median", "largest", "seed-to-seed std, median"], body)


def study3_kernel() -> str:
    """Numerical noise as registered: seed 20 of the station arm (single samples) run again under
    a second BLAS kernel, on another machine than the arm's: its max F1 against the arm's seed 20."""
    (second,) = json.loads(KERNEL3.read_text())
    values = _per_seed("station/single")
    return _kernel_moves(lambda cell: values[cell][KERNEL_SEED], second["max_f1"],
                         f"size of the move under {second['kernel']}")


def study3_kernel_alone() -> str:
    """The BLAS kernel alone (exploratory): seed 20 of the station arm fitted to reported under
    two kernels on one machine, from the same simulated runs."""
    before, after = json.loads(KERNEL3_ALONE.read_text())
    return _kernel_moves(lambda cell: before["max_f1"]["/".join(cell)], after["max_f1"],
                         f"size of the move, {before['kernel']} to {after['kernel']}")


def methods_table(arm: str) -> str:
    """Max F1 %, mean [bootstrap 95 %] over seeds, of every method and fusion of one arm."""
    rows = {key: _index(read(key, "sweep.csv"), "environment", "method", "direction", "metric")
            for key in POINTS if key.startswith(f"{arm}/")}
    worlds = ARMS[arm][2]
    body = []
    for key, index in rows.items():
        for direction, arrow in DIRECTIONS.items():
            for method in methods_of(arm):
                cells = [f"{pct(r['mean'])} {pct_interval(r)}"
                         for r in (index[(w, method, direction, "max_f1")] for w in worlds)]
                body.append([method, arrow, MATCHING[key.split("/")[1]], *cells])
    n = next(iter(rows.values()))[(worlds[0], "L", Q2R, "max_f1")]["n"]
    return markdown(["method", "direction", "matching", *(f"{w} (n={n})" for w in worlds)], body)


def study2_decomposition() -> str:
    """L - H = (L-V - H-V) + [(L - L-V) - (H - H-V)] (`decomposition`) for every evaluation x
    direction x matching cell of the three arms; exploratory, unadjusted."""
    body = [[key.split("/")[0], world, DIRECTIONS[direction], MATCHING[key.split("/")[1]],
             *_decomposition_cells(key, world, direction)] for key, world, direction in cells2()]
    return markdown(["arm", "evaluation", "direction", "matching", *DECOMPOSITION_HEADER], body)


#: paired contrasts reported per evaluation, query to reference, single samples
CONTRASTS = (("L", "L-V"), ("H", "H-V"), ("L", "L-F"), ("L", "A"), ("L-cycle", "L"), ("L-T", "H-T"))


def study2_contrasts() -> str:
    """What touch adds (L - L-V, H - H-V), joint against late fusion (L - L-F), the learning
    rule (L - A), the whisk cycle (L-cycle - L) and the tactile codes (L-T - H-T): max F1,
    query to reference, single samples, mean [bootstrap 95 %] and sign-flip p."""
    body = []
    for key in (k for k in POINTS if k.endswith("/length=1")):
        arm = key.split("/")[0]
        for world in ARMS[arm][2]:
            cells = []
            for a, b in CONTRASTS:
                if "A" in (a, b) and "A" not in methods_of(arm):
                    cells.append("–")
                    continue
                r = _difference(key, world, Q2R, a, b)
                cells.append(f"{pct(r['mean'])} {pct_interval(r)} p={p_value(r['p_sign_flip'])}")
            body.append([arm, world, *cells])
    return markdown(["arm", "evaluation", *(f"{a} − {b}" for a, b in CONTRASTS)], body)


def study2_best() -> str:
    """Per evaluation, direction and matching of each arm: the best method or fusion by mean
    max F1, the runner-up and their paired difference (`best`)."""
    body = [[key.split("/")[0], world, DIRECTIONS[direction], MATCHING[key.split("/")[1]],
             *_best_cells(key, world, direction, methods_of(key.split("/")[0]))] for key, world, direction in cells2()]
    return markdown(["arm", "evaluation", "direction", "matching", *BEST_HEADER], body)


def study2_overall() -> str:
    """Per arm and matching: the methods ranked by mean max F1 over its evaluations and both
    directions (a ranking only), and in how many of its cells each is the best."""
    body = []
    for key in POINTS:
        methods, means, average = methods_of(key.split("/")[0]), _means(key), _averages(key)
        cells = [(w, d) for _, w, d in cells2([key])]
        wins = {m: sum(max(methods, key=lambda x: means[(w, x, d)]) == m for w, d in cells) for m in methods}
        ranked = sorted(methods, key=lambda m: -average[m])
        body.append([key.split("/")[0], MATCHING[key.split("/")[1]], str(len(cells)),
                     *(f"{m} {pct(average[m])} ({wins[m]})" for m in ranked),
                     *([""] * (len(METHODS2) - len(methods)))])
    return markdown(["arm", "matching", "cells", *(f"rank {i} (best in)" for i in range(1, len(METHODS2) + 1))], body)


def _averages(key: str) -> dict[str, float]:
    """Each method's mean max F1 over the evaluations and directions of one arm/point."""
    means, cells = _means(key), [(w, d) for _, w, d in cells2([key])]
    return {m: statistics.fmean(means[(w, m, d)] for w, d in cells) for m in methods_of(key.split("/")[0])}


def study2_rank() -> str:
    """The best method overall: each method's rank by mean max F1 (`study2_overall`) in every
    arm, and its mean rank over the three arms' single samples and over all five arm x
    matching points (A over those it ran in: it is not scored under drop-out)."""
    ranks = {}
    for key in POINTS:
        average = _averages(key)
        ranks[key] = {m: i + 1 for i, m in enumerate(sorted(average, key=lambda m: -average[m]))}
    single = [k for k in POINTS if k.endswith("/length=1")]
    mean_rank = {m: (statistics.fmean(ranks[k][m] for k in single if m in ranks[k]),
                     statistics.fmean(ranks[k][m] for k in POINTS if m in ranks[k])) for m in METHODS2}
    body = [[m, *(str(ranks[k].get(m, "–")) for k in POINTS), f"{mean_rank[m][0]:.1f}", f"{mean_rank[m][1]:.1f}"]
            for m in sorted(METHODS2, key=lambda m: mean_rank[m])]
    return markdown(["method", *(f"{k.split('/')[0]}, {MATCHING[k.split('/')[1]]}" for k in POINTS),
                     "mean rank, single samples", "mean rank, all"], body)


#: resamples of the seeds for the rank intervals, and the seed of their generator
RANK_RESAMPLES = 2000
RANK_SEED = 0


def rank_replicates(points: Mapping[str, Mapping[str, np.ndarray]], resamples: int = RANK_RESAMPLES,
                    seed: int = RANK_SEED) -> dict[str, dict[str, np.ndarray]]:
    """Bootstrap of the ranking over seeds. ``points``: point -> method -> max F1 per seed and
    cell, shape (seeds, cells), the same seeds in every point. Each resample draws the seeds
    with replacement once, for every method and point (paired), and ranks each point's
    methods by their mean over the drawn seeds and the cells (1 = highest; exact ties go to
    the method named first). Returns point -> method -> its rank in each resample."""
    n = len(next(iter(next(iter(points.values())).values())))
    draws = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    ranks = {}
    for key, methods in points.items():
        scores = np.stack([values[draws].mean(axis=(1, 2)) for values in methods.values()])
        ranks[key] = dict(zip(methods, (-scores).argsort(axis=0, kind="stable").argsort(axis=0) + 1, strict=True))
    return ranks


def _point_values(key: str) -> dict[str, np.ndarray]:
    """Method -> its max F1 per seed (rows, in seed order) and cell of one arm/point (columns)."""
    values, cells = _per_seed(key), [(w, d) for _, w, d in cells2([key])]
    seeds = sorted(values[(cells[0][0], "L", cells[0][1])])
    return {m: np.array([[values[(w, m, d)][s] for w, d in cells] for s in seeds])
            for m in methods_of(key.split("/")[0])}


def _interval(replicates: np.ndarray, digits: int = 0) -> str:
    """The (1 - LEVEL)/2 and (1 + LEVEL)/2 percentiles of replicates, as observed values."""
    low, high = np.quantile(replicates, [(1 - LEVEL) / 2, (1 + LEVEL) / 2], method="inverted_cdf")
    return f"[{low:.{digits}f}, {high:.{digits}f}]"


#: the groups of points a mean rank is taken over: the three arms' single samples, all five points
RANK_GROUPS = {"single samples": [k for k in POINTS if k.endswith("/length=1")], "all": list(POINTS)}


def mean_ranks(ranks: Mapping[str, Mapping[str, np.ndarray]],
               points: Sequence[str]) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Each method's mean rank over ``points`` (those it ran in) per resample of
    `rank_replicates`, and the share of resamples in which it is the lowest (ties share it)."""
    methods = list(dict.fromkeys(m for k in points for m in ranks[k]))
    mean = {m: np.mean([ranks[k][m] for k in points if m in ranks[k]], axis=0) for m in methods}
    table = np.stack(list(mean.values()))
    lowest = table == table.min(axis=0)
    return mean, {m: float((lowest[i] / lowest.sum(axis=0)).mean()) for i, m in enumerate(methods)}


def study2_rank_intervals() -> str:
    """How sure the ranking is: each method's rank per arm and matching (`study2_rank`) with
    its 95 % percentile interval over `RANK_RESAMPLES` resamples of the eight seeds, paired
    across methods, arms and matchings (`rank_replicates`); its mean rank over the three
    arms' single samples and over all five points, each with its interval and the share of
    resamples in which it is the lowest (`mean_ranks`: the best method overall)."""
    ranks = rank_replicates({key: _point_values(key) for key in POINTS})
    point = {key: {m: i + 1 for i, m in enumerate(sorted(a, key=lambda m: -a[m]))}
             for key, a in ((k, _averages(k)) for k in POINTS)}
    groups = {name: mean_ranks(ranks, keys) for name, keys in RANK_GROUPS.items()}

    def estimate(m: str, keys: Sequence[str]) -> float:
        return statistics.fmean(point[k][m] for k in keys if m in point[k])

    body = []
    for m in sorted(METHODS2, key=lambda m: estimate(m, RANK_GROUPS["single samples"])):
        cells = [f"{point[k][m]} {_interval(ranks[k][m])}" if m in point[k] else "–" for k in POINTS]
        for name, (mean, best) in groups.items():
            cells += [f"{estimate(m, RANK_GROUPS[name]):.1f} {_interval(mean[m], 1)}", f"{100 * best[m]:.1f}"]
        body.append([m, *cells])
    return markdown(["method", *(f"{k.split('/')[0]}, {MATCHING[k.split('/')[1]]}" for k in POINTS),
                     *(f"{label}, {name}" for name in RANK_GROUPS
                       for label in ("mean rank", "lowest mean rank, % of resamples"))], body)


def study2_settled() -> str:
    """Settledness of the MuPNet methods' test-time inference per evaluation drive, from each
    seed's manifest: the share of samples that ended before the 1000-step cap (settled: the
    relative-change rule or the thresholds) and the share under the layer thresholds
    (stopped), median (min–max) over seeds; "not settled" where the median settled share is
    under 95 %."""
    body = []
    for arm in ARMS:
        manifests = list(_seed_manifests(arm).values())
        for method in LEARNED:
            for world in ARMS[arm][2]:
                cells, unsettled = [], []
                for drive in ("query", "reference"):
                    runs = [m["features"][method][f"{world}/{drive}"]["inference"] for m in manifests]
                    settled = [(r["samples"] - r["capped"]) / r["samples"] for r in runs]
                    cells += [_median_range(settled), _median_range([r["stopped"] / r["samples"] for r in runs])]
                    if statistics.median(settled) < 0.95:
                        unsettled.append(drive)
                body.append([arm, method, world, *cells, ", ".join(unsettled) or "–"])
    return markdown(["arm", "method", "evaluation", "query settled %", "query stopped %", "reference settled %",
                     "reference stopped %", "not settled"], body)


def study2_training() -> str:
    """Epochs the learned methods trained, of the cap, and how many seeds converged (the
    training energy improved by less than 1 % over 20 epochs), from each seed's manifest."""
    body = []
    for arm in ARMS:
        manifests = list(_seed_manifests(arm).values())
        for method in (m for m in (*LEARNED, "A") if m in methods_of(arm)):
            trained = [m["training"][method] for m in manifests]
            epochs = [t["epochs"] for t in trained]
            cap = "/".join(str(c) for c in sorted({t["max_epochs"] for t in trained}))
            body.append([arm, method, str(len(trained)), f"{min(epochs)}–{max(epochs)} of {cap}",
                         f"{sum(bool(t['converged']) for t in trained)} of {len(trained)}"])
    return markdown(["arm", "method", "seeds", "epochs trained", "converged"], body)


@functools.cache  # callers do not mutate it
def _complementarity(arm: str) -> list[list[dict]]:
    """Each seed's complementarity.json (single samples) of one arm, in seed order."""
    folder = ARMS[arm][0] / "length=1" / "seeds"
    return [json.loads((folder / f"seed-{seed}" / "complementarity.json").read_text())
            for seed in sorted(_seed_manifests(arm))]


def complementarity_pairs(arm: str, world: str, direction: str, vision: str) -> list[dict]:
    """Per seed, the complementarity of ``vision`` and its touch-only pair in one cell."""
    return [next(c for c in seed if (c["environment"], c["direction"], c["vision"]) == (world, direction, vision))
            for seed in _complementarity(arm)]


def fusion_headroom(arm: str, world: str, direction: str, vision: str) -> float:
    """The most a fusion of ``vision`` and its touch-only pair could add to recall@1: the mean
    over seeds of the oracle recall@1 (either right) minus the better single modality's."""
    return statistics.fmean(c["oracle_r1"] - max(c["vision_r1"], c["touch_r1"])
                            for c in complementarity_pairs(arm, world, direction, vision))


def study2_complementarity() -> str:
    """Per evaluation and direction, single samples: each vision/touch pair's recall@1 failures
    of vision that touch gets right (rescued of wrong, summed over seeds), its oracle recall@1
    (either right; median over seeds) and its headroom (`fusion_headroom`: mean over seeds of
    the oracle minus the better single modality), from each seed's complementarity.json."""
    body = []
    for arm, (_, _, worlds, _) in ARMS.items():
        for world in worlds:
            for direction, arrow in DIRECTIONS.items():
                cells = [arm, world, arrow]
                for vision in ("L-V", "H-V"):
                    found = complementarity_pairs(arm, world, direction, vision)
                    cells += [f"{sum(c['rescued'] for c in found)} of {sum(c['vision_wrong'] for c in found)}",
                              pct(statistics.median(c["oracle_r1"] for c in found)),
                              f"{100 * fusion_headroom(arm, world, direction, vision):+.1f}"]
                body.append(cells)
    return markdown(["arm", "evaluation", "direction", "L-T rescues of L-V", "L oracle R@1 %, median",
                     "L headroom, points", "H-T rescues of H-V", "H oracle R@1 %, median", "H headroom, points"], body)


def _budget_values(epochs: int) -> tuple[dict[tuple[str, str, str], float], dict]:
    """Max F1 per (evaluation, method, direction) and the manifest of seed 0 at an epoch cap."""
    values = {cell: seeds[0] for cell, seeds in _per_seed(f"budget/epochs={epochs}").items()}
    return values, json.loads((BUDGET2 / f"epochs={epochs}" / "seeds" / "seed-0" / "manifest.json").read_text())


def study2_budget() -> str:
    """The budget trend, seed 0 of the touch arm's L and L-V at epoch caps of 30, 70 and 270
    (the study's cap is 70), single samples: max F1 of L and L-V and L - L-V, points; the
    last rows are the epochs trained."""
    runs = {e: _budget_values(e) for e in BUDGET_EPOCHS}
    body = []
    for world in ARMS["touch"][2]:
        for direction, arrow in DIRECTIONS.items():
            cells = []
            for values, _ in runs.values():
                lv, vv = values[(world, "L", direction)], values[(world, "L-V", direction)]
                cells.append(f"{pct(lv)} / {pct(vv)} / {100 * (lv - vv):+.1f}")
            body.append([world, arrow, *cells])
    for method in ("L", "L-V"):
        body.append([f"epochs trained, {method}", "",
                     *(f"{m['training'][method]['epochs']} of {m['training'][method]['max_epochs']}"
                                                        f"{', converged' if m['training'][method]['converged'] else ''}"
                                                        for _, m in runs.values())])
    return markdown(["evaluation", "direction", *(f"{e} epochs: L / L-V / L − L-V" for e in BUDGET_EPOCHS)], body)


#: the amount a tactile-range warning gives: "up to X scaled units beyond [0, 1]"
RANGE_EXCESS = re.compile(r"up to ([0-9.]+) scaled units beyond")


def tactile_range_excess(tactile_input: str) -> float:
    """The farthest any evaluation's touch lies beyond the training run's range, in scaled
    units, over the tactile-range warnings (``... tactile range (INPUT...)``) of every arm's
    seeds for one ``tactile_input`` ("instant" or "cycle")."""
    found = [RANGE_EXCESS.search(message) for arm in ARMS for manifest in _seed_manifests(arm).values()
             for checks in manifest["warnings"].values() for check, message in checks.items()
             if f"tactile range ({tactile_input}" in check]
    return max(float(match.group(1)) for match in found if match)


def study2_warnings() -> str:
    """The warnings of the second study's seeds (each manifest's ``warnings``, single-sample
    point), per arm and check: in how many seeds and runs it fired, and its first message."""
    body = []
    for arm in ARMS:
        found: dict[str, list[tuple[int, str, str]]] = {}
        for seed, manifest in sorted(_seed_manifests(arm).items()):
            for run, checks in manifest["warnings"].items():
                for check, message in checks.items():
                    found.setdefault(check, []).append((seed, run, message))
        for check, hits in sorted(found.items()):
            body.append([arm, f"`{check}`", str(len({h[0] for h in hits})), str(len(hits)),
                         f"seed {hits[0][0]}, {hits[0][1]}: {hits[0][2]}"])
        if not found:
            body.append([arm, "–", "0", "0", "none"])
    return markdown(["arm", "check", "seeds", "runs", "first message"], body)


TABLES: dict[str, Callable[[], str]] = {
    "difficulty": difficulty,
    "six-penetration": lambda: six_methods("penetration"),
    "six-physical": lambda: six_methods("physical"),
    "primary": primary,
    "best": best,
    "overall": overall,
    "touch-adds": pairs((("L", "L-V"), ("H", "H-V"))),
    "learned-vs-handcrafted": pairs((("L", "H"), ("L", "H-V"), ("L-V", "H-V"))),
    "decomposition": decomposition,
    "transfer": transfer,
    "transfer-differences": transfer_differences,
    "recall-at-full-precision": recall_at_full_precision,
    "sensitivity": sensitivity,
    "budget": budget,
    "stalls": stalls,
    "warnings": warnings,
    "study2-gates": study2_gates,
    "study2-methods-touch": lambda: methods_table("touch"),
    "study2-methods-drop-out": lambda: methods_table("drop-out"),
    "study2-methods-faithful": lambda: methods_table("faithful"),
    "study2-endpoints": study2_endpoints,
    "study2-comparator": study2_comparator,
    "study2-best": study2_best,
    "study2-overall": study2_overall,
    "study2-rank": study2_rank,
    "study2-rank-intervals": study2_rank_intervals,
    "study2-contrasts": study2_contrasts,
    "study2-decomposition": study2_decomposition,
    "study2-complementarity": study2_complementarity,
    "study2-settled": study2_settled,
    "study2-training": study2_training,
    "study2-budget": study2_budget,
    "study3-calibration-gates": study3_calibration_gates,
    "study3-weights": study3_weights,
    "study3-gates-station": lambda: study3_gates("station"),
    "study3-methods-station": lambda: study3_methods("station"),
    "study3-learned-station": lambda: study3_learned("station"),
    "study3-rank": lambda: study3_rank("station"),
    "study3-survival-training": study3_survival_training,
    "study3-survival": study3_survival,
    "study3-machines": study3_machines,
    "study3-rank-faithful": lambda: study3_rank("faithful"),
    "study3-rank-drop-out": lambda: study3_rank("drop-out"),
    "study3-endpoints": study3_endpoints,
    "study3-gates-faithful": lambda: study3_gates("faithful"),
    "study3-gates-drop-out": lambda: study3_gates("drop-out"),
    "study3-kernel": study3_kernel,
    "study3-kernel-alone": study3_kernel_alone,
    "study3-methods-faithful": lambda: study3_methods("faithful"),
    "study3-methods-drop-out": lambda: study3_methods("drop-out"),
    "study3-learned-faithful": lambda: study3_learned("faithful"),
    "study3-learned-drop-out": lambda: study3_learned("drop-out"),
    "study2-warnings": study2_warnings,
}


def main(names: Sequence[str]) -> int:
    unknown = [n for n in names if n not in TABLES]
    if unknown:
        print(f"unknown table(s) {', '.join(unknown)}; tables: {', '.join(TABLES)}", file=sys.stderr)
        return 2
    for name in names or TABLES:
        print(f"<!-- table {name} -->\n{TABLES[name]()}\n<!-- /table -->\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
