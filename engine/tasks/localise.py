"""``WhiskEye-Localise-v0``: place recognition as a reinforcement-learning task.

An episode is a drive of the WhiskEye robot (`WhiskEyeEnv`: one step = one whisk cycle) in
a known world with a reference map: a reference drive of that world (simulated by
`simulate_run`, or a run file) and a place-recognition plugin's features of it, the plugin
fitted once on that drive (`ReferenceMap`, built at the first reset, in the process that
steps, and kept by the environment). Each step the agent moves and whisks; the plugin
describes the new sample as it describes a run file's sample, ranks the reference samples by
its distance, and the best match is scored by the benchmark's own rule (`decide` on
`ground_truth_matrix`): reward 1 when it lies within ``tau`` metres of the true pose and
faces within ``heading_tolerance_deg`` of it, else 0. The true pose is in ``info`` only,
never in the observation. A reset starts the robot at a reference pose drawn from the seed
(there the map has a place), or where ``options={"start": [x, y, yaw_deg]}`` says.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pydantic
from gymnasium import spaces
from gymnasium.vector import SyncVectorEnv
from gymnasium.wrappers import TimeLimit

from vitaplace.engine.base.configfile import format_validation_error
from vitaplace.engine.base.errors import UserError, did_you_mean
from vitaplace.engine.config.inputs import tau_problem
from vitaplace.engine.config.scenario import ScoringSettings
from vitaplace.engine.data.dataset import DatasetError, Run, open_run, shape_problem
from vitaplace.engine.evaluation.evaluate import decide, ground_truth_matrix
from vitaplace.engine.extension.checks import check_methods
from vitaplace.engine.extension.features import FeatureExtractor, Features
from vitaplace.engine.extension.registry import discover
from vitaplace.engine.sim.clearance import footprint_clearance
from vitaplace.engine.sim.environment import EnvironmentSpec
from vitaplace.engine.sim.gym_env import WhiskEyeEnv
from vitaplace.engine.sim.robot import RobotSpec
from vitaplace.engine.sim.simulate import run_spec, simulate_run

__all__ = ["ENV_ID", "LocaliseEnv", "LocaliseStep", "ReferenceMap", "build_map", "localise_vector", "register"]

ENV_ID = "WhiskEye-Localise-v0"
MAX_EPISODE_STEPS = 200  #: 100 s of simulated time
#: the reference drive by default: the environment's route, one lap of E1 or E2 at the route's 0.15 m/s
REFERENCE_SAMPLES = 150
SCORING = ScoringSettings()  #: the benchmark's defaults: tau 0.3 m, heading tolerance 30 deg


@dataclass(frozen=True)
class ReferenceMap:
    """A world's reference drive, a plugin fitted once on it and its features of the drive."""

    run: Run
    extractor: FeatureExtractor
    features: Features
    startable: np.ndarray  #: indices of the reference poses where the robot's body and head are clear


def build_map(environment: EnvironmentSpec, robot: RobotSpec, reference: str | Path | Run | None = None,
              reference_samples: int = REFERENCE_SAMPLES, reference_seed: int = 0, plugin: str = "handcrafted",
              params: Mapping[str, Any] | None = None) -> ReferenceMap:
    """The reference map: ``reference`` (a `Run` or a run file) or a route drive of
    ``reference_samples`` samples simulated with ``reference_seed``; ``plugin`` with ``params``
    fitted on it (as a scenario's fit stage does) and its features of it."""
    if reference is not None:
        run = _reference_run(reference, environment, robot)
    else:
        run = simulate_run(environment, run_spec(kind="route", n_samples=reference_samples), seed=reference_seed,
                           robot=robot, progress=False, name="reference")
    extractor = discover().create(plugin, params)
    extractor.progress = False
    extractor.fit(run)
    check_methods(extractor, plugin, run)  # each step's sample and distances checked as the pipeline's
    poses = np.asarray(run.poses, dtype=np.float64)
    clear = footprint_clearance(environment.obstacles, poses[:, :2], poses[:, 2]) >= 0
    if not clear.any():
        raise UserError(f"{ENV_ID}: no pose of the reference drive {run.name!r} is clear of the obstacles of "
                        f"{environment.name!r}; is it a drive of this environment?")
    return ReferenceMap(run, extractor, extractor.transform(run), np.flatnonzero(clear))


def _reference_run(reference: str | Path | Run, environment: EnvironmentSpec, robot: RobotSpec) -> Run:
    """``reference`` (a `Run` or a run file) as a drive the task can map: recorded in
    ``environment`` (the name the run records, that of a shipped environment or of an
    environment file's ``name``; a run that records none, an imported one, is left to the
    clearance check of `build_map`) and with ``robot``'s whiskers and image size (`shape_problem`,
    as a scenario's runs); else one line naming ``reference``."""
    try:
        run = reference if isinstance(reference, Run) else open_run(reference)
    except DatasetError as exc:
        raise UserError(f"{ENV_ID}: reference: {exc}") from None
    recorded = run.attrs.get("environment")
    if recorded is not None and recorded != environment.name:
        raise UserError(f"{ENV_ID}: reference: {run.path or repr(run.name)} was recorded in environment "
                        f"{recorded!r}, this task's is {environment.name!r}; expected a drive of {environment.name!r}")
    problem = shape_problem(run, robot.n_whiskers, (robot.camera_height, robot.camera_width, 3), "the task's robot")
    if problem:
        raise UserError(f"{ENV_ID}: reference: {problem}")
    return run


@dataclass(frozen=True)
class LocaliseStep:
    """One step's place recognition: the sample's true pose, the reference sample the plugin
    ranks first, and the benchmark's verdict on it (``info`` holds these fields)."""

    true_pose: np.ndarray  #: (3,) x, y [m], yaw [rad] of the robot at the sample
    best_match: int  #: index of the first reference sample at the least plugin distance
    match_pose: np.ndarray  #: (3,) that reference sample's pose
    match_distance: float  #: the plugin's distance (TME) to it
    match_error_m: float  #: its ground-truth distance [m]; inf when the headings differ by more than the tolerance
    has_revisit: bool  #: some reference sample lies within tau and the heading tolerance
    correct: bool  #: every reference at the least distance lies within tau and the heading tolerance
    reward: float  #: the benchmark's rule: the share of the references at the least distance that do (1 or 0 untied)

    def info(self) -> dict[str, Any]:
        return asdict(self)


class LocaliseEnv(gymnasium.Env):
    """Place recognition in one world, one whisk cycle a step (see the module)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, environment: str | Path | EnvironmentSpec = "e1", robot: RobotSpec | dict | None = None,
                 plugin: str = "handcrafted", params: Mapping[str, Any] | None = None,
                 reference: str | Path | Run | None = None, reference_samples: int = REFERENCE_SAMPLES,
                 reference_seed: int = 0, tau: float = SCORING.tau,
                 heading_tolerance_deg: float | None = SCORING.heading_tolerance_deg,
                 render_mode: str | None = None, reference_map: ReferenceMap | None = None, **unknown: Any) -> None:
        if unknown:  # Gymnasium passes every keyword of make() here: a misspelt one is a bad setting
            key = next(iter(unknown))
            known = [p for p in inspect.signature(LocaliseEnv.__init__).parameters if p not in ("self", "unknown")]
            raise UserError(f"{ENV_ID}: unknown keyword {key!r}{did_you_mean(key, known)} (keywords: "
                            f"{', '.join(known)})")
        try:
            scoring = ScoringSettings(tau=tau, heading_tolerance_deg=heading_tolerance_deg)
        except pydantic.ValidationError as exc:
            raise UserError(format_validation_error(ENV_ID, exc, ScoringSettings)) from None
        if not (isinstance(reference_samples, int) and reference_samples >= 1):
            raise UserError(f"{ENV_ID}: reference_samples {reference_samples!r}: expected a whole number >= 1")
        self._inner = WhiskEyeEnv(environment, robot, render_mode=render_mode)
        self.environment, self.robot = self._inner.environment, self._inner.robot
        try:
            self._check_world(scoring.tau, reference)
        except UserError:
            self._inner.close()
            raise
        self.render_mode, self.metadata = render_mode, self._inner.metadata
        self.tau, self.heading_tolerance_deg = scoring.tau, scoring.heading_tolerance_deg
        self._map_settings: dict[str, Any] = {"reference": reference, "reference_samples": reference_samples,
                              "reference_seed": reference_seed, "plugin": plugin, "params": params}
        self._map = reference_map
        self.action_space = self._inner.action_space
        self.observation_space = spaces.Dict({k: v for k, v in self._inner.observation_space.items() if k != "pose"})
        self._warnings: dict[str, str] = {}  # the plugin's warnings about the samples: logged once, not each step
        self.last_step: LocaliseStep | None = None  #: the last step's record
        self._closed = False

    def _check_world(self, tau: float, reference: str | Path | Run | None) -> None:
        """Refuse, at make(), a ``tau`` the arena cannot score (`tau_problem`, as a scenario's
        ``scoring.tau``) and a ``reference`` of another world or robot (`_reference_run`; the
        map itself is built at the first reset)."""
        arena = self.environment.arena
        problem = tau_problem(tau, arena.half_x, arena.half_y, self.environment.name)
        if problem:
            raise UserError(f"{ENV_ID}: tau: {problem}")
        if reference is not None:
            _reference_run(reference, self.environment, self.robot)

    def reference_map(self) -> ReferenceMap:
        """The reference map, built at the first call (`build_map`) and kept."""
        if self._map is None:
            self._map = build_map(self.environment, self.robot, **self._map_settings)
        return self._map

    def _open(self, call: str) -> None:
        if self._closed:
            raise RuntimeError(f"{call}: this {ENV_ID} environment is closed; make a new one (gymnasium.make)")

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        self._open("reset()")
        super().reset(seed=seed)
        ref = self.reference_map()
        if options is None or "start" not in options:
            x, y, yaw = ref.run.poses[int(self.np_random.choice(ref.startable))]
            options = {**(options or {}), "start": [float(x), float(y), math.degrees(float(yaw))]}
        obs, info = self._inner.reset(seed=seed, options=options)
        self.last_step = None
        return self._hide_pose(obs), {**info, "true_pose": obs["pose"].astype(np.float64)}

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        self._open("step()")
        obs, _, terminated, truncated, info = self._inner.step(action)
        self.last_step = record = self.localise(self._inner.last_sample())
        return self._hide_pose(obs), record.reward, terminated, truncated, {**info, **record.info()}

    def localise(self, sample: Run) -> LocaliseStep:
        """Match the one-sample run ``sample`` against the reference map and score the best
        match by the benchmark's rule at its true pose."""
        ref = self.reference_map()
        sample.warnings.update(self._warnings)
        features = ref.extractor.transform(sample)
        self._warnings = sample.warnings
        tme = ref.extractor.distance(features, ref.features)
        pose = np.asarray(sample.poses[:1], dtype=np.float64)
        gtm = ground_truth_matrix(pose, ref.run.poses, self.heading_tolerance_deg)
        verdict = decide(tme, gtm, self.tau, delta=math.inf)  # every best match is the agent's answer
        best = int(verdict.best_match[0])
        share = float(verdict.correct_share[0])  # a tie counts in proportion (docs/DESIGN.md, "Ties")
        return LocaliseStep(true_pose=pose[0], best_match=best, match_pose=np.array(ref.run.poses[best], np.float64),
                            match_distance=float(verdict.best_tme[0]), match_error_m=float(verdict.best_gtm[0]),
                            has_revisit=bool(verdict.has_revisit[0]), correct=share == 1.0, reward=share)

    def render(self) -> np.ndarray | None:
        return self._inner.render()

    def close(self) -> None:
        """Release the simulator; a second call does nothing, `reset` or `step` after it raise one line."""
        if not self._closed:
            self._inner.close()
            self._closed = True

    @staticmethod
    def _hide_pose(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: v for k, v in obs.items() if k != "pose"}


def localise_vector(num_envs: int = 1, max_episode_steps: int | None = None, **kwargs: Any) -> SyncVectorEnv:
    """The vector entry point (``gymnasium.make_vec(ENV_ID, num_envs)``): ``num_envs``
    environments stepped in turn in this process, sharing one reference map (one reference
    drive, the plugin fitted once), built here; each truncated at ``max_episode_steps``."""
    if not (isinstance(num_envs, int) and num_envs >= 1):
        raise UserError(f"{ENV_ID}: num_envs {num_envs!r}: expected a whole number >= 1")
    first = LocaliseEnv(**kwargs)
    shared = {**kwargs, "reference_map": first.reference_map()}
    envs: list[gymnasium.Env] = [first, *(LocaliseEnv(**shared) for _ in range(num_envs - 1))]
    if max_episode_steps is not None:
        envs = [TimeLimit(env, max_episode_steps) for env in envs]
    return SyncVectorEnv([_made(env) for env in envs])


def _made(env: gymnasium.Env) -> Callable[[], gymnasium.Env]:
    """A maker of ``env`` that is already made (SyncVectorEnv takes makers)."""
    return lambda: env


def register() -> None:
    """Register ``WhiskEye-Localise-v0`` (keywords: those of `LocaliseEnv`) with Gymnasium."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point=f"{__name__}:LocaliseEnv",
                           vector_entry_point=f"{__name__}:localise_vector", max_episode_steps=MAX_EPISODE_STEPS)
