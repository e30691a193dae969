"""Plots of environments and simulated runs (top views, camera frames, whisker signals).

`plot_environment` draws an `EnvironmentSpec.top_view()` with optional trajectories; the
evaluation report can reuse it. ``python -m vitaplace.engine.sim.plot docs/images``
regenerates the figures of docs/SIMULATION.md.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_environment", "make_doc_images"]


def plot_environment(
    top_view: Mapping[str, Any],
    trajectories: Mapping[str, np.ndarray] | None = None,
    ax: Any = None,
    show_route: bool = True,
    title: str | None = None,
) -> Any:
    """Draw the arena, landmarks (hatched = visual only), route and ``trajectories``.

    ``trajectories`` maps a label to an (n, >=2) array of x, y (e.g. ``run.poses``).
    Returns the matplotlib axes.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Patch, Polygon, Rectangle
    from matplotlib.transforms import Affine2D

    if ax is None:
        _, ax = plt.subplots(figsize=(5.5, 5.5))
    hx, hy = top_view["width"] / 2, top_view["depth"] / 2
    ax.add_patch(Rectangle((-hx, -hy), 2 * hx, 2 * hy, fill=False, lw=2.5, ec="0.3"))
    for lm in top_view["landmarks"]:
        colour = lm.get("rgba", (0.5, 0.5, 0.5, 1))[:3]
        style = {"fc": colour, "ec": "0.15", "lw": 0.8, "alpha": 0.85, "hatch": None if lm["tactile"] else "//"}
        x, y = lm["pos"]
        if lm["type"] == "cylinder":
            patch: Patch = Circle((x, y), lm["radius"], **style)
        elif lm["type"] == "rock":
            patch = Polygon(lm["polygon"], closed=True, **style)
        else:
            sx, sy = lm["size"]
            patch = Rectangle((x - sx / 2, y - sy / 2), sx, sy, **style)
            patch.set_transform(Affine2D().rotate_deg_around(x, y, lm.get("yaw", 0.0)) + ax.transData)
        ax.add_patch(patch)
    if show_route and top_view.get("route"):
        r = np.array([*top_view["route"], top_view["route"][0]])
        ax.plot(r[:, 0], r[:, 1], ls="--", color="k", lw=1.0, label="route", zorder=3)
    colours = ("tab:blue", "tab:red", "tab:green", "tab:purple")  # at most four trajectories drawn
    for (label, traj), colour in zip((trajectories or {}).items(), colours, strict=False):
        t = np.asarray(traj)
        lw = 0.7 if len(t) > 300 else 1.2
        ax.plot(t[:, 0], t[:, 1], color=colour, lw=lw, label=label, zorder=4)
        ax.plot(t[0, 0], t[0, 1], marker="o", ms=4, color=colour, zorder=5)
    ax.set_xlim(-hx - 0.25, hx + 0.25)
    ax.set_ylim(-hy - 0.25, hy + 0.25)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or top_view.get("name", ""))
    if trajectories or (show_route and top_view.get("route")):
        ax.legend(loc="upper right", fontsize=7, framealpha=0.85)
    return ax


def make_doc_images(out_dir: str | Path, foraging_samples: int = 600, drive_samples: int = 450) -> list[Path]:
    """Regenerate the figures of docs/SIMULATION.md into ``out_dir``; returns the written files."""
    import matplotlib

    matplotlib.use("Agg")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written, frames = _trajectory_figures(out, foraging_samples, drive_samples)
    written.append(_camera_frames_figure(out, frames))
    written.append(_touch_worlds_figure(out, drive_samples))
    written.extend(_robot_figures(out))
    written.append(_whisker_figure(out))
    return written


def _save(fig: Any, path: Path, dpi: int) -> Path:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def _trajectory_figures(
    out: Path, foraging_samples: int, drive_samples: int
) -> tuple[list[Path], dict[str, np.ndarray]]:
    """Top views of E1-E3 with a foraging run and two teleop drives (``<env>_top.png``), and
    four camera frames along drive A of each (returned, by environment)."""
    import matplotlib.pyplot as plt

    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import run_spec, simulate_run

    written: list[Path] = []
    frames: dict[str, np.ndarray] = {}
    for name in ("e1", "e2", "e3"):
        env = load_environment(name)
        forage = simulate_run(env, run_spec(kind="foraging", n_samples=foraging_samples), seed=0, progress=False)
        query = simulate_run(env, run_spec(kind="teleop", n_samples=drive_samples), seed=1, progress=False)
        ref = simulate_run(env, run_spec(kind="teleop", n_samples=drive_samples), seed=2, progress=False)
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
        plot_environment(
            env.top_view(),
            {
                f"foraging ({foraging_samples} samples)": forage.poses,
                "teleop drive A (seed 1)": query.poses,
                "teleop drive B (seed 2)": ref.poses,
            },
            ax=ax,
            title=name.upper(),
        )
        ax.text(0.0, -0.13, env.description.split(" - ", 1)[-1], transform=ax.transAxes, fontsize=8, color="0.3")
        fig.tight_layout()
        written.append(_save(fig, out / f"{name}_top.png", dpi=110))
        idx = np.linspace(0, drive_samples - 1, 4).astype(int)
        frames[name] = query.images[idx]
    return written, frames


def _camera_frames_figure(out: Path, frames: Mapping[str, np.ndarray]) -> Path:
    """Camera frames along a drive through each environment (one row per environment)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 4, figsize=(10, 5.6))
    for row, (name, imgs) in enumerate(frames.items()):
        for col, img in enumerate(imgs):
            axes[row, col].imshow(img)
            axes[row, col].set_xticks([])
            axes[row, col].set_yticks([])
            if col == 0:
                axes[row, col].set_ylabel(name.upper())
    fig.suptitle("robot camera, 120 x 160, at maximum protraction (teleop drive A)")
    fig.tight_layout()
    return _save(fig, out / "camera_frames.png", dpi=100)


def _robot_figures(out: Path) -> list[Path]:
    """The robot next to a landmark, seen from outside (whiskers visible), and an overview of E2."""
    import matplotlib.pyplot as plt
    import mujoco

    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.model import build_model
    from vitaplace.engine.sim.render import Camera
    from vitaplace.engine.sim.simulate import Simulator

    env = load_environment("e2")
    sim = Simulator(env, camera=False)
    sim.reset((0.0, -1.0, -math.pi / 2))  # facing the southern cylinder, its whiskers on it
    sim.cycle()
    big = build_model(env, sim.robot, offscreen=(640, 480))
    d = mujoco.MjData(big.model)
    d.qpos[:] = sim.data.qpos
    mujoco.mj_forward(big.model, d)
    cam = Camera(big.model, 640, 480, camera=0, show_robot=True)
    free = mujoco.MjvCamera()
    free.type = mujoco.mjtCamera.mjCAMERA_FREE
    free.lookat[:] = (0.0, -1.3, 0.2)
    free.distance, free.azimuth, free.elevation = 1.6, 20.0, -30.0
    cam.camera = free
    shot = cam.render(d).copy()
    free.lookat[:] = (0.0, 0.0, 0.0)
    free.distance, free.azimuth, free.elevation = 8.5, 270.0, -58.0
    overview = cam.render(d).copy()
    cam.close()
    sim.close()
    written = []
    for fname, img in (("robot.png", shot), ("arena_e2.png", overview)):
        fig = plt.figure(figsize=(6.4, 4.8), dpi=100)
        fig.figimage(img)
        written.append(_save(fig, out / fname, dpi=100))
    return written


TOUCH_WORLDS = ("touch-alike-boxes", "touch-alike-shapes", "touch-distinct-boxes", "touch-distinct-shapes")


def _touch_worlds_figure(out: Path, drive_samples: int) -> Path:
    """Top views of the four touch worlds, each with two station drives (seeds 1 and 2) and
    its stations (``touch_worlds_top.png``)."""
    import matplotlib.pyplot as plt

    from vitaplace.engine.sim.controllers import StationsRun, stations_of
    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import run_spec, simulate_run

    spec = run_spec(kind="stations", n_samples=drive_samples)
    assert isinstance(spec, StationsRun)
    fig, axes = plt.subplots(2, 2, figsize=(10, 10))
    for ax, name in zip(axes.ravel(), TOUCH_WORLDS, strict=True):
        env = load_environment(name)
        drives = {f"station drive {label} (seed {seed})": simulate_run(env, spec, seed=seed, progress=False).poses
                  for label, seed in (("A", 1), ("B", 2))}
        plot_environment(env.top_view(), drives, ax=ax, title=name)
        for st in stations_of(env, spec):
            ax.plot(*st.point, marker=(3, 0, math.degrees(st.facing) - 90), color="black", markersize=9, ls="none")
    fig.tight_layout()
    return _save(fig, out / "touch_worlds_top.png", dpi=90)


def _whisker_figure(out: Path) -> Path:
    """Whisker signals over one cycle, robot beside a wall (contact) vs. in the open."""
    import matplotlib.pyplot as plt

    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import Simulator

    sim = Simulator(load_environment("e1"), camera=False)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4), sharey=True)
    t = (sim.robot.series_steps() + 1) * sim.robot.timestep
    east_wall = (2.58, 0.0, math.radians(60))  # the east wall ahead and to the right
    for ax, (label, pose) in zip(
        axes, (("open floor", (0.0, 0.0, 0.0)), ("east wall ahead right", east_wall)), strict=True
    ):
        sim.reset(pose)
        sim.cycle()
        series, _, _ = sim.cycle()
        for i, colour in ((3, "tab:red"), (7, "tab:orange"), (1, "tab:purple"), (23, "tab:gray")):
            ax.plot(t, np.degrees(series[:, i, 0]), color=colour, label=f"w{i:02d} x")
            ax.plot(t, np.degrees(series[:, i, 1]), color=colour, ls=":", label=f"w{i:02d} y")
        ax.set_title(label)
        ax.set_xlabel("time in whisk cycle [s] (sample at 0.5 s = max protraction)")
    axes[0].set_ylabel("base deflection [deg]")
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    sim.close()
    return _save(fig, out / "whisker_deflection.png", dpi=100)


if __name__ == "__main__":
    target = sys.argv[1] if len(sys.argv) > 1 else "docs/images"
    for p in make_doc_images(target):
        print(p)
