"""Tests of the MuJoCo WhiskEye-like simulator, the environments and the trajectories."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the mujoco import

import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import vitaplace.engine.sim  # noqa: F401  (selects the GL backend before mujoco is imported)

# isort: split
import mujoco  # noqa: E402

from vitaplace.engine.data.dataset import Run  # noqa: E402
from vitaplace.engine.sim.clearance import Route  # noqa: E402
from vitaplace.engine.sim.environment import (  # noqa: E402
    EnvironmentSpec,
    EnvironmentSpecError,
    environment_files,
    load_environment,
)
from vitaplace.engine.sim.robot import N_WHISKERS, RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import Simulator, run_spec, simulate_run  # noqa: E402

ENVS = sorted(environment_files())
RIGHT = slice(0, 8)  # boards 0-1, the right side of the head
LEFT = slice(16, 24)  # boards 4-5, the left side (boards 2-3 are on top)
#: In the bare 6 m arena (walls' inner faces at +-3 m): 2.55 m east of the centre, heading
#: 60 deg, the east wall is ahead and to the right; the right-side whiskers' bases are
#: ~0.1 m from it (shafts 50-160 mm), the left-side ones ~0.3 m, the body 0.22 m.
WALL_RIGHT = (2.55, 0.0, math.radians(60))
WALL_LEFT = (-2.55, 0.0, math.radians(120))  # its mirror image: the west wall on the left


@pytest.fixture(scope="module")
def e1() -> EnvironmentSpec:
    return load_environment("e1")


#: An empty 6 m square with plain walls: the whisker physics tests need walls and nothing
#: else within reach, whatever the shipped worlds hold.
BARE = {"name": "bare", "arena": {"size": 6.0, "wall_thickness": 0.1}, "landmarks": [], "route": []}


@pytest.fixture(scope="module")
def bare_sim() -> Simulator:
    sim = Simulator(EnvironmentSpec.model_validate(BARE), RobotSpec())
    yield sim
    sim.close()


def _cycles(sim: Simulator, pose, n: int = 2) -> np.ndarray:
    """Reset at ``pose``, hold still for ``n`` whisk cycles, return the last cycle's (S, 24, 2) series."""
    sim.reset(pose)
    for _ in range(n):
        series, _, _ = sim.cycle()
    return series


# ---------------------------------------------------------------------- environments
def test_shipped_environments_are_the_papers():
    assert {"e1", "e2", "e3"} <= set(ENVS)


@pytest.mark.parametrize("name", ENVS)
def test_environment_compiles_and_simulates_2s_without_mujoco_warnings(name):
    env = load_environment(name)
    sim = Simulator(env, RobotSpec(), camera=False)
    try:
        sim.reset((*env.start[:2], math.radians(env.start[2])))
        for _ in range(4):  # 4 whisk cycles = 2 s at 2 Hz, base driving forward and turning
            sim.drive(0.15, 0.3)
            sim.cycle()
        d = sim.data
        assert d.time == pytest.approx(2.0)
        warnings = {mujoco.mjtWarning(i).name: int(d.warning[i].number) for i in range(len(d.warning))}
        assert not any(warnings.values()), warnings
        assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    finally:
        sim.close()


#: WhiskEye's footprint (whiskeye_robot.sdf): body radius 0.23 m; the head, 0.42-0.58 m
#: ahead and 0.16 m wide, is covered by a disc of radius 0.113 m centred 0.5 m ahead.
BODY_R, HEAD_AHEAD, HEAD_R = 0.23, 0.5, 0.113


@pytest.mark.parametrize("name", ENVS)
def test_route_keeps_body_and_head_clear_of_obstacles(name):
    """Every point of the route, with the heading the route is driven at (towards the
    pursuit point 0.3 m further along the loop, or away from its centroid), keeps the body and the head at least
    3 cm from everything (the pursuit controller's corner cutting and noise are a few cm)."""
    env = load_environment(name)
    route = Route(env.route)
    points = route.sample(0.02)
    if env.route_facing == "outward":
        rel = points - np.mean(env.route, axis=0)
        heading = np.arctan2(rel[:, 1], rel[:, 0])
    else:  # pure pursuit: towards the route point 0.3 m further on
        ahead = route.at(np.arange(0.0, route.length, 0.02) + 0.3) - points
        heading = np.arctan2(ahead[:, 1], ahead[:, 0])
    head = points + HEAD_AHEAD * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    assert (env.obstacles.distance_many(points) - BODY_R).min() >= 0.03, "the body would touch something"
    assert (env.obstacles.distance_many(head) - HEAD_R).min() >= 0.03, "the head would touch something"


def test_one_lap_of_the_e1_route_touches_every_landmark_without_collision(e1):
    """E1's route (driven sideways, facing the walls) brings the whiskers onto both boxes and
    the cylinder, and never the body or head (one lap: ~8.5 m at 0.3 m/s)."""
    run = simulate_run(e1, run_spec(kind="route", n_samples=60, speed=0.3), seed=4, progress=False)
    assert run.attrs["body_collision_instants"] == 0
    points = run._get("contact_points")
    for lm_name, lm in zip(e1.landmark_names(), e1.landmarks, strict=True):
        alone = {**lm.model_dump(), "material": None}
        single = EnvironmentSpec.model_validate({"name": "one", "arena": {"size": 50.0}, "landmarks": [alone]})
        assert (single.obstacles.distance_many(points[:, :2]) < 0.01).any(), f"{lm_name} was never touched"


def test_orbit_faces_outward_on_its_circle_and_goes_off_route_when_asked(e1):
    """The orbit stays within a few cm of its 1 m circle, faces away from the centre (the
    camera towards the walls) and goes round counter-clockwise; with off_route_fraction the
    final part runs off_route_offset closer to the centre."""
    spec = run_spec(kind="orbit", n_samples=40, speed=0.3)
    run = simulate_run(e1, spec, seed=2, progress=False)
    r = np.hypot(run.poses[:, 0], run.poses[:, 1])
    phi = np.arctan2(run.poses[:, 1], run.poses[:, 0])
    assert np.abs(r[4:] - 1.0).max() < 0.08
    facing = (run.poses[:, 2] - phi + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(facing).max() < math.radians(12)  # heading noise 3 deg std, plus lag
    assert (np.diff(np.unwrap(phi)) > 0).mean() > 0.9
    off = simulate_run(e1, spec.model_copy(update={"off_route_fraction": 0.5, "off_route_offset": 0.5}), seed=2,
                       progress=False)
    r_off = np.hypot(off.poses[:, 0], off.poses[:, 1])
    np.testing.assert_allclose(r_off[:20], r[:20], atol=1e-9)  # same seed: identical until the detour
    assert np.abs(r_off[-10:] - 0.5).max() < 0.08


def test_top_view_structure(e1):
    tv = load_environment("e2").top_view()
    assert tv["width"] == pytest.approx(6.05) and tv["depth"] == pytest.approx(6.05)
    kinds = {lm["type"] for lm in tv["landmarks"]}
    assert kinds == {"box", "cylinder", "rock"}
    for lm in tv["landmarks"]:
        assert len(lm["pos"]) == 2
        assert ("radius" in lm) == (lm["type"] == "cylinder")
        assert ("size" in lm) == (lm["type"] != "cylinder")
    rock = next(lm for lm in tv["landmarks"] if lm["type"] == "rock")
    assert len(rock["polygon"]) >= 5
    assert tv["route"] == [list(p) for p in load_environment("e2").route]


def test_extends_deep_merges_and_replaces_lists(tmp_path):
    (tmp_path / "parent.yaml").write_text(
        "arena: {size: 5.0, wall_height: 1.0}\n"
        "landmarks: [{type: box, pos: [1, 1], size: [0.5, 0.5, 0.3]}]\n"
        "route: [[0, 0], [1, 0]]\n"
    )
    (tmp_path / "child.yaml").write_text(
        "extends: parent.yaml\narena: {size: 4.0}\n"
        "landmarks: [{type: cylinder, pos: [0, 1], radius: 0.2, height: 0.3}]\n"
    )
    env = load_environment(tmp_path / "child.yaml")
    assert env.name == "child"
    assert env.arena.size == 4.0 and env.arena.wall_height == 1.0  # merged
    assert [lm.type for lm in env.landmarks] == ["cylinder"]  # replaced
    assert env.route == [(0, 0), (1, 0)]


def test_environment_errors_name_file_and_key_path(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("landmarks:\n  - {type: box, pos: [0, 0], size: [1, 1]}\n")
    with pytest.raises(EnvironmentSpecError, match=r"bad\.yaml: landmarks\.0\.size"):
        load_environment(bad)
    bad.write_text("arena: {size: 6, colour: red}\n")
    with pytest.raises(EnvironmentSpecError, match=r"bad\.yaml: arena\.colour: unknown key"):
        load_environment(bad)
    bad.write_text("landmarks:\n  - {type: box, pos: [2.9, 0], size: [1, 1, 0.3]}\n")
    with pytest.raises(EnvironmentSpecError, match=r"bad\.yaml: landmarks\.0\.pos: .*sticks out"):
        load_environment(bad)
    bad.write_text("extends: nowhere.yaml\n")
    with pytest.raises(EnvironmentSpecError, match=r"nowhere\.yaml"):
        load_environment(bad)
    with pytest.raises(EnvironmentSpecError,
                       match=r"missing\.yaml: no such environment file \(shipped environments: .*\be1\b"):
        load_environment(tmp_path / "missing.yaml")


def _png(path: Path, width: int = 4, height: int = 2) -> Path:
    """A ``width`` x ``height`` 8-bit RGB PNG written by hand from the PNG specification: the
    signature, an IHDR chunk, the rows (filter byte 0, then the pixels) deflated in one IDAT
    chunk, IEND; each chunk is length, type, data and the CRC-32 of type and data."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + bytes([200, 40, 40]) * width for _ in range(height))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
    return path


#: texture files MuJoCo cannot read, made in a test's folder, and the words that say why
#: (MuJoCo's own errors at compile time: "Error opening file", "unsupported content type: ''",
#: "PNG file is smaller than a PNG header", "empty PNG file", "error decoding PNG file")
BAD_TEXTURES = {
    "missing": (lambda d: d / "nowhere.png", "no such file"),
    "a folder": (lambda d: (d / "folder.png").mkdir() or d / "folder.png", "is a folder"),
    "not a PNG": (lambda d: (d / "words.png").write_text("hello") and d / "words.png",
                  "is not a PNG image (it does not start with PNG's signature)"),
    "empty": (lambda d: (d / "empty.png").write_bytes(b"") or d / "empty.png", "is empty"),
    "another extension": (lambda d: _png(d / "image.jpg"), "does not end in .png"),
    "cut short": (lambda d: (d / "cut.png").write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0\0\x04") and d / "cut.png",
                  "is a damaged PNG image (no header giving its width and height)"),
    "no IHDR first": (lambda d: (d / "idat.png").write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\x0dIDAT\0\0\0\x04\0\0\0\x02")
                      and d / "idat.png", "is a damaged PNG image (no header giving its width and height)"),
    "no width": (lambda d: _png(d / "flat.png", width=0), "is a damaged PNG image"),
}


@pytest.mark.parametrize("case", BAD_TEXTURES)
def test_a_texture_file_mujoco_cannot_read_is_refused_naming_its_key(tmp_path, case):
    make, words = BAD_TEXTURES[case]
    texture = make(tmp_path)
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"extends: e1\nmaterials: {{wall: {{texture: {{file: {texture.name}}}}}}}\n")
    with pytest.raises(EnvironmentSpecError) as caught:
        load_environment(bad)
    assert str(caught.value).startswith(
        f"{bad}: materials.wall.texture.file: '{tmp_path / texture.name}': {words}"), str(caught.value)
    assert str(caught.value).endswith("; expected a PNG image file (a relative path is relative to the folder of "
                                      "the file that names it)")


def test_a_png_texture_resolves_against_its_own_file_and_compiles(tmp_path, monkeypatch):
    """A file named relative to the YAML that names it (a parent's texture in the parent's
    folder), in either case of .png, loads from any working folder and compiles."""
    from vitaplace.engine.sim.model import build_model

    _png(tmp_path / "worlds" / "textures" / "Wall.PNG")
    (tmp_path / "worlds" / "parent.yaml").write_text(
        "extends: e1\nmaterials: {wall: {texture: {file: textures/Wall.PNG}}}\n")
    (tmp_path / "child.yaml").write_text("extends: worlds/parent.yaml\n")
    monkeypatch.chdir(tmp_path / "worlds" / "textures")
    env = load_environment(tmp_path / "child.yaml")
    assert env.materials["wall"].texture.file == str(tmp_path / "worlds" / "textures" / "Wall.PNG")
    model = build_model(env).model
    assert (2, 4) in {(int(h), int(w)) for h, w in zip(model.tex_height, model.tex_width, strict=True)}


# ---------------------------------------------------------------------- whiskers
def test_wall_contact_deflects_whiskers_far_above_the_noise_floor(bare_sim):
    free = _cycles(bare_sim, (0.0, 0.0, 0.0))  # nothing within reach at the arena centre
    noise = np.degrees(np.abs(free).max())
    assert noise < 0.5, f"free-whisking deflection {noise:.3f} deg"
    pressed = _cycles(bare_sim, WALL_RIGHT)
    right = np.degrees(np.abs(pressed[:, RIGHT]).max())
    left = np.degrees(np.abs(pressed[:, LEFT]).max())
    assert right > 5.0 and right > 20 * noise, f"pressed {right:.2f} deg vs noise {noise:.3f} deg"
    assert left < 0.5, "whiskers on the far side of the head must stay free"


def test_mirror_image_contacts_give_deflections_of_the_same_sign(bare_sim):
    """xy[..., 0] is signed along each whisker's own protraction direction, so a wall on the
    right and its mirror image on the left bend the two sides' whiskers with the same sign."""
    wall_right = _cycles(bare_sim, WALL_RIGHT)[:, RIGHT, 0].mean()
    wall_left = _cycles(bare_sim, WALL_LEFT)[:, LEFT, 0].mean()
    assert abs(wall_right) > math.radians(1) and abs(wall_left) > math.radians(1)
    assert np.sign(wall_right) == np.sign(wall_left)


def test_contacts_are_reported_on_the_touched_surface_with_outward_normals(bare_sim):
    bare_sim.reset(WALL_RIGHT)
    _, points, normals = bare_sim.cycle()
    pts, nrm = np.concatenate(points), np.concatenate(normals)
    assert len(pts) > 0
    assert np.allclose(pts[:, 0], 3.0, atol=0.01)  # the bare arena's east wall inner face is x = 3
    assert np.allclose(nrm, [-1.0, 0.0, 0.0], atol=1e-6)  # pointing into the arena


def test_samples_are_taken_at_maximum_protraction(bare_sim):
    sim = bare_sim
    sim.reset((0.0, 0.0, 0.0))
    m, d, cmd = sim.model, sim.data, sim.sim.whisk_command
    n = sim.robot.steps_per_cycle
    theta = np.empty((2 * n, N_WHISKERS))
    for k in range(2 * n):  # the same per-step servo command the Simulator applies
        d.ctrl[sim.sim.servo_act] = cmd[k % n]
        mujoco.mj_step(m, d)
        theta[k] = d.qpos[sim.sim.theta_qadr]
    last = theta[n:]  # second cycle; the sample is taken after its final step
    assert np.all(np.argmax(last, axis=0) >= n - 2), "theta must peak at the end of the cycle"
    assert np.allclose(last[-1], last.max(axis=0), atol=math.radians(0.05))
    # WhiskEye's joint limits: +-60 deg
    assert np.allclose(np.degrees(last[-1]), 60.0, atol=0.3)
    assert np.allclose(np.degrees(last.min(axis=0)), -60.0, atol=0.3)
    # and the recorded samples of a run
    run = simulate_run(load_environment("e1"), run_spec(kind="route", n_samples=2), seed=0, progress=False)
    assert np.allclose(np.degrees(run.theta), 60.0, atol=1.0)


def test_timestep_halving_converges():
    """Deflection series at dt = 2 ms and 1 ms vs a 0.5 ms reference, robot pressed to walls.

    Tolerance: contacts with friction are stick-slip events, so a single series sample can
    differ by about a degree where a whisker slips one step earlier; we therefore bound the
    RMS error (over all whiskers and samples) to 5 % of the RMS deflection at the default
    2 ms step, and require the error to shrink when the step is halved (first-order method).
    """
    env = load_environment("e1")
    poses = [WALL_RIGHT, (2.3, 0.0, 0.3)]
    series = {}
    for dt in (0.002, 0.001, 0.0005):
        sim = Simulator(env, RobotSpec(timestep=dt), camera=False)
        series[dt] = np.array([_cycles(sim, p) for p in poses])
        sim.close()
    ref = series[0.0005]
    signal = np.sqrt(np.mean(ref**2))
    err2 = np.sqrt(np.mean((series[0.002] - ref) ** 2))
    err1 = np.sqrt(np.mean((series[0.001] - ref) ** 2))
    assert signal > math.radians(0.5)
    assert err2 < 0.05 * signal, f"rms error {np.degrees(err2):.3f} deg vs signal {np.degrees(signal):.3f} deg"
    assert err1 < err2


# ---------------------------------------------------------------------- camera
def test_camera_image_changes_with_pose_and_is_repeatable(bare_sim):
    sim = bare_sim
    sim.reset((0.0, -0.95, 0.0))
    a = sim.render().copy()
    sim.reset((0.0, -0.95, math.pi / 2))
    b = sim.render().copy()
    sim.reset((0.0, -0.95, 0.0))
    a2 = sim.render().copy()
    assert a.shape == (120, 160, 3) and a.dtype == np.uint8
    assert np.array_equal(a, a2), "identical state must render identical pixels"
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 5.0
    assert a.std() > 10, "the frame should show structure, not a flat colour"


def test_camera_projects_a_known_point_where_the_whiskeye_pinhole_model_says():
    """cam0 of whiskeye_robot.sdf: 0.517 m ahead of the base centre, 0.057 m to the left,
    0.315 m above the floor, level, 90 deg horizontal field of view. A small red cube centred
    at a known world point must appear where a pinhole camera with that pose puts it:
    focal length f = (W / 2) / tan(45 deg) pixels, u = W/2 - f Y/X, v = H/2 - f Z/X for
    the point's offset (X ahead, Y left, Z up) from the camera."""
    cube = np.array([2.0, 0.4, 0.4])  # world position of the cube's centre [m]
    env = EnvironmentSpec.model_validate(
        {**BARE, "materials": {"wall": {"rgba": [0.8, 0.8, 0.8, 1]}, "floor": {"rgba": [0.7, 0.7, 0.7, 1]},
                               "red": {"rgba": [1, 0, 0, 1]}},
         "landmarks": [{"type": "box", "pos": cube[:2].tolist(), "z": cube[2] - 0.02, "size": [0.04, 0.04, 0.04],
                        "material": "red", "tactile": False}]}
    )
    sim = Simulator(env, RobotSpec(camera_width=320, camera_height=240))
    try:
        sim.reset((0.0, 0.0, 0.0))
        img = sim.render()
    finally:
        sim.close()
    W, H = 320, 240
    X, Y, Z = cube - np.array([0.5166, 0.0573, 0.315])
    f = (W / 2) / math.tan(math.radians(45))
    u, v = W / 2 - f * Y / X, H / 2 - f * Z / X
    red = (img[..., 0] > 120) & (img[..., 1] < 60) & (img[..., 2] < 60)
    assert red.sum() >= 9, "the cube should cover a few pixels"
    rows, cols = np.nonzero(red)
    # pixel centres are at index + 0.5; a 4 cm cube at 1.5 m spans ~4 px, its centroid
    # within 1 px of the projected centre
    assert abs(cols.mean() + 0.5 - u) < 1.0 and abs(rows.mean() + 0.5 - v) < 1.0, (
        cols.mean() + 0.5, rows.mean() + 0.5, u, v)


def test_missing_gl_gives_one_clear_error():
    """Hide libEGL/libOSMesa from the process: the camera must say what to install and set."""
    code = textwrap.dedent(
        """
        import ctypes, os, sys
        real = ctypes.CDLL
        class Hidden(real):
            def __init__(self, name, *a, **k):
                if name and any(s in str(name) for s in ("EGL", "OSMesa")):
                    raise OSError("hidden by the test")
                super().__init__(name, *a, **k)
        ctypes.CDLL = Hidden
        mode = sys.argv[1]
        if mode == "user":
            os.environ["MUJOCO_GL"] = "osmesa"
        try:
            from vitaplace.engine.sim.environment import EnvironmentSpec
            from vitaplace.engine.sim.model import build_model
            from vitaplace.engine.sim.render import Camera
            sim = build_model(EnvironmentSpec(name="t"))
            Camera(sim.model, 32, 24)
        except Exception as exc:
            print(type(exc).__name__ + ": " + str(exc))
            sys.exit(3)
        print("no error")
        """
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    for mode in ("auto", "user"):
        out = subprocess.run(
            [sys.executable, "-c", code, mode], capture_output=True, text=True, env=env, timeout=120
        )
        assert out.returncode == 3, out.stdout + out.stderr
        msg = out.stdout
        assert "GLUnavailableError" in msg
        assert "libegl1" in msg and "libosmesa6" in msg and "MUJOCO_GL=egl" in msg


def test_the_gl_help_quotes_mujoco_gl(monkeypatch):
    """A line break in the variable stays inside the one error line, escaped."""
    from vitaplace.engine.sim.render import gl_help

    monkeypatch.setenv("MUJOCO_GL", "egl\nx")
    assert "(MUJOCO_GL='egl\\nx'; " in gl_help()
    monkeypatch.delenv("MUJOCO_GL")
    assert "(MUJOCO_GL=(unset); " in gl_help()


# ---------------------------------------------------------------------- runs
def test_same_scenario_and_seed_give_identical_runs(e1):
    spec = run_spec(kind="foraging", n_samples=6)
    a = simulate_run(e1, spec, seed=3, progress=False)
    b = simulate_run(e1, spec, seed=3, progress=False)
    c = simulate_run(e1, spec, seed=4, progress=False)
    assert isinstance(a, Run) and len(a) == 6
    for key in ("poses", "times", "theta", "xy", "deflection", "contact_offsets"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert np.array_equal(a._get("contact_points"), b._get("contact_points"))
    assert np.array_equal(a.images, b.images)
    assert a.attrs == b.attrs
    assert not np.array_equal(a.poses, c.poses)
    assert a.deflection.shape == (6, 25, 24, 2)
    assert a.images.shape == (6, 120, 160, 3)
    assert np.allclose(np.diff(a.times), 0.5)
    assert a.attrs["seed"] == 3 and a.attrs["environment"] == "e1"
    # WhiskEye's camera: 90 deg horizontal, so 2 atan(tan 45 deg x 120/160) = 73.74 deg vertical, level
    camera = a.attrs["camera"]
    assert (camera["width"], camera["height"], camera["hfov_deg"], camera["pitch_deg"]) == (160, 120, 90.0, 0.0)
    assert camera["fovy_deg"] == pytest.approx(73.7398, abs=1e-4)


def test_two_route_runs_differ_but_follow_the_route(e1):
    spec = run_spec(kind="route", n_samples=60)
    a = simulate_run(e1, spec, seed=1, progress=False, name="query")
    b = simulate_run(e1, spec, seed=2, progress=False, name="reference")
    route = Route(e1.route)
    for run in (a, b):
        dist = route.distance(run.poses[:, :2])
        assert dist.max() < 0.25, f"{run.name}: {dist.max():.3f} m off the route"
        assert run.attrs["body_collision_instants"] == 0
    gap = np.linalg.norm(a.poses[:, :2] - b.poses[:, :2], axis=1)
    assert gap.max() > 0.01, "two seeds must not give the same trajectory"
    assert np.diff(a.poses[:, :2], axis=0).any()
    # ~30 s at 0.15 m/s: well past the first corner of the 7.6 m loop
    travelled = np.linalg.norm(np.diff(a.poses[:, :2], axis=0), axis=1).sum()
    assert 2.5 < travelled < 6.0


def test_headway_is_a_move_of_0_1_m_or_a_turn_of_0_3_rad_within_3_s():
    from vitaplace.engine.sim.controllers import Headway

    headway = Headway()
    headway.restart(np.array([0.0, 0.0, 0.0]), 0.0)
    assert not headway.stalled(np.array([0.09, 0.0, 0.29]), 2.9)  # neither yet, but not 3 s
    assert headway.stalled(np.array([0.09, 0.0, 0.29]), 3.0)
    assert not headway.stalled(np.array([0.0, 0.11, 0.0]), 3.5) and headway.since == 3.5  # moved: a new anchor
    assert not headway.stalled(np.array([0.0, 0.11, 0.31]), 6.6) and headway.since == 6.6  # turned
    assert not headway.stalled(np.array([0.0, 0.11, 0.31 - 2 * math.pi]), 9.5)  # a full turn is no turn
    assert headway.stalled(np.array([0.0, 0.11, 0.31 - 2 * math.pi]), 9.6)


def test_a_foraging_robot_whose_turn_is_refused_turns_the_other_way_then_gives_the_state_up(e1):
    """Where one training run of the first teleoperated study stood for its last 348 of 1000
    samples (seed 2968811710, penetration): in E1's south-east, its body 3.5 cm from the
    wall, leaving an explored landmark towards heading 3.168 rad, the short way round (right)
    refused by the guard, backing off too. The robot turns the other way round at once
    (before: it stood still), and with no headway for 3 s (the pose is held here) it gives
    the leave state up for wandering."""
    from vitaplace.engine.sim.controllers import ForagingController, Observation

    controller = ForagingController(run_spec(kind="foraging", n_samples=2), e1.obstacles, np.random.default_rng(0))
    pose = np.array([0.687, -2.474, -0.315])
    nothing = dict(contacts=np.zeros((0, 3)), deflection=np.zeros(N_WHISKERS))
    controller(Observation(time=0.0, pose=pose, **nothing))  # starts wandering; now, leaving:
    controller.mode = "leave"
    leave = controller.states["leave"]
    leave.heading, leave.until = 3.168, 0.0
    controller.headway.restart(pose, 0.0)
    v, w = controller(Observation(time=0.1, pose=pose, **nothing))
    assert v == 0.0 and w > 0.0  # left: the long way round
    for k in range(2, 30):
        controller(Observation(time=0.1 * k, pose=pose, **nothing))
    assert controller.mode == "leave"
    controller(Observation(time=3.0, pose=pose, **nothing))
    assert controller.mode == "wander"


def test_foraging_touches_things_and_never_drives_into_them(e1):
    run = simulate_run(e1, run_spec(kind="foraging", n_samples=120), seed=5, progress=False)
    assert run.attrs["body_collision_instants"] == 0
    assert np.diff(run.contact_offsets).sum() > 0
    # the foraging state machine goes through every mode in 60 s
    modes = run.attrs["controller_modes"]
    assert set(modes) == {"wander", "orient", "explore", "leave", "avoid"} and min(modes.values()) > 0, modes


def test_run_spec_validation():
    with pytest.raises(ValueError):
        run_spec(kind="foraging", n_samples=0)
    with pytest.raises(ValueError):
        run_spec(kind="dance", n_samples=3)
    with pytest.raises(ValueError):
        run_spec(kind="route", n_samples=3, colour="red")
    with pytest.raises(ValueError, match="whole number of timesteps"):
        RobotSpec(whisk_hz=3.0, timestep=0.002)
    with pytest.raises(ValueError, match="no route"):
        simulate_run(EnvironmentSpec(name="empty"), run_spec(kind="route", n_samples=1), seed=0, progress=False)


def test_shipped_environment_files_are_packaged():
    root = Path(vitaplace.engine.sim.environment.__file__).resolve().parents[2]
    assert (root / "scenarios" / "environments" / "base.yaml").is_file()


def test_simulated_run_round_trips_through_hdf5(e1, tmp_path):
    from vitaplace.engine.data.dataset import open_run, write_run

    run = simulate_run(e1, run_spec(kind="route", n_samples=3), seed=9, progress=False, name="r")
    back = open_run(write_run(tmp_path / "r.h5", run))
    for key in ("images", "theta", "xy", "deflection", "poses", "times", "contact_offsets"):
        assert np.array_equal(getattr(back, key), getattr(run, key)), key
    assert back.attrs["seed"] == 9 and back.attrs["run_key"] == run.attrs["run_key"]
    assert back.attrs["robot"] == run.attrs["robot"]
    assert back.attrs["environment"] == "e1"


@pytest.mark.parametrize("tactile", [True, False])
def test_visual_only_landmarks_are_not_felt(tactile):
    env = EnvironmentSpec.model_validate(
        {"name": "t", "landmarks": [{"type": "box", "pos": [0.45, 0.0], "size": [0.4, 1.0, 0.3], "tactile": tactile}]}
    )
    sim = Simulator(env, RobotSpec(), camera=False)
    sim.reset((0.0, 0.0, 0.0))  # the box's near face is 0.25 m ahead: within reach of the whiskers only
    sim.cycle()
    series, points, _ = sim.cycle()
    sim.close()
    n_contacts = sum(len(p) for p in points)
    if tactile:
        assert n_contacts > 0 and np.degrees(np.abs(series).max()) > 2.0
    else:
        assert n_contacts == 0 and np.degrees(np.abs(series).max()) < 0.5


# ---------------------------------------------------------------------- penetration touch model
def test_penetration_deflection_hand_case():
    from vitaplace.engine.sim.model import penetration_deflection

    # 1 cm deep, 10 cm along the shaft, normal along the whisker's -y: 10 * 0.01 * (-1, 0) / 0.2
    got = penetration_deflection(np.array([0.01, 0.02, -0.005]),
                                 np.array([[-1.0, 0.0], [0.6, 0.8], [1.0, 0.0]]),
                                 np.array([0.1, 0.0, 0.05]))
    np.testing.assert_allclose(got, [[-0.5, 0.0], [1.2, 1.6], [0.0, 0.0]])  # 10*0.02*(0.6,0.8)/0.1; not touching


@pytest.fixture(scope="module")
def bare_sims():
    env = EnvironmentSpec.model_validate(BARE)
    sims = {model: Simulator(env, RobotSpec(tactile_model=model), camera=False)
            for model in ("physical", "penetration")}
    yield sims
    for sim in sims.values():
        sim.close()


def test_penetration_whiskers_pass_through_and_report_the_plugin_formula(bare_sims):
    sim = bare_sims["penetration"]
    pose = WALL_RIGHT
    free = []
    sim.reset((0.0, 0.0, math.pi / 2))
    for _ in range(2):
        sim.cycle(on_series=lambda i, p: free.append(sim.sim.theta(sim.data)))
    m, s = sim.model, sim.sim

    def plugin_formula(d) -> tuple[np.ndarray, int]:
        """The plugin's signal recomputed here from MuJoCo's raw contacts in ``d``, and their count."""
        expected, touching = np.zeros((N_WHISKERS, 2)), 0
        for c in d.contact[: d.ncon]:
            g1, g2 = int(c.geom[0]), int(c.geom[1])
            w = s.whisker_of_geom[g1] if s.whisker_of_geom[g1] >= 0 else s.whisker_of_geom[g2]
            if w < 0:
                continue
            touching += 1
            # MuJoCo's frame normal points from geom1 to geom2; we want object -> whisker
            n = np.array(c.frame[:3]) * (1.0 if s.whisker_of_geom[g2] >= 0 else -1.0)
            body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"w{w:02d}")
            R = d.xmat[body].reshape(3, 3)
            along = float((c.pos - d.xpos[body]) @ R[:, 0])
            expected[w] += 10 * max(-c.dist, 0.0) * np.array([n @ R[:, 1], n @ R[:, 2]]) / (along + 0.1)
        return expected, touching

    pressed, compared = [], []

    def record(i, p) -> None:
        pressed.append(s.theta(sim.data))
        expected, touching = plugin_formula(sim.data)
        if touching:
            compared.append((s.xy(sim.data), expected))

    sim.reset(pose)
    for _ in range(2):
        series, _, _ = sim.cycle(on_series=record)
    # the whiskers sweep through the wall as through air
    np.testing.assert_allclose(np.array(pressed), np.array(free), atol=1e-3)
    # touching whiskers on the right only, at some instant of the cycle
    touched = np.abs(series).max(axis=(0, 2))
    assert touched[RIGHT].max() > 0.05 and touched[LEFT].max() == 0.0
    # at every instant with whisker contacts, the signal is the plugin's formula
    assert len(compared) >= 5 and max(np.abs(expected).max() for _, expected in compared) > 0.05
    for actual, expected in compared:
        np.testing.assert_allclose(actual, expected, atol=1e-12)


# ---------------------------------------------------------------------- the sensor contract
def test_stored_xy_is_the_deflection_at_maximum_protraction_and_yaw_is_wrapped(e1):
    run = simulate_run(e1, run_spec(kind="route", n_samples=4), seed=3, progress=False)
    # the series' last instant is the sample instant (maximum protraction)
    np.testing.assert_array_equal(run.xy, run.deflection[:, -1])
    assert np.all(run.poses[:, 2] >= -math.pi) and np.all(run.poses[:, 2] < math.pi)


def test_route_noise_processes_have_the_documented_standard_deviations(e1):
    """The route follower's lateral, heading and speed noise are stationary OU processes with
    the RunSpec's standard deviations: sampled every 0.1 s for 20 000 s, their empirical std
    must be within 5 % (the estimate's own error is ~2 % for 2000 correlation times)."""
    from vitaplace.engine.sim.controllers import make_controller

    spec = run_spec(kind="route", n_samples=2, lateral_noise=0.05, heading_noise_deg=4.0, speed_noise=0.2)
    ctrl, _ = make_controller(e1, spec, np.random.default_rng(0))
    for process, sigma in ((ctrl._lateral, 0.05), (ctrl._heading, math.radians(4.0)), (ctrl._speed, 0.2)):
        samples = np.array([process.step(0.1) for _ in range(200_000)])
        assert np.std(samples) == pytest.approx(sigma, rel=0.05)


def test_obstacle_map_of_a_rectangular_arena():
    env = EnvironmentSpec.model_validate({"name": "rect", "arena": {"width": 8.0, "depth": 4.0}})
    np.testing.assert_allclose(env.obstacles.distance_many(np.array([[0.0, 1.9], [3.9, 0.0], [0.0, 0.0]])),
                               [0.1, 0.1, 2.0])


# ---------------------------------------------------------------------- implausible runs are errors
def test_unstable_physics_fails_the_run_naming_it(e1):
    from vitaplace.engine.sim.simulate import SimulationError

    # validation refuses this stiffness (test_spring_stiffness_stable_range…); built without it,
    # the run itself must still fail, for instabilities validation cannot foresee
    robot = RobotSpec.model_construct(**{**RobotSpec().model_dump(), "spring_stiffness": 1e30})
    with pytest.raises(SimulationError, match=r"run 'bad': the simulation was unstable .*BADQACC"):
        simulate_run(e1, run_spec(kind="route", n_samples=3), seed=0, robot=robot, progress=False, name="bad")


def test_mujocos_warnings_of_an_unstable_run_stay_in_the_debug_log(e1, caplog):
    """MuJoCo warns once per physics step of an unstable run (11504 lines on stderr before the
    error, once); they go to the debug log (-v) and the run's one error names their counters."""
    import logging

    from vitaplace.engine.sim.simulate import SimulationError

    robot = RobotSpec.model_construct(**{**RobotSpec().model_dump(), "spring_stiffness": 1e30})
    with caplog.at_level(logging.DEBUG, logger="vitaplace"), pytest.raises(SimulationError):
        simulate_run(e1, run_spec(kind="route", n_samples=3), seed=0, robot=robot, progress=False, name="bad")
    said = [r for r in caplog.records if r.getMessage().startswith("MuJoCo: ")]
    assert said and {r.levelno for r in said} == {logging.DEBUG}


def test_check_plausible_refuses_still_robots_frozen_cameras_and_escapes(e1):
    from vitaplace.engine.sim.simulate import SimulationError, check_plausible

    rng = np.random.default_rng(0)
    images = rng.integers(0, 255, (4, 6, 8, 3), dtype=np.uint8)
    moving = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
    check_plausible("ok", {}, moving, images, e1)  # nothing wrong
    with pytest.raises(SimulationError, match="never moved"):
        check_plausible("r", {}, np.zeros((4, 3)), images, e1)
    with pytest.raises(SimulationError, match="all 4 camera frames are identical"):
        check_plausible("r", {}, moving, np.repeat(images[:1], 4, axis=0), e1)
    outside = moving.copy()
    outside[2, 1] = 3.5  # the faithful E1's walls are at +-3.025
    with pytest.raises(SimulationError, match="sample 2 is outside the arena"):
        check_plausible("r", {}, outside, images, e1)
    with pytest.raises(SimulationError, match="not finite"):
        check_plausible("r", {}, np.full((4, 3), np.nan), images, e1)


def test_run_and_robot_numbers_must_be_finite():
    with pytest.raises(ValueError, match="max_accel"):
        run_spec(kind="route", n_samples=3, max_accel=float("inf"))
    with pytest.raises(ValueError, match="spring_stiffness"):
        RobotSpec(spring_stiffness=float("nan"))


def test_the_follicle_must_relax_within_a_whisk_cycle():
    """A shaft bent by touch relaxes with time constant c / k (damping over stiffness); one
    longer than the whisk cycle (0.5 s at 2 Hz) would let no deflection build within the
    sample it belongs to (1e308 silenced touch): at k = 0.5 N m/rad, c at most 0.25."""
    RobotSpec(spring_damping=0.25)
    with pytest.raises(ValueError, match=r"relaxation time .* = 0.52 s, longer than a whisk cycle \(0.5 s\)"
                                         r".*at most 0.25 \[type"):
        RobotSpec(spring_damping=0.26)
    with pytest.raises(ValueError, match=r"at most 0.5 \[type"):
        RobotSpec(spring_damping=1e308, whisk_hz=1.0)
    RobotSpec(spring_damping=1e308, tactile_model="penetration")  # its whiskers have no follicle to relax


def test_spring_stiffness_stable_range_is_the_explicit_stability_limit():
    """implicitfast integrates stiffness explicitly: a hinge spring is stable while its natural
    frequency sqrt(k / I) < 2 / dt. For the shortest shaft (50 mm, r 1 mm, 1200 kg/m^3) plus
    the 2e-5 kg m^2 armature at dt = 2 ms that is k < I (2 / dt)^2 = 20.16 N m/rad. Below it
    (0.9x) the whiskers pressed to a wall simulate without warning; above it (1.5x, built
    without validation) MuJoCo reports the simulation unstable; validation refuses it."""
    mass = 1200 * math.pi * 0.001**2 * 0.05
    limit = (2e-5 + mass * 0.05**2 / 3) * (2 / 0.002) ** 2
    assert RobotSpec().max_stable_stiffness(2e-5) == pytest.approx(limit, rel=1e-12)
    with pytest.raises(ValueError, match="beyond the stable range"):
        RobotSpec(spring_stiffness=1.01 * limit)
    env = EnvironmentSpec.model_validate(BARE)
    for factor, stable in ((0.9, True), (1.5, False)):
        robot = RobotSpec.model_construct(**{**RobotSpec().model_dump(), "spring_stiffness": factor * limit})
        sim = Simulator(env, robot, camera=False)
        try:
            _cycles(sim, WALL_RIGHT)
            assert (not sim.sim.warnings(sim.data)) == stable, factor
        finally:
            sim.close()


def test_compiled_robot_has_whiskeyes_body_and_whisker_poses(bare_sim):
    """The compiled model puts the WhiskEye parts where the original model has them
    (whiskeye_robot.sdf, whisker_pose.h; head frame x down, y left, z forward, lifted 0.393 m):
    chassis r 0.23 m, h 0.295 m; board 1 whisker 1 (w00) based at (0.5796, -0.0666,
    0.393 - 0.2046) with its shaft along (0.7050, -0.6823, -0.1936) at theta = 0; board 6
    whisker 4 (w23) at (0.5412, 0.1029, 0.393 - 0.2109) along (0.7045, 0.6820, -0.1964)."""
    m, d = bare_sim.model, mujoco.MjData(bare_sim.model)
    mujoco.mj_forward(m, d)  # base at the origin, every hinge at 0
    chassis = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "chassis")
    np.testing.assert_allclose(m.geom_size[chassis][:2], [0.23, 0.295 / 2])
    for name, base, shaft in (("w00", (0.5796, -0.0666, 0.393 - 0.2046), (0.7050, -0.6823, -0.1936)),
                              ("w23", (0.5412, 0.1029, 0.393 - 0.2109), (0.7045, 0.6820, -0.1964))):
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        np.testing.assert_allclose(d.xpos[body], base, atol=2e-4)
        np.testing.assert_allclose(d.xmat[body].reshape(3, 3)[:, 0], shaft, atol=5e-3)


@pytest.mark.parametrize("name", ["e1", "e2", "e3", "e1-coloured"])
def test_shipped_routes_are_what_the_route_generator_makes(name):
    """Each shipped loop is `routegen`'s output for its world and facing (the YAML comments
    say so), so a change to the generator or the robot's footprint shows up here."""
    from vitaplace.engine.sim.routegen import inner_loop

    env = load_environment(name)
    np.testing.assert_allclose(inner_loop(env, env.route_facing), np.array(env.route), atol=1e-9)


def test_the_simulator_package_exports_its_modules_names():
    import importlib

    from vitaplace.engine import sim

    for name in sim.__all__:
        if name != "SIMULATOR_VERSION":
            defining = [m for m in ("environment", "robot", "simulate", "render")
                        if name in vars(importlib.import_module(f"vitaplace.engine.sim.{m}"))]
            assert defining
            assert getattr(sim, name) is getattr(importlib.import_module(f"vitaplace.engine.sim.{defining[0]}"), name)
    assert sim.simulate_run is simulate_run


def test_without_mujoco_gl_the_first_loadable_library_is_chosen():
    """A fresh process without MUJOCO_GL gets EGL where libEGL loads, else OSMesa where that loads, else none."""
    import ctypes

    def loads(lib: str) -> bool:
        try:
            ctypes.CDLL(lib)
            return True
        except OSError:
            return False

    expected = "egl" if loads("libEGL.so.1") else "osmesa" if loads("libOSMesa.so.8") else "None"
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    code = "import os, vitaplace.engine.sim; print(os.environ.get('MUJOCO_GL'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == expected


def test_the_eye_camera_sees_the_robot_only_when_asked(bare_sim):
    from vitaplace.engine.sim.render import Camera

    data = bare_sim.sim.new_data((0.0, 0.0, 0.0))
    mujoco.mj_forward(bare_sim.model, data)
    images = []
    for show_robot in (False, True, False):
        with Camera(bare_sim.model, 64, 48, show_robot=show_robot) as cam:
            images.append(cam.render(data).copy())
    assert np.array_equal(images[0], images[2]) and not np.array_equal(images[0], images[1])


def test_top_view_plot_closes_the_route(e1):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vitaplace.engine.sim.plot import plot_environment

    tv = e1.top_view()
    ax = plot_environment(tv)
    (route,) = [line for line in ax.get_lines() if line.get_label() == "route"]
    xy = np.column_stack(route.get_data())
    assert len(xy) == len(tv["route"]) + 1 and np.array_equal(xy[0], xy[-1])  # back to the first waypoint
    plt.close(ax.figure)
