"""Bit-identical re-simulation: short runs of every kind, re-simulated, give exactly the
arrays they gave before ``engine/sim/controllers`` was split into a package (issue 28).

`EXPECTED` holds SHA-256 digests recorded with the pre-refactor code (commit c786d7a,
``engine/sim/controllers.py`` in one module) on the development machine (MuJoCo from the
project's pinned environment, EGL rendering). A digest covers every array field of the
`Run` (`FIELDS`, sorted by name: name, dtype, shape and the raw C-order bytes of each) and
the controller's mode counts (``attrs["controller_modes"]``), so any change to a pose, a
command's effect, a deflection, a contact or a pixel changes it. Another MuJoCo or numpy
version may legitimately give other bits, so the digests are kept per build (both recorded
with the old code: the development environment and CI's minimum versions); on a build with
none recorded the test skips, saying so.

The runs: foraging in E2 and E3 (seeds whose 40 samples visit all five states), teleop in
E1 (a detour and a landmark visit: approach, hold, leave), E2 and E3 (three detours, a
visit), route and orbit with and without an off-route part."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402

from vitaplace.engine.data.dataset import FIELDS  # noqa: E402
from vitaplace.engine.sim.controllers import run_spec  # noqa: E402
from vitaplace.engine.sim.environment import load_environment  # noqa: E402
from vitaplace.engine.sim.robot import RobotSpec  # noqa: E402
from vitaplace.engine.sim.simulate import simulate_run  # noqa: E402

#: a tiny camera keeps the rendering cheap; its pixels are still digested
ROBOT = RobotSpec(camera_width=16, camera_height=12)

#: label -> (environment, run settings, seed)
RUNS: dict[str, tuple[str, dict, int]] = {
    "foraging-e2": ("e2", {"kind": "foraging", "n_samples": 40}, 2),
    "foraging-e3": ("e3", {"kind": "foraging", "n_samples": 40}, 1),
    "teleop-e1-detour-visit": ("e1", {"kind": "teleop", "n_samples": 40, "off_route_fraction": 0.3, "detour_count": 1},
                               0),
    "teleop-e2": ("e2", {"kind": "teleop", "n_samples": 40}, 1),
    "teleop-e3-detours": ("e3", {"kind": "teleop", "n_samples": 40, "off_route_fraction": 0.3, "detour_count": 3}, 3),
    "route-e1-off-route": ("e1", {"kind": "route", "n_samples": 30, "off_route_fraction": 0.3}, 0),
    "route-e3": ("e3", {"kind": "route", "n_samples": 30}, 1),
    "orbit-e1-off-route": ("e1", {"kind": "orbit", "n_samples": 30, "off_route_fraction": 0.3}, 0),
    "orbit-e2": ("e2", {"kind": "orbit", "n_samples": 30}, 1),
}

#: per build (MuJoCo and numpy versions: a build may legitimately give other bits), the digests
#: recorded with commit c786d7a's code (before the controllers package), each by simulating
#: `RUNS` with that code in an environment of those versions; a build may hold several sets,
#: one per machine whose floating point gave other bits with the same versions (the same
#: code on an AMD EPYC with AVX-512 and on the first development machine differ)
EXPECTED: dict[str, list[dict[str, str]]] = {
    # the development machine's environment (the README's install, 2026-12-02)
    "mujoco 4.0.0, numpy 2.4.6": [{
        # {'avoid': 47, 'wander': 89, 'orient': 16, 'explore': 46, 'leave': 2}
        "foraging-e2": "c2a4cfe09c89604c25fbbecaa63dbb7b711af7da4770cd46de1662942db19b93",
        # {'avoid': 61, 'wander': 27, 'orient': 7, 'explore': 89, 'leave': 16}
        "foraging-e3": "e74e89e329506b6f39b1c74437b0fc0c37c24098bdc193185c11a23ce4f21b8e",
        # {'orbit': 150}
        "orbit-e1-off-route": "f4166fd423099a87d78ac6eaa8749760ab87d6fc5d2eca56c5ef3e63948e7ab4",
        # {'orbit': 150}
        "orbit-e2": "4dbbaed27041860e898aa96ae7ac2ea7cc46a005cf94c5403a1ad6ffacff293f",
        # {'route': 150}
        "route-e1-off-route": "73f0d3229569b0fef44dbb614615a712359a806ce4724715863deb7ada6a8b08",
        # {'route': 150}
        "route-e3": "d10971ba89b89a66d6e13c611da0b69f924b23a0f5d83c8984ebc310ac613466",
        # {'approach': 65, 'hold': 15, 'leave': 10, 'drive': 110}
        "teleop-e1-detour-visit": "f0884549f77e744e91dfdddea1e1131e02167634adc315b229273b8ce49c2ad4",
        # {'approach': 110, 'hold': 35, 'leave': 25, 'drive': 30}
        "teleop-e2": "15de9e850cce13072bde8a3f54c077292bde9e30744da00b83c8ad5520d44fc5",
        # {'approach': 135, 'leave': 65}
        "teleop-e3-detours": "617ca68a3425a9f865587311b3d8c2e69eb6ab15fd7c00fdcd38e5fbf8629f2c",
    }, {  # the same install on an AMD EPYC machine (AVX-512), recorded with c786d7a's code on it
        # {'avoid': 47, 'wander': 89, 'orient': 16, 'explore': 46, 'leave': 2}
        "foraging-e2": "816257b0f8a512d85dcc3963ee06782efcb4419035169477e038cae1de3b58af",
        # {'avoid': 61, 'wander': 27, 'orient': 7, 'explore': 89, 'leave': 16}
        "foraging-e3": "bb8a8da26493cba6cc0a38da48e437335bf86092ddcf4c57d24816621df93659",
        # {'orbit': 150}
        "orbit-e1-off-route": "de00d9d023e3684a4b523c195783f6b8f71eeb48a1dcdeacc91d30503c5ec3a5",
        # {'orbit': 150}
        "orbit-e2": "5a66780aad41c3da5cdfb41a43da0cd0381259217d17c48646b6e67d619b9262",
        # {'route': 150}
        "route-e1-off-route": "cb1b520729d905ce7fb9235ae4143726b9c9940e4ce781fe01d97e74ea85c527",
        # {'route': 150}
        "route-e3": "8e8cf4f3292d4d670a7345a2cbc766785a0236ed650a671c21513bb242f70cf5",
        # {'approach': 65, 'hold': 15, 'leave': 10, 'drive': 110}
        "teleop-e1-detour-visit": "da29b80903a5388d28080de2b20c6f9ad5965dfc1b8a5ad129a1dd285beebed3",
        # {'approach': 110, 'hold': 35, 'leave': 25, 'drive': 30}
        "teleop-e2": "e614b491c080dc97890daae14d142c2ae28f2bb49a311f19a051cf673c06ede8",
        # {'approach': 135, 'leave': 65}
        "teleop-e3-detours": "26e4a95f17f1113640c3a9ad6173ff1536b3b3888fdfa1d1d1a7261808940b1a",
    }],
    # the declared minimum versions (.ci/minimum-versions.txt, CI's second run)
    "mujoco 3.10.0, numpy 1.26.0": [{
        # {'avoid': 47, 'wander': 89, 'orient': 16, 'explore': 46, 'leave': 2}
        "foraging-e2": "d42b3447ff485fa0c63971d19addfe1eff8875d194d4cf26586083f840b32d38",
        # {'avoid': 62, 'wander': 27, 'orient': 1, 'explore': 42, 'leave': 68}
        "foraging-e3": "a47383a1469d2ab9f2639f59321d04f5e7cd5c4faa538177084043c4e19c9c4e",
        # {'orbit': 150}
        "orbit-e1-off-route": "913c387e726d405e75622d32d604f1ab8aed6ed1099c7b0345634d986fcb7709",
        # {'orbit': 150}
        "orbit-e2": "95f21137f183416c8df6c2e2f5f9b5eeea67777f176e051cc5e9405ed687b1a1",
        # {'route': 150}
        "route-e1-off-route": "5585f00dc70dd4980c00cd756f8330b6358503600d3d84d9f17e8957813792ea",
        # {'route': 150}
        "route-e3": "3189dbad8955c2ee1868888bb0338555a639324c2817c68d02afe97fcc2a1925",
        # {'approach': 65, 'hold': 15, 'leave': 10, 'drive': 110}
        "teleop-e1-detour-visit": "26dacc6d1191acd8bd5daa4515a9e073e92d4f99f16512d8c7fb087e85e40240",
        # {'approach': 110, 'hold': 35, 'leave': 25, 'drive': 30}
        "teleop-e2": "649cb4250d8483951ba171b713b1c7950955d6c555ca48cf26a9a370bb5b761f",
        # {'approach': 135, 'leave': 65}
        "teleop-e3-detours": "e9b6e51986c40e2979e7ad188975c66a7b9e76e1b2e4743c5d63e189cead4c7d",
    }, {  # the same versions on an AMD EPYC machine (AVX-512), recorded with c786d7a's code on it
        # {'avoid': 47, 'wander': 89, 'orient': 16, 'explore': 46, 'leave': 2}
        "foraging-e2": "8965d51e38a59199cde90cf7b16ef6a0d4b41d3500636328340ab87744273f21",
        # {'avoid': 65, 'wander': 27, 'orient': 1, 'explore': 42, 'leave': 65}
        "foraging-e3": "67598640d57865be8b410be14affc630846053cb9aa5a4e9c475db4cfeeb6bf6",
        # {'orbit': 150}
        "orbit-e1-off-route": "4617a78e32d4550b9656d53527909fb54ca3e3eff706d2385c1e16d04372d447",
        # {'orbit': 150}
        "orbit-e2": "20bab3ace88741af422acd16464e4774d89c65e2656769b5006e96454a2301f7",
        # {'route': 150}
        "route-e1-off-route": "3c02672bcf99d27a84412dabbe483522e63e8d8b7f5c522d0d76863d427c7bf6",
        # {'route': 150}
        "route-e3": "11224a5ff3798dd8c43bbc213d4a350336ec3aa3c0cb276e135b6b310a408fed",
        # {'approach': 65, 'hold': 15, 'leave': 10, 'drive': 110}
        "teleop-e1-detour-visit": "e5a5a4286d76a3366b588234e2e270872c3a38ac74d8af5d23bc466d34074bdf",
        # {'approach': 110, 'hold': 35, 'leave': 25, 'drive': 30}
        "teleop-e2": "bdbef68c2503a86af407bcbc3a374ec4b8d582e1ae9241c47d95c160a776553c",
        # {'approach': 135, 'leave': 65}
        "teleop-e3-detours": "5ba0070eab43bbc7637334c9cb8431d22b1e81a0605715bc7b424b603f0a51e3",
    }],
}


def digest(run) -> str:
    h = hashlib.sha256()
    for key in sorted(FIELDS):
        data = np.ascontiguousarray(run._get(key))
        h.update(f"{key}|{data.dtype.str}|{data.shape}|".encode())
        h.update(data.tobytes())
    h.update(json.dumps(run.attrs["controller_modes"], sort_keys=True).encode())
    return h.hexdigest()


@pytest.mark.parametrize("label", sorted(RUNS))
def test_a_short_run_re_simulates_bit_identically(label):
    build = f"mujoco {mujoco.__version__}, numpy {np.__version__}"
    if build not in EXPECTED:
        pytest.skip(f"no digests recorded for {build} (only {'; '.join(EXPECTED)}): record them with c786d7a's code")
    env, settings, seed = RUNS[label]
    run = simulate_run(load_environment(env), run_spec(settings), seed, ROBOT, progress=False)
    recorded = [digests[label] for digests in EXPECTED[build]]
    assert digest(run) in recorded, run.attrs["controller_modes"]


if __name__ == "__main__":  # print the digests of this build (with the old code: to record them)
    for label in sorted(RUNS):
        env, settings, seed = RUNS[label]
        run = simulate_run(load_environment(env), run_spec(settings), seed, ROBOT, progress=False)
        print(f'    "{label}": "{digest(run)}",  # {run.attrs["controller_modes"]}')
