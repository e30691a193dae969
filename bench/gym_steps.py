"""Steps per second of the Gymnasium environments: ``WhiskEye-E1-v0`` (the sensor platform)
and ``WhiskEye-Localise-v0`` (place recognition against a reference map, the hand-crafted
plugin), 1 environment and 2 (``gymnasium.make_vec``: the task's vector entry point, and
``async``, one worker process per environment).

    python bench/gym_steps.py                   # 100 steps each, the default 120x160 camera
    python bench/gym_steps.py --steps 300 --width 32 --height 24

A step is one 2 Hz whisk cycle (250 physics steps of 2 ms, 25 deflection readouts, one camera
frame); the task adds the plugin's features of the new sample and its distances to every
reference sample. Steps per second count every environment's steps (2 environments: 2 per
vector step) over the wall time of the stepping alone; the reference map (a 150-sample
route drive, the plugin fitted once) and the workers' start are timed apart.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")


def timed(make, steps: int, n_envs: int, seed: int = 0) -> dict[str, float]:
    """Make an environment (``make()``), reset it and step it ``steps`` times with a gentle
    random policy; wall times of the making (with the first reset) and of the stepping."""
    import numpy as np

    t0 = time.perf_counter()
    env = make()
    env.reset(seed=seed)
    made = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    low, high = np.array([-0.2, -0.1, -0.5, 0.5]), np.array([0.3, 0.1, 0.5, 1.0])
    shape = (n_envs, 4) if n_envs > 1 else (4,)
    t0 = time.perf_counter()
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(low, high, shape).astype(np.float32))
        if n_envs == 1 and (terminated or truncated):
            env.reset()
    stepping = time.perf_counter() - t0
    env.close()
    return {"setup_s": made, "steps_per_s": steps * n_envs / stepping}


def main(argv: list[str] | None = None) -> int:
    import gymnasium

    import vitaplace.engine.tasks  # noqa: F401  (registers the ids)

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=100, help="steps per case")
    parser.add_argument("--width", type=int, default=160, help="camera width [px]")
    parser.add_argument("--height", type=int, default=120, help="camera height [px]")
    args = parser.parse_args(argv)
    robot = {"camera_width": args.width, "camera_height": args.height}
    cases = {
        "WhiskEye-E1-v0, 1 env": (lambda: gymnasium.make("WhiskEye-E1-v0", robot=robot), 1),
        "WhiskEye-E1-v0, 2 envs sync": (lambda: gymnasium.make_vec("WhiskEye-E1-v0", 2, "sync", robot=robot), 2),
        "WhiskEye-Localise-v0, 1 env": (lambda: gymnasium.make("WhiskEye-Localise-v0", robot=robot), 1),
        "WhiskEye-Localise-v0, 2 envs (vector entry point)":
            (lambda: gymnasium.make_vec("WhiskEye-Localise-v0", 2, robot=robot), 2),
        # last: a forked worker cannot make an EGL context once this process has made one
        "WhiskEye-Localise-v0, 2 envs async (spawn)":
            (lambda: gymnasium.make_vec("WhiskEye-Localise-v0", 2, "async", vector_kwargs={"context": "spawn"},
                                        robot=robot), 2),
    }
    print(f"{args.steps} steps per case, camera {args.width}x{args.height}, {os.cpu_count()} CPUs")
    print(f"{'case':52s} {'setup [s]':>10s} {'steps/s':>9s}")
    for name, (make, n_envs) in cases.items():
        result = timed(make, args.steps, n_envs)
        print(f"{name:52s} {result['setup_s']:10.1f} {result['steps_per_s']:9.1f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
