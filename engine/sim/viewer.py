"""``vitaplace view ENV``: MuJoCo's interactive viewer (`mujoco.viewer`) on an environment
with the WhiskEye at the environment's start pose, whisking as it does in a recording.

The viewer opens a window, so it needs a display; without one `require_display` says so in
one line (a `UserError`) instead of a GLFW traceback or a hang.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import mujoco

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.model import SimModel, build_model
from vitaplace.engine.sim.robot import ROBOT_GROUP, RobotSpec

HEADLESS_HINT = "on a headless machine, `vitaplace video RUN.h5` draws a recorded run into a GIF instead"


def require_display() -> None:
    """Raise `UserError` unless a window can be opened (X11 or Wayland display, GLFW)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UserError(f"vitaplace view needs a display, and DISPLAY and WAYLAND_DISPLAY are unset; {HEADLESS_HINT}")
    try:
        import glfw
    except ImportError as exc:  # the glfw package, or its shared library, is missing
        raise UserError(f"vitaplace view needs GLFW (pip install glfw): {exc}") from None
    if not glfw.init():
        where = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or "the desktop"
        raise UserError(f"vitaplace view cannot open a window on {where} (GLFW failed to start); {HEADLESS_HINT}")


def viewer_scene(environment: EnvironmentSpec, robot: RobotSpec | None = None) -> tuple[SimModel, mujoco.MjData]:
    """The compiled world with the robot at the environment's ``start`` (x, y, yaw in degrees)."""
    sim = build_model(environment, robot)
    x, y, yaw_deg = environment.start
    return sim, sim.new_data((x, y, math.radians(yaw_deg)))


def view(environment: str | Path, robot: RobotSpec | None = None) -> None:
    """Open the viewer on ``environment`` (a file or a shipped name) until its window closes.
    The robot's own geoms (hidden from its camera) are shown; the whiskers whisk."""
    require_display()
    import mujoco.viewer  # needs GLFW's library: only once a display is known to be there

    sim, data = viewer_scene(load_environment(environment), robot)
    model, command = sim.model, sim.whisk_command
    try:
        handle = mujoco.viewer.launch_passive(model, data)
    except RuntimeError as exc:  # macOS: the viewer must run on the main thread, under mjpython
        raise UserError(f"vitaplace view: {exc} (e.g. `mjpython -m vitaplace.engine.cli.main view {environment}`)") from None
    with handle:
        with handle.lock():
            handle.opt.geomgroup[ROBOT_GROUP] = 1
        step = 0
        while handle.is_running():
            started = time.perf_counter()
            with handle.lock():
                data.ctrl[sim.servo_act] = command[step % len(command)]
                mujoco.mj_step(model, data)
            handle.sync()
            step += 1
            time.sleep(max(0.0, model.opt.timestep - (time.perf_counter() - started)))
