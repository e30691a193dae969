"""The report's sections on the learned methods' features, from the manifest's feature facts
(`feature_facts`): their test-time inference (steps, settled share, a warning when most
samples hit the step cap), how much of the tactile input lay inside the training range, and
which modality drives the joint latent."""

from __future__ import annotations

from typing import Any

from vitaplace.engine.extension.features import IN_RANGE_SHARE


def _facts(features: dict[str, dict[str, dict[str, Any]]], kind: str) -> list[tuple[str, str, dict[str, Any]]]:
    """(method, run, facts) for every method and run whose features have facts of ``kind``
    (`feature_facts`: ``inference``, ``tactile_range``)."""
    return [(method, label, facts[kind]) for method, by_run in features.items()
            for label, facts in by_run.items() if facts.get(kind)]


def inference_table(features: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Markdown table of the test-time inference steps per method and evaluation run, for
    methods whose features record them (`feature_facts`): median, 90th percentile and
    largest step count, the share of samples a stopping rule ended before the step cap
    (settled) and the share under every threshold (older facts without ``stopped``: -)."""
    lines = [
        f"| {method} | {label} | {i['median']:.0f} | {i['p90']:.0f} | {i['max']} | "
        f"{100 * (1 - i['capped'] / i['samples']):.1f} | {_percent(i.get('stopped'), i['samples'])} |"
        for method, label, i in _facts(features, "inference")
    ]
    table = _table(["method", "run", "median steps", "90th percentile", "most", "% settled",
                    "% under the thresholds"], lines)
    return "\n".join([table, *_cap_warnings(features)]) if table else ""


def _table(columns: list[str], rows: list[str]) -> str:
    """A markdown table of ``rows`` (each a ``| ... |`` line) under ``columns``; "" without rows."""
    if not rows:
        return ""
    return "\n".join([f"| {' | '.join(columns)} |", "|" + "---|" * len(columns), *rows])


def _percent(count: int | None, total: int) -> str:
    return "-" if count is None else f"{100 * count / total:.1f}"


#: a share of test-time inferences at the step cap from which the report warns
CAP_WARNING_SHARE = 0.5


def _cap_warnings(features: dict[str, dict[str, dict[str, Any]]]) -> list[str]:
    """A warning line per method whose test-time inference hit the step cap in every, or in
    most (`CAP_WARNING_SHARE`), samples of the evaluation runs: its latents did not settle."""
    lines = []
    for method, by_run in features.items():
        inferences: list[Any] = [facts.get("inference") for facts in by_run.values()]
        if not inferences or any(i is None for i in inferences):
            continue
        capped, samples = sum(i["capped"] for i in inferences), sum(i["samples"] for i in inferences)
        if capped / samples >= CAP_WARNING_SHARE:
            every = capped == samples
            share = "every" if every else f"{100 * capped / samples:.0f} % of the"
            lines.append(
                f"**Warning: {share} test-time inference{'' if every else 's'} of {method} hit the step "
                f"cap** ({capped} of {samples} samples): the latents had not settled when they were read; "
                "raise the method's `max_steps` (or its inference rate) before reading much into its numbers."
            )
    return ["", *lines] if lines else []


def _section(heading: str, text: str, table: str) -> list[str]:
    """A report section: its heading, what it shows and its table; none without a table."""
    return [f"## {heading}", "", text, "", table, ""] if table else []


def inference_section(manifest: dict[str, Any]) -> list[str]:
    return _section(
        "Test-time inference",
        "Each sample's latents are inferred until its prediction errors fall under their "
        "thresholds or, where the method has a relative rule (`inference_rtol`), its step has "
        "shrunk below that fraction of its first; otherwise up to the method's step cap "
        "(`max_steps`). A sample is settled when a rule ended it before the cap.",
        inference_table(manifest["features"]),
    )


def tactile_range_table(features: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Markdown table, per method and evaluation run whose features measure the tactile input
    against its training range (`feature_facts`' ``tactile_range``): the share of its values
    (samples x channels) inside the range, the lowest channel's share, the channels under
    `IN_RANGE_SHARE` and the largest excess beyond [0, 1] in scaled units."""
    lines = [
        f"| {method} | {label} | {_percent(r['inside'], r['values']) if r['values'] else '-'} | "
        f"{100 * r['channel_min']:.1f} | {r['channels_under']} of {r['channels']} | {r['beyond']:.3g} |"
        for method, label, r in _facts(features, "tactile_range")
    ]
    return _table(["method", "run", "% of values in range", "lowest channel %",
                   f"channels under {100 * IN_RANGE_SHARE:g} %", "largest excess (scaled units)"], lines)


def tactile_range_section(manifest: dict[str, Any]) -> list[str]:
    return _section(
        "Tactile inputs inside the training range",
        "Each tactile channel is scaled on the training run (`tactile_scaling`). Per method and evaluation run: "
        "the share of the run's tactile values (samples x channels, samples without whiskers left out) inside "
        "their channel's range on the training run, the lowest channel's share, the channels with less than "
        f"{100 * IN_RANGE_SHARE:g} % inside, and how far the farthest value lies beyond [0, 1] in min-max scaled "
        "units (the channel's training range, floored by `tactile_min_range`, is 1). Under `tactile_scaling: clip` "
        "such values are fed saturated at the ends of the training range; otherwise as they are.",
        tactile_range_table(manifest["features"]),
    )


def drive_table(features: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Markdown table, per method and evaluation run with vision's share of the joint drive
    (`feature_facts`' ``drive``): samples with both modalities, the share's median, 10-90 %."""
    lines = [
        f"| {method} | {label} | {d['samples']} | "
        + (f"{d['median']:.3f} | {d['p10']:.3f} - {d['p90']:.3f} |" if d["samples"] else "- | - |")
        for method, label, d in _facts(features, "drive")
    ]
    return _table(["method", "run", "samples with both modalities", "vision's share, median", "10-90 %"], lines)


def drive_section(manifest: dict[str, Any]) -> list[str]:
    return _section(
        "Which modality drives the joint latent",
        "Per learned method fed both modalities and evaluation run: at each sample's settled latents, vision's "
        "share of the drive on the joint latent, ||T_v|| / (||T_v|| + ||T_t||), T_m being the gradient of the "
        "joint edge of modality m's energy in the joint latent (docs/MUPNET.md, \"Which modality drives the joint "
        "latent\"); 0.5 is an equal pull, touch's share is 1 minus vision's. Samples missing a modality (a query "
        "drop-out) are left out.",
        drive_table(manifest["features"]),
    )
