"""The public API does not break silently: the names of docs/API.md's "Stable import paths"
import from the modules they are listed under, the API modules export exactly their row,
the docs' examples import only listed names, and the listed classes and functions require
no argument beyond the ones pinned here (a new one needs a default)."""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
SECTION = "## Stable import paths"


def stable_names(text: str) -> dict[str, tuple[str, ...]]:
    """Module -> names, from the table under `SECTION` of ``text`` (a row without names: the
    module itself is what is imported)."""
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(vitaplace[\w.]*)` \| (.*) \|$", section, re.MULTILINE)
    return {module: tuple(re.findall(r"`(\w+)`", names)) for module, names in rows}


STABLE = stable_names((ROOT / "docs" / "API.md").read_text())

#: the arguments each listed class, function or method requires, as the docs show them: an
#: argument added later needs a default, so that code written against the docs keeps running
REQUIRED: dict[str, tuple[str, ...]] = {
    "vitaplace.load_scenario": ("scenario",),
    "vitaplace.run": ("scenario",),
    "vitaplace.read_results": ("out",),
    "vitaplace.open_run": ("path",),
    "vitaplace.simulate": ("environment",),
    "vitaplace.extractors": (),
    "vitaplace.fit_extractor": ("plugin", "train"),
    "vitaplace.unguarded_script": (),
    "vitaplace.plugin.discover": (),
    "vitaplace.testing.check_extractor": ("cls",),
    "vitaplace.testing.synthetic_run": (),
    "vitaplace.testing.parametrize_with_checks": ("extractors",),
    "vitaplace.engine.sim.load_environment": ("path",),
    "vitaplace.engine.sim.simulate_run": ("environment", "run", "seed"),
    "vitaplace.engine.sim.run_spec": (),
    "vitaplace.engine.data.dataset.write_run": ("path", "run"),
    "vitaplace.engine.export.read_package": ("folder",),
    "vitaplace.engine.network.pc.Network": ("config", "seed"),
    "vitaplace.engine.network.pc.Network.train": ("inputs", "training"),
    "vitaplace.engine.network.pc.Network.infer": ("inputs", "max_steps"),
    "vitaplace.engine.network.pc.Network.load": ("directory",),
    "vitaplace.engine.network.pc.Network.save": ("directory",),
    "vitaplace.engine.network.pc.NetworkConfig": ("modalities", "joint", "activation", "slope"),
    "vitaplace.engine.network.pc.ModalityConfig": ("input_size", "layers", "eta_y", "eta_w", "threshold"),
    "vitaplace.engine.network.pc.JointConfig": ("size", "eta_y", "eta_w", "threshold"),
    "vitaplace.engine.network.pc.TrainingConfig": ("epochs", "batch_size", "inference_steps", "seed", "converge_window",
                                                   "converge_tol"),
    "vitaplace.engine.network.selection.get_backend": (),
}


def missing_names(stable: dict[str, tuple[str, ...]]) -> list[str]:
    """``module.name`` of every listed name that does not import (``module: why`` for a module)."""
    missing = []
    for module, names in stable.items():
        try:
            imported = importlib.import_module(module)
        except ImportError as exc:
            missing.append(f"{module}: {exc}")
            continue
        for name in names:
            try:
                getattr(imported, name)
            except (AttributeError, ImportError):
                missing.append(f"{module}.{name}")
    return missing


def test_the_list_has_every_public_module():
    assert {"vitaplace", "vitaplace.plugin", "vitaplace.testing", "vitaplace.engine.network.pc"} <= set(STABLE)
    assert {"Network", "NetworkConfig", "TrainingConfig"} <= set(STABLE["vitaplace.engine.network.pc"])
    assert STABLE["vitaplace.engine.sim.gym_env"] == ()


def test_every_listed_name_imports():
    assert missing_names(STABLE) == []


def test_a_name_or_module_that_is_gone_is_named():
    assert missing_names({"vitaplace.plugin": ("Run", "Runn"), "vitaplace.nowhere": ()}) == [
        "vitaplace.plugin.Runn", "vitaplace.nowhere: No module named 'vitaplace.nowhere'"]


@pytest.mark.parametrize("module", ["vitaplace", "vitaplace.plugin", "vitaplace.testing"])
def test_each_api_module_exports_its_row(module):
    exported = importlib.import_module(module).__all__
    assert len(set(exported)) == len(exported), sorted(n for n in exported if exported.count(n) > 1)
    assert sorted(exported) == sorted(STABLE[module])


def documented_imports(text: str) -> list[tuple[str, tuple[str, ...]]]:
    """(module, names) of what the Python examples of a Markdown ``text`` take from vitaplace:
    each ``from vitaplace... import a, b`` line, each ``import vitaplace...`` (no names), and
    each ``vitaplace.NAME`` used in the code (as ``("vitaplace", (NAME,))``)."""
    found = []
    for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
        for line in block.splitlines():
            code = line.split("#", 1)[0]
            if match := re.match(r"\s*from (vitaplace[\w.]*) import \(?([\w\s,]+)", code):
                names = [part.split(" as ")[0].strip() for part in match[2].split(",")]
                found.append((match[1], tuple(name for name in names if name)))
            elif match := re.match(r"\s*import (vitaplace[\w.]*)", code):
                found.append((match[1], ()))
            else:
                found += [("vitaplace", (name,)) for name in re.findall(r"(?<![\w.\"'])vitaplace\.(\w+)", code)]
    return found


def unlisted(documented: list[tuple[str, tuple[str, ...]]], stable: dict[str, tuple[str, ...]]) -> list[str]:
    """One line for each documented import of a module or name `stable` does not list."""
    return [f"{module} is not listed" if module not in stable else f"{module}.{name} is not listed"
            for module, names in documented for name in (names or ("",))
            if module not in stable or (name and name not in stable[module])]


def test_the_docs_import_only_listed_names():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    problems = [f"{page.relative_to(ROOT)}: {line}" for page in pages
                for line in unlisted(documented_imports(page.read_text()), STABLE)]
    assert problems == []
    assert len([page for page in pages if documented_imports(page.read_text())]) >= 3  # the parser reads the examples


def test_an_unlisted_import_of_an_example_is_named():
    text = ("```python\nfrom vitaplace.plugin import Run, hookimpl as h  # the API\n"
            "import vitaplace.engine.sim.gym_env\n"
            "import vitaplace.engine.cli\nrows = vitaplace.run('q')\nx = vitaplace.engine.sim.RobotSpec()\n"
            "ep = EntryPoint(group=\"vitaplace.features\")\n```\n"
            "```console\n$ python -c 'import vitaplace.engine.base'\n```\n")
    documented = documented_imports(text)
    assert documented == [("vitaplace.plugin", ("Run", "hookimpl")), ("vitaplace.engine.sim.gym_env", ()),
                          ("vitaplace.engine.cli", ()), ("vitaplace", ("run",)), ("vitaplace", ("engine",))]
    assert unlisted(documented, STABLE) == ["vitaplace.engine.cli is not listed", "vitaplace.engine is not listed"]


def resolve(dotted: str) -> Any:
    """The object ``dotted`` names: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            found = getattr(found, name)
        return found
    raise ImportError(dotted)


def required_arguments(callable_: Any) -> tuple[str, ...]:
    """The parameters a call must pass: no default, not ``*args`` / ``**kwargs``, not self / cls."""
    signature = inspect.signature(callable_)
    return tuple(name for name, p in signature.parameters.items() if name not in ("self", "cls")
                 and p.default is p.empty and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))


def test_no_listed_callable_requires_a_new_argument():
    listed = {f"{module}.{name}" for module, names in STABLE.items() for name in names}
    assert {dotted.rsplit(".", 1)[0] if dotted not in listed else dotted for dotted in REQUIRED} <= listed
    added = {dotted: sorted(set(required_arguments(resolve(dotted))) - set(pinned))
             for dotted, pinned in REQUIRED.items()}
    assert {dotted: new for dotted, new in added.items() if new} == {}, "give these arguments a default"


def test_a_required_argument_added_to_a_dataclass_is_found():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Config:
        epochs: int
        prior: float
        seed: int = 0

    assert required_arguments(Config) == ("epochs", "prior")
    assert required_arguments(lambda a, *rest, b=1, **more: None) == ("a",)

    class Model:
        def fit(self, data, *, seed): ...

    assert required_arguments(Model.fit) == ("data", "seed")


def test_the_changelog_keeps_its_format():
    """CHANGELOG.md (Keep a Changelog): `[Unreleased]` first, its entries under the format's kinds."""
    text = (ROOT / "CHANGELOG.md").read_text()
    assert re.findall(r"^## \[(.+?)\]", text, re.MULTILINE)[0] == "Unreleased"
    assert set(re.findall(r"^### (.+)$", text, re.MULTILINE)) <= {"Added", "Changed", "Deprecated", "Removed", "Fixed",
                                                                  "Security"}
