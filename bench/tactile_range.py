#!/usr/bin/env python
"""The tactile range gate: do a scenario's evaluation drives press the whiskers within what its
training run saw?

For every shipped scenario (scenarios/*.yaml) with a ``mupnet`` method fed touch, or for the
scenarios named, this simulates the training run and every evaluation drive through the
pipeline's simulate stage and its cache (``OUT/<scenario>/cache``, as `vitaplace simulate`;
no method is fitted), fits each tactile channel's range on the training run as the plugin
does (`vitaplace.plugins.mupnet.inputs.TactileRange`, from the raw tactile values of the
method's ``tactile_input``) and prints, per scenario, tactile input and evaluation (query and
reference pooled; samples a query drop-out leaves without whiskers are left out), the share of
the evaluation's tactile values inside the training range - all channels pooled, and the
worst channel's - with PASS when both are at least `GATE` (99 %), else FAIL. Methods whose
tactile input is the same share a row.

    MUJOCO_GL=egl python bench/tactile_range.py                        # every shipped scenario
    MUJOCO_GL=egl python bench/tactile_range.py touch-benchmark --out /tmp/range \\
        --set 'train.run={kind: visits, n_samples: 1000}'

``--set`` overrides apply to every scenario named (as `vitaplace simulate --set`); ``--json``
writes the rows. Exit status 0 when every row passes, 1 otherwise, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.config.loading import load_scenario
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.pipeline import plan
from vitaplace.engine.pipeline.stages.simulate import simulate
from vitaplace.engine.pipeline.store import Store
from vitaplace.plugins.mupnet.extractor import MupnetParams
from vitaplace.plugins.mupnet.inputs import TactileRange, tactile_values

ROOT = Path(__file__).resolve().parents[1]
#: the share of tactile values (pooled, and in the worst channel) inside the training range a row needs
GATE = 0.99


def tactile_inputs(scenario: Scenario, store: Store) -> dict[tuple[str, int], tuple[MupnetParams, list[str]]]:
    """The distinct tactile inputs of the scenario's ``mupnet`` methods fed touch: (tactile_input,
    cycle_points) -> (the first such method's parameters, the names of the methods with it)."""
    found: dict[tuple[str, int], tuple[MupnetParams, list[str]]] = {}
    for method in scenario.methods:
        if method.plugin != "mupnet":
            continue
        params = MupnetParams.model_validate(plan.params_for(scenario, store.registry, method))
        if "tactile" in params.modalities:
            key = (params.tactile_input, params.cycle_points if params.tactile_input == "cycle" else 0)
            found.setdefault(key, (params, []))[1].append(method.name)
    return found


def inside_shares(values: np.ndarray, fitted: TactileRange) -> tuple[float, float]:
    """The share of (N, C) ``values`` inside their channel's training range, pooled and in the worst channel."""
    inside = ~fitted.outside(values)
    return float(inside.mean()), float(inside.mean(axis=0).min())


def gate_rows(scenario: Scenario, store: Store) -> list[dict[str, Any]]:
    """One row per tactile input and evaluation of ``scenario`` (module docstring)."""
    inputs = tactile_inputs(scenario, store)
    if not inputs:
        return []
    runs = {label: store.run(run) for label, run in simulate(store, scenario).runs.items()}
    rows = []
    for params, methods in inputs.values():
        fitted = TactileRange.fit(tactile_values(runs["train"], params), params)
        for evaluation in scenario.evaluations:
            parts = []
            for side in ("query", "reference"):
                label = f"{evaluation.name}/{side}"
                missing, _ = plan.dropout_of(scenario, label, len(runs[label]))
                fed = ~missing.get("whiskers", np.zeros(len(runs[label]), bool))
                parts.append(tactile_values(runs[label], params)[fed])
            values = np.concatenate(parts)
            pooled, worst = inside_shares(values, fitted)
            rows.append({"scenario": scenario.name, "train_run": scenario.train.run.kind if scenario.train.run else
                         "recorded", "tactile_input": params.tactile_input, "methods": methods,
                         "evaluation": evaluation.name, "values": int(values.size), "inside": pooled,
                         "worst_channel": worst, "pass": pooled >= GATE and worst >= GATE})
    return rows


def shipped() -> list[str]:
    return sorted(p.stem for p in (ROOT / "scenarios").glob("*.yaml"))


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("scenarios", nargs="*", help="scenario names or files (default: every shipped scenario)")
    parser.add_argument("--out", type=Path, default=Path("runs") / "tactile-range",
                        help="folder of each scenario's simulate stage and cache: OUT/<scenario>")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a scenario override, as `vitaplace simulate --set` (repeatable)")
    parser.add_argument("--json", type=Path, help="write the rows here")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    rows: list[dict[str, Any]] = []
    print("| scenario | train run | tactile input (methods) | evaluation | values | % inside | worst channel % "
          "| gate |\n|---|---|---|---|---|---|---|---|")
    for name in args.scenarios or shipped():
        start = time.perf_counter()
        try:
            scenario, _ = load_scenario(name, args.overrides)
            scenario_rows = gate_rows(scenario, Store(args.out / scenario.name, progress=not args.no_progress))
        except UserError as exc:
            print(f"tactile_range: {exc}", file=sys.stderr)
            return 2
        for r in scenario_rows:
            print(f"| {r['scenario']} | {r['train_run']} | {r['tactile_input']} ({', '.join(r['methods'])}) | "
                  f"{r['evaluation']} | {r['values']} | {100 * r['inside']:.2f} | {100 * r['worst_channel']:.1f} | "
                  f"{'PASS' if r['pass'] else 'FAIL'} |", flush=True)
        if scenario_rows:
            print(f"<!-- {name}: {time.perf_counter() - start:.0f} s -->", flush=True)
        rows += scenario_rows
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0 if all(r["pass"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
