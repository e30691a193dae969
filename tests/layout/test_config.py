"""Configuration pieces on their own: the memory estimate of a simulated run and the lookup of
shipped files."""

import numpy as np
import pytest

from vitaplace.engine.base.shipped import ENVIRONMENTS_DIR, SCENARIOS_DIR, environment_files, shipped_file
from vitaplace.engine.config.memory import run_bytes
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.sim.controllers import run_spec
from vitaplace.engine.sim.robot import RobotSpec


@pytest.mark.parametrize("whiskers", [24, 6])
def test_run_bytes_covers_the_arrays_of_the_run_with_the_robots_whiskers(monkeypatch, whiskers):
    """The estimate is the run's arrays (frames, deflection series, theta and xy per whisker)
    plus at most 64 bytes a sample for the rest (poses, times), for the robot's whisker count."""
    monkeypatch.setattr(RobotSpec, "n_whiskers", property(lambda self: whiskers))
    robot = RobotSpec(camera_width=10, camera_height=8, deflection_samples=3)
    spec = run_spec(kind="foraging", n_samples=7)
    n, s = spec.n_samples, robot.deflection_samples
    run = Run.from_arrays(
        images=np.zeros((n, 8, 10, 3), np.uint8), theta=np.zeros((n, whiskers), np.float32),
        xy=np.zeros((n, whiskers, 2), np.float32), poses=np.zeros((n, 3)),
        deflection=np.zeros((n, s, whiskers, 2), np.float32),
    )
    arrays = sum(getattr(run, name).nbytes for name in ("images", "theta", "xy", "deflection"))
    assert arrays == n * (8 * 10 * 3 + whiskers * (4 + 8) + s * whiskers * 8)  # by hand
    assert 0 <= run_bytes(spec, robot) - arrays <= 64 * n


def test_shipped_files_are_found_by_name_in_their_own_folder():
    assert shipped_file("quickstart") == SCENARIOS_DIR / "quickstart.yaml"
    assert shipped_file("quickstart.yaml", (SCENARIOS_DIR,)) == SCENARIOS_DIR / "quickstart.yaml"
    assert shipped_file("e1") == ENVIRONMENTS_DIR / "e1.yaml"
    assert shipped_file("e1", (SCENARIOS_DIR,)) is None
    assert shipped_file("quickstart", (ENVIRONMENTS_DIR,)) is None
    assert shipped_file("../quickstart", (ENVIRONMENTS_DIR,)) is None  # nothing outside the folder
    assert environment_files()["e1"] == ENVIRONMENTS_DIR / "e1.yaml"
    assert not any(name.startswith("base") for name in environment_files())


def test_environment_and_scenario_files_are_told_apart_by_their_schemas_own_keys():
    """`vitaplace validate/simulate FILE` decides from the top-level keys whether FILE is an
    environment or a scenario: the keys of one schema that the other lacks (old names too)."""
    from vitaplace.engine.base.shipped import ENVIRONMENTS_DIR, SCENARIOS_DIR
    from vitaplace.engine.cli.commands import _is_environment_file, own_top_level_keys

    environment_keys, scenario_keys = own_top_level_keys()
    # the shared ones (name, description) belong to neither; the rename of scoring is a scenario's
    assert {"arena", "landmarks", "route", "start"} <= environment_keys
    assert {"train", "evaluations", "methods", "scoring", "evaluation", "robot", "seed"} <= scenario_keys
    assert not environment_keys & scenario_keys and not {"name", "description"} & (environment_keys | scenario_keys)
    environments, scenarios = sorted(ENVIRONMENTS_DIR.glob("*.yaml")), sorted(SCENARIOS_DIR.glob("*.yaml"))
    assert len(environments) >= 3 and len(scenarios) >= 3
    assert all(_is_environment_file(str(path)) for path in environments)
    assert not any(_is_environment_file(str(path)) for path in scenarios)
