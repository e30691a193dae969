"""Shared fixtures: the devices kernel and backend tests run on, and a seed per test.

Every device test is parametrised over ``cpu`` and ``cuda``; the ``cuda`` half carries the
``cuda`` marker and is skipped where no CUDA driver and device exist (CI), so a GPU machine
runs both halves with the same command (``pytest -m cuda`` for the GPU half alone).
"""

import functools
import hashlib
from pathlib import Path

import pytest


@functools.cache
def cuda_present() -> bool:
    from vitaplace.engine.network.selection import cuda_available

    return cuda_available()


DEVICES = [
    pytest.param("cpu", id="cpu"),
    pytest.param("cuda", id="cuda", marks=pytest.mark.cuda),
]


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    """A Warp device name; the cuda half skips without a CUDA device."""
    if request.param == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    return request.param


#: The behavioural tests (inference lowers the energy, training lowers the error, samples stop
#: on their own, ...) run on every backend: numpy, fixed (numpy without BLAS), Warp on the CPU,
#: Warp on CUDA (skipped without a CUDA device). The maths tests (finite differences in float64) stay on numpy.
BACKENDS = [
    pytest.param(("numpy", None), id="numpy"),
    pytest.param(("fixed", None), id="fixed"),
    pytest.param(("warp", "cpu"), id="warp-cpu"),
    pytest.param(("warp", "cuda"), id="warp-cuda", marks=pytest.mark.cuda),
]


@pytest.fixture(scope="module", params=BACKENDS)
def backend(request):
    """A function giving a fresh backend of the parametrised kind (a network owns its backend)."""
    from vitaplace.engine.network.selection import get_backend

    name, device = request.param
    if device == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    if name == "warp":
        pytest.importorskip("warp")
    return lambda: get_backend(name, device)


@pytest.fixture
def seed(request) -> int:
    """A seed for a test whose data may be any random draw (as nengo's ``seed`` fixture): derived
    from the test's module and name with its parameters, so it is the same on every run and
    machine, differs between tests, and does not change when the file moves to another folder."""
    name = f"{Path(request.node.path).stem}::{request.node.name}"
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def install_plugin(site: Path, module: str, source: str, project: str, version: str, entry_point: str) -> None:
    """Install a feature-extractor plugin into the folder ``site`` as pip would, without pip:
    the module ``module``.py holding ``source``, and a dist-info of distribution ``project``
    ``version`` whose ``vitaplace.features`` entry point ``entry_point`` is that module.
    Put ``site`` on a process's path to have the plugin discovered there."""
    (site / f"{module}.py").write_text(source)
    dist = site / f"{project.replace('-', '_')}-{version}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project}\nVersion: {version}\n")
    (dist / "entry_points.txt").write_text(f"[vitaplace.features]\n{entry_point} = {module}\n")


def reseal(folder: Path) -> None:
    """Write the folder's completion record anew over what it holds now: as if its own run had
    produced the damaged files (a buggy plugin, a bad disk), so the row checks must catch them."""
    import json

    from vitaplace.engine.outputs import completion, outdir
    files = json.loads((folder / outdir.COMPLETED).read_text())["files"]
    completion.write(folder, [folder / name for name in files])


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A known defect is marked ``@pytest.mark.bug("what is wrong")`` and fails until fixed;
    ``xfail`` would hide it behind a passing run, so a test carrying it stops the session."""
    hiding = [item.nodeid for item in items if item.get_closest_marker("xfail")]
    if hiding:
        raise pytest.UsageError("xfail hides a known defect; mark it @pytest.mark.bug(...) instead: "
                                f"{', '.join(hiding)}")


#: the paper's training and touch scaling, pinned in the committed study scenarios' MuPNet methods
#: (tests/layout/test_study_pins.py), and the touch scaling in their autoencoder controls
_CPU_PINS = {"training_inference": "plain", "inference_steps": 20, "weight_optimizer": "sgd", "held_out": 0.0,
             "tactile_scaling": "range", "weight_norm": "none"}
_STUDIES = ("paper-cpu", "coloured-cpu", "paper-cpu-physical", "paper-cpu-controls", "study2", "study2-budget",
            "study2-dropout", "study2-faithful")
#: per scenario and plugin, the parameters added since ad309c2 (with their values)
SINCE_AD309C2: dict[tuple[str, str], dict[str, object]] = {
    **{(name, "mupnet"): _CPU_PINS for name in _STUDIES},
    **{(name, "autoencoder"): {"tactile_scaling": "range"} for name in _STUDIES},
    ("paper", "mupnet"): {"training_inference": "plain", "weight_optimizer": "sgd", "held_out": 0.0,
                          "converge_window": 0, "latent_prior": 0.0, "inference_solver": "gd", "inference_rtol": None,
                          "tactile_scaling": "range", "weight_norm": "none"},
}
#: per scenario and plugin, parameters its file gave at ad309c2 and no longer gives (their values then)
_SETTLING = {"latent_prior": 1.0, "inference_solver": "preconditioned", "inference_rtol": 3.0e-6, "max_steps": 1000}
REMOVED_SINCE_AD309C2: dict[tuple[str, str], dict[str, object]] = {
    ("touch-benchmark", "mupnet"): {"epochs": 90, "latent_prior": 1.0},
    **{(name, "mupnet"): _SETTLING for name in ("quickstart", "near-duplicate")},  # they follow the defaults
}


def ad309c2_params(name: str, plugin: str, params: dict) -> dict:
    """The given parameters as the scenario's file at ad309c2 gave them (`SINCE_AD309C2`)."""
    added = SINCE_AD309C2.get((name, plugin), {})
    assert all(params[k] == v for k, v in added.items()), f"{name}: the pins changed"
    return {**{k: v for k, v in params.items() if k not in added}, **REMOVED_SINCE_AD309C2.get((name, plugin), {})}
