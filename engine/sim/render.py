"""The robot's camera: fast headless rendering through `mujoco.Renderer`.

Speed settings: the model is built with ``visual.quality`` ``shadowsize=0, offsamples=0``
(no shadow map, no multisampling), materials have zero reflectance, lights cast no
shadows, and the scene flags for shadows and reflections are switched off here. The
offscreen buffer is only as large as the largest image requested. The robot's own geoms
(group 3) are hidden from its camera. Measured here (Mesa llvmpipe, 2 cores): ~1 ms per
120x160 frame instead of ~35 ms with MuJoCo's default quality settings.

Processes: a renderer belongs to the process that made it. EGL's state does not survive
``fork``: a child forked from a process that had made an EGL context hangs making its own
(measured here, Mesa llvmpipe), so `Camera` refuses there in one line instead, and a camera
inherited over ``fork`` is never used or freed in the child (freeing it touches the parent's
GL state). Make cameras lazily, in the process that renders (as `Simulator` does).
"""

from __future__ import annotations

import os
import time

from vitaplace.engine.sim.glsetup import INSTALL_HINT, STATE, GLUnavailableError, select_gl_backend

select_gl_backend()

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from vitaplace.engine.sim.robot import ROBOT_GROUP  # noqa: E402

__all__ = ["Camera", "GLUnavailableError", "gl_help"]

#: the process that made this process's first GL context; a forked child inherits it
_GL_MAKER: dict[str, int | None] = {"pid": None}
#: renderers inherited over fork: kept referenced so that nothing frees them in this process
_INHERITED: list[mujoco.Renderer] = []


def gl_help(cause: BaseException | str | None = None) -> str:
    backend = repr(os.environ["MUJOCO_GL"]) if "MUJOCO_GL" in os.environ else "(unset)"
    msg = (
        f"vitaplace could not create an OpenGL context for the robot camera (MUJOCO_GL={backend}; "
        f"{STATE.get('reason') or 'no backend chosen'}). {INSTALL_HINT}"
    )
    if cause is not None:
        msg += f" Underlying error: {cause}"
    return msg


def check_fork_safe() -> None:
    """Raise GLUnavailableError when this process was forked from one that had made an EGL
    context: making another one here would hang."""
    maker = _GL_MAKER["pid"]
    if maker is not None and maker != os.getpid() and os.environ.get("MUJOCO_GL", "").lower() == "egl":
        raise GLUnavailableError(
            f"this process was forked from process {maker} after that one had made an EGL context, and EGL "
            f"cannot make another one after fork: start the worker processes with the 'spawn' or 'forkserver' "
            f"method (Gymnasium: vector_kwargs={{'context': 'spawn'}}), or fork before the first frame is rendered"
        )


class Camera:
    """Renders the named model camera to uint8 RGB arrays (H, W, 3).

    ``render_time`` accumulates the wall time spent rendering (scene update + GL + readback);
    ``fog`` draws the model's fog (set in the model before the camera is made).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        width: int,
        height: int,
        camera: str | int = "eye",
        show_robot: bool = False,
        fog: bool = False,
    ) -> None:
        check_fork_safe()
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except ValueError:
            raise
        except Exception as exc:  # GL library missing / no display / context creation failed
            raise GLUnavailableError(gl_help(exc)) from exc
        self.pid = os.getpid()  #: the process this camera renders in
        if _GL_MAKER["pid"] is None:
            _GL_MAKER["pid"] = self.pid
        scene = self._renderer.scene
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        scene.flags[mujoco.mjtRndFlag.mjRND_FOG] = int(fog)  # the model's fog (`simulate.apply_fog`)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[ROBOT_GROUP] = 1 if show_robot else 0
        if isinstance(camera, str):
            cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if cam_id < 0:
                raise ValueError(f"camera {camera!r} does not exist in the model")
        else:
            cam_id = camera
        self.camera: int | mujoco.MjvCamera = cam_id
        self.width, self.height = width, height
        self.render_time = 0.0
        self.frames = 0

    def render(self, data: mujoco.MjData, out: np.ndarray | None = None) -> np.ndarray:
        t0 = time.perf_counter()
        self._renderer.update_scene(data, camera=self.camera, scene_option=self._option)
        img = self._renderer.render(out=out)
        self.render_time += time.perf_counter() - t0
        self.frames += 1
        return img

    def close(self) -> None:
        """Free the renderer; one inherited over fork is only let go of (see the module)."""
        renderer = getattr(self, "_renderer", None)
        if renderer is not None:
            if self.pid == os.getpid():
                renderer.close()
            else:
                _INHERITED.append(renderer)
            self._renderer = None

    def __enter__(self) -> Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
