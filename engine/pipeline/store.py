"""The stage store: what every stage of one run shares. It owns the output folder, the cache
(``OUT/cache``, or the sweep's shared one), which stages are forced, the one "done" rule
(an output sealed for its key with a matching digest, `checksum`), the record of every stage
item, the runs opened so far, and the run warnings, a ledger by run label.

A stage is a function ``(store, scenario, upstream records) -> record``
(`vitaplace.engine.pipeline.stages`); it hands each item's work to `Store.stage`, which runs
it unless its output is done, seals what it wrote and keeps, beside the output, the run
warnings the work raised, so that a later run that finds the output cached reports them too.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vitaplace.engine.base.atomic import write_text_atomic
from vitaplace.engine.base.cpus import usable_cpus
from vitaplace.engine.config.scenario import ScenarioError
from vitaplace.engine.data.dataset import Run, open_run
from vitaplace.engine.extension.features import FeatureExtractor
from vitaplace.engine.extension.registry import Registry, discover
from vitaplace.engine.outputs import checksum, outdir
from vitaplace.engine.pipeline.keys import STAGES
from vitaplace.engine.pipeline.records import ModelFile, RunFile, StageRecord

log = logging.getLogger("vitaplace")


class WarningLedger:
    """The run warnings of one run of a scenario: run label -> feature -> message. An opened
    run's ``warnings`` is its entry here, so `warn_once` from a plugin writes into the ledger."""

    def __init__(self) -> None:
        self.by_run: dict[str, dict[str, str]] = {}

    def of(self, label: str) -> dict[str, str]:
        """The warnings of run ``label`` (feature -> message), an entry from now on."""
        return self.by_run.setdefault(label, {})

    def raised(self) -> dict[str, dict[str, str]]:
        """The runs with warnings and theirs, in the order the runs were opened."""
        return {label: dict(warnings) for label, warnings in self.by_run.items() if warnings}

    @contextmanager
    def recording(self) -> Iterator[dict[str, dict[str, str]]]:
        """Within: the warnings raised inside (label -> feature -> message), filled on leaving
        (a run's warnings keep the order they were raised in)."""
        counts = {label: len(warnings) for label, warnings in self.by_run.items()}
        raised: dict[str, dict[str, str]] = {}
        yield raised
        for label, warnings in self.by_run.items():
            new = dict(list(warnings.items())[counts.get(label, 0):])
            if new:
                raised[label] = new

    def restore(self, raised: dict[str, dict[str, str]]) -> None:
        """Warnings recorded earlier (`recording`) put back, each where it is not yet."""
        for label, warnings in raised.items():
            for feature, message in warnings.items():
                self.of(label).setdefault(feature, message)


@dataclass(frozen=True)
class Made:
    """A stage item's output: the SHA-256 of its content and what its work returned (None
    when it came from the cache)."""

    digest: str
    result: Any = None


class Store:
    """The output folder, cache, forced stages, stage records, opened runs, loaded models
    and warnings of one run of a scenario (see the module docstring)."""

    def __init__(self, out: Path, force: Iterable[str] = (), progress: bool = True, registry: Registry | None = None,
                 workers: int | None = None, cache: Path | None = None) -> None:
        self.out = Path(out)
        self.force = set(force)
        unknown = self.force - set(STAGES)
        if unknown:
            raise ScenarioError(f"--force: unknown stage(s) {', '.join(sorted(unknown))}; stages: {', '.join(STAGES)}")
        self.progress = progress
        #: processes recording runs in parallel (default: one per CPU this process may use)
        self.workers = workers or usable_cpus()
        self.registry = registry or discover()
        #: where stage outputs are cached (default OUT/cache; sweeps share one across seeds)
        self.cache = Path(cache) if cache is not None else outdir.cache_dir(self.out)
        self.records: list[StageRecord] = []
        self.warnings = WarningLedger()
        self._opened: dict[str, Run] = {}
        self._models: dict[Path, FeatureExtractor] = {}

    def done(self, stage: str, item: str, output: Path, key: str) -> bool:
        """The one "done" rule of every stage: ``output`` is there and sealed for ``key`` with
        a matching digest (`checksum`); anything else but "not made yet" is logged."""
        problem = checksum.check(output, key)
        if problem is None:
            return True
        if problem not in ("absent", "made for other settings"):
            log.warning("%-9s %-28s cached output %s is %s: recomputing", stage, item, output.name, problem)
        return False

    def stage(self, stage: str, item: str, key: str, output: Path, work: Callable[[], Any], inputs: Iterable[str] = (),
              done: bool | None = None) -> Made:
        """Run ``work()`` unless ``output`` is done for ``key`` (`done`, or ``done`` when the
        caller has checked already) and the stage is not forced; seal what it wrote."""
        start = time.perf_counter()
        if done is None:
            done = self.done(stage, item, output, key)
        result = None
        if done and stage not in self.force:
            status = "cached"
            log.info("%-9s %-28s cached (%s)", stage, item, key)
            self._restore_warnings(output)
        else:
            status = "ran"
            log.info("%-9s %-28s running (%s)", stage, item, key)
            with self.warnings.recording() as raised:
                result = work()
            self._keep_warnings(output, raised)
            checksum.seal(output, key)
        seconds = time.perf_counter() - start
        # relative to the output folder when inside the folder that holds it (a sweep's seed
        # folder and the sweep's shared cache: ../cache/...), so the records move with it
        beside = output.resolve().is_relative_to(self.out.resolve().parent)
        where = os.path.relpath(output, self.out) if beside else output
        log.debug("%-9s %-28s %s in %.2f s: %s", stage, item, status, seconds, where)
        self.records.append(StageRecord(stage, item, key, status, round(seconds, 3), list(inputs), str(where)))
        return Made(checksum.sealed_digest(output), result)

    def record(self, record: StageRecord) -> None:
        """The record of a stage item that needed no work (a recorded run file)."""
        self.records.append(record)

    @staticmethod
    def _warnings_path(output: Path) -> Path:
        return output.with_name(output.name + ".warnings.json")

    def _keep_warnings(self, output: Path, raised: dict[str, dict[str, str]]) -> None:
        """Beside a stage's output, the run warnings its work raised (label -> feature -> message)."""
        path = self._warnings_path(output)
        if raised:
            write_text_atomic(path, json.dumps(raised))
        else:
            path.unlink(missing_ok=True)

    def _restore_warnings(self, output: Path) -> None:
        """The run warnings the work of a now cached stage raised (`_keep_warnings`)."""
        path = self._warnings_path(output)
        if path.is_file():
            self.warnings.restore(json.loads(path.read_text()))

    def open(self, label: str, path: Path) -> Run:
        """The run file ``path`` of run ``label``, opened once per run of the scenario (its
        fields load lazily, once), named as the scenario names it, its warnings in the ledger."""
        if label not in self._opened:
            run = open_run(path)
            run.name = label  # warnings and errors name the run as the scenario does
            run.warnings = self.warnings.of(label)
            self._opened[label] = run
        return self._opened[label]

    def run(self, run: RunFile) -> Run:
        """The opened run of record ``run``, with its drop-out (`open`)."""
        opened = self.open(run.label, run.path)
        opened.missing = run.missing
        return opened

    def model(self, model: ModelFile) -> FeatureExtractor:
        """The fitted extractor of ``model``: the one the fit stage kept, else loaded from its folder once."""
        if model.folder not in self._models:
            self.keep_model(model.folder, self.registry.get(model.plugin).load(model.folder))
        return self._models[model.folder]

    def keep_model(self, folder: Path, extractor: FeatureExtractor) -> None:
        """An extractor the fit stage fitted into ``folder``, kept for the later stages."""
        extractor.progress = self.progress
        self._models[folder] = extractor
