"""The tables of docs/RESULTS.md, computed from the study's committed summaries.

    python docs/results/tables.py            # every table, each under its name
    python docs/results/tables.py six-penetration

Each table in RESULTS.md sits between ``<!-- table NAME -->`` and ``<!-- /table -->`` and is
exactly what this script prints for NAME (`tests/layout/test_results_doc.py` checks it), so no
number in the text can drift from the files `vitaplace sweep` and `vitaplace sensitivity`
wrote: ``sweep.csv`` (statistics over seeds per world x method x direction x value),
``sweep-diff.csv`` (paired differences between methods, with the sign-flip p),
``sweep-seeds.csv`` (every value per seed) and ``sensitivity.csv`` (per seed, max F1
rescored under other ground truths), and each seed's ``manifest.json`` and ``report.md``
(copied into ``seeds/seed-N/``), in
``paper-cpu-sweep/`` (penetration touch model) and ``paper-cpu-physical-sweep/`` (physical
whiskers). Proportions are printed in percent, intervals are the percentile bootstrap over
seeds unless a column says otherwise.
"""

from __future__ import annotations

import csv
import functools
import json
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from vitaplace.engine.study.summary import describe, difference_bounds, sign_flip_p

HERE = Path(__file__).resolve().parent
#: touch model -> the sweep folder of its scenario
STUDIES = {"penetration": HERE / "paper-cpu-sweep", "physical": HERE / "paper-cpu-physical-sweep"}
WORLDS = ("E1", "E2", "E3")
METHODS = ("L", "L-V", "L-T", "H", "H-V", "H-T")
Q2R, R2Q = "query-to-reference", "reference-to-query"
DIRECTIONS = {Q2R: "q→r", R2Q: "r→q"}
#: the paper's reading of each world, L (learned) vs H (hand-crafted), F1
PAPER = {"E1": "similar F1", "E2": "L: higher precision", "E3": "L 72.94 %, H 62.34 %"}


@functools.cache  # each file is read once, however many tables use it (callers do not mutate rows)
def read(study: str, name: str) -> list[dict[str, str]]:
    with open(STUDIES[study] / name, newline="") as handle:
        return list(csv.DictReader(handle))


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


def _means(study: str) -> dict[tuple[str, str, str], float]:
    rows = read(study, "sweep.csv")
    return {(r["environment"], r["method"], r["direction"]): float(r["mean"]) for r in rows if r["metric"] == "max_f1"}


def best() -> str:
    """Per world, direction and touch model: the method with the highest mean max F1, the
    runner-up, and their paired difference."""
    body = []
    for study in STUDIES:
        means = _means(study)
        for world in WORLDS:
            for direction, arrow in DIRECTIONS.items():
                ranked = sorted(METHODS, key=lambda m: -means[(world, m, direction)])
                first, second = ranked[:2]
                r = _difference(study, world, direction, first, second)
                body.append([world, study, arrow, f"{first} ({pct(means[(world, first, direction)])})",
                             f"{second} ({pct(means[(world, second, direction)])})",
                             f"{pct(r['mean'])} {pct_interval(r)}", p_value(r["p_sign_flip"])])
    return markdown(["world", "touch model", "direction", "best (mean max F1 %)", "runner-up",
                     "best − runner-up, points [bootstrap 95 %]", "sign-flip p"], body)


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


def _per_seed(study: str, metric: str = "max_f1") -> dict[tuple[str, str, str], dict[int, float]]:
    """``{(world, method, direction): {seed: value}}`` of ``metric`` from ``sweep-seeds.csv``."""
    values: dict[tuple[str, str, str], dict[int, float]] = {}
    for r in read(study, "sweep-seeds.csv"):
        if r["metric"] == metric:
            values.setdefault((r["environment"], r["method"], r["direction"]), {})[int(r["seed"])] = float(r["value"])
    return values


def interaction(study: str, world: str, direction: str) -> tuple[list[float], dict[str, float], float]:
    """What touch costs L less than H, (L - L-V) - (H - H-V), max F1, per seed from
    ``sweep-seeds.csv`` (the summaries hold no paired statistics of it): the per-seed values,
    their `describe` (mean, std, t and bootstrap intervals; no block interval, the block
    replicates are not committed) and their sign-flip p."""
    values = _per_seed(study)
    cells = [values[(world, m, direction)] for m in ("L", "L-V", "H", "H-V")]
    seeds = sorted(set.intersection(*(set(c) for c in cells)))
    assert all(set(c) == set(seeds) for c in cells), (study, world, direction, "methods differ in their seeds")
    lv, vv, h, hv = cells
    d = [(lv[s] - vv[s]) - (h[s] - hv[s]) for s in seeds]
    low, high = difference_bounds("max_f1")  # a difference of two such differences lies in [-2, 2]
    return d, describe(d, (low - high, high - low)), sign_flip_p(d)


def _paired_cell(r: dict[str, str], p: str | float) -> str:
    return f"{pct(r['mean'])} {pct_interval(r)}, t {pct_interval(r, 't')}, p={p_value(p)}"


def decomposition() -> str:
    """L - H = (L-V - H-V) + [(L - L-V) - (H - H-V)], max F1, per world, direction and touch
    model: what vision contributes and what touch costs L less than H (negative: more). Each
    term's mean over seeds [bootstrap 95 %], its t 95 % interval and sign-flip p; the first
    two from ``sweep-diff.csv``, the third computed per seed (`interaction`). The means add
    up exactly; their rounded values may differ by 0.1."""
    body = []
    for study in STUDIES:
        for direction, arrow in DIRECTIONS.items():
            for world in WORLDS:
                cells = [world, study, arrow]
                for a, b in (("L", "H"), ("L-V", "H-V")):
                    r = _difference(study, world, direction, a, b)
                    cells.append(_paired_cell(r, r["p_sign_flip"]))
                _, stats, p = interaction(study, world, direction)
                body.append([*cells, _paired_cell({k: str(v) for k, v in stats.items()}, p)])
    return markdown(["world", "touch model", "direction", "L − H, points", "= L-V − H-V (vision)",
                     "+ (L − L-V) − (H − H-V) (touch)"], body)


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
                    la, lb = values[(world, "L", tau, heading)], values[(world, b, tau, heading)]
                    d = [la[s] - lb[s] for s in sorted(la) if s in lb]
                    stats = describe(d, difference_bounds("max_f1"))
                    cells.append(f"{pct(stats['mean'])} [{pct(stats['boot_low'])}, {pct(stats['boot_high'])}] "
                                 f"p={p_value(sign_flip_p(d))}")
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
            body.append([method, study, str(len(manifests)), f"{min(epochs)}–{max(epochs)} of {'/'.join(map(str, cap))}",
                         f"{converged} of {len(manifests)}", f"{100 * capped / samples:.1f} ({capped} of {samples})"])
    return markdown(["method", "touch model", "seeds", "epochs trained", "converged", "test samples at the step cap, %"],
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
