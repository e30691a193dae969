"""What every process of a sweep must share with its driver: vitaplace's version, its git
commit and whether the checkout has uncommitted changes, and the installed feature plugins.

Ray's probe task (one per node, before any seed) and each SLURM array task (before its seed)
compare their own `installation` with the driver's through `mismatch`: one function for both.
"""

from __future__ import annotations

from typing import Any


def installation() -> dict[str, Any]:
    """This process's vitaplace version, git commit, dirty state (None outside a git
    checkout) and installed feature plugins (entry point = distribution==version)."""
    from importlib.metadata import entry_points

    import vitaplace.engine
    from vitaplace.engine.extension.hookspecs import ENTRY_POINT_GROUP
    from vitaplace.engine.pipeline.provenance import git_commit, git_dirty

    plugins = sorted(
        f"{ep.name}={dist.name}=={dist.version}" if (dist := getattr(ep, "dist", None)) else f"{ep.name}=unknown"
        for ep in entry_points(group=ENTRY_POINT_GROUP)
    )
    commit = git_commit()
    return {"version": vitaplace.engine.__version__, "commit": commit, "dirty": git_dirty() if commit else None,
            "plugins": plugins}


def describe(found: dict[str, Any]) -> str:
    """``vitaplace V (commit C[, with uncommitted changes]; plugins ...)``."""
    changes = ", with uncommitted changes" if found.get("dirty") else ""
    return (f"vitaplace {found['version']} (commit {found['commit'] or 'unknown'}{changes}; "
            f"plugins {', '.join(found['plugins']) or 'none'})")


def mismatch(driver: dict[str, Any], theirs: dict[str, Any], where: str) -> str | None:
    """None when ``theirs`` (the installation ``where`` runs, e.g. "node n1") equals the
    driver's on every key of the driver's; else the one-line reason."""
    if {key: theirs.get(key) for key in driver} == driver:
        return None
    return (f"{where} runs {describe(theirs)} but this driver runs {describe(driver)}; "
            "install the same vitaplace and plugins on every node")
