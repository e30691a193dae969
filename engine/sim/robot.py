"""The WhiskEye robot as data: its parameters (`RobotSpec`) and the original robot's geometry.

Geometry from the public Gazebo model of WhiskEye (repository
aalto-intelligent-robotics/ViTa-SLAM, branch ``whiskeye_robot``: ``whiskeye_robot.sdf``
and ``src/plugin/whisker_pose.h``), with the neck at its default pose, the head level
and facing forward. The model file's head frame has x down, y left and z forward; a
rotation maps it onto the base frame (x forward, y left, z up) and a lift of 0.393 m
puts the camera at its recorded 0.315 m above the floor.

Kinematic tree::

    base            slide x, slide y, hinge yaw (world frame) - 3 velocity actuators
    ├─ chassis      cylinder r = 0.23 m, h = 0.295 m (collides with the world, not the whiskers)
    └─ head         box around the whisker bases, 0.42-0.58 m ahead, 0.18-0.31 m high
       ├─ camera "eye" (the model's cam0): 0.517 m ahead, 0.057 m left, 0.315 m high,
       │  level, 90 deg horizontal field of view
       └─ 24 whiskers = 6 boards x 4 (shafts 50, 70, 100, 160 mm, front to back);
          each whisker is ONE body with three hinges at its base:
            w{i}_theta   protraction, driven by a position servo (whisking)
            w{i}_dx      compliant base, in-plane bending (spring + damper)
            w{i}_dy      compliant base, out-of-plane bending (spring + damper)
          and one capsule geom (the shaft) that collides with tactile world objects only.

Whisker index ``i = board * 4 + column``, boards numbered as on the robot (board b here
is the model's board b + 1): 0-1 on the right side (lower, upper), 2-3 on top (right,
left), 4-5 on the left side (upper, lower); columns 0-3 run front to back (the
MultiPredNet/WhiskEye ``4 x 6`` layout: ``theta[col, board]``). At theta = 0 every shaft
points 45 deg away from straight ahead (outward, and upward for the top boards); the
original joint limits are +-60 deg, so full protraction carries each shaft 15 deg past
straight ahead.

Every whisker has a right-handed shaft frame: x along the shaft from base to tip, z the
protraction axis (from the model file), y = z x x, the direction in which protraction
sweeps the tip. Sign conventions:

* ``theta`` - protraction angle; positive = swept forward (rostrally), on every board.
* ``xy[..., 0]`` - in-plane component: for ``physical``, the rotation of the shaft about
  its frame's z axis at the base, positive bending the tip toward +y (forward, the
  direction of protraction); for ``penetration``, the contact normal's y component.
* ``xy[..., 1]`` - out-of-plane component (frame z), likewise.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from vitaplace.engine.base.configfile import NumbersNotBooleans
from vitaplace.engine.data.dataset import MAX_DEFLECTION_SAMPLES

__all__ = ["RobotSpec", "whisker_layout", "camera_fovy_deg", "N_WHISKERS", "N_BOARDS", "N_COLUMNS"]

N_BOARDS = 6
N_COLUMNS = 4
N_WHISKERS = N_BOARDS * N_COLUMNS

BODY_RADIUS = 0.23  #: chassis radius [m]
BODY_HEIGHT = 0.295  #: chassis height [m]
HEAD_POS = (0.50, 0.0, 0.245)  #: head box centre in the base frame [m]
HEAD_HALF = (0.08, 0.08, 0.065)  #: head box half-extents [m]; the whisker bases sit on and just beyond its front
CAMERA_POS = (0.5166, 0.0573, 0.315)  #: the model's cam0 in the base frame [m]
#: Per whisker at theta = 0, in the base frame: base position [m], shaft direction and
#: protraction axis (unit vectors), from the model's whisker_pose.h (rounded to 0.1 mm).
WHISKER_BASES = (
    ((0.5796, -0.0666, 0.1884), (0.7050, -0.6823, -0.1936), (0.0529, -0.2183, 0.9744)),
    ((0.5671, -0.0795, 0.1868), (0.7072, -0.6922, -0.1441), (0.0177, -0.1840, 0.9828)),
    ((0.5543, -0.0921, 0.1854), (0.7066, -0.7016, -0.0919), (-0.0177, -0.1491, 0.9887)),
    ((0.5411, -0.1043, 0.1841), (0.7045, -0.7084, -0.0436), (-0.0529, -0.1140, 0.9921)),
    ((0.5890, -0.0624, 0.2354), (0.7057, -0.6828, 0.1890), (0.0529, 0.3137, 0.9481)),
    ((0.5766, -0.0743, 0.2407), (0.7056, -0.6685, 0.2349), (0.0177, 0.3474, 0.9376)),
    ((0.5638, -0.0858, 0.2460), (0.7069, -0.6488, 0.2818), (-0.0177, 0.3803, 0.9247)),
    ((0.5505, -0.0969, 0.2511), (0.7045, -0.6300, 0.3267), (-0.0529, 0.4122, 0.9096)),
    ((0.5979, -0.0272, 0.2729), (0.7061, -0.3409, 0.6206), (0.0529, 0.8981, 0.4365)),
    ((0.5854, -0.0317, 0.2850), (0.7076, -0.2962, 0.6416), (0.0177, 0.9141, 0.4051)),
    ((0.5726, -0.0359, 0.2970), (0.7061, -0.2528, 0.6615), (-0.0177, 0.9279, 0.3725)),
    ((0.5594, -0.0400, 0.3085), (0.7046, -0.2051, 0.6793), (-0.0529, 0.9393, 0.3391)),
    ((0.5979, 0.0243, 0.2737), (0.7068, 0.2052, 0.6769), (0.0529, 0.9393, -0.3391)),
    ((0.5854, 0.0299, 0.2855), (0.7076, 0.2531, 0.6598), (0.0177, 0.9279, -0.3725)),
    ((0.5726, 0.0355, 0.2968), (0.7062, 0.2973, 0.6425), (-0.0177, 0.9141, -0.4051)),
    ((0.5594, 0.0409, 0.3078), (0.7046, 0.3437, 0.6208), (-0.0529, 0.8981, -0.4365)),
    ((0.5890, 0.0608, 0.2374), (0.7034, 0.6312, 0.3269), (0.0529, 0.4122, -0.9096)),
    ((0.5766, 0.0731, 0.2417), (0.7056, 0.6507, 0.2806), (0.0177, 0.3803, -0.9247)),
    ((0.5638, 0.0851, 0.2455), (0.7072, 0.6668, 0.2351), (-0.0177, 0.3474, -0.9376)),
    ((0.5505, 0.0968, 0.2493), (0.7045, 0.6846, 0.1870), (-0.0529, 0.3137, -0.9481)),
    ((0.5797, 0.0660, 0.1907), (0.7050, 0.7077, -0.0463), (0.0529, -0.1211, -0.9912)),
    ((0.5672, 0.0787, 0.1879), (0.7056, 0.7018, -0.0984), (0.0177, -0.1562, -0.9876)),
    ((0.5544, 0.0910, 0.1849), (0.7078, 0.6908, -0.1475), (-0.0177, -0.1910, -0.9814)),
    ((0.5412, 0.1029, 0.1821), (0.7045, 0.6820, -0.1964), (-0.0529, -0.2252, -0.9729)),
)
WHISKER_DENSITY = 1200.0  #: shaft material density [kg/m^3] (plastic)
ROBOT_GROUP = 3  #: geom group of the robot's own geoms (hidden from its camera)


#: a whisker shaft's length [mm]: positive, at most half a metre
WhiskerLength = Annotated[float, Field(gt=0, le=500)]


def camera_fovy_deg(hfov_deg: float, width: int, height: int) -> float:
    """Vertical field of view of a pinhole camera with horizontal field ``hfov_deg`` and an
    image of ``width`` x ``height`` pixels (square pixels)."""
    return math.degrees(2.0 * math.atan(math.tan(math.radians(hfov_deg) / 2.0) * height / width))


class RobotSpec(NumbersNotBooleans):
    """Robot, sensor and physics parameters. Every field has a default (the WhiskEye-like robot)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # whisking
    whisk_hz: float = Field(2.0, gt=0, le=20, description="whisking frequency; one sample per whisk cycle [Hz]")
    protraction_min_deg: float = Field(-60.0, ge=-80, le=80, description="full retraction angle [deg] (WhiskEye: -60)")
    protraction_max_deg: float = Field(60.0, ge=-80, le=80, description="full protraction angle [deg] (WhiskEye: 60)")
    whisker_lengths_mm: tuple[WhiskerLength, WhiskerLength, WhiskerLength, WhiskerLength] = Field(
        (50.0, 70.0, 100.0, 160.0), description="shaft length per column, front to back [mm], each in (0, 500]"
    )
    whisker_radius_mm: float = Field(1.0, gt=0.1, le=5, description="shaft (capsule) radius [mm]")
    # compliant base (two orthogonal spring hinges)
    spring_stiffness: float = Field(0.5, gt=0, description="follicle spring stiffness per axis [N m/rad]")
    spring_damping: float = Field(5e-3, ge=0, description="follicle damping per axis [N m s/rad]; "
                                  "with physical touch at most spring_stiffness / whisk_hz (relaxation within a cycle)")
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
    camera_hfov_deg: float = Field(
        90.0, gt=5, lt=170, description="horizontal field of view [deg] (WhiskEye: 90); the vertical one follows from "
        "the image's aspect"
    )
    camera_pitch_deg: float = Field(
        0.0, ge=-60, le=60, description="camera tilt, negative = down [deg] (WhiskEye: level)"
    )
    # base
    base_mass: float = Field(10.0, gt=0, description="mass of the mobile base [kg] (WhiskEye model: 10)")
    base_servo_hz: float = Field(10.0, gt=0, le=50, description="bandwidth of the base's pose servo [Hz]")
    # simulation
    timestep: float = Field(
        0.002, ge=1e-4, le=0.01, description="physics timestep [s], 0.1 ms to 10 ms (below, a run takes hours)"
    )
    deflection_samples: int = Field(
        25, ge=1, le=MAX_DEFLECTION_SAMPLES, description="samples S of the per-cycle deflection series"
    )

    @model_validator(mode="after")
    def _check(self) -> RobotSpec:
        if self.protraction_max_deg <= self.protraction_min_deg:
            raise ValueError("protraction_max_deg must be larger than protraction_min_deg")
        if self.tactile_model == "penetration" and self.whisker_friction != type(self).model_fields[
                "whisker_friction"].default:
            raise ValueError(f"whisker_friction {self.whisker_friction:g} is ignored by tactile_model penetration "
                             "(its whiskers pass through objects without friction); leave it out or choose physical")
        steps = self.whisk_period / self.timestep
        if abs(steps - round(steps)) > 1e-6 * steps:
            raise ValueError(
                f"the whisk period 1/whisk_hz = {self.whisk_period:g} s must be a whole number of "
                f"timesteps ({self.timestep:g} s); got {steps:.4f} steps"
            )
        if round(steps) < self.deflection_samples:
            raise ValueError(
                f"deflection_samples ({self.deflection_samples}) exceeds the physics steps per whisk cycle "
                f"({round(steps)})"
            )
        relaxation = self.spring_damping / self.spring_stiffness
        if self.tactile_model == "physical" and relaxation > self.whisk_period:
            raise ValueError(
                f"spring_damping = {self.spring_damping:g} N m s/rad gives the follicle a relaxation time "
                f"spring_damping / spring_stiffness = {relaxation:.3g} s, longer than a whisk cycle "
                f"({self.whisk_period:g} s): a shaft could not bend within the sample it touches in; at most "
                f"{self.whisk_period * self.spring_stiffness:.4g}"
            )
        for name, stiffness, limit in (
            ("spring_stiffness", self.spring_stiffness, self.max_stable_stiffness(self.spring_armature)),
            ("servo_kp", self.servo_kp, self.max_stable_stiffness(self.servo_armature)),
        ):
            if stiffness > limit:
                raise ValueError(
                    f"{name} = {stiffness:g} N m/rad is beyond the stable range at timestep {self.timestep:g} s: "
                    f"at most {limit:.4g} (natural frequency sqrt(k / I) below 2 / timestep for the shortest whisker)"
                )
        return self

    def max_stable_stiffness(self, armature: float) -> float:
        """The largest angular stiffness [N m/rad] a whisker hinge with ``armature`` can have at
        this timestep: MuJoCo's implicitfast integrator treats damping implicitly but stiffness
        explicitly, so the spring's natural frequency sqrt(k / I) must stay below 2 / timestep,
        I being the hinge's rotor inertia plus the lightest shaft's (a rod of length L and mass
        m turning about its end: m L^2 / 3)."""
        length = min(self.whisker_lengths_mm) / 1000.0
        mass = WHISKER_DENSITY * math.pi * (self.whisker_radius_mm / 1000.0) ** 2 * length
        inertia = armature + mass * length**2 / 3.0
        return inertia * (2.0 / self.timestep) ** 2

    @property
    def n_whiskers(self) -> int:
        """Whiskers the robot carries (its boards times the whiskers on each)."""
        return N_WHISKERS

    @property
    def whisk_period(self) -> float:
        return 1.0 / self.whisk_hz

    @property
    def camera_fovy_deg(self) -> float:
        """Vertical field of view [deg] of the recorded image."""
        return camera_fovy_deg(self.camera_hfov_deg, self.camera_width, self.camera_height)

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
    """Per whisker: name, board, column, side (+1 left / -1 right / 0 top), base position in
    the base frame, shaft-frame orientation quaternion (w, x, y, z) at theta = 0 and length [m]."""
    from scipy.spatial.transform import Rotation

    out = []
    for i, (pos, shaft, axis) in enumerate(WHISKER_BASES):
        board, col = divmod(i, N_COLUMNS)
        x = np.asarray(shaft, dtype=float)
        x /= np.linalg.norm(x)
        z = np.asarray(axis, dtype=float)
        z = z - (z @ x) * x  # the model's axes are orthogonal to 0.3 %: make them exactly so
        z /= np.linalg.norm(z)
        qx, qy, qz, qw = Rotation.from_matrix(np.column_stack([x, np.cross(z, x), z])).as_quat()
        out.append(
            {
                "index": i,
                "name": f"w{i:02d}",
                "board": board,
                "column": col,
                "side": (-1, -1, 0, 0, 1, 1)[board],
                "pos": tuple(float(v) for v in pos),
                "quat": (float(qw), float(qx), float(qy), float(qz)),
                "length": robot.whisker_lengths_mm[col] / 1000.0,
            }
        )
    return out
