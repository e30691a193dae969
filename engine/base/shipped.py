"""The files shipped with vitaplace: the scenarios of the `vitaplace.scenarios` package and
the environments in its ``environments/`` folder. The one module that knows where they live;
everything that accepts "a file, or the name of a shipped one" looks names up here."""

from __future__ import annotations

from pathlib import Path

import vitaplace.scenarios
from vitaplace.engine.base.errors import did_you_mean

SCENARIOS_DIR = Path(vitaplace.scenarios.__file__).resolve().parent
ENVIRONMENTS_DIR = SCENARIOS_DIR / "environments"
#: where `shipped_file` looks by default: scenarios, then environments
SHIPPED_DIRS = (SCENARIOS_DIR, ENVIRONMENTS_DIR)


def shipped_file(name: str | Path, folders: tuple[Path, ...] = SHIPPED_DIRS) -> Path | None:
    """The shipped file ``name`` (``e1``, ``e1.yaml``, ``quickstart``, ``environments/e1.yaml``)
    in the first of ``folders`` that has it, or None when vitaplace ships no such file."""
    for folder in folders:
        for candidate in (folder / name, folder / f"{name}.yaml"):
            candidate = candidate.resolve()
            if candidate.is_file() and candidate.is_relative_to(folder):
                return candidate
    return None


def scenario_names() -> list[str]:
    """The shipped scenarios by name."""
    return sorted(path.stem for path in SCENARIOS_DIR.glob("*.yaml"))


def environment_files() -> dict[str, Path]:
    """The shipped environments by name (``base*`` files, which only serve ``extends:``, excluded)."""
    return {p.stem: p for p in sorted(ENVIRONMENTS_DIR.glob("*.yaml")) if not p.stem.startswith("base")}


def shipped_names_hint(name: str | Path, what: str = "environments") -> str:
    """``"shipped environments: e1, e2, ...; did you mean 'e2'?"`` (or scenarios): the tail of
    the one-line error for a file ``name`` that is neither there nor shipped."""
    names = list(environment_files()) if what == "environments" else scenario_names()
    return f"shipped {what}: {', '.join(names)}{did_you_mean(Path(name).stem, names)}"
