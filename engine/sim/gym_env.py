"""A Gymnasium environment of the WhiskEye robot (the optional extra ``gym``).

``gymnasium.make("WhiskEye-E1-v0")`` (E2, E3 likewise; ``gymnasium.make("WhiskEye-v0",
environment="my-arena.yaml")`` for any environment file) gives a `WhiskEyeEnv`: each step is
one whisk cycle of the simulator's own `Simulator` (the same MuJoCo model, physics step,
whisk cycle, camera and whisker sensing as ``vitaplace simulate``), ending at full protraction,
where a run file's sample is taken.

* action: Box (4,) float32, (forward [m/s], strafe leftward [m/s], turn [rad/s], whisk
  amplitude [share of the full amplitude, 0..1]); held for the cycle and re-issued to the
  base at the run's control rate, as a controller's command is. An action outside the Box,
  or not numbers, is refused in one line (Gymnasium's ``ClipAction`` wrapper clips instead).
* observation: Dict of ``image`` (H, W, 3) uint8 (the robot's camera), ``theta`` (24,) the
  protraction angles [rad], ``xy`` (24, 2) the two-axis whisker deflections (the run file's
  fields of the same names) and ``pose`` (3,) the base's ground-truth x, y [m] and yaw [rad].
* reset(seed=...): a start pose drawn from the seed (uniform over the arena, with 0.1 m of
  clearance around body and head); ``options={"start": [x, y, yaw_deg]}`` places it.
* terminated when the chassis or head touches the world; truncated by ``max_episode_steps``
  (the registered ids: 1000 steps, 500 s).
* the camera is made at the first frame, in the process that steps: ``gymnasium.make_vec``
  with ``vectorization_mode="async"`` works with forked workers as well as spawned ones.
* ``record=True`` keeps the episode's steps; `WhiskEyeEnv.write_run` writes them as a run
  file (the format ``vitaplace simulate`` writes, atomically), to be scored like any other.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

try:
    import gymnasium
    from gymnasium import spaces
except ImportError:  # pragma: no cover - exercised where the extra is missing
    raise ImportError(
        "vitaplace's Gymnasium environment needs the gym extra: pip install 'vitaplace[gym]'"
    ) from None
import numpy as np

from vitaplace.engine.base.cpus import configure_blas_threads
from vitaplace.engine.data.dataset import Run, write_run
from vitaplace.engine.sim.clearance import footprint_clearance
from vitaplace.engine.sim.controllers import RUN_KINDS
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment
from vitaplace.engine.sim.robot import N_WHISKERS, RobotSpec
from vitaplace.engine.sim.simulate import ControlTicks, Samples, Simulator, run_from_samples

__all__ = ["WhiskEyeEnv", "register_envs", "MAX_SPEED", "MAX_TURN", "ENV_IDS"]

#: the largest forward and sideways speed [m/s]: the bound of a run's ``speed`` setting
MAX_SPEED = float(next(m.le for m in RUN_KINDS["teleop"].model_fields["speed"].metadata if hasattr(m, "le")))
MAX_TURN = 1.0  #: the largest turn rate [rad/s] (the teleoperator turns at 0.25 rad/s)
START_CLEARANCE = 0.1  #: a drawn start pose keeps this much room around body and head [m]
CONTROL_HZ = 10.0  #: the base's command is re-issued at this rate, a run's default control rate [Hz]
ENV_IDS = {"WhiskEye-E1-v0": "e1", "WhiskEye-E2-v0": "e2", "WhiskEye-E3-v0": "e3"}
OPTIONS = ("start",)
#: bounds of the whisker signal: a base deflection [rad] stops at the spring's limit (at most
#: 90 deg); the penetration signal 10 depth / (s + 0.1) stays far below 1000
XY_BOUND = {"physical": math.pi, "penetration": 1000.0}


class WhiskEyeEnv(gymnasium.Env):
    """The WhiskEye robot in one environment; one step is one whisk cycle (see the module)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}
    action_space: spaces.Box
    observation_space: spaces.Dict

    def __init__(self, environment: str | Path | EnvironmentSpec = "e1", robot: RobotSpec | dict | None = None,
                 render_mode: str | None = None, record: bool = False) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: only 'rgb_array' (or None) is supported")
        configure_blas_threads()  # the agent's own numpy shares the CPUs with the simulator
        self.environment = environment if isinstance(environment, EnvironmentSpec) else load_environment(environment)
        self.robot = RobotSpec.model_validate(robot) if isinstance(robot, dict) else (robot or RobotSpec())
        self.render_mode, self.record = render_mode, bool(record)
        self.metadata = {**self.metadata, "render_fps": self.robot.whisk_hz}
        self._sim = Simulator(self.environment, self.robot)
        series_hz = self.robot.deflection_samples * self.robot.whisk_hz
        self._ticks = ControlTicks(self._sim, lambda _obs: self._command, "gym",
                                   every=max(1, int(round(series_hz / CONTROL_HZ))))
        self._command = (0.0, 0.0, 0.0)
        self.action_space = spaces.Box(np.array([-MAX_SPEED, -MAX_SPEED, -MAX_TURN, 0.0], dtype=np.float32),
                                       np.array([MAX_SPEED, MAX_SPEED, MAX_TURN, 1.0], dtype=np.float32),
                                       dtype=np.float32)
        arena = self.environment.arena
        h, w = self.robot.camera_height, self.robot.camera_width
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, (h, w, 3), dtype=np.uint8),
            "theta": spaces.Box(-math.pi, math.pi, (N_WHISKERS,), dtype=np.float32),
            "xy": spaces.Box(-XY_BOUND[self.robot.tactile_model], XY_BOUND[self.robot.tactile_model], (N_WHISKERS, 2),
                             dtype=np.float32),
            "pose": spaces.Box(np.array([-arena.half_x, -arena.half_y, -math.pi], dtype=np.float32),
                               np.array([arena.half_x, arena.half_y, math.pi], dtype=np.float32), dtype=np.float32),
        })
        self._image = np.zeros((h, w, 3), dtype=np.uint8)
        self._steps: list[dict[str, Any]] = []
        self._last: dict[str, Any] | None = None  #: the last step, recorded or not (`last_sample`)
        self._start: tuple[float, float, float] | None = None
        self._seed: int | None = None
        self._closed = False

    def _open(self, call: str) -> None:
        if self._closed:
            raise RuntimeError(f"{call}: this WhiskEyeEnv is closed; make a new one (gymnasium.make)")

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        self._open("reset()")
        super().reset(seed=seed)
        if seed is not None:
            self._seed = int(seed)
        unknown = sorted(set(options or {}) - set(OPTIONS))
        if unknown:
            raise ValueError(f"reset: unknown option {unknown[0]!r} (options: {', '.join(OPTIONS)})")
        start = (options or {}).get("start")
        pose = self._place(start) if start is not None else self._draw_start()
        self._sim.reset(pose)
        self._sim.set_whisk_amplitude(1.0)
        self._sim.body_collisions = 0
        self._start, self._steps, self._last = pose, [], None
        obs = self._observe()
        return obs, {"time": 0.0, "whisker_contacts": 0}

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self._open("step()")
        a = self._action(action)
        if self._start is None:
            raise RuntimeError("call reset() before step()")
        sim = self._sim
        forward, strafe, turn, amplitude = (float(v) for v in a)
        self._command = (forward, turn, strafe)
        sim.set_whisk_amplitude(amplitude)
        sim.drive(*self._command)
        collisions = sim.body_collisions
        series, points, normals = sim.cycle(self._ticks)
        obs = self._observe()
        touched = sum(len(p) for p in points)
        self._last = {"obs": obs, "series": series.astype(np.float32), "time": float(sim.data.time),
                      "pose": sim.sim.pose(sim.data), "points": np.concatenate(points),
                      "normals": np.concatenate(normals), "action": [forward, strafe, turn, amplitude]}
        if self.record:
            self._steps.append(self._last)
        terminated = sim.body_collisions > collisions
        info = {"time": float(sim.data.time), "whisker_contacts": int(touched), "body_collision": terminated}
        return obs, 0.0, terminated, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode == "rgb_array":
            return self._image.copy()
        return None

    def close(self) -> None:
        """Release the simulator (its renderer); a second call does nothing, and `reset` or
        `step` after it raise one line."""
        if not self._closed:
            self._sim.close()
            self._closed = True

    # ------------------------------------------------------------------ recording
    def write_run(self, path: str | Path, name: str = "gym") -> Path:
        """Write the steps of this episode (since the last reset) as a run file at ``path``,
        atomically: one sample per step, the same fields and attributes as ``vitaplace simulate``
        writes (the run's settings: kind ``gym``, the start pose and every action)."""
        if not self.record:
            raise ValueError("write_run: this environment was made without record=True")
        if not self._steps:
            raise ValueError("write_run: no steps taken since reset")
        return write_run(path, self.recorded_run(name))

    def recorded_run(self, name: str = "gym") -> Run:
        """The episode's steps as an in-memory `Run` (see `write_run`)."""
        return self._run(self._steps, name)

    def last_sample(self, name: str = "sample") -> Run:
        """The last step as a one-sample in-memory `Run`, recorded or not: what a feature
        extractor's ``transform`` reads, as it reads a run file's sample."""
        if self._last is None:
            raise ValueError("last_sample: no step taken since reset")
        return self._run([self._last], name)

    def _run(self, st: list[dict[str, Any]], name: str) -> Run:
        counts = np.concatenate([[0], np.cumsum([len(s["points"]) for s in st])]).astype(np.int64)
        samples = Samples(
            images=np.stack([s["obs"]["image"] for s in st]),
            theta=np.stack([s["obs"]["theta"] for s in st]),
            xy=np.stack([s["obs"]["xy"] for s in st]),
            deflection=np.stack([s["series"] for s in st]),
            poses=np.stack([s["pose"] for s in st]),
            times=np.array([s["time"] for s in st]),
            points=[s["points"] for s in st], normals=[s["normals"] for s in st], counts=counts,
        )
        x, y, yaw = self._start  # type: ignore[misc]
        settings = {"kind": "gym", "n_samples": len(st), "start": [x, y, math.degrees(yaw)],
                    "control_hz": CONTROL_HZ, "actions": [s["action"] for s in st]}
        seed = -1 if self._seed is None else self._seed
        return run_from_samples(self._sim, samples, self.environment, settings, self.robot, seed, name,
                                {"gym": len(st)})

    # ------------------------------------------------------------------ helpers
    def _action(self, action: Any) -> np.ndarray:
        """``action`` as a float64 (4,) array; one line naming it when it is not numbers of
        that shape or lies outside the Box: refused, not clipped (Gymnasium leaves clipping to
        its ``ClipAction`` wrapper)."""
        try:
            a = np.asarray(action)
        except ValueError:  # a ragged sequence
            a = np.asarray(None)
        if a.dtype.kind not in "biuf":
            raise ValueError(f"action {_one_line(action)} is not numbers: expected an array of shape (4,), float32 "
                             "(forward, strafe, turn, whisk amplitude)")
        box = self.action_space
        if a.shape != box.shape:
            raise ValueError(f"action {_one_line(a.tolist())} has shape {a.shape}: expected an array of shape "
                             f"{box.shape}, float32 (forward, strafe, turn, whisk amplitude)")
        if not np.all(np.isfinite(a)) or not box.contains(a.astype(np.float32)):
            raise ValueError(f"action {_one_line(a.tolist())} is outside the action space (forward, strafe, turn, "
                             f"whisk amplitude) within {box.low.tolist()}..{box.high.tolist()}; "
                             "gymnasium.wrappers.ClipAction clips actions into it")
        return a.astype(np.float64)

    def _observe(self) -> dict[str, np.ndarray]:
        sim = self._sim
        self._image = sim.render(out=self._image)
        pose = sim.sim.pose(sim.data)
        return {
            "image": self._image.copy(),
            "theta": sim.sim.theta(sim.data).astype(np.float32),
            "xy": sim.sim.xy(sim.data).astype(np.float32),
            "pose": pose.astype(np.float32),
        }

    def _place(self, start: Any) -> tuple[float, float, float]:
        try:
            x, y, yaw_deg = (float(v) for v in start)
        except (TypeError, ValueError):
            raise ValueError(f"reset: option 'start' must be [x, y, yaw_deg], got {start!r}") from None
        arena = self.environment.arena
        if not (abs(x) < arena.half_x and abs(y) < arena.half_y and math.isfinite(yaw_deg)):
            raise ValueError(f"reset: option 'start' {[x, y, yaw_deg]} is outside the arena "
                             f"(|x| < {arena.half_x:g}, |y| < {arena.half_y:g})")
        yaw = math.radians(yaw_deg)
        clearance = float(footprint_clearance(self.environment.obstacles, np.array([[x, y]]), np.array([yaw]))[0])
        if clearance < 0:
            raise ValueError(f"reset: option 'start' {[x, y, yaw_deg]} puts the robot's body or head "
                             f"{-clearance:.2f} m into an obstacle")
        return (x, y, yaw)

    def _draw_start(self) -> tuple[float, float, float]:
        arena, rng = self.environment.arena, self.np_random
        obstacles = self.environment.obstacles
        for _ in range(10000):
            x, y = rng.uniform(-arena.half_x, arena.half_x), rng.uniform(-arena.half_y, arena.half_y)
            yaw = rng.uniform(-math.pi, math.pi)
            if footprint_clearance(obstacles, np.array([[x, y]]), np.array([yaw]))[0] >= START_CLEARANCE:
                return (float(x), float(y), float(yaw))
        raise ValueError(f"{self.environment.name}: no start pose with {START_CLEARANCE} m of clearance found")


def _one_line(value: Any, width: int = 80) -> str:
    """``repr(value)`` on one line, cut at ``width`` characters."""
    text = " ".join(repr(value).split())
    return text if len(text) <= width else text[:width - 3] + "..."


def register_envs() -> None:
    """Register ``WhiskEye-E1-v0``, ``-E2-``, ``-E3-`` and ``WhiskEye-v0`` (any environment file,
    ``environment=``) with Gymnasium; called on import of this module and by Gymnasium's
    ``gymnasium.envs`` entry point."""
    entry = f"{__name__}:WhiskEyeEnv"
    for env_id, name in {**ENV_IDS, "WhiskEye-v0": "e1"}.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry, kwargs={"environment": name}, max_episode_steps=1000)


register_envs()
