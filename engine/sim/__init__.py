"""MuJoCo simulation of the WhiskEye-like robot.

Importing this package picks a headless GL backend (``MUJOCO_GL=egl``, else ``osmesa``)
unless ``MUJOCO_GL`` is already set; see `vitaplace.engine.sim.glsetup`. The public names
below are imported lazily, so ``load_environment`` does not pull in MuJoCo.

Main entry points::

    from vitaplace.engine.sim import load_environment, simulate_run, RobotSpec, run_spec
    env = load_environment("e1")
    run = simulate_run(env, run_spec(kind="foraging", n_samples=100), seed=0)
"""

from importlib import import_module
from typing import Any

from vitaplace.engine.sim.glsetup import select_gl_backend

select_gl_backend()

#: Version of the simulated behaviour (robot model, controllers, sensors): part of every
#: simulate stage's cache key, so raise it whenever the same specs would record other data.
#: 2: WhiskEye geometry, routes for its footprint, detours that follow the offset path.
#: 3: the teleop run kind, the touch_share run attribute, the shared look-ahead guard.
#: 4: teleop turns at teleop.launch's 0.25 rad/s; holds at a landmark count samples with contact.
#: 5: a teleop drive blocked on its path finds a way round (it stood still until the run ended).
#: 6: a foraging robot whose turn and backing off are refused turns the other way or creeps forward, and
#:    gives a state up after 3 s without headway (it too stood still until the run ended).
#: 7: a foraging avoid that starts where the last one stalled judges its escape headings by the whole
#:    footprint a step along them (an obstacle at the body's flank kept it dithering there).
SIMULATOR_VERSION = 7

_EXPORTS = {
    "EnvironmentSpecError": "environment",
    "EnvironmentSpec": "environment",
    "load_environment": "environment",
    "environment_files": "environment",
    "RobotSpec": "robot",
    "RunSpec": "simulate",
    "run_spec": "simulate",
    "simulate_run": "simulate",
    "GLUnavailableError": "render",
}

__all__ = sorted([*_EXPORTS, "SIMULATOR_VERSION"])


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(import_module(f"vitaplace.engine.sim.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
