"""Compile environment + robot into one MuJoCo model and read the robot's sensors.

The model is built as a `mujoco.MjSpec` by `vitaplace.engine.sim.build` (physics settings
stated there); `build_model` compiles it and sets the actuator gains from the compiled
inertias.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.sim.build import model_spec
from vitaplace.engine.sim.condition import LightCondition
from vitaplace.engine.sim.environment import EnvironmentSpec
from vitaplace.engine.sim.robot import N_WHISKERS, RobotSpec, whisker_layout

__all__ = ["ModelCompileError", "SimModel", "build_model"]


class ModelCompileError(UserError, ValueError):
    """An environment that MuJoCo cannot compile for a reason its validation cannot see (a PNG
    texture damaged past its header): one line naming the environment and what MuJoCo said,
    here and from a worker process."""


@dataclass
class SimModel:
    """A compiled model plus the addresses of everything the simulator reads and drives."""

    env: EnvironmentSpec
    robot: RobotSpec
    model: mujoco.MjModel
    spec: mujoco.MjSpec = field(repr=False)  #: the uncompiled model (actuator gains: placeholders)
    base_qadr: np.ndarray  #: (3,) qpos addresses of x, y, yaw
    base_dofadr: np.ndarray  #: (3,)
    theta_qadr: np.ndarray  #: (24,)
    xy_qadr: np.ndarray  #: (24, 2)
    drive_act: np.ndarray  #: (3,) actuator ids of the base drives (ctrl: vx, vy, yaw rate)
    drive_actadr: np.ndarray  #: (3,) d.act addresses of the drives (integrated reference pose)
    servo_act: np.ndarray  #: (24,) actuator ids of the protraction servos
    whisker_of_geom: np.ndarray  #: (ngeom,) whisker index of a geom, -1 for other geoms
    whisker_body: np.ndarray  #: (24,) body id of each whisker
    is_body_geom: np.ndarray  #: (ngeom,) bool: chassis / head geoms
    #: (steps_per_cycle,) servo target applied during each physics step of a whisk cycle
    whisk_command: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    #: servo phase lag [rad] and gain compensated in `whisk_command`
    servo_phase_lag: float = 0.0
    servo_gain: float = 1.0
    layout: list[dict] = field(repr=False, default_factory=list)

    @property
    def xml(self) -> str:
        """MJCF text of the model (for debugging; actuator gains are the placeholders)."""
        return self.spec.to_xml()

    # ------------------------------------------------------------ state access
    def new_data(self, pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> mujoco.MjData:
        """Fresh data with the base at ``pose`` (x, y, yaw [rad]) and the whiskers fully protracted."""
        d = mujoco.MjData(self.model)
        self.set_pose(d, pose)
        d.qpos[self.theta_qadr] = math.radians(self.robot.protraction_max_deg)
        d.ctrl[self.servo_act] = self.whisk_command[0]
        mujoco.mj_forward(self.model, d)
        return d

    def set_pose(self, d: mujoco.MjData, pose: tuple[float, float, float]) -> None:
        """Teleport the base (and its servo reference) to ``pose``; velocities are zeroed."""
        d.qpos[self.base_qadr] = pose
        d.qvel[self.base_dofadr] = 0.0
        d.act[self.drive_actadr] = pose

    def pose(self, d: mujoco.MjData) -> np.ndarray:
        """Ground-truth pose (x, y, yaw) of the base; yaw wrapped to [-pi, pi)."""
        x, y, yaw = d.qpos[self.base_qadr]
        return np.array([x, y, (yaw + math.pi) % (2 * math.pi) - math.pi])

    def theta(self, d: mujoco.MjData) -> np.ndarray:
        """Protraction angle per whisker [rad], (24,)."""
        return d.qpos[self.theta_qadr].copy()

    def xy(self, d: mujoco.MjData) -> np.ndarray:
        """Two-axis whisker signal (24, 2) of the robot's tactile model: the base deflection
        [rad] (``physical``) or the Gazebo plugin's penetration signal (``penetration``)."""
        if self.robot.tactile_model == "penetration":
            return self.penetration_xy(d)
        return d.qpos[self.xy_qadr].copy()

    def _whisker_contact_arrays(
        self, d: mujoco.MjData
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """All whisker-world contacts: (positions (k, 3), normals (k, 3) out of the touched
        object toward the whisker, signed distances (k,), whisker indices (k,)) or None."""
        n = d.ncon
        if n == 0:
            return None
        con = d.contact
        geom = _contact_geoms(con, n)
        w1 = self.whisker_of_geom[geom[:, 0]]
        w2 = self.whisker_of_geom[geom[:, 1]]
        mask = (w1 >= 0) | (w2 >= 0)
        if not mask.any():
            return None
        idx = np.flatnonzero(mask)
        whisker = np.where(w1[idx] >= 0, w1[idx], w2[idx])
        normal = con.frame[idx, :3].copy()
        # MuJoCo's normal points from geom1 to geom2: make it point from the whisker to the
        # object, then negate: out of the object, toward the whisker
        normal[w2[idx] >= 0] *= -1.0
        return con.pos[idx].copy(), -normal, con.dist[idx].copy(), whisker

    def whisker_contacts(self, d: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Contacts between whisker shafts and the world in ``d``.

        Returns ``points`` (k, 3) world-frame contact positions, ``normals`` (k, 3) unit
        surface normals of the touched object (pointing out of the object, toward the
        whisker) and ``whisker`` (k,) whisker indices. One contact per whisker (the deepest).
        """
        found = self._whisker_contact_arrays(d)
        if found is None:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        pos, normal, dist, whisker = found
        order = np.lexsort((dist, whisker))
        whisker, first = np.unique(whisker[order], return_index=True)
        sel = order[first]
        return pos[sel], normal[sel], whisker.astype(np.int64)

    def penetration_xy(self, d: mujoco.MjData) -> np.ndarray:
        """The Gazebo WhiskEye plugin's touch signal (24, 2): per whisker, the sum over its
        contacts of ``10 * depth * normal / (s + 0.1)``, the normal (out of the object) in the
        whisker's frame (components along its y and z axes, x being the shaft) and ``s`` the
        contact's distance along the shaft from the base [m]."""
        out = np.zeros((N_WHISKERS, 2))
        found = self._whisker_contact_arrays(d)
        if found is None:
            return out
        pos, normal, dist, whisker = found
        body = self.whisker_body[whisker]
        frames = d.xmat[body].reshape(-1, 3, 3)  # columns: the whisker frame's axes in world
        local_normal = np.einsum("kij,ki->kj", frames, normal)
        along = np.einsum("ki,ki->k", pos - d.xpos[body], frames[:, :, 0])
        np.add.at(out, whisker, penetration_deflection(-dist, local_normal[:, 1:], along))
        return out

    def body_contacts(self, d: mujoco.MjData) -> int:
        """Number of contacts between the robot's chassis/head and the world in ``d``."""
        n = d.ncon
        if n == 0:
            return 0
        geom = _contact_geoms(d.contact, n)
        return int(np.count_nonzero(self.is_body_geom[geom[:, 0]] | self.is_body_geom[geom[:, 1]]))

    def warnings(self, d: mujoco.MjData) -> dict[str, int]:
        """Non-zero MuJoCo warning counters of ``d`` by name."""
        out = {}
        for i in range(mujoco.mjtWarning.mjNWARNING.value):
            count = int(d.warning[i].number)
            if count:
                out[mujoco.mjtWarning(i).name] = count
        return out


def build_model(env: EnvironmentSpec, robot: RobotSpec | None = None, offscreen: tuple[int, int] = (0, 0),
                light: LightCondition | None = None) -> SimModel:
    """Compile ``env`` + robot (its lights changed by ``light``, a run's condition) and derive
    actuator gains from the compiled inertias."""
    robot = robot or RobotSpec()
    try:
        spec = model_spec(env, robot, offscreen, light)
        m = spec.compile()
    except ValueError as exc:  # MuJoCo's message may run over lines: one line here
        said = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise ModelCompileError(f"environment {env.name!r}: MuJoCo could not compile the model: {said}") from None

    def jid(name: str) -> int:
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

    def aid(name: str) -> int:
        return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

    layout = whisker_layout(robot)
    names = [w["name"] for w in layout]
    base_j = [jid(n) for n in ("base_x", "base_y", "base_yaw")]
    theta_j = [jid(f"{n}_theta") for n in names]
    xy_j = [[jid(f"{n}_dx"), jid(f"{n}_dy")] for n in names]
    whisker_of_geom = np.full(m.ngeom, -1, dtype=np.int64)
    for i, n in enumerate(names):
        whisker_of_geom[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n)] = i

    sim = SimModel(
        env=env,
        robot=robot,
        model=m,
        spec=spec,
        base_qadr=m.jnt_qposadr[base_j].copy(),
        base_dofadr=m.jnt_dofadr[base_j].copy(),
        theta_qadr=m.jnt_qposadr[theta_j].copy(),
        xy_qadr=m.jnt_qposadr[np.array(xy_j)].copy(),
        drive_act=np.array([aid(n) for n in ("drive_x", "drive_y", "drive_yaw")]),
        drive_actadr=m.actuator_actadr[[aid(n) for n in ("drive_x", "drive_y", "drive_yaw")]].copy(),
        servo_act=np.array([aid(f"{n}_servo") for n in names]),
        whisker_of_geom=whisker_of_geom,
        whisker_body=np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]),
        is_body_geom=np.isin(np.arange(m.ngeom),
                             [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in ("chassis", "head")]),
        layout=layout,
    )
    assert len(sim.servo_act) == N_WHISKERS

    # Joint-space inertia at the initial configuration -> damping gains and servo phase.
    d = mujoco.MjData(m)
    d.qpos[sim.theta_qadr] = math.radians(robot.protraction_max_deg)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, full, d.qM) if _fullm_takes_qm() else mujoco.mj_fullM(m, d, full)
    diag = np.diag(full)
    _set_drive_gains(sim, diag)
    theta_dof = m.jnt_dofadr[theta_j]
    with np.errstate(over="ignore"):  # an absurd servo_armature: the command check below names it
        inertia = float(np.mean(diag[theta_dof]))
    kp = robot.servo_kp
    kv = 2.0 * robot.servo_damping_ratio * math.sqrt(kp * inertia)
    for a in sim.servo_act:
        m.actuator_biasprm[a, 2] = -kv
    # Servo response H(iw) = kp / (kp - I w^2 + i kv w): pre-compensate phase and gain so the
    # measured protraction peaks exactly at the end of every whisk cycle (the sample instant).
    w = 2 * math.pi * robot.whisk_hz
    re, im = kp - inertia * w * w, kv * w
    sim.servo_phase_lag = math.atan2(im, re)
    sim.servo_gain = kp / math.hypot(re, im)
    lo, hi = math.radians(robot.protraction_min_deg), math.radians(robot.protraction_max_deg)
    centre, amp = (hi + lo) / 2, (hi - lo) / 2
    n = robot.steps_per_cycle
    t_mid = (np.arange(n) + 0.5) * robot.timestep  # a step's control acts over [t_j, t_j + dt]
    # cycle time origin: a cycle ends (t = T) at maximum protraction
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # checked next
        sim.whisk_command = centre + (np.float64(amp) / sim.servo_gain) * np.cos(w * t_mid + sim.servo_phase_lag)
    _check_servo_command(sim.whisk_command, robot, sim.servo_gain)
    return sim


def _set_drive_gains(sim: SimModel, diag: np.ndarray) -> None:
    """The base's pose servos critically damped at ``base_servo_hz`` from the diagonal ``diag``
    of the joint-space inertia; a UserError naming the robot's keys when a gain overflows."""
    wb = 2 * math.pi * sim.robot.base_servo_hz
    for a, dof in zip(sim.drive_act, sim.base_dofadr, strict=True):
        kp_b, kv_b = float(diag[dof]) * wb * wb, 2.0 * float(diag[dof]) * wb
        if not math.isfinite(kp_b):
            raise UserError(f"robot: base_mass {sim.robot.base_mass:g} kg and base_servo_hz "
                            f"{sim.robot.base_servo_hz:g} give the base's pose servo an infinite gain "
                            "(inertia x (2 pi base_servo_hz)^2); expected a lighter base")
        sim.model.actuator_gainprm[a, 0] = kp_b
        sim.model.actuator_biasprm[a, 1] = -kp_b
        sim.model.actuator_biasprm[a, 2] = -kv_b


def _check_servo_command(command: np.ndarray, robot: RobotSpec, gain: float) -> None:
    """A UserError naming the servo settings when the pre-compensated protraction command is
    not a control MuJoCo accepts: finite and below its bound on any value (``mjMAXVAL``, 1e10),
    beyond which it flags the control as unstable at the first step."""
    if np.all(np.abs(command) < mujoco.mjMAXVAL):
        return
    raise UserError(
        f"robot: servo_kp {robot.servo_kp:g}, servo_damping_ratio {robot.servo_damping_ratio:g} and servo_armature "
        f"{robot.servo_armature:g} leave the protraction servo a gain of {gain:.3g} at whisk_hz {robot.whisk_hz:g}, "
        f"so whisking needs commands beyond MuJoCo's bound of {mujoco.mjMAXVAL:g} rad; expected a stiffer servo "
        "(servo_kp) or less damping or armature"
    )


def penetration_deflection(depth: np.ndarray, normal_yz: np.ndarray, along: np.ndarray) -> np.ndarray:
    """The WhiskEye plugin's signal of single contacts: ``10 * depth * normal / (s + 0.1)``.

    ``depth`` (k,) penetration depths [m] (negative: not touching, counted as 0),
    ``normal_yz`` (k, 2) the contact normal's components across the shaft (whisker frame
    y, z), ``along`` (k,) the contact's distance along the shaft from the base [m].
    """
    depth = np.maximum(np.asarray(depth, dtype=float), 0.0)
    return 10.0 * depth[:, None] * np.asarray(normal_yz, dtype=float) / (np.asarray(along, dtype=float)[:, None] + 0.1)


def _contact_geoms(con: Any, n: int) -> np.ndarray:  # con: MjData.contact
    """(n, 2) geom ids of the contacts (``geom`` array in recent MuJoCo, geom1/geom2 before)."""
    geom = getattr(con, "geom", None)
    if geom is not None and np.ndim(geom) == 2:
        return np.asarray(geom)[:n]
    return np.stack([np.asarray(con.geom1)[:n], np.asarray(con.geom2)[:n]], axis=1)


def _fullm_takes_qm() -> bool:
    """mj_fullM's signature changed between MuJoCo versions (M, dst, qM) -> (m, d, dst)."""
    doc = mujoco.mj_fullM.__doc__ or ""
    return "qM" in doc.split("->")[0]
