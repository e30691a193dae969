"""The tables of docs/BENCHMARK.md, computed from the committed `vitaplace difficulty` run of
the touch benchmark (``touch-benchmark-difficulty/difficulty.json``, its ``--json`` output).

    python docs/results/benchmark.py             # every table, each under its name
    python docs/results/benchmark.py --write     # put them into docs/BENCHMARK.md

Each table sits in BENCHMARK.md between ``<!-- table NAME -->`` and ``<!-- /table -->`` and is
exactly what this script prints for NAME (`tests/layout/test_results_doc.py` checks it).
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vitaplace.engine.cli.difficulty import TOUCH, VISION, headroom, table

HERE = Path(__file__).resolve().parent
RUN = HERE / "touch-benchmark-difficulty" / "difficulty.json"
DOC = HERE.parent / "BENCHMARK.md"


def rows() -> list[dict[str, Any]]:
    """The committed run's rows; the headroom gate came after it, so each row gets it
    undeclared, its value from the row's own complementarity (what the command writes now)."""
    measured = json.loads(RUN.read_text())
    for row in measured:
        row["gates"].setdefault("headroom_min", {"gate": None, "value": headroom(row["complementarity"]), "met": None})
    return measured


def _pct(value: float | None) -> str:
    return "none" if value is None else f"{100 * value:.1f} %"


def complementarity() -> str:
    """Per evaluation and direction: chance, H-V's, H-T's and the oracle's recall@1."""
    header = ["evaluation", "direction", "queries with a true match", "chance R@1", f"{VISION} R@1", f"{TOUCH} R@1",
              "oracle R@1"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows():
        c = row["complementarity"]
        cells = [row["environment"], row["direction"], str(c["n_revisit"]), _pct(row["difficulty"]["chance_r1"]),
                 _pct(c["vision_r1"]), _pct(c["touch_r1"]), _pct(c["oracle_r1"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


TABLES = {"gates": lambda: table(rows()), "complementarity": complementarity}


def written(text: str) -> str:
    """``text`` (BENCHMARK.md) with every marked table replaced by what `TABLES` computes."""
    def fill(match: re.Match[str]) -> str:
        return f"<!-- table {match[1]} -->\n{TABLES[match[1]]()}\n<!-- /table -->"
    return re.sub(r"<!-- table ([\w-]+) -->\n.*?<!-- /table -->", fill, text, flags=re.S)


def main(argv: Sequence[str]) -> int:
    if list(argv) == ["--write"]:
        DOC.write_text(written(DOC.read_text()))
        return 0
    for name, make in TABLES.items():
        print(f"<!-- table {name} -->\n{make()}\n<!-- /table -->\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
