#!/usr/bin/env python
"""What the evaluation run kinds record, per shipped world: two runs of a kind with
independent seeds (reference, query), and for each

* ``touch``     share of samples with whisker contact at the sampling instant (`Run.touch_mask`),
  reference and query;
* ``near_m``    median (and 90th percentile) distance from a query pose to its nearest
  reference pose [m];
* ``near_deg``  median heading difference to that nearest reference pose [deg];
* ``matched``   share of queries with a reference pose within 0.3 m (the default tau), and
  the median distance and heading difference over those;
* ``coll``      body collision instants (run attrs), both runs.

    MUJOCO_GL=egl python bench/drives.py [--worlds e1,e2,e3] [--kinds teleop,route]
        [--samples 300] [--seeds 1,2] [--tactile-model physical|penetration]

Images are rendered at 16 x 12 px (not used here). Prints one line per world and kind.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial import cKDTree

from vitaplace.engine.sim import RobotSpec, load_environment, run_spec, simulate_run


def nearest(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance [m] and absolute heading difference [deg] from each query pose to its nearest reference pose."""
    dist, index = cKDTree(reference[:, :2]).query(query[:, :2])
    dyaw = np.angle(np.exp(1j * (query[:, 2] - reference[index, 2])))
    return dist, np.degrees(np.abs(dyaw))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", default="e1,e2,e3")
    parser.add_argument("--kinds", default="teleop,route")
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--seeds", default="1,2", help="reference seed, query seed")
    parser.add_argument("--tactile-model", default="physical", choices=("physical", "penetration"))
    args = parser.parse_args()
    ref_seed, query_seed = (int(s) for s in args.seeds.split(","))
    robot = RobotSpec(camera_width=16, camera_height=12, tactile_model=args.tactile_model)
    for world in args.worlds.split(","):
        env = load_environment(world)
        for kind in args.kinds.split(","):
            spec = run_spec(kind=kind, n_samples=args.samples)
            ref, query = (simulate_run(env, spec, seed, robot) for seed in (ref_seed, query_seed))
            dist, dyaw = nearest(query.poses, ref.poses)
            matched = dist < 0.3
            print(
                f"{world} {kind:7s} touch {ref.touch_mask().mean():.2f}/{query.touch_mask().mean():.2f}  "
                f"near_m {np.median(dist):.3f} (p90 {np.percentile(dist, 90):.3f})  near_deg {np.median(dyaw):.1f}  "
                f"matched {matched.mean():.2f}: {np.median(dist[matched]):.3f} m {np.median(dyaw[matched]):.1f} deg  "
                f"coll {ref.attrs['body_collision_instants']}/{query.attrs['body_collision_instants']}",
                flush=True,
            )


if __name__ == "__main__":
    main()
