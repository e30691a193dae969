"""The report's cost per figure setting: CPU seconds of `write_report` on copies of a finished
run folder, one per ``report.figures`` (all, summary, none) x ``report.pdf`` (on, off).

    vitaplace run quickstart --out runs/quickstart
    python bench/report_figures.py runs/quickstart

Each copy leaves out the cache, the report and its figures and sets the ``report`` section of
its scenario.resolved.yaml; prints CPU and wall seconds and the figure files drawn.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import yaml

from vitaplace.engine.report.report import write_report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished `vitaplace run` folder")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        for figures in ("all", "summary", "none"):
            for pdf in (True, False):
                out = Path(shutil.copytree(args.run, Path(scratch) / f"{figures}-{pdf}",
                                           ignore=shutil.ignore_patterns("cache", "figures", "report.md*")))
                resolved = yaml.safe_load((out / "scenario.resolved.yaml").read_text())
                resolved["report"] = {"figures": figures, "pdf": pdf}
                (out / "scenario.resolved.yaml").write_text(yaml.safe_dump(resolved, sort_keys=False))
                cpu, wall = time.process_time(), time.perf_counter()
                write_report(out)
                cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
                drawn = len(list((out / "figures").iterdir())) if (out / "figures").is_dir() else 0
                print(f"figures {figures:<8} pdf {'on' if pdf else 'off':<4} CPU {cpu:6.2f} s  wall {wall:6.2f} s  "
                      f"{drawn} files", flush=True)


if __name__ == "__main__":
    main()
