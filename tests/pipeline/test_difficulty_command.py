"""`vitaplace difficulty`: the hand-crafted family alone on a scenario's evaluations, its
touch measures and complementarity against each evaluation's gates."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.difficulty import GATES, gate_results, headroom, table  # noqa: E402
from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.config.scenario import Gates  # noqa: E402
from vitaplace.engine.evaluation import evaluate as ev  # noqa: E402
from vitaplace.engine.evaluation.complementarity import complementarity  # noqa: E402

ENV_E1 = str(Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml")


@pytest.mark.parametrize("gates, values, expected", [
    # nothing declared: every gate "-" (met None), the values still reported
    ({}, {"touch_correspondence": 0.5, "rescue": 0.2, "hv_max_f1": 0.9, "headroom": 0.05}, (None, None, None, None)),
    # the bound itself meets a gate: 0.7 >= 0.7, 0.25 >= 0.25, 0.85 <= 0.85, 0.1 >= 0.1
    ({"touch_correspondence_min": 0.7, "rescue_min": 0.25, "hv_max_f1_max": 0.85, "headroom_min": 0.1},
     {"touch_correspondence": 0.7, "rescue": 0.25, "hv_max_f1": 0.85, "headroom": 0.1}, (True, True, True, True)),
    # just past each bound: missed
    ({"touch_correspondence_min": 0.7, "rescue_min": 0.25, "hv_max_f1_max": 0.85, "headroom_min": 0.1},
     {"touch_correspondence": 0.69, "rescue": 0.24, "hv_max_f1": 0.86, "headroom": 0.09}, (False, False, False, False)),
    # no value (no touched query with a true match; vision never wrong; no query to recall): a
    # declared gate is missed
    ({"touch_correspondence_min": 0.0, "rescue_min": 0.0, "headroom_min": 0.0},
     {"touch_correspondence": None, "rescue": None, "hv_max_f1": 0.1, "headroom": None}, (False, False, None, False)),
])
def test_gates_by_hand(gates, values, expected):
    results = gate_results(Gates(**gates), values)
    assert list(results) == list(GATES)
    assert tuple(r["met"] for r in results.values()) == expected
    assert [r["value"] for r in results.values()] == [values[measure] for measure, _ in GATES.values()]
    assert [r["gate"] for r in results.values()] == [gates.get(g) for g in GATES]


def test_the_rescue_gate_reads_tied_best_matches_in_proportion():
    # tau 0.3; q0's true match r0, q1's r1. Vision is wrong on both (best r1, r0). Touch is right
    # on q0 and ties r0 (wrong) with r1 (right) on q1: rescued 1 + 1/2 of 2, 75 %, which meets a
    # 70 % gate (the lowest index, r0, would rescue 1 of 2 and miss it)
    gtm = np.array([[0.1, 1.0], [1.0, 0.1]])
    vision = ev.decide(np.array([[0.5, 0.1], [0.1, 0.5]]), gtm, 0.3, np.inf)
    touch = ev.decide(np.array([[0.1, 0.5], [0.2, 0.2]]), gtm, 0.3, np.inf)
    c = complementarity(vision, touch)
    assert (c["rescued"], c["vision_wrong"], c["rescue"]) == (1.5, 2, 0.75)
    gates = gate_results(Gates(rescue_min=0.7), {"touch_correspondence": 1.0, "rescue": c["rescue"], "hv_max_f1": 0.0,
                                                 "headroom": 0.0})
    assert gates["rescue_min"] == {"gate": 0.7, "value": 0.75, "met": True}
    measured = {"environment": "E", "direction": "query-to-reference", "complementarity": c, "gates": gates,
                "difficulty": {"touch_both_share": 1.0, "touch_one_side_share": 0.0}}
    assert table([measured]).splitlines()[2].split(" | ")[5] == "1.50 of 2: 75.0 % (>= 70.0 %)"


def test_the_headroom_is_the_oracle_recall_over_the_better_single_modality():
    # vision right on q0 and q1 of four, touch on q1, q2 and q3: the oracle on all four, the
    # better single method (touch) on 75 %: 25 points a fusion could add at most
    gtm = np.array([[0.1, 1.0, 1.0, 1.0], [1.0, 0.1, 1.0, 1.0], [1.0, 1.0, 0.1, 1.0], [1.0, 1.0, 1.0, 0.1]])
    right = {"vision": [0, 1, 3, 2], "touch": [1, 1, 2, 3]}  # each query's best reference
    decided = {m: ev.decide(np.where(np.arange(4) == np.array(best)[:, None], 0.1, 0.9), gtm, 0.3, np.inf)
               for m, best in right.items()}
    c = complementarity(decided["vision"], decided["touch"])
    assert (c["vision_r1"], c["touch_r1"], c["oracle_r1"]) == (0.5, 0.75, 1.0)
    assert headroom(c) == 0.25
    assert headroom({**c, "oracle_r1": None}) is None


def test_difficulty_runs_the_handcrafted_family_alone_and_prints_gates(tmp_path, capsys):
    scenario = {
        "name": "d",
        "train": {"environment": ENV_E1, "run": {"kind": "foraging", "n_samples": 5}},
        "evaluations": [{"name": "E1", "environment": ENV_E1, "run": {"kind": "route", "n_samples": 8},
                         "gates": {"touch_correspondence_min": 0.0, "hv_max_f1_max": 0.0}}],
        # a learned method and a pair of its own: neither is run (no fit of L)
        "methods": [{"name": "L", "plugin": "mupnet"}, {"name": "L-V", "plugin": "mupnet"}],
        "scoring": {"tau": 0.3, "complementarity": [{"vision": "L-V", "touch": "L"}]},
    }
    path = tmp_path / "d.yaml"
    path.write_text(yaml.safe_dump(scenario))
    host = tmp_path / "out"
    assert main(["-q", "difficulty", str(path), "--out", str(host), "--json", "--no-progress"]) == 0
    out = host / "difficulty"  # its own folder in --out
    rows = json.loads(capsys.readouterr().out)  # stdout holds the JSON and nothing else
    manifest = json.loads((out / "manifest.json").read_text())
    assert list(manifest["methods"]) == ["H", "H-V", "H-T"]
    assert not any(r["stage"] == "fit" and r["item"].startswith("L") for r in manifest["stages"])
    assert [(r["environment"], r["direction"]) for r in rows] == [("E1", "query-to-reference")]
    row = rows[0]
    results = {r["method"]: r for r in json.loads((out / "results.json").read_text())}
    assert row["difficulty"] == results["H"]["difficulty"] and row["hv_max_f1"] == results["H-V"]["max_f1"]
    # the complementarity by a plain loop over the two evaluations' matrices: each query's
    # chance of being right, the share of true matches among its tied best references
    right = {}
    for method in ("H-V", "H-T"):
        with np.load(out / "evaluations" / "E1" / method / "query-to-reference" / "matrices.npz") as m:
            tme, gtm = m["tme"], m["gtm"]
        revisit = [i for i in range(len(tme)) if gtm[i].min() <= 0.3]
        right[method] = {i: float(np.mean([gtm[i, j] <= 0.3 for j in range(tme.shape[1]) if tme[i, j] == tme[i].min()]))
                         for i in revisit}
    v, t = right["H-V"], right["H-T"]
    c = row["complementarity"]
    assert (c["vision"], c["touch"], c["n_revisit"]) == ("H-V", "H-T", len(revisit))
    assert (c["vision_r1"], c["touch_r1"]) == (pytest.approx(sum(v.values()) / len(revisit)),
                                               pytest.approx(sum(t.values()) / len(revisit)))
    assert (c["vision_wrong"], c["rescued"]) == (pytest.approx(sum(1 - v[i] for i in revisit)),
                                                 pytest.approx(sum((1 - v[i]) * t[i] for i in revisit)))
    assert c["oracle_r1"] == pytest.approx(sum(1 - (1 - v[i]) * (1 - t[i]) for i in revisit) / len(revisit))
    assert json.loads((out / "complementarity.json").read_text()) == [
        {"environment": "E1", "direction": "query-to-reference", **c}]
    gates = row["gates"]
    touch = row["difficulty"]["touch_correspondence"]
    assert gates["touch_correspondence_min"] == {"gate": 0.0, "value": touch, "met": touch is not None}
    assert gates["rescue_min"]["met"] is None  # not declared
    assert gates["hv_max_f1_max"]["met"] == (row["hv_max_f1"] <= 0.0)
    # without --json: the table, a missed gate as MISSED with its value, an undeclared one as "-" (cached: quick)
    assert main(["-q", "difficulty", str(path), "--out", str(host), "--no-progress"]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("| evaluation | direction | touch both sides |") and len(table) == 3
    cells = table[2].split(" | ")
    assert cells[5].endswith("(-)")
    f1 = f"{100 * row['hv_max_f1']:.1f} % (<= 0.0 %)"
    assert cells[6] == (f1 if row["hv_max_f1"] <= 0.0 else f"MISSED {f1}")
    assert gates["headroom_min"]["met"] is None and cells[7] == f"{100 * headroom(c):.1f} % (-) |"
