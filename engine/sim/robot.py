"""The WhiskEye-like robot, generated as MJCF by code.

Kinematic tree::

    base            slide x, slide y, hinge yaw (world frame) - 3 velocity actuators
    ├─ chassis      cylinder r = 0.10 m (collides with the world, not with the whiskers)
    └─ head         box at 0.16 m ahead of the base centre, 0.15 m above the floor
       ├─ camera "eye" looking forward along the head's x axis
       └─ 24 whiskers = 6 row-boards (3 per side: top/middle/bottom) x 4 columns
          each whisker is ONE body with three hinges at its follicle:
            w{i}_theta   protraction, driven by a position servo (whisking)
            w{i}_dx      compliant base, in-plane bending (spring + damper)
            w{i}_dy      compliant base, out-of-plane bending (spring + damper)
          and one capsule geom (the shaft) that collides with tactile world objects only.

Whisker index ``i = board * 4 + column``; boards 0-2 are the left side (top, middle,
bottom), 3-5 the right side; columns 0-3 run front to back with shaft lengths 50, 70,
100, 160 mm (the MultiPredNet/WhiskEye ``4 x 6`` layout: ``theta[col, board]``).

Sign conventions (every whisker has the same right-handed shaft frame: x along the shaft
from base to tip, z the board normal (roughly up), y = z x x):

* ``theta`` - protraction angle relative to the rest angle; positive = swept forward
  (rostrally) on both sides of the head.
* ``xy[..., 0]`` - rotation of the shaft about its frame's z axis at the follicle; positive
  bends the tip toward the frame's +y. Because the frame is not mirrored between the sides,
  an object pushing both sides' whiskers backward gives opposite signs left and right.
* ``xy[..., 1]`` - positive bends the tip up (toward the frame's +z).
"""

from __future__ import annotations

import math

import numpy as np
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from vitaplace.engine.sim.environment import BIT_BODY, BIT_WHISKER, _fmt, _tag

__all__ = ["RobotSpec", "robot_mjcf", "whisker_layout", "N_WHISKERS", "N_BOARDS", "N_COLUMNS"]

N_BOARDS = 6
N_COLUMNS = 4
N_WHISKERS = N_BOARDS * N_COLUMNS

BASE_RADIUS = 0.10  #: chassis radius [m]
HEAD_POS = (0.16, 0.0, 0.15)  #: head centre in the base frame [m]
HEAD_HALF = (0.05, 0.04, 0.03)  #: head box half-extents [m]
FOLLICLE_Y = 0.045  #: lateral offset of the row-boards (follicles) from the head centre [m]
#: rest angle of each column's shaft from straight ahead (outward positive) [deg]
REST_YAW_DEG = (50.0, 60.0, 70.0, 80.0)
#: elevation of each row-board (top, middle, bottom) [deg]
ROW_PITCH_DEG = (20.0, 0.0, -20.0)
ROW_Z = (0.02, 0.0, -0.02)  #: follicle height of each row in the head frame [m]
COLUMN_X = (0.045, 0.03, 0.015, 0.0)  #: follicle position of each column along the head [m]
WHISKER_DENSITY = 1200.0  #: shaft material density [kg/m^3] (plastic)


class RobotSpec(BaseModel):
    """Robot, sensor and physics parameters. Every field has a default (the WhiskEye-like robot)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # whisking
    whisk_hz: float = Field(2.0, gt=0, le=20, description="whisking frequency; one sample per whisk cycle [Hz]")
    protraction_min_deg: float = Field(-30.0, ge=-80, le=80, description="full retraction angle [deg]")
    protraction_max_deg: float = Field(45.0, ge=-80, le=80, description="full protraction angle [deg]")
    whisker_lengths_mm: tuple[float, float, float, float] = Field(
        (50.0, 70.0, 100.0, 160.0), description="shaft length per column, front to back [mm]"
    )
    whisker_radius_mm: float = Field(1.0, gt=0.1, le=5, description="shaft (capsule) radius [mm]")
    # compliant base (two orthogonal spring hinges)
    spring_stiffness: float = Field(0.5, gt=0, description="follicle spring stiffness per axis [N m/rad]")
    spring_damping: float = Field(5e-3, ge=0, description="follicle damping per axis [N m s/rad]")
    spring_armature: float = Field(2e-5, ge=0, description="rotor inertia added to each spring hinge [kg m^2]")
    spring_range_deg: float = Field(45.0, gt=0, le=90, description="mechanical limit of the deflection [deg]")
    # protraction servo
    servo_kp: float = Field(10.0, gt=0, description="protraction servo stiffness [N m/rad]")
    servo_damping_ratio: float = Field(1.0, ge=0, description="protraction servo damping ratio")
    servo_armature: float = Field(2e-4, ge=0, description="protraction joint rotor inertia [kg m^2]")
    servo_max_torque: float = Field(
        0.3, gt=0, description="torque limit of the protraction servo: a blocked whisker stalls it [N m]"
    )
    whisker_friction: float = Field(0.3, ge=0, description="sliding friction of the shafts")
    tactile_model: Literal["physical", "penetration"] = Field(
        "physical",
        description="physical: compliant whiskers bent by contact, xy = base deflection [rad]; penetration: the "
        "Gazebo WhiskEye plugin's model, whiskers pass through objects and xy = 10 sum(depth normal) / (s + 0.1)",
    )
    # camera
    camera_width: int = Field(160, ge=8, le=2048, description="recorded image width [px]")
    camera_height: int = Field(120, ge=8, le=2048, description="recorded image height [px]")
    camera_fovy_deg: float = Field(60.0, gt=5, lt=170, description="vertical field of view [deg]")
    camera_pitch_deg: float = Field(-5.0, ge=-60, le=60, description="camera tilt, negative = down [deg]")
    # base
    base_mass: float = Field(4.0, gt=0, description="mass of the mobile base [kg]")
    base_servo_hz: float = Field(10.0, gt=0, le=50, description="bandwidth of the base's pose servo [Hz]")
    # simulation
    timestep: float = Field(0.002, gt=0, le=0.01, description="physics timestep [s]")
    deflection_samples: int = Field(25, ge=1, le=1000, description="samples S of the per-cycle deflection series")

    @model_validator(mode="after")
    def _check(self) -> RobotSpec:
        if self.protraction_max_deg <= self.protraction_min_deg:
            raise ValueError("protraction_max_deg must be larger than protraction_min_deg")
        steps = self.whisk_period / self.timestep
        if abs(steps - round(steps)) > 1e-6 * steps:
            raise ValueError(
                f"the whisk period 1/whisk_hz = {self.whisk_period:g} s must be a whole number of "
                f"timesteps ({self.timestep:g} s); got {steps:.4f} steps"
            )
        if round(steps) < self.deflection_samples:
            raise ValueError(
                f"deflection_samples ({self.deflection_samples}) exceeds the physics steps per whisk cycle ({round(steps)})"
            )
        return self

    @property
    def whisk_period(self) -> float:
        return 1.0 / self.whisk_hz

    @property
    def steps_per_cycle(self) -> int:
        return int(round(self.whisk_period / self.timestep))

    def series_steps(self) -> np.ndarray:
        """Step indices (0-based, within a cycle) after which the deflection series is sampled.

        Evenly spread over the cycle; the last one is the cycle's final step (the sample).
        """
        n, s = self.steps_per_cycle, self.deflection_samples
        return (np.arange(1, s + 1) * n) // s - 1


def whisker_layout(robot: RobotSpec) -> list[dict]:
    """Per whisker: name, board, column, side (+1 left / -1 right), follicle position in the
    head frame, rest orientation quaternion (w, x, y, z) and length [m]."""
    from scipy.spatial.transform import Rotation

    out = []
    for board in range(N_BOARDS):
        side = 1 if board < 3 else -1
        row = board % 3
        for col in range(N_COLUMNS):
            i = board * N_COLUMNS + col
            yaw = side * REST_YAW_DEG[col]
            pitch = ROW_PITCH_DEG[row]
            rot = Rotation.from_euler("ZY", [yaw, -pitch], degrees=True)  # intrinsic: yaw, then tilt up
            qx, qy, qz, qw = rot.as_quat()
            out.append(
                {
                    "index": i,
                    "name": f"w{i:02d}",
                    "board": board,
                    "column": col,
                    "side": side,
                    "pos": (COLUMN_X[col], side * FOLLICLE_Y, ROW_Z[row]),
                    "quat": (qw, qx, qy, qz),
                    "length": robot.whisker_lengths_mm[col] / 1000.0,
                }
            )
    return out


def robot_mjcf(robot: RobotSpec) -> tuple[str, str]:
    """MJCF fragments ``(body_xml, actuator_xml)`` of the robot (base body at the origin)."""
    lo = math.radians(-robot.spring_range_deg)
    hi = math.radians(robot.spring_range_deg)
    r = robot.whisker_radius_mm / 1000.0
    body_geom = {"contype": str(BIT_BODY), "conaffinity": "0", "group": "3"}
    whisker_geom = {
        "contype": str(BIT_WHISKER),
        "conaffinity": "0",
        "group": "3",
        "density": _fmt(WHISKER_DENSITY),
        "friction": f"{robot.whisker_friction:g} 0.005 0.0001",
        "rgba": "0.85 0.85 0.8 1",
    }
    if robot.tactile_model == "penetration":
        # contacts are still detected (depth, normal) but nearly forceless: a 1000 s time
        # constant and ~0 impedance, dominating the mix with the world geom's parameters
        whisker_geom.update(solref="1000 1", solimp="0.0001 0.0001 0.001", solmix="1e9", friction="0 0 0")
    lines = [
        '<body name="base" pos="0 0 0">',
        '  <joint name="base_x" type="slide" axis="1 0 0"/>',
        '  <joint name="base_y" type="slide" axis="0 1 0"/>',
        '  <joint name="base_yaw" type="hinge" axis="0 0 1"/>',
        "  "
        + _tag(
            "geom",
            {
                "name": "chassis",
                "type": "cylinder",
                "size": _fmt((BASE_RADIUS, 0.05)),
                "pos": "0 0 0.06",
                "mass": _fmt(robot.base_mass),
                "rgba": "0.25 0.25 0.3 1",
                **body_geom,
            },
        ),
        "  "
        + _tag(
            "geom",
            {
                "name": "neck",
                "type": "capsule",
                "fromto": "0.03 0 0.11 0.12 0 0.15",
                "size": "0.015",
                "mass": "0.2",
                "rgba": "0.3 0.3 0.35 1",
                "contype": "0",
                "conaffinity": "0",
                "group": "3",
            },
        ),
        f'  <body name="head" pos="{_fmt(HEAD_POS)}">',
        "    "
        + _tag(
            "geom",
            {
                "name": "head",
                "type": "box",
                "size": _fmt(HEAD_HALF),
                "mass": "0.4",
                "rgba": "0.9 0.9 0.92 1",
                **body_geom,
            },
        ),
    ]
    # camera: looks along the head's +x, image right = -y, tilted by camera_pitch_deg
    p = math.radians(robot.camera_pitch_deg)
    d = np.array([math.cos(p), 0.0, math.sin(p)])
    right = np.array([0.0, -1.0, 0.0])
    up = np.cross(right, d)
    lines.append(
        "    "
        + _tag(
            "camera",
            {
                "name": "eye",
                "pos": _fmt((HEAD_HALF[0] + 0.002, 0.0, 0.015)),
                "xyaxes": _fmt((*right, *up)),
                "fovy": _fmt(robot.camera_fovy_deg),
            },
        )
    )
    for w in whisker_layout(robot):
        n = w["name"]
        lines += [
            f'    <body name="{n}" pos="{_fmt(w["pos"])}" quat="{_fmt(w["quat"])}">',
            f'      <joint name="{n}_theta" type="hinge" axis="0 0 {-w["side"]}" armature="{_fmt(robot.servo_armature)}"/>',
            f'      <joint name="{n}_dx" type="hinge" axis="0 0 1" stiffness="{_fmt(robot.spring_stiffness)}" '
            f'damping="{_fmt(robot.spring_damping)}" armature="{_fmt(robot.spring_armature)}" '
            f'limited="true" range="{_fmt((lo, hi))}"/>',
            f'      <joint name="{n}_dy" type="hinge" axis="0 -1 0" stiffness="{_fmt(robot.spring_stiffness)}" '
            f'damping="{_fmt(robot.spring_damping)}" armature="{_fmt(robot.spring_armature)}" '
            f'limited="true" range="{_fmt((lo, hi))}"/>',
            "      "
            + _tag(
                "geom",
                {"name": n, "type": "capsule", "fromto": _fmt((0, 0, 0, w["length"], 0, 0)), "size": _fmt(r), **whisker_geom},
            ),
            "    </body>",
        ]
    lines += ["  </body>", "</body>"]

    # actuators: the base is a kinematic-style servo: each drive integrates its control (a
    # commanded velocity: world vx, vy and yaw rate) into a reference position (actuator
    # activation) and tracks it with a stiff PD law, so contacts cannot push the robot away.
    # Each protraction hinge has a position servo. Gains (kp, kv) are set in model.py from the
    # compiled inertias; the values written here are placeholders.
    acts = [
        f'<general name="drive_{n}" joint="base_{n}" dyntype="integrator" gaintype="fixed" biastype="affine" '
        f'gainprm="1" biasprm="0 -1 0" actlimited="false"/>'
        for n in ("x", "y", "yaw")
    ]
    for w in whisker_layout(robot):
        n = w["name"]
        acts.append(
            f'<general name="{n}_servo" joint="{n}_theta" gaintype="fixed" biastype="affine" '
            f'gainprm="{_fmt(robot.servo_kp)}" biasprm="0 {_fmt(-robot.servo_kp)} 0" '
            f'forcelimited="true" forcerange="{_fmt((-robot.servo_max_torque, robot.servo_max_torque))}"/>'
        )
    return "\n".join(lines), "\n".join(acts)
