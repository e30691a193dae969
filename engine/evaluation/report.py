"""The Markdown report of a scenario run, with the paper's figures (paper Fig. 4-5): results,
sample counts, every method's parameters, figures per evaluation, training, provenance."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np

from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.evaluation import figures
from vitaplace.engine.atomic import write_text_atomic
from vitaplace.engine.plugins import plugin_distributions
from vitaplace.engine.pipeline import outdir
from vitaplace.engine.pipeline.provenance import provenance
from vitaplace.engine.config.scenario import training_world_evaluation
from vitaplace.engine.sim.environment import load_environment

if TYPE_CHECKING:
    from vitaplace.engine.pipeline.runner import Pipeline


def _pct(value: Any) -> str:
    return "–" if value is None else f"{100 * float(value):.2f}"


def results_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table: one row per environment x method x direction (F1, P, R in %; F1 at
    the training world's threshold, ``f1_at_e1_threshold``)."""
    ks = sorted({k for row in rows for k in row.get("recall_at_k", {})}, key=int)
    header = ["environment", "method", "direction", "max F1 %", "P %", "R %", "AUC", "δ at max F1",
              "F1 % at training δ"]
    header += [f"R@{k} %" for k in ks]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [
            row["environment"], row["method"], row["direction"], _pct(row["max_f1"]),
            _pct(row.get("precision_at_max_f1")), _pct(row.get("recall_at_max_f1")),
            f"{row['auc']:.3f}", "–" if row["delta_at_max_f1"] is None else f"{row['delta_at_max_f1']:.4g}",
            _pct(row.get("f1_at_e1_threshold")),
        ]
        cells += [_pct(row["recall_at_k"].get(k)) for k in ks]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def _per_pair(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The first row of each environment x direction: what the evaluation pair itself has,
    the same for every method."""
    first: dict[tuple[str, str], dict[str, Any]] = {}
    for row in rows:
        first.setdefault((row["environment"], row["direction"]), row)
    return list(first.values())


def samples_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of the sample counts per environment x direction: queries, references,
    revisits (queries with a true match)."""
    lines = ["| environment | direction | queries | references | revisits |", "|---|---|---|---|---|"]
    for row in _per_pair(rows):
        lines.append(f"| {row['environment']} | {row['direction']} | {row['n_queries']} | "
                     f"{row.get('n_references', '–')} | {row['n_revisit']} |")
    return "\n".join(lines)


def _number(value: Any, digits: int) -> str:
    return "–" if value is None else f"{float(value):.{digits}f}"


def difficulty_table(rows: list[dict[str, Any]]) -> str:
    """Markdown table of each evaluation pair's ``difficulty`` (per environment x direction)."""
    lines = [
        "| environment | direction | nearest ref. median m | nearest ref. 90th pct. m | nearest ref. heading median ° "
        "| chance R@1 % | query touch % | reference touch % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in _per_pair(rows):
        d = row["difficulty"]
        cells = [
            row["environment"], row["direction"], _number(d["nearest_ref_median_m"], 3),
            _number(d["nearest_ref_p90_m"], 3), _number(d["nearest_ref_heading_median_deg"], 1),
            _pct(d["chance_r1"]), _pct(d["query_touch_share"]), _pct(d["reference_touch_share"]),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def method_parameters(pipeline: Pipeline) -> dict[str, tuple[str, dict[str, Any], dict[str, Any]]]:
    """Per method: its plugin, the parameters the scenario sets (with the derived seed) and
    the plugin's defaults for the others."""
    out = {}
    for method in pipeline.scenario.methods:
        given = pipeline.method_params(method)
        full = pipeline.registry.get(method.plugin).validate_params(given).model_dump(mode="json")
        out[method.name] = (method.plugin, {k: full[k] for k in full if k in given},
                            {k: v for k, v in full.items() if k not in given})
    return out


def _params_text(params: dict[str, Any]) -> str:
    return ", ".join(f"{k}={json.dumps(v)}" for k, v in params.items()) or "none"


def _methods_section(pipeline: Pipeline) -> list[str]:
    lines = ["## Methods", ""]
    for name, (plugin, given, defaults) in method_parameters(pipeline).items():
        lines += [f"- **{name}** (`{plugin}`): {_params_text(given)}; defaults: {_params_text(defaults)}"]
    return lines + [""]


def inference_table(pipeline: Pipeline) -> str:
    """Markdown table of the test-time inference steps per method and evaluation run, for
    methods whose features record them (``inference_steps``, ``inference_stopped``): median,
    90th percentile and largest step count, and the share of samples that hit the step cap."""
    from vitaplace.engine.features import load_features

    lines = []
    for method in pipeline.scenario.methods:
        for label in pipeline.runs():
            if label == "train":
                continue
            features = load_features(pipeline.features_path(method, label))
            if "inference_steps" not in features:
                break
            steps, stopped = features["inference_steps"], features["inference_stopped"].astype(bool)
            lines.append(
                f"| {method.name} | {label} | {np.median(steps):.0f} | {np.percentile(steps, 90):.0f} | "
                f"{steps.max()} | {100 * (~stopped).mean():.1f} |"
            )
    if not lines:
        return ""
    table = ["| method | run | median steps | 90th percentile | most | % at the cap |", "|---|---|---|---|---|---|", *lines]
    return "\n".join(table + _cap_warnings(pipeline))


#: a share of test-time inferences at the step cap from which the report warns
CAP_WARNING_SHARE = 0.5


def _cap_warnings(pipeline: Pipeline) -> list[str]:
    """A warning line per method whose test-time inference hit the step cap in every, or in
    most (`CAP_WARNING_SHARE`), samples of the evaluation runs: its latents did not settle."""
    from vitaplace.engine.features import load_features

    lines = []
    for method in pipeline.scenario.methods:
        stopped = [load_features(pipeline.features_path(method, label)).get("inference_stopped")
                   for label in pipeline.runs() if label != "train"]
        if not stopped or any(s is None for s in stopped):
            continue
        capped = ~np.concatenate(stopped).astype(bool)
        if capped.mean() >= CAP_WARNING_SHARE:
            share = "every" if capped.all() else f"{100 * capped.mean():.0f} % of the"
            lines.append(
                f"**Warning: {share} test-time inference{'' if capped.all() else 's'} of {method.name} hit the step "
                f"cap** ({capped.sum()} of {capped.size} samples): the latents had not settled when they were read; "
                "raise the method's `max_steps` (or its inference rate) before reading much into its numbers."
            )
    return ["", *lines] if lines else []


def _inputs_section(pipeline: Pipeline) -> list[str]:
    """Which runs were read from recorded files (with the file and what data it holds), and
    every method x evaluation run whose feature arrays were all zero, i.e. which features
    carried no information there (e.g. ViTa-SLAM's tactile ones on a run without contacts)."""
    from vitaplace.engine.features import load_features

    lines = []
    for label, path in pipeline.recorded.items():
        run = pipeline.open(label)
        contacts = int(run.contact_offsets[-1])
        lines.append(
            f"- `{label}` read from `{path}`: {len(run)} samples, {contacts or 'no'} whisker contacts, "
            f"{run.deflection.shape[1]} deflection sample(s) per whisk cycle"
        )
    for method in pipeline.scenario.methods:
        for label in pipeline.runs():
            if label == "train":
                continue
            features = load_features(pipeline.features_path(method, label))
            arrays = {k: v for k, v in features.items() if v.dtype.kind == "f" and v.ndim >= 2}
            zero = sorted(k for k, v in arrays.items() if not v.any())
            if zero:
                used = ", ".join(f"`{k}`" for k in sorted(arrays) if k not in zero) or "nothing"
                lines.append(
                    f"- **{method.name}** on `{label}`: features {', '.join(f'`{k}`' for k in zero)} are all zero "
                    f"(no data for them in this run), so it matched on {used} alone there"
                )
    if not lines:
        return []
    head = "Runs read from recorded files, and features that carried no information:" if pipeline.recorded else \
        "Features that carried no information:"
    return ["## Inputs", "", head, "", *lines, ""]


def _warnings_section(pipeline: Pipeline) -> list[str]:
    """Every run's warnings (robot collisions, data a method could not use), as in manifest.json."""
    lines = [f"- {message}" for run in pipeline.opened.values() for message in run.warnings.values()]
    return ["## Warnings", "", *lines, ""] if lines else []


def write_report(pipeline: Pipeline, rows: list[dict[str, Any]]) -> None:
    """figures/ (PNG + PDF) and report.md for the evaluated scenario."""
    out, scenario = pipeline.out, pipeline.scenario
    fig_dir = out / outdir.FIGURES
    tau, heading = scenario.evaluation.tau, scenario.evaluation.heading_tolerance_deg
    true_match = f"a reference pose within τ = {tau} m" + ("" if heading is None else f" facing within {heading:g}°")
    _, source = training_world_evaluation(scenario)
    sections = [f"# vitaplace report — {scenario.name}", ""]
    if scenario.description:
        sections += [scenario.description.strip(), ""]
    sections += [
        f"Place recognition, single best match per query; a true match is {true_match}"
        + (" (position only)" if heading is None else "")
        + ". P and R are at the δ that maximises F1 in each evaluation; F1 at training δ is the F1 at the δ that "
        f"maximised the method's F1 in the training world's evaluation, applied unchanged. Training world: {source}. "
        "AUC is the step-wise average precision: the sum over acceptance thresholds δ, in increasing order, of the "
        "recall gained times the precision there (the area under the drawn step curve; 1 is perfect).",
        "",
        results_table(rows),
        "",
        *_warnings_section(pipeline),
        "## Samples",
        "",
        f"Training run: {len(pipeline.open('train'))} samples. A revisit is a query with {true_match} (only "
        "revisits can be recalled).",
        "",
        samples_table(rows),
        "",
        "## Difficulty",
        "",
        "Properties of each evaluation pair, the same for every method. Over the queries with a true match: the "
        "distance from each query to its nearest reference pose by position (median, 90th percentile) and the "
        "heading difference to it (median); chance R@1 is the mean share of references that are true matches (a "
        "random guess's recall@1). Touch: the share of samples with a whisker deflected at the sampling instant.",
        "",
        difficulty_table(rows),
        "",
        *_methods_section(pipeline),
    ]
    inference = inference_table(pipeline)
    if inference:
        sections += [
            "## Test-time inference",
            "",
            "Each sample's latents are inferred until its prediction errors fall under their "
            "thresholds, or up to the method's step cap (`max_steps`).",
            "",
            inference,
            "",
        ]
    for e in scenario.evaluations:
        arena = load_environment(e.environment).top_view() if e.environment is not None else None
        curves = {}
        sections += [f"## {e.name}", "", f"![PR curves](figures/pr-{e.name}.png)", ""]
        for method in scenario.methods:
            for direction, q, r in pipeline.directions():
                folder = pipeline.evaluation_dir(e.name, method.name, direction)
                with np.load(folder / outdir.MATRICES) as m:
                    tme, gtm = m["tme"], m["gtm"]
                curve = ev.load_curve(folder / outdir.PR_CURVE)
                curves[method.name if len(pipeline.directions()) == 1 else f"{method.name} {direction}"] = curve
                decisions = ev.load_decisions(folder / "decisions.npz")
                stem = f"{e.name}-{method.name}-{direction}"
                figures.plot_matrices(fig_dir / f"matrices-{stem}", tme, gtm, decisions, title=f"{e.name} {method.name}")
                figures.plot_trajectories(
                    fig_dir / f"trajectories-{stem}",
                    pipeline.open(f"{e.name}/{q}").poses,
                    pipeline.open(f"{e.name}/{r}").poses,
                    decisions,
                    arena=arena,
                    title=f"{e.name} {method.name}: matches at max F1",
                )
                sections += [
                    f"### {method.name} ({direction})",
                    "",
                    f"![GTM and TME](figures/matrices-{stem}.png)",
                    "",
                    f"![trajectories](figures/trajectories-{stem}.png)",
                    "",
                ]
        figures.plot_pr_curves(fig_dir / f"pr-{e.name}", curves, title=f"{e.name}: precision-recall")
    training = [(m.name, pipeline.training_record(m)["history"]) for m in scenario.methods]
    training = [(name, history) for name, history in training if history]
    if training:
        sections += ["## Training", ""]
        for name, history in training:
            figures.plot_energy(fig_dir / f"training-{name}", history, title=f"{name}: training energy per layer")
            sections += [f"![training {name}](figures/training-{name}.png)", ""]
    sections += _inputs_section(pipeline)
    origin = provenance()
    packages = ", ".join(f"{name} {v}" for name, v in origin["packages"].items() if v)
    plugins = ", ".join(sorted({f"{p['distribution']} {p['version']}" for p in plugin_distributions(pipeline.registry).values()}))
    dirty = " with uncommitted changes" if origin["git_dirty"] else ""
    sections += [
        "## Provenance",
        "",
        f"vitaplace {origin['vitaplace_version']}, commit {origin['git_commit'] or 'unknown'}{dirty}, scenario seed "
        f"{scenario.seed}; {packages}; feature plugins from {plugins or 'no distribution'}. Seeds, timings and "
        "machine in manifest.json, resolved configuration in scenario.resolved.yaml.",
        "",
    ]
    write_text_atomic(out / outdir.REPORT, "\n".join(sections))
