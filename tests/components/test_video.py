"""Looking at the robot: `vitaplace video RUN.h5` animates a run; `vitaplace view ENV` says in one
line when there is no display, puts the robot where the environment starts, opens framed on it
with the arena on screen, and quits with exit 0 on Ctrl-C or when its window closes (under
Xvfb when it is installed)."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import threading
import time

import numpy as np
import pytest
from PIL import Image

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.data.dataset import Run, write_run  # noqa: E402
from vitaplace.engine.sim.video import MAX_FRAMES, frame_indices  # noqa: E402

#: matplotlib's tab:red, which marks touching whiskers and contacts
RED = np.array([214, 39, 40])


def _run(tmp_path, n: int = 5):
    """A small recorded run; at sample 2 whisker 3 touches and three contacts are recorded."""
    rng = np.random.default_rng(0)
    xy = np.zeros((n, 24, 2))
    xy[2, 3] = (0.05, 0.0)
    offsets = np.zeros(n + 1, dtype=np.int64)
    offsets[3:] = 3  # sample 2 owns contacts 0..2
    t = np.linspace(0, 1, n)
    return write_run(tmp_path / "run.h5", Run.from_arrays(
        images=rng.integers(0, 255, (n, 12, 16, 3), dtype=np.uint8), theta=np.zeros((n, 24)), xy=xy,
        poses=np.c_[t, t, np.zeros(n)], contact_points=np.array([[0.5, 0.4, 0.1], [0.55, 0.45, 0.1], [0.6, 0.4, 0.1]]),
        contact_normals=np.tile([1.0, 0.0, 0.0], (3, 1)), contact_offsets=offsets, name="tiny",
    ))


def _red_pixels(frame: Image.Image, third: int) -> int:
    rgb = np.asarray(frame.convert("RGB")).astype(int)
    width = rgb.shape[1] // 3
    part = rgb[:, third * width:(third + 1) * width]
    return int((np.abs(part - RED).sum(axis=2) < 60).sum())


def test_video_has_a_frame_per_sample_and_shows_touch_and_contacts(tmp_path, capsys):
    path = _run(tmp_path)
    assert main(["-q", "video", str(path)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote 5 frames to {tmp_path / 'run.gif'}"
    gif = Image.open(tmp_path / "run.gif")
    assert gif.n_frames == 5
    frames = []
    for k in range(5):
        gif.seek(k)
        frames.append(gif.copy())
    # sample 2: the touching whisker's bar (right panel) and the contacts (top view) turn red
    assert _red_pixels(frames[2], 2) > _red_pixels(frames[0], 2) + 50
    assert _red_pixels(frames[2], 1) > _red_pixels(frames[0], 1) + 10
    assert _red_pixels(frames[3], 1) == pytest.approx(_red_pixels(frames[0], 1), abs=10)  # contacts of one cycle only


def test_video_step_and_an_mp4_without_any_ffmpeg(tmp_path, capsys, monkeypatch):
    path = _run(tmp_path)
    assert main(["-q", "video", str(path), "--step", "2", "--out", str(tmp_path / "v" / "every-2nd.gif")]) == 0
    assert Image.open(tmp_path / "v" / "every-2nd.gif").n_frames == 3  # samples 0, 2, 4
    from matplotlib import animation

    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # not installed: importing it fails
    capsys.readouterr()
    assert main(["video", str(path), "--out", str(tmp_path / "v.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "ffmpeg" in err[0] and "vitaplace[video]" in err[0], err
    assert not (tmp_path / "v.mp4").exists()


def test_an_mp4_without_ffmpeg_on_the_path_is_written_with_the_video_extras_ffmpeg(tmp_path, capsys, monkeypatch):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    import matplotlib

    path = _run(tmp_path)
    monkeypatch.setitem(matplotlib.rcParams, "animation.ffmpeg_path", "ffmpeg")  # matplotlib's default, restored
    monkeypatch.setenv("PATH", "")
    assert main(["-q", "video", str(path), "--step", "2", "--out", str(tmp_path / "v.mp4")]) == 0
    assert (tmp_path / "v.mp4").read_bytes()[4:8] == b"ftyp"  # an MP4 (ISO base media) file
    frames, _ = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "v.mp4"))
    assert frames == 3  # samples 0, 2, 4


def _empty_run(tmp_path):
    """A recorded run of no samples."""
    return write_run(tmp_path / "empty.h5", Run.from_arrays(
        images=np.zeros((0, 12, 16, 3), dtype=np.uint8), theta=np.zeros((0, 24)), xy=np.zeros((0, 24, 2)),
        poses=np.zeros((0, 3)), name="empty"))


# what `vitaplace video` refuses in one line before drawing anything: (arguments after RUN, message)
REFUSED = {
    "fps nan": (["--fps", "nan"], "--fps nan: expected frames per second in [0.1, 50]"),
    "fps inf": (["--fps", "inf"], "--fps inf: expected frames per second in [0.1, 50]"),
    "fps 1e-9": (["--fps", "1e-9"], "--fps 1e-09: expected frames per second in [0.1, 50]"),
    "fps 0": (["--fps", "0"], "--fps 0.0: expected frames per second in [0.1, 50]"),
    "fps above 50": (["--fps", "50.5"], "--fps 50.5: expected frames per second in [0.1, 50]"),
    "step 0": (["--step", "0"], "--step 0: expected a whole number >= 1"),
    "out under a file": (["--out", "{tmp}/file/v.gif"], "--out {tmp}/file: exists and is not a directory"),
    "out a folder": (["--out", "{tmp}/folder"], "--out {tmp}/folder: is a folder"),
    "out without an extension": (["--out", "{tmp}/video"], "--out {tmp}/video: has no extension; expected a video "
                                 "file ending in .gif or .mp4 (e.g. {tmp}/video.gif)"),
    "out another format": (["--out", "{tmp}/v.avi"], "--out {tmp}/v.avi: ends in '.avi'; expected a video file "
                           "ending in .gif or .mp4"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_video_refuses_bad_settings_in_one_line_before_drawing(tmp_path, capsys, case):
    path = _run(tmp_path)
    (tmp_path / "file").write_text("")
    (tmp_path / "folder").mkdir()
    args, message = REFUSED[case]
    before = sorted(tmp_path.rglob("*"))
    assert main(["video", str(path), *(a.format(tmp=tmp_path) for a in args)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and message.format(tmp=tmp_path) in lines[0], lines
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, not even a temporary folder


def test_a_run_without_samples_is_one_line(tmp_path, capsys):
    assert main(["video", str(_empty_run(tmp_path))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "empty: the run has no samples" in err[0] and not (tmp_path / "empty.gif").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_out_is_one_line(tmp_path, capsys):
    path = _run(tmp_path)
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro").chmod(0o500)
    assert main(["video", str(path), "--out", str(tmp_path / "ro" / "v.gif")]) == 2
    assert "cannot write there" in capsys.readouterr().err


@pytest.mark.parametrize("fps", [0.1, 50])
def test_the_fps_range_ends_give_their_frame_durations(tmp_path, fps):
    """A GIF frame lasts 1000 / fps ms: 10 s at 0.1 fps, 20 ms at 50 fps (two hundredths)."""
    out = tmp_path / "v.gif"
    assert main(["-q", "video", str(_run(tmp_path, n=3)), "--fps", str(fps), "--out", str(out)]) == 0
    gif = Image.open(out)
    durations = []
    for k in range(gif.n_frames):
        gif.seek(k)
        durations.append(gif.info["duration"])
    assert durations == [1000 / fps] * 3


@pytest.mark.parametrize("n, step, expected", [(5, None, 5), (MAX_FRAMES, None, MAX_FRAMES),
                                               (MAX_FRAMES + 1, None, 151), (1000, None, 250), (1000, 1, 1000),
                                               (7, 3, 3)])
def test_frame_indices(n, step, expected):
    frames = frame_indices(n, step)
    assert len(frames) == expected and frames[0] == 0 and len(set(np.diff(frames))) <= 1


def test_view_without_a_display_is_one_line_and_exit_2(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", "e1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vitaplace: error: vitaplace view needs a display")
    assert "DISPLAY" in err[0] and "vitaplace video" in err[0]


def test_the_viewer_shows_the_robot_at_the_environments_start():
    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.viewer import viewer_scene

    env = load_environment("e2")
    sim, data = viewer_scene(env)
    x, y, yaw_deg = env.start
    np.testing.assert_allclose(sim.pose(data), [x, y, math.radians(yaw_deg)], atol=1e-9)
    assert sim.model.ngeom > 24 and (sim.whisker_of_geom >= 0).sum() >= 24  # the world and the whiskered robot


def _scene_camera(sim, data, camera):
    """MuJoCo's own frame for ``camera``: position, forward, up and right (the two eyes averaged)."""
    import mujoco

    scene = mujoco.MjvScene(sim.model, 2000)
    mujoco.mjv_updateScene(sim.model, data, mujoco.MjvOption(), None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
    pos = (scene.camera[0].pos + scene.camera[1].pos) / 2
    forward, up = np.array(scene.camera[0].forward), np.array(scene.camera[0].up)
    return pos, forward, up, np.cross(forward, up)


@pytest.mark.parametrize("name,arena,start", [
    ("e1", None, None),
    ("e3", None, None),
    ("e1", {"width": 9.0, "depth": 3.0}, (3.9, -1.2, 135.0)),  # a long arena, the robot near a corner
])
def test_the_viewer_opens_looking_at_the_robot_with_every_corner_of_the_arena_on_screen(name, arena, start):
    import mujoco

    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.viewer import VIEW_ELEVATION_DEG, _frame, viewer_scene

    env = load_environment(name)
    if arena is not None:
        env = env.model_copy(update={"arena": env.arena.model_copy(update=arena), "start": start,
                                     "landmarks": [], "route": []})
    sim, data = viewer_scene(env)
    camera = mujoco.MjvCamera()
    _frame(camera, env, sim, data)
    pos, forward, up, right = _scene_camera(sim, data, camera)
    x, y, yaw_deg = env.start
    # on the camera's axis: the robot, seen from behind (its heading is the view's azimuth) and from above
    to_robot = np.array([x, y, 0.245]) - pos
    np.testing.assert_allclose(np.cross(to_robot / np.linalg.norm(to_robot), forward), 0, atol=1e-5)
    np.testing.assert_allclose(forward[:2] / np.linalg.norm(forward[:2]),
                               [math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))], atol=1e-6)
    assert math.degrees(math.asin(-forward[2])) == pytest.approx(-VIEW_ELEVATION_DEG, abs=1e-4)
    # every corner of the walls (outside, floor and top) within the vertical half-angle on both axes
    hx, hy = env.arena.half_x + env.arena.wall_thickness, env.arena.half_y + env.arena.wall_thickness
    tan_half = math.tan(math.radians(sim.model.vis.global_.fovy) / 2)
    ratios = []
    for cx in (-hx, hx):
        for cy in (-hy, hy):
            for cz in (0.0, env.arena.wall_height):
                v = np.array([cx, cy, cz]) - pos
                depth = v @ forward
                ratios.append(max(abs(v @ right), abs(v @ up)) / depth / tan_half)
    assert max(ratios) <= 1 + 1e-6  # all on screen ...
    assert max(ratios) >= 0.999  # ... from no further away than that needs


def _xvfb_display():
    """Start Xvfb on a free display; (process, ":N")."""
    import subprocess

    read, write = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    with os.fdopen(read) as pipe:
        number = pipe.readline().strip()
    if not number:
        xvfb.kill()
        pytest.skip("Xvfb did not start")
    return xvfb, f":{number}"


@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb (apt-get install xvfb)")
def test_the_viewer_opens_on_xvfb_and_ctrl_c_quits_it_with_exit_0_within_seconds():
    """Ctrl-C (SIGINT) is the quit sent: it made the viewer segfault (exit 139) or hang while
    GLFW had been started in the process before the viewer's own thread started it again."""
    import selectors
    import signal
    import subprocess
    import sys

    xvfb, display = _xvfb_display()
    env = {**os.environ, "DISPLAY": display}
    env.pop("WAYLAND_DISPLAY", None)
    try:
        # started as a shell starts it, Ctrl-C not ignored: an ignored SIGINT survives exec, and a
        # test before this one may leave this process ignoring it
        with subprocess.Popen([sys.executable, "-m", "vitaplace.engine.cli.main", "view", "e1"], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)) as viewer:
            try:
                said, deadline = "", time.monotonic() + 120
                with selectors.DefaultSelector() as sel:
                    sel.register(viewer.stderr, selectors.EVENT_READ)
                    while "is open" not in said and viewer.poll() is None and time.monotonic() < deadline:
                        if sel.select(timeout=1.0):
                            said += viewer.stderr.readline()
                assert "is open" in said, f"the viewer did not open: {said!r} (exit {viewer.poll()})"
                time.sleep(1.0)  # a few frames drawn
                viewer.send_signal(signal.SIGINT)
                sent = time.monotonic()
                rc = viewer.wait(timeout=15)
                quit_s = time.monotonic() - sent
                err = viewer.stderr.read()
            finally:
                if viewer.poll() is None:
                    viewer.kill()
        assert rc == 0, f"exit {rc}: {err}"
        assert quit_s < 10 and "Traceback" not in err and "interrupted" not in err
    finally:
        xvfb.terminate()
        xvfb.wait()


def test_view_on_a_display_with_no_x_server_is_one_line_without_glfws_warnings(monkeypatch, capfd):
    """GLFW's own two-line warning came before the refusal; its reason is now in the line."""
    monkeypatch.setenv("DISPLAY", ":4917")  # no X server answers there
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", "e1"]) == 2
    captured = capfd.readouterr()  # the file descriptors: a child process's output too
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vitaplace: error: vitaplace view cannot open a window on "
                                               "DISPLAY=':4917'")
    assert "(GLFW failed to start: " in err[0] and "vitaplace video" in err[0] and captured.out == ""


def test_a_display_variable_holding_a_line_break_is_quoted_in_the_one_line(monkeypatch, capfd):
    monkeypatch.setenv("DISPLAY", ":4917\nINJECTED")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    assert main(["view", "e1"]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot open a window on DISPLAY=':4917\\nINJECTED' (GLFW" in err[0], err


class _FakeViewer:
    """`mujoco.viewer.launch_passive` stand-in: a window thread that, like MuJoCo's, is a daemon
    and takes a while to finish once asked to close; ``interrupt_at`` raises Ctrl-C in a sync."""

    def __init__(self, frames: int, interrupt_at: int | None = None):
        import mujoco

        self.frames, self.interrupt_at, self.synced = frames, interrupt_at, 0
        self.closing, self.window_gone = threading.Event(), threading.Event()
        self.cam, self.opt = mujoco.MjvCamera(), mujoco.MjvOption()
        self._thread = threading.Thread(target=self._window, daemon=True)

    def _window(self):
        self.closing.wait()
        time.sleep(0.3)  # tearing down the window and GL context
        self.window_gone.set()

    def launch_passive(self, model, data):
        self._thread.start()
        return self

    def lock(self):
        return contextlib.nullcontext()

    def is_running(self):
        return not self.closing.is_set() and self.synced < self.frames

    def sync(self):
        self.synced += 1
        if self.synced == self.interrupt_at:
            raise KeyboardInterrupt

    def close(self):
        self.closing.set()


@pytest.mark.parametrize("interrupt_at", [None, 3])
def test_view_returns_only_once_the_viewers_window_thread_has_finished(monkeypatch, interrupt_at):
    """Closing the window, or Ctrl-C (then `view` returns normally: exit 0), asks the viewer to
    close and waits for its thread: a daemon thread left drawing while the interpreter shut
    down made `vitaplace view` exit 139."""
    import mujoco.viewer

    from vitaplace.engine.sim import viewer

    fake = _FakeViewer(frames=5, interrupt_at=interrupt_at)
    monkeypatch.setattr(viewer, "require_display", lambda: None)
    monkeypatch.setattr(mujoco.viewer, "launch_passive", fake.launch_passive)
    try:
        viewer.view("e1")
    except KeyboardInterrupt:
        pytest.fail("Ctrl-C went past `view` (the command then says 'interrupted' and exits 130)")
    assert fake.closing.is_set() and fake.window_gone.is_set()
    assert fake.synced == (interrupt_at or 5)


def test_an_existing_video_is_kept_unless_replace_is_given(tmp_path, capsys):
    path = _run(tmp_path, n=3)
    old = tmp_path / "run.gif"
    old.write_bytes(b"an earlier video")
    assert main(["video", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"vitaplace: error: --out {old}: exists; --replace draws the video over it, or give another --out"]
    assert old.read_bytes() == b"an earlier video"
    assert main(["-q", "video", str(path), "--replace"]) == 0
    assert Image.open(old).n_frames == 3
