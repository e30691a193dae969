"""Simulation driver: run the robot in an environment and record a `Run`.

One sample per whisk cycle, taken at maximum protraction (the end of each cycle):

* ``images``      camera frame (H, W, 3) uint8
* ``theta``       (24,) protraction angle of every whisker [rad]
* ``xy``          (24, 2) two-axis base deflection [rad]
* ``deflection``  (S, 24, 2) the xy deflection sampled S times, evenly, over the cycle
                  (the last entry is the sample instant itself)
* contacts        world-frame points + outward unit normals of every whisker-world contact
                  present at those S instants (at most one per whisker and instant)
* ``poses``       ground-truth (x, y, yaw) of the base; ``times`` simulation time [s]

Same environment + run spec + robot spec + seed => bitwise-identical physics and poses on
the same machine (MuJoCo is deterministic; all randomness comes from ``seed``).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import mujoco
import numpy as np
from tqdm.auto import tqdm

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.data.dataset import Run
from vitaplace.engine.sim.condition import Condition, Fog, degrade, noise_rng
from vitaplace.engine.sim.controllers import Observation, RunSpec, key_form, make_controller, run_spec
from vitaplace.engine.sim.environment import EnvironmentSpec
from vitaplace.engine.sim.glsetup import STATE as GL_STATE
from vitaplace.engine.sim.model import SimModel, build_model
from vitaplace.engine.sim.render import Camera
from vitaplace.engine.sim.robot import N_WHISKERS, RobotSpec

__all__ = ["RobotSpec", "RunSpec", "run_spec", "simulate_run", "Simulator", "apply_fog", "run_hash"]


def run_hash(environment: EnvironmentSpec, run: RunSpec | Mapping[str, Any], robot: RobotSpec, seed: int) -> str:
    """Content hash of everything that determines a simulated run (the run's settings in their
    version-6 key form, `key_form`, so that hashes stay valid; a mapping, such as a Gymnasium
    drive's settings and actions, as it is)."""
    payload = json.dumps(
        {
            "environment": environment.model_dump(mode="json"),
            "run": dict(run) if isinstance(run, Mapping) else key_form(run),
            "robot": robot.model_dump(mode="json"),
            "seed": int(seed),
        },
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def apply_fog(model: mujoco.MjModel, fog: Fog | None) -> None:
    """Set ``fog`` in the compiled ``model`` (MuJoCo keeps its distances in units of the
    model's extent); a `Camera` made after this with ``fog`` draws it where its scene enables fog."""
    if fog is None:
        return
    model.vis.map.fogstart = fog.start_m / model.stat.extent
    model.vis.map.fogend = fog.end_m / model.stat.extent
    model.vis.rgba.fog[:] = (*fog.colour, 1.0)


class Simulator:
    """Steps one robot in one environment, whisk cycle by whisk cycle.

    Lower-level than `simulate_run` (which is what the scenario runner calls); tests and
    benchmarks use it to place the robot and read its sensors directly. Its camera is made at
    the first `render`, in the process that renders (again in a process forked after that), so
    a Simulator made in one process may step in another. ``condition`` (a run's
    lighting, camera state and fog, `engine/sim/condition.py`) changes the model's lights, fills
    its air with the fog and degrades every rendered frame, its noise drawn from ``seed``'s camera stream (`noise_rng`).
    """

    def __init__(self, environment: EnvironmentSpec, robot: RobotSpec | None = None, camera: bool = True,
                 condition: Condition | None = None, seed: int = 0) -> None:
        self.robot = robot or RobotSpec()
        self.env = environment
        self.condition = condition or Condition()
        self._noise = noise_rng(seed)
        self.sim: SimModel = build_model(environment, self.robot, light=self.condition.light)
        self.model = self.sim.model
        apply_fog(self.model, self.condition.fog)
        self.data = self.sim.new_data((0.0, 0.0, 0.0))
        self._camera_on = camera
        self.camera: Camera | None = None  #: made by the first `render` (in the process rendering)
        self.series_steps = self.robot.series_steps()
        self._chunks = np.diff(np.concatenate([[-1], self.series_steps]))  # steps before each series sample
        self._cmd = [float(c) for c in self.sim.whisk_command]
        servo = self.sim.servo_act
        contiguous = np.array_equal(servo, np.arange(servo[0], servo[0] + len(servo)))
        self._servo = slice(int(servo[0]), int(servo[-1]) + 1) if contiguous else servo
        self.physics_time = 0.0
        self.body_collisions = 0  #: series instants at which the chassis or head touched the world

    # ------------------------------------------------------------------ control
    def reset(self, pose: tuple[float, float, float]) -> None:
        """Restart at ``pose`` (x, y, yaw [rad]), time 0, whiskers fully protracted."""
        self.data = self.sim.new_data(pose)

    def drive(self, v: float, w: float, lateral: float = 0.0) -> None:
        """Command forward speed ``v`` [m/s], yaw rate ``w`` [rad/s] and sideways (leftward)
        speed ``lateral`` [m/s] of the holonomic base."""
        yaw = self.data.qpos[self.sim.base_qadr[2]]
        ctrl = self.data.ctrl
        a = self.sim.drive_act
        c, s = math.cos(yaw), math.sin(yaw)
        ctrl[a[0]] = v * c - lateral * s
        ctrl[a[1]] = v * s + lateral * c
        ctrl[a[2]] = w

    def set_whisk_amplitude(self, share: float) -> None:
        """Whisk at ``share`` (0..1) of the full amplitude from the next step on, still peaking
        at full protraction at each cycle's end (the sample instant): the servo command is
        scaled about full protraction, ``hi + share (command - hi)``; 0 holds the whiskers
        fully protracted (their pose at `reset`)."""
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"whisk amplitude {share!r} is outside [0, 1]")
        hi = math.radians(self.robot.protraction_max_deg)
        self._cmd = [hi + share * (float(c) - hi) for c in self.sim.whisk_command]

    def cycle(
        self, on_series: Callable[[int, np.ndarray], object] | None = None
    ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """Simulate one whisk cycle; it ends at maximum protraction.

        ``on_series(i, contact_points)`` is called after each of the S series instants (e.g. a
        controller tick) with the whisker contact points (k, 3) present at that instant.
        Returns the (S, 24, 2) deflection series and per-instant contact points / normals.
        """
        m, d, sim = self.model, self.data, self.sim
        ctrl, servo, cmd = d.ctrl, self._servo, self._cmd
        S = len(self.series_steps)
        series = np.empty((S, N_WHISKERS, 2))
        points: list[np.ndarray] = []
        normals: list[np.ndarray] = []
        j = 0
        t0 = time.perf_counter()
        step = mujoco.mj_step
        read_xy = sim.xy
        for i, chunk in enumerate(self._chunks):
            for _ in range(chunk):
                ctrl[servo] = cmd[j]
                step(m, d)
                j += 1
            series[i] = read_xy(d)
            if d.ncon and sim.body_contacts(d):
                self.body_collisions += 1
            p, n, _ = sim.whisker_contacts(d)
            points.append(p)
            normals.append(n)
            if on_series is not None:
                on_series(i, p)
        self.physics_time += time.perf_counter() - t0
        return series, points, normals

    def render(self, out: np.ndarray | None = None) -> np.ndarray:
        if not self._camera_on:
            raise RuntimeError("this Simulator was created with camera=False")
        if self.camera is None or self.camera.pid != os.getpid():
            if self.camera is not None:
                self.camera.close()  # inherited over fork: let go of, not freed
            self.camera = Camera(self.model, self.robot.camera_width, self.robot.camera_height,
                                 fog=self.condition.fog is not None)
        image = self.camera.render(self.data, out=out)
        image[...] = degrade(image, self.condition.camera, self._noise)
        return image

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()


log = logging.getLogger("vitaplace.sim")
# MuJoCo's own warnings (e.g. "the simulation is unstable", once per step of an unstable run)
# go to the debug log (-v), not to stderr: the counters in mjData still record them and
# check_plausible turns them into one error line naming them.
mujoco.set_mju_user_warning(lambda message: log.debug("MuJoCo: %s", message.strip()))


class SimulationError(UserError):
    """A recorded run that cannot be right: unstable physics, a robot that never moved,
    identical frames, poses outside the arena."""


def check_plausible(name: str, mujoco_warnings: dict[str, int], poses: np.ndarray, images: np.ndarray,
                    environment: EnvironmentSpec) -> None:
    """Raise SimulationError naming run ``name`` when its recording is physically implausible."""
    if mujoco_warnings:
        raise SimulationError(
            f"run {name!r}: the simulation was unstable (MuJoCo warnings {mujoco_warnings}); check the robot's "
            "stiffness, damping, masses and timestep"
        )
    if not np.all(np.isfinite(poses)):
        raise SimulationError(f"run {name!r}: poses are not finite")
    hx, hy = environment.arena.half_x, environment.arena.half_y
    outside = (np.abs(poses[:, 0]) > hx) | (np.abs(poses[:, 1]) > hy)
    if outside.any():
        k = int(np.argmax(outside))
        raise SimulationError(f"run {name!r}: sample {k} is outside the arena "
                              f"at ({poses[k, 0]:.2f}, {poses[k, 1]:.2f})")
    if len(poses) > 1:
        travelled = float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T)))
        if travelled < 0.01:
            raise SimulationError(f"run {name!r}: the robot never moved ({travelled:.3g} m in {len(poses)} samples)")
        if np.all(images == images[:1]):
            raise SimulationError(f"run {name!r}: all {len(images)} camera frames are identical")


class Samples(NamedTuple):
    """The arrays a run's samples are written into: allocated by `allocate_samples`, filled
    by `simulate_samples`, turned into a `Run` by `run_from_samples`."""

    images: np.ndarray  #: (N, H, W, 3) uint8
    theta: np.ndarray  #: (N, 24) float32
    xy: np.ndarray  #: (N, 24, 2) float32
    deflection: np.ndarray  #: (N, S, 24, 2) float32
    poses: np.ndarray  #: (N, 3) float64
    times: np.ndarray  #: (N,) float64
    points: list[np.ndarray]  #: per sample, the contact points (k, 3) of its whisk cycle
    normals: list[np.ndarray]  #: ... and their normals (k, 3)
    counts: np.ndarray  #: (N + 1,) int64, cumulative contact counts (the run's contact offsets)


def allocate_samples(n_samples: int, robot: RobotSpec) -> Samples:
    """Empty arrays for ``n_samples`` samples of ``robot``'s sensors."""
    N, S = n_samples, robot.deflection_samples
    return Samples(
        images=np.empty((N, robot.camera_height, robot.camera_width, 3), dtype=np.uint8),
        theta=np.empty((N, N_WHISKERS), dtype=np.float32),
        xy=np.empty((N, N_WHISKERS, 2), dtype=np.float32),
        deflection=np.empty((N, S, N_WHISKERS, 2), dtype=np.float32),
        poses=np.empty((N, 3), dtype=np.float64),
        times=np.empty(N, dtype=np.float64),
        points=[],
        normals=[],
        counts=np.zeros(N + 1, dtype=np.int64),
    )


#: whisk cycles a controller that records only some (`records_sample`) may go without a sample
#: before the run is an error: four laps of E1's loop at the teleoperator's speed
MAX_UNRECORDED_CYCLES = 1000


class ControlTicks:
    """The controller in the loop: called after each deflection-series instant of a cycle, it
    drives the robot with the controller's command every ``every`` instants, observing the
    whisker contacts gathered since the last tick; it counts the ticks spent in each
    controller mode and the time the controller took."""

    def __init__(self, sim: Simulator, controller: Callable[[Observation], tuple[float, ...]], kind: str,
                 every: int) -> None:
        self.sim, self.controller, self.kind, self.every = sim, controller, kind, every
        self.pending: list[np.ndarray] = []  #: contact points (k, 3) since the last tick
        self.mode_counts: dict[str, int] = {}
        self.control_s = 0.0

    def __call__(self, i: int, contact_points: np.ndarray) -> None:
        if len(contact_points):
            self.pending.append(contact_points)
        if i % self.every != self.every - 1:
            return
        sim, d = self.sim, self.sim.data
        contacts = np.concatenate(self.pending) if self.pending else np.zeros((0, 3))
        self.pending.clear()
        obs = Observation(
            time=float(d.time),
            pose=sim.sim.pose(d),
            contacts=contacts,
            deflection=np.linalg.norm(sim.sim.xy(d), axis=1),
        )
        t0 = time.perf_counter()
        sim.drive(*self.controller(obs))
        self.control_s += time.perf_counter() - t0
        mode = getattr(self.controller, "mode", self.kind)
        self.mode_counts[mode] = self.mode_counts.get(mode, 0) + 1


def simulate_samples(sim: Simulator, samples: Samples, tick: ControlTicks, warmup_cycles: int, name: str,
                   progress: bool) -> None:
    """The simulation loop: ``warmup_cycles`` whisk cycles, then one cycle per sample, each
    sample read at the cycle's end (maximum protraction); closes ``sim``."""
    images, theta, xy, deflection, poses, times, all_points, all_normals, counts = samples
    for _ in range(warmup_cycles):
        sim.cycle()
    records = getattr(tick.controller, "records_sample", lambda: True)
    bar = tqdm(total=len(poses), unit="sample", desc=name, disable=not progress, smoothing=0.1, leave=False)
    try:
        for k in range(len(poses)):
            for _ in range(MAX_UNRECORDED_CYCLES + 1):  # a controller may sample some cycles only (stations)
                series, points, normals = sim.cycle(tick)
                if records():
                    break
            else:
                raise SimulationError(f"run {name!r}: no sample in {MAX_UNRECORDED_CYCLES} whisk cycles after sample "
                                      f"{k} (its controller records only some cycles and stopped recording)")
            d = sim.data
            deflection[k] = series
            xy[k] = series[-1]
            theta[k] = sim.sim.theta(d)
            poses[k] = sim.sim.pose(d)
            times[k] = d.time
            sim.render(out=images[k])
            pts = np.concatenate(points)
            all_points.append(pts)
            all_normals.append(np.concatenate(normals))
            counts[k + 1] = counts[k] + len(pts)
            bar.update(1)
    finally:
        bar.close()
        sim.close()


def run_from_samples(sim: Simulator, samples: Samples, environment: EnvironmentSpec, run: RunSpec | Mapping[str, Any],
                     robot: RobotSpec, seed: int, name: str, mode_counts: dict[str, int]) -> Run:
    """The simulated samples as a `Run` with everything that made them in its ``attrs``;
    raises SimulationError when the recording is implausible (`check_plausible`)."""
    warn = sim.sim.warnings(sim.data)
    check_plausible(name, warn, samples.poses, samples.images, environment)
    layout = sim.sim.layout
    attrs: dict[str, Any] = {
        "seed": int(seed),
        "run_key": run_hash(environment, run, robot, seed),
        "environment": environment.name,
        "environment_spec": environment.model_dump(mode="json"),
        "robot": robot.model_dump(mode="json"),
        "camera": {
            "width": robot.camera_width,
            "height": robot.camera_height,
            "hfov_deg": robot.camera_hfov_deg,
            "fovy_deg": robot.camera_fovy_deg,
            "pitch_deg": robot.camera_pitch_deg,
        },
        "run": dict(run) if isinstance(run, Mapping) else run.model_dump(mode="json"),
        "timestep": robot.timestep,
        "steps_per_cycle": robot.steps_per_cycle,
        "sample_period_s": robot.whisk_period,
        "deflection_sample_times_s": ((robot.series_steps() + 1) * robot.timestep).tolist(),
        "whiskers": {
            "length_m": [w["length"] for w in layout],
            "board": [w["board"] for w in layout],
            "column": [w["column"] for w in layout],
            "side": [w["side"] for w in layout],
        },
        "servo_phase_lag_rad": sim.sim.servo_phase_lag,
        "controller_modes": mode_counts,
        "body_collision_instants": sim.body_collisions,
        "mujoco_version": mujoco.__version__,
        "mujoco_warnings": warn,
        "gl_backend": GL_STATE.get("chosen"),
    }
    run_out = Run.from_arrays(
        images=samples.images,
        theta=samples.theta,
        xy=samples.xy,
        poses=samples.poses,
        times=samples.times,
        deflection=samples.deflection,
        contact_points=np.concatenate(samples.points).astype(np.float32) if samples.points else np.zeros((0, 3)),
        contact_normals=np.concatenate(samples.normals).astype(np.float32) if samples.normals else np.zeros((0, 3)),
        contact_offsets=samples.counts,
        name=name,
        attrs=attrs,
    )
    #: share of samples with whisker contact at the sampling instant
    run_out.attrs["touch_share"] = float(run_out.touch_mask().mean())
    return run_out


def simulate_run(
    environment: EnvironmentSpec,
    run: RunSpec,
    seed: int,
    robot: RobotSpec | None = None,
    progress: bool = True,
    name: str = "run",
    stats: dict[str, Any] | None = None,
) -> Run:
    """Simulate one run and return it as an in-memory `Run`.

    ``run.kind == "foraging"`` drives the tactile-attention foraging controller from the
    environment's ``start`` (or ``run.start``); ``"teleop"`` drives the emulated keyboard
    teleoperator along its own copy of the environment's route; ``"route"`` follows the
    route with the run's noise settings. ``attrs["touch_share"]`` is the share of samples
    with whisker contact at the sampling instant (`Run.touch_mask`). ``stats``, if given, receives timing figures
    (``physics_s`` - stepping and sensor readout, ``control_s`` - the controller,
    ``render_s``, ``wall_s`` - everything including model build, ``samples_per_s``) - kept
    out of ``attrs`` so the recorded data stay reproducible.
    """
    robot = robot or RobotSpec()
    wall0 = time.perf_counter()
    sim = Simulator(environment, robot, condition=run.condition, seed=seed)
    rng = np.random.default_rng(seed)
    controller, start = make_controller(environment, run, rng, robot.whisk_period)
    sim.reset(start)
    samples = allocate_samples(run.n_samples, robot)
    series_hz = robot.deflection_samples * robot.whisk_hz
    tick = ControlTicks(sim, controller, run.kind, every=max(1, int(round(series_hz / run.control_hz))))
    simulate_samples(sim, samples, tick, run.warmup_cycles, name, progress)
    run_out = run_from_samples(sim, samples, environment, run, robot, seed, name, tick.mode_counts)
    if stats is not None:
        wall = time.perf_counter() - wall0
        stats.update(
            physics_s=sim.physics_time - tick.control_s,
            control_s=tick.control_s,
            render_s=sim.camera.render_time if sim.camera else 0.0,
            wall_s=wall,
            samples=run.n_samples,
            samples_per_s=run.n_samples / wall if wall > 0 else float("inf"),
        )
    return run_out
