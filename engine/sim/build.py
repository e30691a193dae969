"""Environment + robot schema -> one `mujoco.MjSpec` (the MuJoCo model, built by code).

Data flows one way: `EnvironmentSpec` and `RobotSpec` (pure schema, no MuJoCo) are read
here and turned into an ``MjSpec``; `vitaplace.engine.sim.model.build_model` compiles it.
``spec.to_xml()`` gives the equivalent MJCF text for debugging (`SimModel.xml`).

Physics settings (stated here once, quoted in docs/SIMULATION.md):

* ``timestep`` = `RobotSpec.timestep` (default 2 ms = 250 steps per 2 Hz whisk cycle);
* ``integrator="implicitfast"`` - damping of the follicle springs, servo and base drives
  is integrated implicitly, so the stiff-ish whisker dynamics (spring natural frequency
  ~23 Hz, servo ~35 Hz) are stable and accurate at 2 ms;
* ``solver="Newton"``, ``iterations=50``, ``ls_iterations=20``, ``tolerance=1e-8``,
  pyramidal friction cones, default soft-contact parameters (``solref`` 0.02 s time
  constant, i.e. 10 timesteps);
* gravity off: the base is planar (x, y, yaw) and never leaves the floor, and the whisker
  readings are zero-offset like calibrated Hall sensors (no sag of the shafts).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import mujoco
import numpy as np

from vitaplace.engine.sim.condition import LightCondition, light_rgb
from vitaplace.engine.sim.environment import (
    BIT_BODY,
    BIT_WHISKER,
    WORLD_TACTILE_AFFINITY,
    WORLD_VISUAL_AFFINITY,
    BoxLandmark,
    CylinderLandmark,
    EnvironmentSpec,
    LightingSpec,
    MaterialSpec,
    RockLandmark,
)
from vitaplace.engine.sim.robot import (
    BODY_HEIGHT,
    BODY_RADIUS,
    CAMERA_POS,
    HEAD_HALF,
    HEAD_POS,
    ROBOT_GROUP,
    WHISKER_DENSITY,
    RobotSpec,
    whisker_layout,
)

__all__ = ["model_spec"]

WORLD_FRICTION = (0.3, 0.005, 0.0001)  #: sliding, torsional, rolling friction of walls and landmarks
UP = np.array([0.0, 0.0, 1.0])

_GEOM = mujoco.mjtGeom
_RGB = mujoco.mjtTextureRole.mjTEXROLE_RGB


def model_spec(env: EnvironmentSpec, robot: RobotSpec, offscreen: tuple[int, int] = (0, 0),
               light: LightCondition | None = None) -> mujoco.MjSpec:
    """The uncompiled model of ``env`` with the robot in it (base at the origin).

    ``offscreen`` (width, height) enlarges the offscreen render buffer beyond the robot's image;
    ``light`` changes the environment's lights (a run's condition, `engine/sim/condition.py`).
    The actuator gains are placeholders; `build_model` sets them from the compiled inertias.
    """
    spec = mujoco.MjSpec()
    spec.modelname = f"vitaplace_{env.name}"
    spec.compiler.degree = True
    spec.compiler.autolimits = True
    _set_options(spec, env, robot, offscreen)
    spec.add_texture(
        name="sky", type=mujoco.mjtTexture.mjTEXTURE_SKYBOX, builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,
        rgb1=env.background_rgb, rgb2=env.background_rgb, width=8, height=8,
    )
    _add_lighting(spec, env.lighting, light)
    _add_world(spec, env)
    _add_robot(spec, robot)
    return spec


def _set_options(spec: mujoco.MjSpec, env: EnvironmentSpec, robot: RobotSpec, offscreen: tuple[int, int]) -> None:
    """Solver and integrator (see the module docstring), render buffer, clipping planes, shadows."""
    opt = spec.option
    opt.timestep = robot.timestep
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    opt.iterations = 50
    opt.ls_iterations = 20
    opt.tolerance = 1e-8
    opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    opt.gravity = (0.0, 0.0, 0.0)
    spec.stat.extent = 2 * max(env.arena.half_x, env.arena.half_y)
    spec.stat.center = (0.0, 0.0, 0.5)
    vis = spec.visual
    vis.global_.offwidth = max(robot.camera_width, offscreen[0], 64)
    vis.global_.offheight = max(robot.camera_height, offscreen[1], 64)
    vis.quality.shadowsize = 2048 if env.lighting.shadows else 0
    vis.quality.offsamples = 0
    vis.map.znear = 0.002
    vis.map.zfar = 3.0


def _add_lighting(spec: mujoco.MjSpec, lighting: LightingSpec, condition: LightCondition | None = None) -> None:
    """The camera-mounted headlight (diffuse only), an ambient-only light and the suns, each
    level scaled and tinted by the run's light ``condition`` (`light_rgb`) and the suns along
    its direction when it gives one."""
    head = spec.visual.headlight
    head.ambient = (0.0, 0.0, 0.0)
    head.diffuse = light_rgb(lighting.headlight, condition)
    head.specular = (0.0, 0.0, 0.0)
    head.active = 1 if lighting.headlight > 0 else 0
    sun = dict(type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=(0.0, 0.0, 5.0))
    spec.worldbody.add_light(
        name="ambient", dir=(0.0, 0.0, -1.0), diffuse=(0.0, 0.0, 0.0), specular=(0.0, 0.0, 0.0),
        ambient=light_rgb(lighting.ambient, condition), castshadow=False, **sun,
    )
    direction = None if condition is None else condition.direction
    for k, light in enumerate(lighting.lights):
        spec.worldbody.add_light(
            name=f"sun{k}", dir=direction or light.direction, diffuse=light_rgb(light.diffuse, condition),
            specular=light_rgb(light.specular, condition), castshadow=lighting.shadows, **sun,
        )


def _add_material(spec: mujoco.MjSpec, name: str, mat: MaterialSpec, texture: str | None,
                  texrepeat: Sequence[float], texuniform: bool) -> None:
    """A material (reflectance 0: fast rendering), its RGB texture ``texture`` when given."""
    m = spec.add_material(name=name, rgba=mat.rgba, specular=mat.specular, shininess=mat.shininess, reflectance=0.0)
    if texture is not None:
        m.textures[_RGB] = texture
        m.texrepeat = texrepeat
        m.texuniform = texuniform


def _add_assets(spec: mujoco.MjSpec, env: EnvironmentSpec) -> None:
    """Every named material (with its texture) and the rocks' convex meshes."""
    for mname, mat in env.materials.items():
        tex = mat.texture
        if tex is not None:
            t = spec.add_texture(name=f"tex_{mname}", type=mujoco.mjtTexture.mjTEXTURE_2D)
            if tex.file is not None:
                t.file = tex.file
            else:
                t.builtin = getattr(mujoco.mjtBuiltin, f"mjBUILTIN_{tex.builtin.upper()}")
                t.rgb1, t.rgb2, t.markrgb = tex.rgb1, tex.rgb2, tex.markrgb
                t.mark = getattr(mujoco.mjtMark, f"mjMARK_{tex.mark.upper()}")
                t.random, t.width, t.height = tex.random, tex.width, tex.height
        _add_material(spec, f"mat_{mname}", mat, None if tex is None else f"tex_{mname}", mat.texrepeat, mat.texuniform)
    for name, lm in zip(env.landmark_names(), env.landmarks, strict=True):
        if isinstance(lm, RockLandmark):
            spec.add_mesh(name=f"mesh_{name}", uservert=lm.vertices().ravel())


def _static_geom(spec: mujoco.MjSpec, name: str, **attrs: object) -> mujoco.MjsGeom:
    """A world geom in its own fixed body: MuJoCo's broad phase prunes per body, so this
    keeps the whiskers from being tested against every wall and landmark at every step."""
    return spec.worldbody.add_body(name=name).add_geom(name=name, **attrs)


def _add_world(spec: mujoco.MjSpec, env: EnvironmentSpec) -> None:
    """Floor, walls (with their panels), boards and landmarks."""
    _add_assets(spec, env)
    a = env.arena
    hx, hy, t, h = a.half_x, a.half_y, a.wall_thickness, a.wall_height
    spec.worldbody.add_geom(
        name="floor", type=_GEOM.mjGEOM_PLANE, size=(hx + t, hy + t, 0.1), material=f"mat_{a.floor_material}",
        contype=0, conaffinity=0,
    )
    solid = dict(contype=0, conaffinity=WORLD_TACTILE_AFFINITY, friction=WORLD_FRICTION)
    # Each wall is a thin box whose local +z faces the arena, so a 2-D texture lands on
    # the inner face and repeats `wall_panels` times along it.
    sides: dict[Literal["north", "south", "east", "west"], tuple[float, float, float, float]] = {
        "north": (0.0, hy + t / 2, -90.0, hx + t),
        "south": (0.0, -hy - t / 2, 90.0, hx + t),
        "east": (hx + t / 2, 0.0, 180.0, hy + t),
        "west": (-hx - t / 2, 0.0, 0.0, hy + t),
    }
    for wname, (cx, cy, yaw, half_len) in sides.items():
        wall = a.walls.get(wname)
        material = a.wall_material if wall is None else wall.material
        look: dict[str, object] = (  # no material: the wall has an entry (wall_material is a name)
            {"rgba": wall.rgba} if wall is not None and material is None else {"material": f"mat_wall_{material}"}
        )
        if material is not None and spec.material(f"mat_wall_{material}") is None:
            mat = env.materials[material]
            tex = None if mat.texture is None else f"tex_{material}"
            _add_material(spec, f"mat_wall_{material}", mat, tex, (a.wall_panels, 1.0), False)
        # local frame: x along the wall, y up, z into the arena
        inward = np.array([math.cos(math.radians(yaw)), math.sin(math.radians(yaw)), 0.0])
        along = np.cross(UP, inward)
        _static_geom(
            spec, f"wall_{wname}", type=_GEOM.mjGEOM_BOX, pos=(cx, cy, h / 2), size=(half_len, h / 2, t / 2),
            xyaxes=(*along, *UP), **look, **solid,
        )
        if wall is not None and wall.panel is not None:
            pn = wall.panel
            face = np.array([cx, cy]) + inward[:2] * t / 2  # centre of the wall's inner face
            centre = face + inward[:2] * (pn.protrusion - pn.depth / 2) + along[:2] * pn.offset
            _static_geom(
                spec, f"panel_{wname}", type=_GEOM.mjGEOM_BOX, pos=(*centre, (pn.bottom + pn.top) / 2),
                size=(pn.width / 2, (pn.top - pn.bottom) / 2, pn.depth / 2), xyaxes=(*along, *UP), rgba=pn.rgba,
                **solid,
            )
    for k, board in enumerate(env.boards):
        front = np.array([math.cos(math.radians(board.yaw)), math.sin(math.radians(board.yaw)), 0.0])
        side = np.cross(UP, front)
        body = spec.worldbody.add_body(name=f"board{k}")
        flat = dict(type=_GEOM.mjGEOM_BOX, xyaxes=(*side, *front), contype=0, conaffinity=0)
        body.add_geom(
            name=f"board{k}", pos=(*board.pos, board.bottom + board.height / 2),
            size=(board.width / 2, board.thickness / 2, board.height / 2), rgba=board.rgba, **flat,
        )
        if board.strip_height > 0:
            top = board.bottom + board.height
            strip_pos = np.array([*board.pos, top - board.strip_below_top]) + front * (board.thickness / 2 + 0.002)
            body.add_geom(
                name=f"board{k}_strip", pos=strip_pos, size=(board.width / 2, 0.002, board.strip_height / 2),
                rgba=board.strip_rgba, **flat,
            )
    for name, lm in zip(env.landmark_names(), env.landmarks, strict=True):
        look = {"rgba": lm.rgba} if lm.material is None else {"material": f"mat_{lm.material}"}
        x, y = lm.pos
        if isinstance(lm, BoxLandmark):
            shape = dict(type=_GEOM.mjGEOM_BOX, pos=(x, y, lm.z + lm.size[2] / 2), size=np.array(lm.size) / 2)
        elif isinstance(lm, CylinderLandmark):
            shape = dict(type=_GEOM.mjGEOM_CYLINDER, pos=(x, y, lm.z + lm.height / 2), size=(lm.radius, lm.height / 2))
        else:
            shape = dict(type=_GEOM.mjGEOM_MESH, meshname=f"mesh_{name}", pos=(x, y, lm.z))
        _static_geom(
            spec, f"lm_{name}", euler=(0.0, 0.0, lm.yaw), contype=0,
            conaffinity=WORLD_TACTILE_AFFINITY if lm.tactile else WORLD_VISUAL_AFFINITY, friction=WORLD_FRICTION,
            **look, **shape,
        )


def _add_robot(spec: mujoco.MjSpec, robot: RobotSpec) -> None:
    """The WhiskEye robot (kinematic tree in `vitaplace.engine.sim.robot`) and its actuators."""
    base = spec.worldbody.add_body(name="base")
    for n, jtype, axis in (("x", "SLIDE", (1, 0, 0)), ("y", "SLIDE", (0, 1, 0)), ("yaw", "HINGE", (0, 0, 1))):
        base.add_joint(name=f"base_{n}", type=getattr(mujoco.mjtJoint, f"mjJNT_{jtype}"), axis=axis)
    body_bits = dict(contype=BIT_BODY, conaffinity=0, group=ROBOT_GROUP)
    base.add_geom(
        name="chassis", type=_GEOM.mjGEOM_CYLINDER, size=(BODY_RADIUS, BODY_HEIGHT / 2),
        pos=(0.0, 0.0, BODY_HEIGHT / 2), mass=robot.base_mass, rgba=(0.25, 0.25, 0.3, 1.0), **body_bits,
    )
    base.add_geom(
        name="neck", type=_GEOM.mjGEOM_CAPSULE,
        fromto=(0.1, 0.0, BODY_HEIGHT, HEAD_POS[0] - HEAD_HALF[0], 0.0, HEAD_POS[2]),
        size=(0.03, 0, 0), mass=0.2, rgba=(0.3, 0.3, 0.35, 1.0), contype=0, conaffinity=0, group=ROBOT_GROUP,
    )
    head = base.add_body(name="head", pos=HEAD_POS)
    head.add_geom(name="head", type=_GEOM.mjGEOM_BOX, size=HEAD_HALF, mass=0.4, rgba=(0.9, 0.9, 0.92, 1.0), **body_bits)
    # camera: looks along the base's +x, image right = -y, tilted by camera_pitch_deg
    p = math.radians(robot.camera_pitch_deg)
    right = np.array([0.0, -1.0, 0.0])
    up = np.cross(right, np.array([math.cos(p), 0.0, math.sin(p)]))
    head.add_camera(name="eye", pos=np.subtract(CAMERA_POS, HEAD_POS), xyaxes=(*right, *up), fovy=robot.camera_fovy_deg)

    whisker_geom = dict(
        type=_GEOM.mjGEOM_CAPSULE, size=(robot.whisker_radius_mm / 1000.0, 0, 0), contype=BIT_WHISKER, conaffinity=0,
        group=ROBOT_GROUP, density=WHISKER_DENSITY, friction=(robot.whisker_friction, 0.005, 0.0001),
        rgba=(0.85, 0.85, 0.8, 1.0),
    )
    if robot.tactile_model == "penetration":
        # contacts are still detected (depth, normal) but nearly forceless: a 1000 s time
        # constant and ~0 impedance, dominating the mix with the world geom's parameters
        whisker_geom.update(solref=(1000.0, 1.0), solimp=(0.0001, 0.0001, 0.001, 0.5, 2.0), solmix=1e9,
                            friction=(0, 0, 0))
    # As in the original XML model: the range is written in radians but compiler.degree
    # reads it in degrees, so the compiled limit is +-spring_range_deg * pi / 180 degrees.
    limit = math.radians(robot.spring_range_deg)
    spring = dict(
        type=mujoco.mjtJoint.mjJNT_HINGE, stiffness=robot.spring_stiffness, damping=robot.spring_damping,
        armature=robot.spring_armature, limited=mujoco.mjtLimited.mjLIMITED_TRUE, range=(-limit, limit),
    )
    layout = whisker_layout(robot)
    for w in layout:
        n = w["name"]
        body = head.add_body(name=n, pos=np.subtract(w["pos"], HEAD_POS), quat=w["quat"])
        body.add_joint(name=f"{n}_theta", type=mujoco.mjtJoint.mjJNT_HINGE, axis=(0, 0, 1),
                       armature=robot.servo_armature)
        body.add_joint(name=f"{n}_dx", axis=(0, 0, 1), **spring)
        body.add_joint(name=f"{n}_dy", axis=(0, -1, 0), **spring)
        body.add_geom(name=n, fromto=(0, 0, 0, w["length"], 0, 0), **whisker_geom)

    # actuators: the base is a kinematic-style servo: each drive integrates its control (a
    # commanded velocity: world vx, vy and yaw rate) into a reference position (actuator
    # activation) and tracks it with a stiff PD law, so contacts cannot push the robot away.
    # Each protraction hinge has a position servo. Gains (kp, kv) are set in model.py from the
    # compiled inertias; the values written here are placeholders.
    def servo(name: str, joint: str, kp: float, **attrs: object) -> None:
        spec.add_actuator(
            name=name, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT, gaintype=mujoco.mjtGain.mjGAIN_FIXED,
            biastype=mujoco.mjtBias.mjBIAS_AFFINE, gainprm=_params(kp), biasprm=_params(0.0, -kp, 0.0), **attrs,
        )

    for n in ("x", "y", "yaw"):
        servo(f"drive_{n}", f"base_{n}", 1.0, dyntype=mujoco.mjtDyn.mjDYN_INTEGRATOR,
              actlimited=mujoco.mjtLimited.mjLIMITED_FALSE)
    for w in layout:
        servo(f"{w['name']}_servo", f"{w['name']}_theta", robot.servo_kp, forcelimited=mujoco.mjtLimited.mjLIMITED_TRUE,
              forcerange=(-robot.servo_max_torque, robot.servo_max_torque))


def _params(*values: float) -> np.ndarray:
    """A 10-element gain/bias parameter vector starting with ``values``."""
    out = np.zeros(10)
    out[: len(values)] = values
    return out
