"""Parameter grids: ``vitaplace sweep SCENARIO --grid PATH=V1,V2,... --seeds ...``.

A ``--grid`` names any ``--set`` path and a comma-separated list of values, each parsed as
YAML as a ``--set`` value is (commas inside ``[...]``, ``{...}`` or quotes do not split).
Several ``--grid`` options form the Cartesian product (`grid_points`, the first option
varying slowest); their paths must not overlap (one equal to or inside another: the later
assignment would overwrite the earlier's value while the folders name both), nor may a
``--grid`` path hold a ``--set`` path (the point's value would replace what ``--set`` sets). A
grid of more than `MAX_POINTS` points runs only when confirmed (``--yes``, `check_size`);
loading the points, preparing their jobs and writing their summaries show a progress bar
once they take more than `PROGRESS_DELAY_S` seconds.

Each grid point is one scenario (the sweep's ``--set`` overrides, then the
point's assignments) run over every seed into its own folder ``OUT/<point>``, named
``LABEL=VALUE`` joined by commas (`point_name`): LABEL is the path's last part (the whole path
where two options share it), VALUE the value as given with any character other than letters,
digits and ``. _ + -`` written as ``_``. All points share the stage cache ``OUT/cache``.

Each point's folder gets the summary `vitaplace aggregate` writes (`summarise_point`); ``OUT``
gets ``grid.csv`` (every point's summary rows, with the point and its values first),
``grid.md`` (its metrics table) and ``grid.json`` (`write_grid_summary`). A sweep into an
``OUT`` whose summary covers seeds or grid points the new sweep lacks (or a plain sweep's
summary where a grid's goes, or the reverse) is refused unless told to replace it
(`check_replace`): nothing is lost unasked, and adding seeds or points to a sweep is allowed.
"""

from __future__ import annotations

import itertools
import json
import math
import re
from collections import Counter
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.scenario import RENAMED_KEYS, Scenario, ScenarioError, current_key
from vitaplace.engine.outputs.outdir import seed_dir
from vitaplace.engine.report.figures import write_pr_bands
from vitaplace.engine.study.summary import (
    LEGEND,
    STAT_HEADER,
    SUMMARY_COLUMNS,
    SUMMARY_FILES,
    csv_text,
    json_safe,
    stat_cells,
    write_summary,
)

#: the files `write_grid_summary` writes into a grid sweep's folder
GRID_FILES = ("grid.csv", "grid.md", "grid.json")
#: what a value's text keeps in a folder name; anything else becomes "_"
UNSAFE = re.compile(r"[^A-Za-z0-9._+-]")
OPENING, CLOSING = "[{", "]}"
#: the most grid points a sweep runs without ``--yes``
MAX_POINTS = 1000
#: seconds a step over the grid points runs before its progress bar shows (a small grid shows none)
PROGRESS_DELAY_S = 2.0


@dataclass(frozen=True)
class Axis:
    """One ``--grid PATH=V1,V2,...``: the path (renamed keys under their current names) and
    its values, as given and as parsed."""

    path: str
    texts: tuple[str, ...]
    values: tuple[Any, ...]


@dataclass(frozen=True)
class GridPoint:
    """One point of a grid: its folder name in the sweep's ``OUT`` ("" for a sweep without a
    grid: ``OUT`` itself), its value per path, the ``--set`` assignments that make it, and
    (`load_points`) its validated scenario and resolved mapping."""

    name: str
    values: Mapping[str, Any] = field(default_factory=dict)
    assignments: tuple[str, ...] = ()
    scenario: Scenario | None = None
    resolved: Mapping[str, Any] = field(default_factory=dict)


def split_values(text: str) -> list[str]:
    """``text`` split at the commas outside brackets, braces and quotes, each part stripped."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in OPENING or ch in CLOSING:
            depth += 1 if ch in OPENING else -1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    return [part.strip() for part in [*parts, text[start:]]]


def _set_path(assignment: str) -> str:
    """The path a ``--set`` assignment sets, its first part under its current name (silently:
    loading the scenario warns about an old name)."""
    first, dot, rest = assignment.partition("=")[0].removesuffix("+").strip().partition(".")
    return RENAMED_KEYS.get(first, first) + dot + rest


def _values(raw: str, where: str) -> tuple[list[str], list[Any]]:
    """The texts and YAML values of a ``--grid``'s comma-separated list; ScenarioError for an
    empty value, one that is not YAML, or a value given twice."""
    texts = split_values(raw)
    if "" in texts:
        raise ScenarioError(f"{where}: an empty value; expected VALUE1,VALUE2,... (each parsed as YAML)")
    try:
        values = [yaml.safe_load(t) for t in texts]
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{where}: a value is not YAML ({' '.join(str(exc).split())})") from None
    # a number by its value: 1 and 1.0 set the same field alike (pydantic reads either)
    check_once(where, texts, [float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                              else yaml.safe_dump(v) for v in values])
    return texts, values


def check_once(where: str, texts: Sequence[str], keys: Sequence[Hashable] | None = None) -> None:
    """ScenarioError naming ``where`` (an option) when one of its values is given more than
    once: the values compared by ``keys`` (their parsed form; default the texts), shown as
    ``texts``. The one check of a list option's repeats (``--grid``, ``--seeds``, ``--tau``)."""
    keys = list(texts) if keys is None else list(keys)
    counts = Counter(keys)
    twice = [t for t, k in zip(texts, keys, strict=True) if counts[k] > 1]
    if twice:
        raise ScenarioError(f"{where}: the value {twice[0]} is given more than once ({', '.join(twice)})")


def seed_range() -> tuple[int, int]:
    """[low, high) of a scenario's ``seed``, from its schema: a run's seed keeps the same bounds."""
    bounds = Scenario.model_fields["seed"].metadata
    return next(b.ge for b in bounds if hasattr(b, "ge")), next(b.lt for b in bounds if hasattr(b, "lt"))


def check_seeds(seeds: Sequence[int]) -> None:
    """A sweep's ``--seeds``: each once, each a scenario's seed; a ScenarioError naming the first
    that is not (checked before anything is written)."""
    check_once("--seeds", [str(seed) for seed in seeds], seeds)
    low, high = seed_range()
    for seed in seeds:
        if not low <= seed < high:
            raise ScenarioError(f"--seeds: {seed} is not a valid scenario seed ({low} <= seed < {high})")


def inside(path: str, outer: str) -> bool:
    """Whether ``path`` is ``outer`` or lies inside it (``scoring.tau`` inside ``scoring``)."""
    return path == outer or path.startswith(outer + ".")


def parse_axes(options: Sequence[str], overrides: Sequence[str] = ()) -> list[Axis]:
    """The ``--grid`` options as axes; ScenarioError (one line naming the option) for a
    missing ``=`` or an append (``+=``), an empty value, a value twice, a path twice or
    overlapping another axis's (`inside` either way), a path ``--set`` (``overrides``) also
    sets or one that holds a ``--set`` path, or the seed."""
    axes: list[Axis] = []
    fixed = [_set_path(o) for o in overrides]
    for option in options:
        where = f"--grid '{option}'"
        key, sep, raw = option.partition("=")
        if not sep or not key.strip() or key.endswith("+"):
            raise ScenarioError(f"{where}: expected KEY.PATH=VALUE1,VALUE2,... (e.g. methods.0.params.epochs=30,90)")
        first, dot, rest = key.strip().partition(".")
        path = current_key(first, where) + dot + rest
        if path == "seed":
            raise ScenarioError(f"{where}: the seeds are --seeds, not a grid")
        if path in fixed:
            raise ScenarioError(f"{where}: --set also sets {path}; give it in one of --grid and --set")
        held = next((f for f in fixed if inside(f, path)), None)
        if held is not None:
            raise ScenarioError(f"{where}: each value replaces all of {path}, and with it what --set {held} sets; "
                                f"give {held} inside the --grid values, or grid a path inside {path}")
        if any(axis.path == path for axis in axes):
            raise ScenarioError(f"{where}: {path} is already a --grid axis; give all its values in one --grid")
        other = next((a.path for a in axes if inside(path, a.path) or inside(a.path, path)), None)
        if other is not None:
            raise ScenarioError(f"{where}: {path} overlaps the --grid axis {other} (one path inside the other: "
                                "the later would overwrite the earlier's values while the folders name both); "
                                "give one of them")
        texts, values = _values(raw, where)
        axes.append(Axis(path, tuple(texts), tuple(values)))
    return axes


def check_size(axes: Sequence[Axis], seeds: int, confirmed: bool) -> int:
    """The number of grid points of ``axes``; UserError (one line, before anything is loaded)
    when it is over `MAX_POINTS` and not ``confirmed`` (``--yes``)."""
    size = math.prod(len(axis.values) for axis in axes)
    if size > MAX_POINTS and not confirmed:
        shape = " x ".join(str(len(axis.values)) for axis in axes)
        raise UserError(f"--grid: {size} grid points ({shape}) x {seeds} seed(s) = {size * seeds} runs, over "
                        f"{MAX_POINTS} points; give --yes to run them all")
    return size


def progress_bar(items: Sequence[Any], what: str, shown: bool) -> Any:
    """``items`` wrapped in a progress bar of ``what`` (e.g. "grid points loaded"), drawn on
    stderr once the loop has run `PROGRESS_DELAY_S` seconds (never unless ``shown``)."""
    from tqdm import tqdm

    return tqdm(items, desc=what, unit="point", delay=PROGRESS_DELAY_S, disable=not shown)


def _labels(axes: Sequence[Axis]) -> list[str]:
    """Each axis's label in folder names: its path's last part, unless another axis shares it."""
    last = [axis.path.rsplit(".", 1)[-1] for axis in axes]
    return [name if last.count(name) == 1 else axis.path for name, axis in zip(last, axes, strict=True)]


def point_name(labels: Sequence[str], texts: Sequence[str]) -> str:
    """The folder name of a grid point: ``label=value`` per axis, joined by commas."""
    return ",".join(f"{label}={UNSAFE.sub('_', text)}" for label, text in zip(labels, texts, strict=True))


def grid_points(axes: Sequence[Axis]) -> list[GridPoint]:
    """The Cartesian product of ``axes`` (the first varying slowest); without axes, the one
    point "" (a plain sweep). ScenarioError when two points would share a folder name."""
    if not axes:
        return [GridPoint("")]
    labels, points = _labels(axes), []
    for combination in itertools.product(*(range(len(axis.values)) for axis in axes)):
        texts = [axis.texts[i] for axis, i in zip(axes, combination, strict=True)]
        points.append(GridPoint(
            point_name(labels, texts),
            {axis.path: axis.values[i] for axis, i in zip(axes, combination, strict=True)},
            tuple(f"{axis.path}={text}" for axis, text in zip(axes, texts, strict=True)),
        ))
    names = Counter(p.name for p in points)
    clash = next((n for n, k in names.items() if k > 1), None)
    if clash is not None:
        raise ScenarioError(f"--grid: two grid points would share the folder {clash}; give values that differ in "
                            "letters, digits or . _ + -")
    return points


def load_points(points: Sequence[GridPoint], load: Callable[[Sequence[str]], tuple[Scenario, dict[str, Any]]],
                progress: bool = False) -> list[GridPoint]:
    """Each point with the scenario and resolved mapping ``load(assignments)`` gives; its
    error (an unknown path, a value out of range) as one line naming the grid point.
    ``progress``: a progress bar (`progress_bar`) over the points."""
    loaded = []
    for point in progress_bar(points, "grid points loaded", progress):
        try:
            scenario, resolved = load(point.assignments)
        except UserError as exc:
            if not point.name:
                raise
            raise ScenarioError(f"--grid point {point.name}: {exc}") from None
        loaded.append(replace(point, scenario=scenario, resolved=resolved))
    return loaded


def _covered(out: Path) -> tuple[str, list[str], list[int]] | None:
    """(summary file, grid points, seeds) that the summary in ``out`` covers (the points [""]
    for a plain sweep's sweep.json); None without one. UserError for one that cannot be read."""
    for name in ("grid.json", "sweep.json"):
        path = out / name
        if not path.is_file():
            continue
        try:
            record = json.loads(path.read_text())
            if name == "grid.json":
                return name, [p["name"] for p in record["points"]], sorted(record["seeds"])
            return name, [""], sorted({*record["seeds"], *map(int, record.get("failed", {}))})
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UserError(f"--out {out}: its summary {name} cannot be read ({type(exc).__name__}: {exc}); give "
                            "--replace to replace it, or another --out") from None
    return None


def _describe(points: Sequence[str], seeds: Sequence[int]) -> str:
    where = "no grid" if list(points) == [""] else f"grid points {' '.join(points)}"
    return f"{where}, seeds {' '.join(map(str, seeds))}"


def check_replace(out: Path, points: Sequence[GridPoint], seeds: Sequence[int], replace_it: bool) -> None:
    """Refuse (UserError, before anything is written) a sweep of ``points`` x ``seeds`` into
    ``out`` whose summary covers a grid point or a seed the sweep lacks, unless
    ``replace_it``; then remove the summary files of the other kind (a grid's in ``out`` when
    this sweep has none, a plain sweep's and its pr-bands figures when it has one)."""
    names = [p.name for p in points]
    if replace_it:
        stale = [out / n for n in GRID_FILES] if names == [""] else [
            *(out / n for n in SUMMARY_FILES), *out.glob("pr-bands-*")]
        for path in stale:
            path.unlink(missing_ok=True)
        return
    found = _covered(out)
    if found is None:
        return
    summary, old_points, old_seeds = found
    if set(old_points) - set(names) or set(old_seeds) - set(seeds):
        raise UserError(f"--out {out}: its summary ({summary}) covers {_describe(old_points, old_seeds)}, which this "
                        f"sweep of {_describe(names, sorted(seeds))} would replace; give --replace to replace it, or "
                        "another --out")


def summarise_point(out: Path, point: GridPoint, name: str, rows: Sequence[Mapping[str, Any]],
                    failed: Mapping[int, str], workers: int = 1) -> list[dict[str, Any]]:
    """The summary of the seeds of ``point`` (of the scenario ``name``) that succeeded
    (``rows``, seed-tagged) as `vitaplace aggregate` writes it, with its PR-band figures, into
    the point's folder ``out/<point>`` (``out`` without a grid), beside its seed folders;
    ``failed``: its failed seeds; ``workers``: processes for its block bootstrap. Returns the
    summary rows."""
    folder, ok = out / point.name, sorted({row["seed"] for row in rows})
    grid = {"grid": dict(point.values)} if point.name else {}
    info = {"scenario": name, **grid, "seeds": ok, "failed": {str(s): m for s, m in sorted(failed.items())}}
    folders = {seed: seed_dir(folder, seed) for seed in ok}
    title = f"{name}{f' ({point.name})' if point.name else ''}: {len(ok)} seed(s)"
    summary = write_summary(folder, rows, title, info, folders, workers)["summary"]
    write_pr_bands(folder, folders, rows)
    return summary


def write_grid_summary(out: Path, title: str, points: Sequence[GridPoint], seeds: Sequence[int],
                       summaries: Mapping[str, Sequence[Mapping[str, Any]]],
                       failed: Mapping[str, Mapping[int, str]]) -> list[dict[str, Any]]:
    """grid.csv, grid.md and grid.json in ``out``: every point's summary rows (``summaries``,
    point name -> `summarise_point`'s rows) with the point's name and values first;
    ``failed``: point name -> its failed seeds. Returns grid.csv's rows."""
    paths = list(points[0].values)
    rows = [{"point": p.name, **{k: json.dumps(v) for k, v in p.values.items()}, **row}
            for p in points for row in summaries.get(p.name, [])]
    write_text_atomic(out / "grid.csv", csv_text(rows, ["point", *paths, *SUMMARY_COLUMNS]))
    head = ["point", "environment", "method", "direction", "metric", *STAT_HEADER]
    lines = [f"# {title}: grid of {len(points)} point(s) x {len(seeds)} seed(s)", "", LEGEND, "",
             "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lines += ["| " + " | ".join([r["point"], r["environment"], r["method"], r["direction"], r["metric"],
                                 *stat_cells(r)]) + " |" for r in rows if r["kind"] == "metric"]
    write_text_atomic(out / "grid.md", "\n".join(lines) + "\n")
    axes = {path: list({json.dumps(p.values[path], sort_keys=True): p.values[path] for p in points}.values())
            for path in paths}
    record = {"scenario": title, "grid": axes, "seeds": sorted(seeds),
              "points": [{"name": p.name, "values": dict(p.values), "folder": str(out / p.name),
                          "failed": {str(s): m for s, m in sorted(failed.get(p.name, {}).items())}} for p in points],
              "summary": rows}
    write_text_atomic(out / "grid.json", json.dumps(json_safe(record), indent=2))
    return rows
