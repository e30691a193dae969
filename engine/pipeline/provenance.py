"""Where a result came from: vitaplace's version and git commit, the versions of the
packages that compute it, and the machine. Written into manifest.json and the report."""

from __future__ import annotations

import os
import platform
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from vitaplace.engine import __version__
from vitaplace.engine.base.cpus import blas_libraries, usable_cpus

#: distributions whose version can change a result
PACKAGES = ("numpy", "scipy", "scikit-learn", "mujoco", "warp-lang", "pluggy", "h5py", "pydantic")
#: the source tree vitaplace runs from
SOURCE = Path(__file__).parent


def _git(where: Path, *args: str) -> subprocess.CompletedProcess | None:
    """``git ARGS`` in folder ``where`` (None when git cannot run)."""
    try:
        return subprocess.run(["git", *args], cwd=where, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None


def git_commit() -> str | None:
    """The commit of the source tree vitaplace runs from, when it is a git checkout."""
    result = _git(SOURCE, "rev-parse", "HEAD")
    return (result.stdout.strip() or None) if result is not None else None


def git_dirty(where: Path = SOURCE) -> bool | None:
    """Whether the checkout holding ``where`` (default: vitaplace's source) has tracked files
    that differ from its commit; None when it is no git checkout."""
    result = _git(where, "status", "--porcelain", "--untracked-files=no")
    if result is None or result.returncode != 0:
        return None
    return bool(result.stdout.strip())


def package_versions() -> dict[str, str | None]:
    """Installed version of each of `PACKAGES` (None when absent)."""
    out: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def provenance() -> dict[str, Any]:
    """vitaplace version, commit and whether the checkout has uncommitted changes, package
    versions and the machine, as plain data."""
    return {
        "vitaplace_version": __version__,
        "git_commit": git_commit(),
        "git_dirty": git_dirty(),
        "packages": package_versions(),
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "cpus_usable": usable_cpus(), "blas": blas_libraries()},
    }
