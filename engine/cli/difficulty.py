"""``vitaplace difficulty SCENARIO``: whether touch can matter in a scenario's evaluations,
measured with the hand-crafted family alone, against each evaluation's ``gates``.

It runs the pipeline's stages up to the evaluation (cached as any run's) on the scenario with
its methods replaced by `FAMILY`: the ``handcrafted`` plugin with its default parameters (H),
vision only (H-V) and touch only (H-T). No learned method is fitted. Per evaluation and
direction it prints the touch measures of the difficulty (``touch_both_share``,
``touch_one_side_share``, ``touch_correspondence``), the complementarity of H-V and H-T and
H-V's max F1 and the headroom (the oracle's recall@1 minus the better single modality's),
each gate beside its value: ``MISSED`` when the value does not meet it (also
when there is no value), ``-`` when the evaluation declares none. A missed gate does not
change the exit status: the command reports, the reader decides.
"""

from __future__ import annotations

import json
from typing import Any

from vitaplace.engine.config.scenario import Gates, Scenario
from vitaplace.engine.evaluation.complementarity import count_text
from vitaplace.engine.outputs.rows import ResultRow

__all__ = ["FAMILY", "GATES", "VISION", "TOUCH", "difficulty_rows", "family_overrides", "gate_results", "headroom",
           "table"]

VISION, TOUCH = "H-V", "H-T"
#: the methods `vitaplace difficulty` runs instead of the scenario's
FAMILY = [
    {"name": "H", "plugin": "handcrafted"},
    {"name": VISION, "plugin": "handcrafted", "params": {"use_tactile": False}},
    {"name": TOUCH, "plugin": "handcrafted", "params": {"use_visual": False}},
]
#: gate -> (the measure it bounds, whether the gate is a minimum), the measures' names as printed
GATES = {
    "touch_correspondence_min": ("touch_correspondence", True),
    "rescue_min": ("rescue", True),
    "hv_max_f1_max": ("hv_max_f1", False),
    "headroom_min": ("headroom", True),
}


def family_overrides() -> list[str]:
    """The ``--set`` assignments that make a scenario's methods `FAMILY` (and drop the pairs
    its ``scoring.complementarity`` names, H-V and H-T pair by themselves, and its fusions of
    methods no longer there)."""
    return [f"methods={json.dumps(FAMILY)}", "scoring.complementarity=[]", "fusions=[]"]


def gate_results(gates: Gates, values: dict[str, float | None]) -> dict[str, dict[str, Any]]:
    """Per gate of `GATES`: ``{"gate": the bound or None, "value": the measure, "met": True,
    False or None (no gate)}``; a declared gate with no value (None) is not met."""
    results = {}
    for gate, (measure, is_min) in GATES.items():
        bound, value = getattr(gates, gate), values[measure]
        if bound is None:
            met = None
        else:
            met = value is not None and (value >= bound if is_min else value <= bound)
        results[gate] = {"gate": bound, "value": value, "met": met}
    return results


def headroom(pair: dict[str, Any]) -> float | None:
    """What a fusion of the pair could add to recall@1 at most: the oracle's (each query right
    when either method is) minus the better method's; None without queries to recall."""
    if pair["oracle_r1"] is None:
        return None
    return pair["oracle_r1"] - max(pair["vision_r1"], pair["touch_r1"])


def difficulty_rows(scenario: Scenario, rows: list[ResultRow],
                    complementarity: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per evaluation and direction: its ``difficulty``, the complementarity of H-V
    and H-T there, H-V's max F1 and the gates' results (`gate_results`)."""
    gates = {e.name: e.gates for e in scenario.evaluations}
    out = []
    for row in (r for r in rows if r.method == VISION):
        where = (row.environment, row.direction)
        pair = next(c for c in complementarity if (c["environment"], c["direction"]) == where
                    and (c["vision"], c["touch"]) == (VISION, TOUCH))
        pair = {k: v for k, v in pair.items() if k not in ("environment", "direction")}
        difficulty = row.difficulty.dump() if row.difficulty is not None else {}
        values = {"touch_correspondence": difficulty.get("touch_correspondence"), "rescue": pair["rescue"],
                  "hv_max_f1": row.max_f1, "headroom": headroom(pair)}
        out.append({"environment": row.environment, "direction": row.direction, "difficulty": difficulty,
                    "complementarity": pair, "hv_max_f1": row.max_f1,
                    "gates": gate_results(gates[row.environment], values)})
    return out


def _pct(value: float | None) -> str:
    return "none" if value is None else f"{100 * value:.1f} %"


def _gated(result: dict[str, Any], is_min: bool) -> str:
    """A measure beside its gate: ``52.0 %``, ``52.0 % (>= 40.0 %)``, ``MISSED 52.0 % (>= 70.0 %)``."""
    value = _pct(result["value"])
    if result["met"] is None:
        return f"{value} (-)"
    bound = f"({'>=' if is_min else '<='} {_pct(result['gate'])})"
    return f"{value} {bound}" if result["met"] else f"MISSED {value} {bound}"


def table(rows: list[dict[str, Any]]) -> str:
    """The rows of `difficulty_rows` as a Markdown table, each gated measure beside its gate."""
    header = ["evaluation", "direction", "touch both sides", "touch one side", "touch correspondence",
              f"{TOUCH} rescues of {VISION}'s R@1 failures", f"{VISION} max F1", "headroom (oracle - best R@1)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for measured in rows:
        d, c, g = measured["difficulty"], measured["complementarity"], measured["gates"]
        gated = {gate: _gated(g[gate], is_min) for gate, (_, is_min) in GATES.items()}
        cells = [measured["environment"], measured["direction"], _pct(d["touch_both_share"]),
                 _pct(d["touch_one_side_share"]), gated["touch_correspondence_min"],
                 f"{count_text(c['rescued'])} of {count_text(c['vision_wrong'])}: {gated['rescue_min']}",
                 gated["hv_max_f1_max"], gated["headroom_min"]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
