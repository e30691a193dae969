"""``vitaplace video RUN.h5``: an animation of a recorded run, one frame per sample: the
robot's camera frame, the top view with the trajectory so far and the whisker contacts of
that whisk cycle, and each whisker's deflection at the sampling instant.

Written with matplotlib's animation writers: GIF through Pillow (always there), MP4 through
ffmpeg: the one on the PATH, else the one the ``video`` extra installs (imageio-ffmpeg). Works
for imported runs too (no arena, no contacts: the top view then shows the trajectory alone).
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib import animation
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.data.dataset import TOUCH_THRESHOLD, Run
from vitaplace.engine.outputs.outdir import writable_dir

log = logging.getLogger("vitaplace")

#: at most this many frames unless a step is given (a long run is subsampled evenly)
MAX_FRAMES = 300
FORMATS = (".gif", ".mp4")
#: frames per second a video may have: a GIF stores each frame's duration in whole
#: hundredths of a second, so 50 fps (2/100 s) is the fastest it holds and 0.1 fps (10 s a frame) the slowest allowed
FPS_RANGE = (0.1, 50.0)


def frame_indices(n_samples: int, step: int | None = None) -> np.ndarray:
    """The samples drawn: every ``step``-th; by default every one, or every k-th with the
    smallest k that keeps the animation within `MAX_FRAMES` frames."""
    step = step or max(1, math.ceil(n_samples / MAX_FRAMES))
    return np.arange(0, n_samples, step)


def _writer(suffix: str, fps: float) -> animation.AbstractMovieWriter:
    if suffix == ".gif":
        return animation.PillowWriter(fps=fps)  # type: ignore[arg-type]  # matplotlib's stubs say int; a float works
    if suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            _use_pip_ffmpeg()
        return animation.FFMpegWriter(fps=fps)  # type: ignore[arg-type]  # matplotlib's stubs say int; a float works
    raise UserError(f"video: unknown format {suffix!r}; expected {' or '.join(FORMATS)}")


def _use_pip_ffmpeg() -> None:
    """Point matplotlib at imageio-ffmpeg's ffmpeg (``rcParams["animation.ffmpeg_path"]``) when
    there is none on the PATH; UserError, one line, when imageio-ffmpeg is not installed either."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise UserError('an MP4 video needs ffmpeg: install the video extra (pip install "vitaplace[video]") '
                        "or put ffmpeg on the PATH (e.g. `apt-get install ffmpeg`); or write a .gif") from None
    matplotlib.rcParams["animation.ffmpeg_path"] = imageio_ffmpeg.get_ffmpeg_exe()


def check_video(run: Run, path: Path, fps: float) -> None:
    """UserError, one line, unless ``run`` has samples, ``fps`` is inside `FPS_RANGE` (so
    finite) and ``path`` can be written (not a folder, one of the `FORMATS`, its folder
    writable): checked before anything is drawn."""
    low, high = FPS_RANGE
    if not (isinstance(fps, (int, float)) and low <= fps <= high):
        raise UserError(f"--fps {fps}: expected frames per second in [{low:g}, {high:g}]")
    if len(run) == 0:
        raise UserError(f"{run.name}: the run has no samples; nothing to animate")
    if path.is_dir():
        raise UserError(f"--out {path}: is a folder; expected the video file to write (e.g. {path / 'run.gif'})")
    if path.suffix.lower() not in FORMATS:
        given = f"ends in {path.suffix!r}" if path.suffix else "has no extension"
        raise UserError(f"--out {path}: {given}; expected a video file ending in {' or '.join(FORMATS)} "
                        f"(e.g. {path.with_suffix('.gif')})")
    writable_dir(path.parent)


def _top_view(run: Run) -> dict | None:
    """The arena of a simulated run (its recorded environment), None for imported runs."""
    from vitaplace.engine.sim.environment import EnvironmentSpec

    spec = run.attrs.get("environment_spec")
    return EnvironmentSpec.model_validate(spec).top_view() if isinstance(spec, dict) else None


def write_video(run: Run, path: str | os.PathLike, fps: float = 5.0, step: int | None = None) -> tuple[Path, int]:
    """Animate ``run`` into ``path`` (.gif or .mp4, written atomically) after `check_video`;
    returns the path and the number of frames (`frame_indices`)."""
    from vitaplace.engine.sim.plot import plot_environment

    path = Path(path)
    check_video(run, path, fps)
    writer = _writer(path.suffix.lower(), fps)
    frames = frame_indices(len(run), step)
    poses, times, deflection = run.poses, run.times, np.linalg.norm(run.xy, axis=2)
    fig = Figure(figsize=(12, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    camera_ax, top_ax, whisker_ax = fig.subplots(1, 3, width_ratios=[1.2, 1, 1.1])

    camera = camera_ax.imshow(run.image_batch(0, 1)[0])
    camera_ax.set_axis_off()
    camera_ax.set_title("camera")

    arena = _top_view(run)
    if arena is not None:
        plot_environment(arena, ax=top_ax, show_route=False, title="top view")
    else:
        margin = 0.3
        top_ax.set_xlim(poses[:, 0].min() - margin, poses[:, 0].max() + margin)
        top_ax.set_ylim(poses[:, 1].min() - margin, poses[:, 1].max() + margin)
        top_ax.set_aspect("equal")
        top_ax.set_xlabel("x [m]")
        top_ax.set_ylabel("y [m]")
        top_ax.set_title("top view (no arena recorded)")
    top_ax.plot(poses[:, 0], poses[:, 1], color="0.75", lw=0.8, zorder=4)
    (travelled,) = top_ax.plot([], [], color="tab:blue", lw=1.4, zorder=5, label="trajectory")
    heading = top_ax.quiver([0], [0], [1], [0], color="tab:blue", angles="xy", scale_units="xy", scale=4, zorder=7)
    contacts = top_ax.scatter([], [], s=10, c="tab:red", zorder=6, label="whisker contacts of the cycle")
    top_ax.legend(loc="upper right", fontsize=7)

    n_whiskers = deflection.shape[1]
    bars = whisker_ax.bar(np.arange(n_whiskers), deflection[0], color="tab:grey")
    whisker_ax.axhline(TOUCH_THRESHOLD, color="tab:red", lw=0.8, ls="--", label=f"touch threshold {TOUCH_THRESHOLD:g}")
    whisker_ax.set_ylim(0, max(float(deflection.max()), 2 * TOUCH_THRESHOLD) * 1.05)
    whisker_ax.set_xlabel("whisker")
    whisker_ax.set_ylabel("deflection |xy| at the sample [rad]")
    whisker_ax.set_title("whiskers (red: touching)")
    whisker_ax.legend(loc="upper right", fontsize=7)

    def draw(i: int) -> None:
        camera.set_data(run.image_batch(i, i + 1)[0])  # one frame at a time: no whole image stack in memory
        travelled.set_data(poses[: i + 1, 0], poses[: i + 1, 1])
        heading.set_offsets([poses[i, :2]])
        heading.set_UVC([math.cos(poses[i, 2])], [math.sin(poses[i, 2])])
        points, _ = run.contacts(i)
        contacts.set_offsets(points[:, :2] if len(points) else np.empty((0, 2)))

        for bar, value in zip(bars, deflection[i], strict=True):
            bar.set_height(value)
            bar.set_color("tab:red" if value > TOUCH_THRESHOLD else "tab:grey")
        fig.suptitle(f"{run.name}: sample {i + 1} of {len(run)}, t = {times[i]:.1f} s")

    movie = animation.FuncAnimation(fig, draw, frames=[int(i) for i in frames], repeat=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    # writers pick the format by the file's extension: write under the real name in a
    # temporary folder beside the target, then rename
    with tempfile.TemporaryDirectory(prefix=f".{path.name}.", dir=path.parent) as scratch:
        staged = Path(scratch) / path.name
        movie.save(staged, writer=writer, dpi=80)
        os.replace(staged, path)
    log.info("video: %d frames of the %d samples of %s in %s", len(frames), len(run), run.name, path)
    return path, len(frames)
