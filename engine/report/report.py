"""The Markdown report of a scenario run, with the paper's figures (paper Fig. 4-5): results,
sample counts, every method's parameters, figures per evaluation, training, provenance.

The report is a function of the output folder alone (`write_report`): it reads
``results.json``, ``manifest.json``, ``scenario.resolved.yaml`` and the files `outdir`
places for it (each evaluation's matrices, curve and decisions, its poses and arena, the
training curves), never the cache, the plugins or a live pipeline. The run's report stage
and ``vitaplace report OUT`` (`rebuild_report`) call the same function.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pydantic
import yaml

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.scenario import ReportSettings
from vitaplace.engine.evaluation import pairfiles
from vitaplace.engine.evaluation.complementarity import count_text
from vitaplace.engine.evaluation.difficulty import STAY_RADIUS
from vitaplace.engine.evaluation.pairfiles import load_curve, load_decisions
from vitaplace.engine.outputs import completion
from vitaplace.engine.outputs.checksum import digest
from vitaplace.engine.outputs.outdir import (
    COMPLEMENTARITY,
    DECISIONS,
    FIGURES,
    MANIFEST,
    MATRICES,
    PR_CURVE,
    REPORT,
    RESULTS_JSON,
    arena_path,
    evaluation_dir,
    poses_path,
    training_path,
)
from vitaplace.engine.outputs.rows import Difficulty, ResultRow, SequenceMatching, parse_row
from vitaplace.engine.report import figures
from vitaplace.engine.report.learned import drive_section, inference_section, tactile_range_section
from vitaplace.engine.report.training import training_section

#: the manifest entries the report reads (a change to one of them changes the report's key)
MANIFEST_KEYS = ("scenario", "seed", "vitaplace_version", "git_commit", "git_dirty", "packages", "plugins", "recorded",
                 "warnings", "training_world", "methods", "runs", "features")
#: the files of each evaluation folder the report reads
EVALUATION_FILES = (MATRICES, PR_CURVE, DECISIONS)


class ReportError(UserError):
    """An output folder the report cannot be built from; the message names the file."""


def _pct(value: Any) -> str:
    return "–" if value is None else f"{100 * float(value):.2f}"


#: a share of queries with a tied best match from which the report warns
TIED_WARNING = 0.1


def results_table(rows: Sequence[ResultRow]) -> str:
    """Markdown table: one row per environment x method x direction (F1, P, R in %; F1 at
    the training world's threshold, ``f1_at_e1_threshold``; recall@K; the share of queries
    whose best match is tied), then a warning per row where that share is `TIED_WARNING` or more."""
    ks = sorted({k for row in rows for k in row.recall_at_k or {}}, key=int)
    header = ["environment", "method", "direction", "max F1 %", "P %", "R %", "AUC", "δ at max F1",
              "F1 % at training δ"]
    header += [f"R@{k} %" for k in ks] + ["tied best %"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [
            row.environment, row.method, row.direction, _pct(row.max_f1),
            _pct(row.precision_at_max_f1), _pct(row.recall_at_max_f1),
            f"{row.auc:.3f}", "–" if row.delta_at_max_f1 is None else f"{row.delta_at_max_f1:.4g}",
            _pct(row.f1_at_e1_threshold),
        ]
        cells += [_pct((row.recall_at_k or {}).get(k)) for k in ks] + [_pct(row.tied_share)]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    warnings = [
        f"- WARNING {row.method} in {row.environment} ({row.direction}): the best match of {_pct(row.tied_share)} % "
        "of the queries is tied, so its scores count those queries by the tie rule (correct in proportion), not "
        "by a match it found" for row in rows if row.tied_share is not None and row.tied_share >= TIED_WARNING]
    return "\n".join(lines + ([""] + warnings if warnings else []))


def _per_pair(rows: Sequence[ResultRow]) -> list[ResultRow]:
    """The first row of each environment x direction: what the evaluation pair itself has,
    the same for every method."""
    first: dict[tuple[str, str], ResultRow] = {}
    for row in rows:
        first.setdefault((row.environment, row.direction), row)
    return list(first.values())


def samples_table(rows: Sequence[ResultRow]) -> str:
    """Markdown table of the sample counts per environment x direction: queries, references,
    revisits (queries with a true match)."""
    lines = ["| environment | direction | queries | references | revisits |", "|---|---|---|---|---|"]
    for row in _per_pair(rows):
        references = "–" if row.n_references is None else row.n_references
        lines.append(f"| {row.environment} | {row.direction} | {row.n_queries} | {references} | {row.n_revisit} |")
    return "\n".join(lines)


def _number(value: Any, digits: int) -> str:
    return "–" if value is None else f"{float(value):.{digits}f}"


def difficulty_table(rows: Sequence[ResultRow]) -> str:
    """Markdown table of each evaluation pair's ``difficulty`` (per environment x direction)."""
    lines = [
        "| environment | direction | nearest ref. median m | nearest ref. 90th pct. m | nearest ref. heading median ° "
        "| chance R@1 % | query touch % | reference touch % | query longest stay % | reference longest stay % "
        "| touch both sides % | touch one side % | touch correspondence % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in _per_pair(rows):
        d = row.difficulty or Difficulty()  # measures a run of an older version lacks are None
        cells = [
            row.environment, row.direction, _number(d.nearest_ref_median_m, 3),
            _number(d.nearest_ref_p90_m, 3), _number(d.nearest_ref_heading_median_deg, 1),
            _pct(d.chance_r1), _pct(d.query_touch_share), _pct(d.reference_touch_share),
            _pct(d.query_longest_stay_share), _pct(d.reference_longest_stay_share),
            _pct(d.touch_both_share), _pct(d.touch_one_side_share), _pct(d.touch_correspondence),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def complementarity_table(records: list[dict[str, Any]]) -> str:
    """Markdown table of the complementarity records (complementarity.json): per evaluation,
    direction and vision-only / touch-only pair, the recalls@1, the vision method's wrong best
    matches, how many of them the touch method gets right, and the oracle's recall@1."""
    lines = [
        "| environment | direction | vision | touch | revisits | vision R@1 % | touch R@1 % | vision wrong "
        "| rescued by touch | rescued % | oracle R@1 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in records:
        cells = [c["environment"], c["direction"], c["vision"], c["touch"], str(c["n_revisit"]),
                 _pct(c["vision_r1"]), _pct(c["touch_r1"]), count_text(c["vision_wrong"]), count_text(c["rescued"]),
                 _pct(c["rescue"]), _pct(c["oracle_r1"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _complementarity_section(out: Path) -> list[str]:
    """The complementarity table, when a vision-only and a touch-only method ran (none in
    the folders of older runs, which have no complementarity.json)."""
    path = out / COMPLEMENTARITY
    records = _read_json(path, "the complementarity records a `vitaplace run` writes") if path.is_file() else []
    if not records:
        return []
    return [
        "## Complementarity",
        "",
        "Whether touch rescues vision, per vision-only and touch-only pair: over the queries with a true match "
        "(revisits), each method's recall@1 at its single best match; the vision method's wrong best matches, how "
        "many of those the touch method gets right (rescued) and their share; the oracle takes whichever of the "
        "two is right, the ceiling of any fusion that picks one of their matches.",
        "",
        complementarity_table(records),
        "",
    ]


def _params_text(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={json.dumps(v)}" for k, v in params.items()) or "none"


def _methods_section(methods: dict[str, dict[str, Any]]) -> list[str]:
    """One line per method (manifest ``methods``): its plugin, the parameters the scenario
    sets (with the derived seed) and the plugin's defaults for the others."""
    lines = ["## Methods", ""]
    for name, method in methods.items():
        lines += [f"- **{name}** (`{method['plugin']}`): {_params_text(method['params'])}; "
                  f"defaults: {_params_text(method['defaults'])}"]
    return lines + [""]


def _inputs_section(manifest: dict[str, Any]) -> list[str]:
    """Which runs were read from recorded files (with the file and what data it holds), and
    every method x evaluation run whose feature arrays were all zero, i.e. which features
    carried no information there (e.g. ViTa-SLAM's tactile ones on a run without contacts)."""
    lines = []
    for label, path in manifest["recorded"].items():
        run = manifest["runs"][label]
        lines.append(
            f"- `{label}` read from `{path}`: {run['samples']} samples, {run['whisker_contacts'] or 'no'} whisker "
            f"contacts, {run['deflection_samples']} deflection sample(s) per whisk cycle"
        )
    for method, by_run in manifest["features"].items():
        for label, facts in by_run.items():
            if facts["zero"]:
                used = ", ".join(f"`{k}`" for k in facts["arrays"] if k not in facts["zero"]) or "nothing"
                lines.append(
                    f"- **{method}** on `{label}`: features {', '.join(f'`{k}`' for k in facts['zero'])} are all zero "
                    f"(no data for them in this run), so it matched on {used} alone there"
                )
    if not lines:
        return []
    head = "Runs read from recorded files, and features that carried no information:" if manifest["recorded"] else \
        "Features that carried no information:"
    return ["## Inputs", "", head, "", *lines, ""]


def _warnings_section(manifest: dict[str, Any]) -> list[str]:
    """Every run's warnings (robot collisions, data a method could not use), as in manifest.json."""
    lines = [f"- {message}" for messages in manifest["warnings"].values() for message in messages.values()]
    return ["## Warnings", "", *lines, ""] if lines else []


def _header(manifest: dict[str, Any], description: str, rows: Sequence[ResultRow]) -> list[str]:
    """Title, description and what the results table shows, then the table."""
    tau, heading = rows[0].tau, rows[0].heading_tolerance_deg
    sections = [f"# vitaplace report — {manifest['scenario']}", ""]
    if description:
        sections += [description.strip(), ""]
    return sections + [
        f"Place recognition, single best match per query{_matching(rows[0].sequence, tau)}; a true match is "
        f"{_true_match(tau, heading)}"
        + (" (position only)" if heading is None else "")
        + ". P and R are at the δ that maximises F1 in each evaluation; F1 at training δ is the F1 at the δ that "
        f"maximised the method's F1 in the training world's evaluation, applied unchanged. Training world: "
        f"{manifest['training_world']}. "
        "AUC is the step-wise average precision: the sum over acceptance thresholds δ, in increasing order, of the "
        "recall gained times the precision there (the area under the drawn step curve; 1 is perfect). A query whose "
        "best distance several references share (tied best %) counts as correct in proportion to the true matches "
        "among them, the expected value of a random pick, at every measure (docs/DESIGN.md, \"Ties\").",
        "",
        results_table(rows),
        "",
    ]


def _matching(sequence: SequenceMatching | None, tau: float) -> str:
    """How the distances were matched: single samples (nothing to say) or sequences."""
    if sequence is None:
        return ""
    if sequence.metres is not None:
        return (f", scored by sequences of {sequence.length} points over {sequence.metres:g} m of travelled distance "
                f"(SeqSLAM with the runs' recorded poses as odometry: local contrast over ±{sequence.window} "
                f"references{_window_caveat(sequence, tau)})")
    return (f", scored by sequences of {sequence.length} queries (SeqSLAM: local contrast over "
            f"±{sequence.window} references{_window_caveat(sequence, tau)}, the best straight line at "
            f"{sequence.velocity_steps} relative velocities in [{sequence.velocity_min:g}, "
            f"{sequence.velocity_max:g}])")


def _window_caveat(sequence: SequenceMatching, tau: float) -> str:
    """How much reference drive the contrast window covers, and a warning where it is no more
    than one place (2 tau): each reference is then contrasted with the references of its own
    place, which takes away the true match's lead (docs/DESIGN.md, Sequence matching)."""
    span = sequence.window_span_m
    if span is None:
        return ""
    text = f", a median {span:.2f} m of the reference drive"
    if span <= 2 * tau:
        text += (f": WARNING no more than one place (2τ = {2 * tau:g} m), so each reference is contrasted "
                 "with its own place's references and the true match loses its lead; raise scoring.sequence.window")
    return text


def _true_match(tau: float, heading: float | None) -> str:
    return f"a reference pose within τ = {tau} m" + ("" if heading is None else f" facing within {heading:g}°")


def _samples_and_difficulty(manifest: dict[str, Any], rows: Sequence[ResultRow]) -> list[str]:
    """The sample counts and the difficulty of each evaluation pair."""
    true_match = _true_match(rows[0].tau, rows[0].heading_tolerance_deg)
    return [
        "## Samples",
        "",
        f"Training run: {manifest['runs']['train']['samples']} samples. A revisit is a query with {true_match} (only "
        "revisits can be recalled).",
        "",
        samples_table(rows),
        "",
        "## Difficulty",
        "",
        "Properties of each evaluation pair, the same for every method. Over the queries with a true match: the "
        "distance from each query to its nearest reference pose by position (median, 90th percentile) and the "
        "heading difference to it (median); chance R@1 is the mean share of references that are true matches (a "
        "random guess's recall@1). Touch: the share of samples with a whisker deflected at the sampling instant. "
        f"Longest stay: the longest stretch of consecutive samples within {STAY_RADIUS} m of its first, as a share "
        "of the run (a drive whisking a landmark stays a few samples; a stuck one, much of the run). Whether touch "
        "can matter: pair each query that has a true match with its nearest true match by position; touch both "
        "sides and one side are the shares of those pairs touched on both sides and on exactly one; touch "
        "correspondence is, among the touched queries that have a true match, the share whose pair is touched.",
        "",
        difficulty_table(rows),
        "",
    ]


def _dropout_section(rows: Sequence[ResultRow]) -> list[str]:
    """The evaluations whose query samples lost a sensor (``query_dropout`` of their rows)."""
    lost = {row.environment: row.query_dropout for row in rows if row.query_dropout is not None}
    if not lost:
        return []
    table = ["| evaluation | without camera % | without whiskers % |", "|---|---|---|"]
    table += [f"| {name} | {_pct(shares.camera)} | {_pct(shares.whiskers)} |" for name, shares in lost.items()]
    return [
        "## Query drop-out",
        "",
        "Shares of each evaluation's query samples that lacked a sensor, drawn from the scenario seed (manifest.json, "
        "`dropout`, lists the samples); each method described them by the sensor left.",
        "",
        *table,
        "",
    ]


def _evaluation_sections(out: Path, rows: Sequence[ResultRow], settings: ReportSettings) -> list[str]:
    """Per evaluation: its PR curves, and (``figures: all``) per method and direction its
    matrices with the decisions and its matches drawn over the trajectories (figures into
    OUT/figures, from the evaluation's saved curve, matrices and decisions); with ``figures:
    none`` a line saying that none were drawn."""
    if settings.figures == "none":
        return ["## Figures", "", "None drawn (the scenario's `report.figures` is `none`).", ""]
    fig_dir, formats = out / FIGURES, figure_formats(settings)
    one_direction = len({row.direction for row in rows}) == 1
    sections = []
    for environment in dict.fromkeys(row.environment for row in rows):
        curves = {}
        sections += [f"## {environment}", "", f"![PR curves](figures/pr-{environment}.png)", ""]
        for row in (r for r in rows if r.environment == environment):
            folder = evaluation_dir(out, environment, row.method, row.direction)
            curves[row.method if one_direction else f"{row.method} {row.direction}"] = load_curve(folder / PR_CURVE)
            if settings.figures == "all":
                sections += _pair_figures(out, row, formats)
        figures.plot_pr_curves(fig_dir / f"pr-{environment}", curves, title=f"{environment}: precision-recall",
                               formats=formats)
    return sections


def _pair_figures(out: Path, row: ResultRow, formats: Sequence[str]) -> list[str]:
    """The matrices with the decisions and the matches over the trajectories of one method and
    direction of one evaluation (drawn into OUT/figures), and the report lines showing them."""
    environment, method, direction = row.environment, row.method, row.direction
    folder = evaluation_dir(out, environment, method, direction)
    decisions = load_decisions(folder / DECISIONS)
    arena_file = arena_path(out, environment)
    arena = json.loads(arena_file.read_text()) if arena_file.is_file() else None
    query, reference = direction.split("-to-")
    with np.load(poses_path(out, environment)) as poses:
        query_poses, reference_poses = poses[query], poses[reference]
    stem, fig_dir = f"{environment}-{method}-{direction}", out / FIGURES
    lines = [f"### {method} ({direction})", ""]
    if (folder / MATRICES).is_file():
        with np.load(folder / MATRICES) as m:
            figures.plot_matrices(fig_dir / f"matrices-{stem}", m["tme"], m["gtm"], decisions,
                                  title=f"{environment} {method}", formats=formats)
        lines += [f"![GTM and TME](figures/matrices-{stem}.png)", ""]
    else:
        lines += [f"Matrices not drawn: {decisions.n_queries} queries x {len(reference_poses)} references is over "
                  f"the {pairfiles.FULL_MATRIX_LIMIT:,} entries held whole (FULL_MATRIX_LIMIT).", ""]
    figures.plot_trajectories(fig_dir / f"trajectories-{stem}", query_poses, reference_poses, decisions,
                              arena=arena, title=f"{environment} {method}: matches at max F1", formats=formats)
    return lines + [f"![trajectories](figures/trajectories-{stem}.png)", ""]


def figure_formats(settings: ReportSettings) -> tuple[str, ...]:
    """The formats each figure is saved in: PNG, and PDF when asked; none without figures."""
    if settings.figures == "none":
        return ()
    return ("png", "pdf") if settings.pdf else ("png",)


def report_settings(out: Path, resolved: Mapping[str, Any]) -> ReportSettings:
    """The ``report`` settings of the resolved scenario of ``out`` (the defaults where it sets
    none); ReportError naming the file when they are not valid."""
    try:
        return ReportSettings.model_validate(resolved.get("report") or {})
    except pydantic.ValidationError as exc:
        problem = exc.errors()[0]
        where = ".".join(str(p) for p in ("report", *problem["loc"]))
        raise ReportError(f"{out / completion.SCENARIO}: {where}: {problem['msg']}") from None


def _provenance_section(manifest: dict[str, Any]) -> list[str]:
    packages = ", ".join(f"{name} {v}" for name, v in manifest["packages"].items() if v)
    plugins = ", ".join(sorted({f"{p['distribution']} {p['version']}" for p in manifest["plugins"].values()}))
    dirty = " with uncommitted changes" if manifest["git_dirty"] else ""
    return [
        "## Provenance",
        "",
        f"vitaplace {manifest['vitaplace_version']}, commit {manifest['git_commit'] or 'unknown'}{dirty}, "
        f"scenario seed {manifest['seed']}; {packages}; feature plugins from {plugins or 'no distribution'}. "
        "Seeds, timings and machine in manifest.json, resolved configuration in scenario.resolved.yaml.",
        "",
    ]


def report_files(out: Path, rows: Sequence[ResultRow | Mapping[str, Any]], methods: list[str]) -> list[Path]:
    """Every file the report reads besides the manifest: results, complementarity (when
    there), resolved scenario, each row's evaluation files (``rows``: results rows, or
    mappings `parse_row` reads), each evaluation's poses and (if simulated) arena, each
    method's training curves (if recorded)."""
    out = Path(out)
    parsed = [parse_row(row, f"{out / RESULTS_JSON}: row {i}", ReportError) for i, row in enumerate(rows)]
    files = [out / RESULTS_JSON, out / completion.SCENARIO] + [p for p in [out / COMPLEMENTARITY] if p.is_file()]
    files += [path for row in parsed for name in EVALUATION_FILES
              if (path := evaluation_dir(out, row.environment, row.method, row.direction) / name).is_file()
              or name != MATRICES]  # a pair over FULL_MATRIX_LIMIT has no matrices
    for environment in dict.fromkeys(row.environment for row in parsed):
        files += [poses_path(out, environment)] + [p for p in [arena_path(out, environment)] if p.is_file()]
    return files + [p for name in methods if (p := training_path(out, name)).is_file()]


def _read_json(path: Path, expected: str) -> Any:
    """``path``'s JSON content, or ReportError naming the file and what was expected."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise ReportError(f"{path}: missing; expected {expected}") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ReportError(f"{path}: unreadable ({type(exc).__name__}); expected {expected}") from None


def read_inputs(out: Path) -> tuple[dict[str, Any], list[ResultRow]]:
    """The manifest's entries the report reads (`MANIFEST_KEYS`) and the result rows of the
    run in ``out``; ReportError naming the file when one is missing or is not what a run writes."""
    out = Path(out)
    manifest = _read_json(out / MANIFEST, "the manifest a `vitaplace run` writes")
    rows = _read_json(out / RESULTS_JSON, "the result rows a `vitaplace run` writes")
    missing = [k for k in MANIFEST_KEYS if not isinstance(manifest, dict) or k not in manifest]
    if missing:
        raise ReportError(f"{out / MANIFEST}: no {', '.join(missing)}; expected the manifest of a `vitaplace run` "
                          "(those of older versions lack these entries)")
    if not isinstance(rows, list) or not rows:
        raise ReportError(f"{out / RESULTS_JSON}: expected a non-empty list of result rows")
    rows = [parse_row(row, f"{out / RESULTS_JSON}: row {i}", ReportError) for i, row in enumerate(rows)]
    # how each method's training ended: absent where no method reports it
    return {**{k: manifest[k] for k in MANIFEST_KEYS}, "training": manifest.get("training") or {}}, rows


def report_key_inputs(out: Path) -> dict[str, Any]:
    """Everything the report of ``out`` depends on: the manifest entries it reads and the
    digest of every other file it reads (the report stage's key is a hash of this)."""
    manifest, rows = read_inputs(out)
    files = report_files(out, rows, list(manifest["methods"]))
    return {"manifest": manifest, "files": {str(p.relative_to(out)): digest(p) for p in files}}


def _fusions_section(rows: Sequence[ResultRow], fusions: list[dict[str, Any]]) -> list[str]:
    """The late fusions' chosen weights, per fusion and direction (the same in every evaluation)."""
    settings = {f["name"]: f for f in fusions}
    chosen = {(row.method, row.direction): row.fusion for row in rows if row.fusion is not None}
    if not chosen:
        return []
    lines = ["## Late fusions", "",
             "d = d_V / σ_V + w · d_T / σ_T of a vision-only and a touch-only method (σ: the spread of each one's "
             "distances where w is chosen), w the weight of the scenario's grid with the largest max F1 on the "
             "selection evaluation (ties: the smallest), applied unchanged to every evaluation.", "",
             "| fusion | vision + touch | chosen on | direction | w | σ_V | σ_T | max F1 there |",
             "|---|---|---|---|---|---|---|---|"]
    for (name, direction), f in chosen.items():
        s = settings[name]
        lines.append(f"| {name} | {s['vision']} + {s['touch']} | {s.get('select_on') or 'the training world'} "
                     f"| {direction} | {f.weight:g} | {f.sigma_vision:.4g} | {f.sigma_touch:.4g} "
                     f"| {100 * f.selection_max_f1:.2f} % |")
    return lines + [""]


def write_report(out: Path) -> ReportSettings:
    """report.md for the run in ``out`` and the figures its scenario's ``report`` settings ask
    for (`ReportSettings`) in figures/, from its files alone; returns those settings."""
    out = Path(out)
    manifest, rows = read_inputs(out)
    resolved = yaml.safe_load((out / completion.SCENARIO).read_text()) or {}
    settings = report_settings(out, resolved)
    description = resolved.get("description", "")
    sections = [
        *_header(manifest, description, rows),
        *_warnings_section(manifest),
        *_samples_and_difficulty(manifest, rows),
        *_complementarity_section(out),
        *_fusions_section(rows, resolved.get("fusions") or []),
        *_dropout_section(rows),
        *_methods_section(manifest["methods"]),
        *inference_section(manifest),
        *tactile_range_section(manifest),
        *drive_section(manifest),
        *_evaluation_sections(out, rows, settings),
        *training_section(out, list(manifest["methods"]), manifest["training"], figure_formats(settings)),
        *_inputs_section(manifest),
        *_provenance_section(manifest),
    ]
    write_text_atomic(out / REPORT, "\n".join(sections))
    return settings


def rebuild_report(out: Path) -> tuple[Path, ReportSettings]:
    """``vitaplace report OUT``: check that ``out`` holds a finished run whose files the
    report reads are all there and unchanged since (its completion record), then
    `write_report`; returns the report's path and the settings it drew its figures with."""
    out = Path(out)
    manifest, rows = read_inputs(out)
    files = report_files(out, rows, list(manifest["methods"]))
    missing = next((p for p in files if not p.is_file()), None)
    if missing is not None:
        raise ReportError(f"{missing}: missing; expected it in the folder of a finished `vitaplace run`")
    recorded = [str(p.relative_to(out)) for p in files if p.name != completion.SCENARIO]  # the record has its own
    wrong = completion.problem(out, [MANIFEST, *recorded])
    if wrong:
        raise ReportError(f"{out}: not a finished run: {wrong}")
    return out / REPORT, write_report(out)
