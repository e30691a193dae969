"""E1, E2, E3 against the original Gazebo worlds, the visual aliasing they were built for, and the
design of the four touch worlds (appearance x shape).

The expected numbers are written here from the original files — aalto-intelligent-
robotics/ViTa-SLAM, commit 8c0d62e, src/whiskeye_gazebo/worlds/ICRA20_dataset_generation_
{square,crowded,tactile_only}.world (the <state> poses) — never read from vitaplace.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import math

import numpy as np
import pytest

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)

# isort: split
import mujoco  # noqa: E402

from vitaplace.engine.sim.environment import BoxLandmark, CylinderLandmark, RockLandmark, load_environment  # noqa: E402
from vitaplace.engine.sim.model import build_model  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import Simulator  # noqa: E402

# Every world: walls 6.3 long, 0.15 thick, 1.5 high centred at (+-3.1, 0), (0, +-3.1).
WALL_CENTRE, WALL_THICKNESS, WALL_HEIGHT = 3.1, 0.15, 1.5
INSIDE = 2 * (WALL_CENTRE - WALL_THICKNESS / 2)  # 6.05
WALL_GREY = {"west": 0.2, "north": 0.2, "east": 1.0, "south": 1.0}
PANEL_RGB = {"west": (0, 1, 0), "north": (0, 0, 1), "east": (1, 0, 0), "south": (1, 0, 0)}
# Panel: 0.2 deep x 1.1 wide, from ~0.53 to ~1.47 above the floor, protruding 0.125.
PANEL = {"width": 1.1, "depth": 0.2, "bottom": 0.53, "top": 1.47, "protrusion": 0.125}

# Landmarks: (type, x, y, bottom z); boxes 1 x 1 x 0.3, cylinders r 0.5 h 0.3, yaw 0.
E1 = [("box", 2.138, 0.0, 0.0), ("box", -2.138, 0.0, 0.0), ("cylinder", 0.0, -2.138, 0.0)]
E2 = E1 + [("box", -1.051, 1.943, 0.0), ("cylinder", 1.641, 1.823, 0.0), ("cylinder", 1.725, -1.639, 0.0),
           ("rock", 0.0, 0.0, 0.0)]
E3 = [("rock", 0.0, 0.0, 0.0),
      ("box", -0.638, -1.704, 0.0), ("box", -1.833, 0.0, 0.0), ("box", -1.611, 0.989, 0.0),
      ("box", -0.073, 1.899, 0.0), ("box", 0.892, 1.747, 0.0), ("box", 1.665, -0.130, 0.129),
      ("cylinder", -1.454, -0.977, 0.0), ("cylinder", 1.334, -1.106, 0.0), ("cylinder", 0.449, -1.714, 0.0),
      ("cylinder", 1.487, 0.944, 0.0), ("cylinder", -1.047, 1.881, 0.0)]
WORLDS = {"e1": E1, "e2": E2, "e3": E3}


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_landmarks_are_the_originals(name):
    env = load_environment(name)
    got = sorted((lm.type, *lm.pos, lm.z) for lm in env.landmarks)
    expected = sorted(WORLDS[name])
    assert [g[0] for g in got] == [e[0] for e in expected]
    assert np.array([g[1:] for g in got]) == pytest.approx(np.array([e[1:] for e in expected]))
    for lm in env.landmarks:
        assert lm.yaw == 0.0
        assert env.materials[lm.material].rgba[:3] == env.materials[env.arena.floor_material].rgba[:3]  # floor grey
        if isinstance(lm, BoxLandmark):
            assert lm.size == (1.0, 1.0, 0.3)
        elif isinstance(lm, CylinderLandmark):
            assert (lm.radius, lm.height) == (0.5, 0.3)
        else:
            assert isinstance(lm, RockLandmark)
            # Rock1.dae at scale 0.25: about 0.80 x 0.91 in plan, 0.33 high
            extent = lm.vertices().max(axis=0) - lm.vertices().min(axis=0)
            assert extent == pytest.approx((0.80, 0.91, 0.33), abs=1e-6)


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_arena_walls_panels_light_and_background_are_the_originals(name):
    env = load_environment(name)
    a = env.arena
    assert 2 * a.half_x == pytest.approx(INSIDE) and 2 * a.half_y == pytest.approx(INSIDE)
    assert (a.wall_thickness, a.wall_height) == (WALL_THICKNESS, WALL_HEIGHT)
    for wall, grey in WALL_GREY.items():
        spec = a.walls[wall]
        assert spec.material is None and spec.rgba == (grey, grey, grey, 1.0)
        assert spec.panel.rgba[:3] == PANEL_RGB[wall]
        assert {k: getattr(spec.panel, k) for k in PANEL} == PANEL and spec.panel.offset == 0.0
    assert env.background_rgb == (0.7, 0.7, 0.7)
    light = env.lighting
    assert len(light.lights) == 1
    assert (light.lights[0].direction, light.lights[0].diffuse, light.lights[0].specular) == (
        (-0.5, 0.1, -0.9), 0.8, 0.2)
    assert (light.ambient, light.headlight, light.shadows) == (0.4, 0.0, False)
    banner = env.boards[0]  # 3.6 x 3.43 at (0.5, 5.0), top at 2.43 m
    assert (banner.pos, banner.width, banner.height, banner.bottom + banner.height) == ((0.5, 5.0), 3.6, 3.43, 2.43)


def test_compiled_geometry_puts_walls_panels_and_the_floating_box_where_the_originals_are():
    m = build_model(load_environment("e3"), RobotSpec()).model

    def geom(name):
        g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
        assert g >= 0, name
        return g

    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    # the east wall's box: centre x = 3.1, half thickness 0.075, half height 0.75
    east = geom("wall_east")
    assert d.geom_xpos[east] == pytest.approx((3.1, 0.0, 0.75))
    assert sorted(m.geom_size[east]) == pytest.approx(sorted((0.075, 0.75, 3.175)))
    # its panel: front face 0.125 in front of the wall's inner face (x = 3.025), 0.2 deep
    panel = geom("panel_east")
    assert d.geom_xpos[panel] == pytest.approx((3.025 - 0.125 + 0.1, 0.0, (0.53 + 1.47) / 2))
    assert sorted(m.geom_size[panel]) == pytest.approx(sorted((0.55, 0.47, 0.1)))
    # the floating box of tactile_only: bottom at 0.129, 0.3 high
    box = geom("lm_box_e_floating")
    assert d.geom_xpos[box] == pytest.approx((1.665, -0.130, 0.129 + 0.15))


def _view(sim: Simulator, pose) -> np.ndarray:
    sim.reset(pose)
    return sim.render().astype(np.float64) / 255.0


def test_e1_aliases_east_and_south_but_not_north_and_west():
    """East and south walls are both white with a red panel and both get no direct sun, and
    the box in front of the east wall and the cylinder in front of the south wall are the
    same grey and height: views of them from mirror-image poses (the reflection across
    y = -x maps east onto south) differ only by the landmark's outline. North and west are
    both dark grey but their panels are blue and green, over the panel's whole area, and
    the sun lights them differently. Measure: mean absolute RGB difference of the frames;
    the aliased pair must differ by less than half as much as the distinct pair."""
    sim = Simulator(load_environment("e1"), RobotSpec())
    try:
        # from 1 m before the arena centre on the mirror line, looking at the wall
        east = _view(sim, (0.0, 0.0, 0.0))
        south = _view(sim, (0.0, 0.0, -math.pi / 2))
        north = _view(sim, (0.0, 0.0, math.pi / 2))
        west = _view(sim, (0.0, 0.0, math.pi))
    finally:
        sim.close()
    aliased = np.abs(east - south).mean()
    distinct = np.abs(north - west).mean()
    assert aliased < 0.5 * distinct, (aliased, distinct)
    # the red panel is in view: the east frame holds many strongly red pixels
    red = (east[..., 0] > 0.3) & (east[..., 1] < 0.1) & (east[..., 2] < 0.1)  # unlit red: 0.4 ambient
    assert red.mean() > 0.02


def test_validate_does_not_load_mujoco():
    """Validation is pure schema work: `vitaplace validate` never imports MuJoCo (nor Warp)."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from vitaplace.engine.cli.main import main\n"
        "try:\n    main(['validate', 'quickstart'])\nexcept SystemExit as exc:\n    assert not exc.code, exc.code\n"
        "print(sorted(m for m in ('mujoco', 'warp') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr


def test_schema_modules_do_not_import_mujoco():
    """The environment and robot schemas are pure data: only the model builder loads MuJoCo."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import vitaplace.engine.sim.environment, vitaplace.engine.sim.robot\n"
        "print('mujoco' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stdout + out.stderr


def test_model_xml_compiles_to_the_same_model():
    """`SimModel.xml` (the MjSpec written as MJCF, for debugging) compiles to the built model
    (rock meshes included, to the printed precision; actuator gains there are placeholders)."""
    sim = build_model(load_environment("e3"), RobotSpec())
    m, x = sim.model, mujoco.MjModel.from_xml_string(sim.xml)
    assert (x.nbody, x.ngeom, x.njnt, x.nu, x.nmesh) == (m.nbody, m.ngeom, m.njnt, m.nu, m.nmesh)
    for key in ("geom_size", "geom_pos", "geom_quat", "geom_contype", "geom_conaffinity", "body_mass", "jnt_range"):
        np.testing.assert_allclose(getattr(x, key), getattr(m, key), rtol=1e-5, atol=1e-6, err_msg=key)


# ---------------------------------------------------------------------- the touch worlds
TOUCH = {("alike", "boxes"): "touch-alike-boxes", ("alike", "shapes"): "touch-alike-shapes",
         ("distinct", "boxes"): "touch-distinct-boxes", ("distinct", "shapes"): "touch-distinct-shapes"}


def _geometry(env) -> list[dict]:
    return [lm.model_dump(mode="json", exclude={"rgba", "material"}) for lm in env.landmarks]


def _appearance(env) -> tuple:
    walls = env.arena.model_dump(mode="json")["walls"]
    colours = [lm.material or tuple(lm.rgba) for lm in env.landmarks]
    return walls, colours


def test_the_touch_worlds_cross_appearance_and_shape():
    """Two worlds of a shape column share landmarks (all but colour) and route; two of an
    appearance row share walls, panels and landmark colours. Look alike: four identical walls
    and panels, all landmarks one colour; look different: four panel colours, each landmark in
    its wall's. Feel alike: four identical boxes; feel different: four landmark shapes (box,
    a box turned 45 deg, rock, cylinder). Every landmark's nearest point is E1's 1.638 m from
    the centre (the rock's within 1 cm)."""
    worlds = {key: load_environment(name) for key, name in TOUCH.items()}
    for shape in ("boxes", "shapes"):
        a, d = worlds[("alike", shape)], worlds[("distinct", shape)]
        assert _geometry(a) == _geometry(d) and a.route == d.route
    for look in ("alike", "distinct"):
        assert _appearance(worlds[(look, "boxes")]) == _appearance(worlds[(look, "shapes")])
    walls, colours = _appearance(worlds[("alike", "boxes")])
    assert len({str(w) for w in walls.values()}) == 1 and len(set(colours)) == 1
    walls, colours = _appearance(worlds[("distinct", "boxes")])
    panels = {side: tuple(w["panel"]["rgba"]) for side, w in walls.items()}
    assert len(set(panels.values())) == 4 and len(set(colours)) == 4
    env = worlds[("distinct", "boxes")]
    for lm in env.landmarks:
        assert tuple(lm.rgba) == panels[lm.name]  # each landmark in its wall's colour (the names are the sides)
    boxes = [(lm.type, tuple(lm.size), lm.yaw) for lm in worlds[("alike", "boxes")].landmarks]
    assert len(set(boxes)) == 1 and boxes[0] == ("box", (1.0, 1.0, 0.3), 0.0)
    shapes = [(lm.type, getattr(lm, "yaw", 0.0)) for lm in worlds[("alike", "shapes")].landmarks]
    assert shapes == [("box", 0.0), ("box", 45.0), ("rock", 0.0), ("cylinder", 0.0)]
    for env in worlds.values():
        assert len(env.landmarks) >= 4 and all(lm.tactile for lm in env.landmarks)
        nearest = env.obstacles.landmark_distance_many(np.zeros((1, 2)))[0]
        assert nearest == pytest.approx(1.638, abs=0.01)
