"""The declared minimum versions: every ">=" bound of pyproject.toml is pinned in
.ci/minimum-versions.txt, which CI installs in a second venv to run the tests against."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
REQUIREMENT = re.compile(r"^([A-Za-z0-9_.-]+)(?:\[[^\]]*\])?>=([0-9][0-9A-Za-z.]*)$")


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _release(version: str) -> tuple[int, ...]:
    """1.26 and 1.26.0 are the same release."""
    parts = [int(p) for p in version.split(".")]
    while parts and parts[-1] == 0:
        parts.pop()
    return tuple(parts)


#: extras the minimum-versions run cannot install, and why
UNTESTED_EXTRAS = {
    "tensorcores": "CUDA libraries, for a GPU machine; CI has none",
    "mlflow": "~20 more distributions; CI's third step installs the newest into the first venv and runs "
              "tests/study/test_mlflow.py",
}


def declared_minimums() -> dict[str, tuple[int, ...]]:
    """Distribution -> lower bound, over the dependencies and every extra but `UNTESTED_EXTRAS`."""
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    requirements = [*project["dependencies"],
                    *(r for name, extra in extras.items() if name not in UNTESTED_EXTRAS for r in extra)]
    bounds: dict[str, tuple[int, ...]] = {}
    for requirement in requirements:
        match = REQUIREMENT.match(requirement.replace(" ", ""))
        assert match, f"pyproject.toml: {requirement!r} is not NAME>=VERSION: give it a lower bound CI can test"
        name, bound = _normal(match[1]), _release(match[2])
        assert bounds.setdefault(name, bound) == bound, f"pyproject.toml: {name} has two lower bounds"
    return bounds


def pinned() -> dict[str, tuple[int, ...]]:
    pins = {}
    for line in (ROOT / ".ci" / "minimum-versions.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if "==" in line:  # a pinned lower bound (other lines constrain dependencies of dependencies)
            name, _, version = line.partition("==")
            pins[_normal(name)] = _release(version)
    return pins


def test_every_lower_bound_is_pinned_for_the_minimum_versions_run():
    assert pinned() == declared_minimums()


def test_the_minimum_versions_run_installs_every_tested_extra():
    """CI installs ".[test]" with the pins: every other tested extra must be part of it."""
    tomllib = pytest.importorskip("tomllib")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    in_test = {r.replace(" ", "") for r in extras["test"]}
    for name, requirements in extras.items():
        if name not in UNTESTED_EXTRAS:
            assert {r.replace(" ", "") for r in requirements} <= in_test, f"extra {name!r} is not in the test extra"
