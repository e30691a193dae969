"""``vitaplace view ENV``: MuJoCo's interactive viewer (`mujoco.viewer`) on an environment
with the WhiskEye at the environment's start pose, whisking as it does in a recording.

The viewer opens a window, so it needs a display; without one `require_display` says so in
one line (a `UserError`) instead of a GLFW traceback or a hang.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import mujoco
import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.model import SimModel, build_model
from vitaplace.engine.sim.robot import HEAD_POS, ROBOT_GROUP, RobotSpec

HEADLESS_HINT = "on a headless machine, `vitaplace video RUN.h5` draws a recorded run into a GIF instead"


# Run in a child process: GLFW initialised (and its error handler set) in this process
# before `mujoco.viewer` starts its own on the viewer's thread made quitting segfault or hang,
# and GLFW's own warnings about a missing X server went to the terminal before the refusal.
_PROBE = """
import sys
try:
    import glfw
except ImportError as exc:
    print(f"vitaplace view needs GLFW (pip install glfw): {exc}")
    sys.exit(3)
said = []
glfw.set_error_callback(
    lambda code, text: said.append(text.decode(errors="replace") if isinstance(text, bytes) else str(text))
)
ok = glfw.init()
if ok:
    glfw.terminate()
print(said[-1] if said else "")
sys.exit(0 if ok else 1)
"""
PROBE_TIMEOUT_S = 30.0


def require_display() -> None:
    """Raise `UserError` unless a window can be opened (X11 or Wayland display, GLFW).
    GLFW is started (and stopped) in a child process, never in this one."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UserError(f"vitaplace view needs a display, and DISPLAY and WAYLAND_DISPLAY are unset; {HEADLESS_HINT}")
    shown = [f"{name}={os.environ[name]!r}" for name in ("DISPLAY", "WAYLAND_DISPLAY") if os.environ.get(name)]
    where = shown[0] if shown else "the desktop"  # quoted: a line break in the variable stays in the one line
    try:
        probe = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise UserError(f"vitaplace view: GLFW did not start on {where} within {PROBE_TIMEOUT_S:g} s; "
                        f"{HEADLESS_HINT}") from None
    said = " ".join(probe.stdout.split())
    if probe.returncode == 3:
        raise UserError(said)
    if probe.returncode != 0:
        reason = f": {said}" if said else ""
        raise UserError(f"vitaplace view cannot open a window on {where} (GLFW failed to start{reason}); "
                        f"{HEADLESS_HINT}")


def viewer_scene(environment: EnvironmentSpec, robot: RobotSpec | None = None) -> tuple[SimModel, mujoco.MjData]:
    """The compiled world with the robot at the environment's ``start`` (x, y, yaw in degrees)."""
    sim = build_model(environment, robot)
    x, y, yaw_deg = environment.start
    return sim, sim.new_data((x, y, math.radians(yaw_deg)))


VIEW_ELEVATION_DEG = -60.0  #: the opening view looks down on the robot at this angle


def viewer_camera(
    environment: EnvironmentSpec, pose: np.ndarray, fovy_deg: float
) -> tuple[np.ndarray, float, float, float]:
    """The free camera the viewer opens with: ``(lookat, distance, azimuth, elevation)``
    (degrees, MuJoCo's convention). It looks at the robot (at its head's height) from
    behind, down at `VIEW_ELEVATION_DEG`, from the nearest distance at which every corner of
    the arena (floor and wall tops, outside the walls) is inside the vertical field of view
    ``fovy_deg`` both up-down and left-right, so the whole arena is on screen in any window at
    least as wide as it is high. A corner at ``v`` from the look-at point is at depth
    ``v.f + d`` and off-axis ``max(|v.r|, |v.u|)``; in view when that is <= depth * tan(fovy/2)."""
    x, y, yaw = (float(v) for v in pose)
    lookat = np.array([x, y, HEAD_POS[2]])
    hx = environment.arena.half_x + environment.arena.wall_thickness
    hy = environment.arena.half_y + environment.arena.wall_thickness
    corners = np.array([(sx * hx, sy * hy, z) for sx in (-1, 1) for sy in (-1, 1)
                        for z in (0.0, environment.arena.wall_height)])
    azimuth, elevation = math.degrees(yaw), VIEW_ELEVATION_DEG
    ca, sa = math.cos(yaw), math.sin(yaw)
    ce, se = math.cos(math.radians(elevation)), math.sin(math.radians(elevation))
    forward, up = np.array([ce * ca, ce * sa, se]), np.array([-se * ca, -se * sa, ce])
    right = np.cross(forward, up)
    v = corners - lookat
    off_axis = np.maximum(np.abs(v @ right), np.abs(v @ up))
    distance = float((off_axis / math.tan(math.radians(fovy_deg) / 2) - v @ forward).max())
    return lookat, distance, azimuth, elevation


def _frame(camera: mujoco.MjvCamera, environment: EnvironmentSpec, sim: SimModel, data: mujoco.MjData) -> None:
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    lookat, camera.distance, camera.azimuth, camera.elevation = viewer_camera(
        environment, sim.pose(data), float(sim.model.vis.global_.fovy))
    camera.lookat[:] = lookat


def view(environment: str | Path, robot: RobotSpec | None = None) -> None:
    """Open the viewer on ``environment`` (a file or a shipped name) until its window closes
    or Ctrl-C. The robot's own geoms (hidden from its camera) are shown; the whiskers whisk."""
    require_display()
    import mujoco.viewer  # needs GLFW's library: only once a display is known to be there

    spec = load_environment(environment)
    sim, data = viewer_scene(spec, robot)
    model, command = sim.model, sim.whisk_command
    before = set(threading.enumerate())
    try:
        handle = mujoco.viewer.launch_passive(model, data)
    except RuntimeError as exc:  # macOS: the viewer must run on the main thread, under mjpython
        raise UserError(f"vitaplace view: {exc} "
                        f"(e.g. `mjpython -m vitaplace.engine.cli.main view {environment}`)") from None
    viewer_threads = [t for t in threading.enumerate() if t not in before]
    print(f"vitaplace view: {spec.name} is open; close its window or press Ctrl-C here to quit",
          file=sys.stderr, flush=True)
    try:
        with handle.lock():
            handle.opt.geomgroup[ROBOT_GROUP] = 1
            _frame(handle.cam, spec, sim, data)
        step = 0
        while handle.is_running():
            started = time.perf_counter()
            with handle.lock():
                data.ctrl[sim.servo_act] = command[step % len(command)]
                mujoco.mj_step(model, data)
            handle.sync()
            step += 1
            time.sleep(max(0.0, model.opt.timestep - (time.perf_counter() - started)))
    except KeyboardInterrupt:  # Ctrl-C in the terminal quits the viewer as closing its window does
        pass
    finally:
        # The viewer's thread is a daemon: left running while the interpreter shuts down, it
        # drew into freed GLFW state (exit 139). Ask it to stop and wait until it has.
        handle.close()
        for thread in viewer_threads:
            thread.join(timeout=10.0)
