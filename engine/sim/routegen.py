"""Route design for the shipped environments: a loop around the arena's centre that keeps
the WhiskEye's body and head clear of every obstacle and runs as far out as they allow, so
the whiskers reach the landmarks on the way.

On each ray from the centre, every ``step_deg`` degrees, the waypoint is the farthest point
of the innermost stretch where the body (a disc of `BODY_RADIUS`) and the head (a disc of
`HEAD_RADIUS`, `HEAD_CENTRE` ahead) keep ``margin`` from everything (less, down to 40 %,
on rays through a narrow passage), capped at ``r_max``.
The head points along the loop (``facing="travel"``, counter-clockwise: the whiskers on
the outer side of the head brush what the loop bends around) or away from the centre
(``facing="outward"``: the whiskers reach ahead into what lies beyond the loop). The
robot's whiskers extend ~0.16 m beyond the head, and only ~0.03 m beyond the body's side,
so a straight pass alongside an object does not touch it.

Print an environment's loop as YAML: ``python -m vitaplace.engine.sim.routegen e3``
"""

from __future__ import annotations

import math
import sys

import numpy as np

from vitaplace.engine.sim.clearance import footprint_clearance
from vitaplace.engine.sim.environment import EnvironmentSpec, load_environment

__all__ = ["inner_loop"]


def inner_loop(
    env: EnvironmentSpec, facing: str = "travel", step_deg: float = 10.0, margin: float = 0.15, r_max: float = 1.6
) -> np.ndarray:
    """Waypoints (n, 2) of the loop described in the module docstring."""
    radii = np.arange(0.3, r_max + 1e-9, 0.01)
    out = []
    for phi in np.radians(np.arange(0.0, 360.0, step_deg)):
        xy = radii[:, None] * np.array([math.cos(phi), math.sin(phi)])
        heading = phi + (math.pi / 2 if facing == "travel" else 0.0)
        clearance = footprint_clearance(env.obstacles, xy, np.full(len(radii), heading))
        # the margin is relaxed in steps to 40 % on rays where a narrow passage needs it
        for m in margin * np.array([1.0, 0.8, 0.6, 0.4]):
            ok = clearance >= m
            if ok.any():
                break
        else:
            raise ValueError(f"environment {env.name!r}: no clear waypoint on the ray at {math.degrees(phi):.0f} deg")
        first = int(np.argmax(ok))
        stop = first + int(np.argmin(ok[first:])) if not ok[first:].all() else len(radii)
        out.append(xy[stop - 1])
    return np.round(np.array(out), 3)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    env = load_environment(args[0])
    print("route:")
    for x, y in inner_loop(env, env.route_facing):
        print(f"  - [{x:g}, {y:g}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
