"""Memory estimates: refuse, before any compute, runs and networks that cannot fit in this
machine's memory."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from vitaplace.engine.config.scenario import Scenario, ScenarioError
from vitaplace.engine.sim.controllers import RunSpec
from vitaplace.engine.sim.robot import RobotSpec


def physical_memory() -> int | None:
    """Bytes of RAM of this machine (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def run_bytes(run: RunSpec, robot: RobotSpec) -> int:
    """Memory a recorded run takes while it is simulated: frames, deflection series, sensors."""
    frame = robot.camera_height * robot.camera_width * 3
    series = robot.deflection_samples * robot.n_whiskers * 2 * 4
    return run.n_samples * (frame + series + robot.n_whiskers * 3 * 4 + 64)


def run_memory_problem(run: RunSpec, robot: RobotSpec, limit: int | None) -> str | None:
    """Why ``run`` cannot be simulated in ``limit`` bytes of memory (None: it fits, or the
    limit is unknown)."""
    need = run_bytes(run, robot)
    if limit is None or need <= limit:
        return None
    return (f"{run.n_samples} samples of {robot.camera_height}x{robot.camera_width} frames need "
            f"{need / 1e9:.3g} GB of memory; this machine has {limit / 1e9:.3g} GB")


def check_memory(
    path: Path, scenario: Scenario, methods: list[tuple[Any, Any]], limit: int | None, train_samples: int
) -> None:
    """Refuse, before any compute, runs and networks that cannot fit in this machine's memory."""
    if limit is None:
        return
    runs = [("train.run", scenario.train.run)] + [(f"evaluations.{i}.run", e.run)
                                                  for i, e in enumerate(scenario.evaluations)]
    for where, run in runs:
        if run is None:  # a recorded run: it fits, it was recorded
            continue
        problem = run_memory_problem(run, scenario.robot, limit)
        if problem:
            raise ScenarioError(f"{path}: {where}.n_samples: {problem}")
    for i, (extractor, params) in enumerate(methods):
        need, key, what = extractor.memory_bytes(params, train_samples)
        if need > limit:
            raise ScenarioError(
                f"{path}: methods.{i}.params.{key}: {what} need {need / 1e9:.3g} GB of memory for the method; "
                f"this machine has {limit / 1e9:.3g} GB"
            )
