"""Lint: the package's folders are floors (`LAYERS`: a module imports only from its own floor's
package or from lower floors, never from a sibling on its floor); the import graph has no
cycle; no function is longer than `MAX_FUNCTION_LINES`; the plugin API keeps its documented
import paths.

Every ``import`` in engine/, kernels/, plugins/ and api/ counts: module-level ones, those
inside functions (imported lazily) and those under ``if TYPE_CHECKING:`` (a cycle of type-only
imports still ties the modules together for a reader and for a type checker). A module's
implicit import of its parent packages does not count. A failure names one cycle per
strongly connected set of modules, e.g. ``vitaplace.engine.a -> vitaplace.engine.b -> vitaplace.engine.a``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11, as tests/study/test_packaging.py

ROOT = Path(__file__).resolve().parents[2]


def source_packages(root: Path) -> dict[str, str]:
    """Source folder -> the package it installs as: pyproject.toml's ``package-dir``, less the
    folders that hold no Python code (the shipped scenarios)."""
    package_dir = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    return {folder: package for package, folder in package_dir.items() if any((root / folder).rglob("*.py"))}


PACKAGES = source_packages(ROOT)
#: The floors of the package, lowest first. A module belongs to the longest entry that is its
#: name or a package above it (``vitaplace`` and ``vitaplace.engine`` name those two modules
#: alone: the API and the version). It may import its own entry and lower floors; the entries
#: of one floor are siblings that do not import each other. docs/DESIGN.md draws them.
LAYERS: list[tuple[str, ...]] = [
    ("vitaplace.scenarios",),  # the shipped scenario and environment files
    ("vitaplace.engine.base", "vitaplace.engine"),  # errors, atomic writes, CPUs, YAML files; the version
    ("vitaplace.kernels", "vitaplace.engine.outputs"),  # Warp kernels; the output-folder contract
    ("vitaplace.engine.data", "vitaplace.engine.network"),  # run files; the predictive-coding network
    ("vitaplace.engine.sim", "vitaplace.engine.extension"),  # the simulator; the extractor interface, hooks, registry
    ("vitaplace.plugin", "vitaplace.testing"),  # the plugin API and its contract suite
    ("vitaplace.plugins", "vitaplace.engine.config"),  # the shipped plugins; scenarios
    ("vitaplace.engine.evaluation",),  # metrics: matching, PR curves, difficulty
    # one run's report; reinforcement-learning tasks; the benchmark as data
    ("vitaplace.engine.report", "vitaplace.engine.tasks", "vitaplace.engine.export"),
    # the pipeline's floors: what stages hand on and the files a run writes beside its stages;
    # the cache keys, a scenario's plan, simulation jobs, the manifest; the stage store and
    # scoring of one evaluation folder; the stages, one module each, none importing another;
    # their orchestration
    ("vitaplace.engine.pipeline.records", "vitaplace.engine.pipeline.processes", "vitaplace.engine.pipeline.provenance",
     "vitaplace.engine.pipeline.output_checks", "vitaplace.engine.pipeline.results"),
    ("vitaplace.engine.pipeline.keys", "vitaplace.engine.pipeline.plan", "vitaplace.engine.pipeline.simulation",
     "vitaplace.engine.pipeline.manifest"),
    ("vitaplace.engine.pipeline.store", "vitaplace.engine.pipeline.scoring"),
    tuple(f"vitaplace.engine.pipeline.stages.{stage}"
          for stage in ("simulate", "fit", "transform", "evaluate", "fuse", "compare", "report")),
    ("vitaplace.engine.pipeline",),  # the stages' orchestration (orchestrate.py)
    ("vitaplace.engine.study",),  # across runs: aggregate, sensitivity, statistics
    ("vitaplace.engine.cli",),
    ("vitaplace",),  # the Python API
]
#: entries that name one module, not a package and what is under it
EXACT = {"vitaplace", "vitaplace.engine"}
#: the longest a function of the package may be (decorators and docstring included)
MAX_FUNCTION_LINES = 80


def module_files(root: Path, packages: dict[str, str]) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file under the source folders."""
    modules: dict[str, Path] = {}
    for folder, package in packages.items():
        for file in sorted((root / folder).rglob("*.py")):
            parts = file.relative_to(root / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((package, *parts))] = file
    return modules


def imported_names(module: str, file: Path) -> set[str]:
    """Every dotted name ``module``'s file imports, anywhere in it; for ``from X import Y`` both
    X and X.Y (Y may be a submodule)."""
    is_package = file.name == "__init__.py"
    names: set[str] = set()
    for node in ast.walk(ast.parse(file.read_text(), str(file))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the package holding this module
                base = module.split(".")[: len(module.split(".")) - node.level + (1 if is_package else 0)]
                source = ".".join([*base, *([node.module] if node.module else [])])
            else:
                source = node.module or ""
            names.add(source)
            names.update(f"{source}.{alias.name}" for alias in node.names)
    return names


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the modules of ``modules`` it imports (itself excluded)."""
    return {module: {name for name in imported_names(module, file) if name in modules and name != module}
            for module, file in modules.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One shortest cycle through the first module of every strongly connected set of more
    than one module, as the list of modules along it (first == last)."""
    names = sorted(graph)
    index = {name: i for i, name in enumerate(names)}
    rows = [index[a] for a in names for _ in graph[a]]
    cols = [index[b] for a in names for b in sorted(graph[a])]
    matrix = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    _, labels = connected_components(matrix, directed=True, connection="strong")
    found = []
    for label in sorted(set(labels)):
        members = np.flatnonzero(labels == label)
        if len(members) < 2:
            continue
        start = members[0]
        # shortest way back to `start`: breadth first from each of its successors in the set
        paths = []
        for successor in matrix[start].indices:
            if labels[successor] != label:
                continue
            _, predecessors = breadth_first_order(matrix, successor, directed=True, return_predecessors=True)
            path = [start]
            while path[-1] != successor:
                path.append(predecessors[path[-1]])
            paths.append([start, *reversed(path)])
        found.append([names[i] for i in min(paths, key=len)])
    return found


def entry_of(module: str, layers: list[tuple[str, ...]], exact: set[str]) -> str | None:
    """The `layers` entry ``module`` belongs to: the longest that is its name or, unless in
    ``exact``, a package above it; None when there is none."""
    found = [e for floor in layers for e in floor
             if module == e or (e not in exact and module.startswith(e + "."))]
    return max(found, key=len, default=None)


def upward_imports(graph: dict[str, set[str]], layers: list[tuple[str, ...]], exact: set[str]) -> list[str]:
    """One line per import that breaks the floors: from a module to a higher floor, to a
    sibling on its own floor, or of a module that no entry places."""
    floor = {entry: i for i, entry_floor in enumerate(layers) for entry in entry_floor}
    broken = []
    for module in sorted(graph):
        here = entry_of(module, layers, exact)
        if here is None:
            broken.append(f"{module} is on no floor (add it to LAYERS)")
            continue
        for name in sorted(graph[module]):
            there = entry_of(name, layers, exact)
            if there is None or there == here:
                continue
            if floor[there] > floor[here]:
                broken.append(f"{module} (floor {floor[here]}, {here}) imports {name} from the higher floor "
                              f"{floor[there]} ({there})")
            elif floor[there] == floor[here]:
                broken.append(f"{module} ({here}) imports {name} from its sibling {there} on floor {floor[here]}")
    return broken


def test_every_module_stands_on_its_floor():
    graph = import_graph(module_files(ROOT, PACKAGES))
    assert upward_imports(graph, LAYERS, EXACT) == []
    declared = {entry for floor in LAYERS for entry in floor}
    assert declared <= set(graph) | {m.rsplit(".", 1)[0] for m in graph}  # no entry names a module that is gone


def test_an_upward_a_sibling_and_an_unplaced_import_are_each_named(tmp_path):
    package = tmp_path / "pkg"
    for folder in ("low", "mid_a", "mid_b", "top"):
        (package / folder).mkdir(parents=True)
        (package / folder / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "low" / "x.py").write_text("def f():\n    from pkg.top import t\n")  # lazy, still upward
    (package / "mid_a" / "a.py").write_text("from pkg.low import x\nfrom ..mid_b import b\n")  # down: fine; sibling
    (package / "mid_b" / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pkg.top.t\n")
    (package / "top" / "t.py").write_text("import pkg.low.x\nimport pkg.mid_a.a\n")  # down: fine
    (package / "stray.py").write_text("")
    layers = [("pkg.low", "pkg"), ("pkg.mid_a", "pkg.mid_b"), ("pkg.top",)]
    graph = import_graph(module_files(tmp_path, {"pkg": "pkg"}))
    assert upward_imports(graph, layers, {"pkg"}) == [
        "pkg.low.x (floor 0, pkg.low) imports pkg.top from the higher floor 2 (pkg.top)",
        "pkg.low.x (floor 0, pkg.low) imports pkg.top.t from the higher floor 2 (pkg.top)",
        "pkg.mid_a.a (pkg.mid_a) imports pkg.mid_b from its sibling pkg.mid_b on floor 1",
        "pkg.mid_a.a (pkg.mid_a) imports pkg.mid_b.b from its sibling pkg.mid_b on floor 1",
        "pkg.mid_b.b (floor 1, pkg.mid_b) imports pkg.top.t from the higher floor 2 (pkg.top)",
        "pkg.stray is on no floor (add it to LAYERS)",
    ]
    # the same tree with the upward imports gone passes
    (package / "low" / "x.py").write_text("import os\n")
    (package / "mid_a" / "a.py").write_text("from pkg.low import x\n")
    (package / "mid_b" / "b.py").write_text("")
    (package / "stray.py").unlink()
    assert upward_imports(import_graph(module_files(tmp_path, {"pkg": "pkg"})), layers, {"pkg"}) == []


def test_the_package_map_is_pyprojects():
    assert PACKAGES == {"api": "vitaplace", "engine": "vitaplace.engine", "kernels": "vitaplace.kernels",
                        "plugins": "vitaplace.plugins", "scenarios": "vitaplace.scenarios"}


def test_the_package_has_no_import_cycle():
    graph = import_graph(module_files(ROOT, PACKAGES))
    assert len(graph) > 60  # the walk found the package (not an empty folder)
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(cycle) for cycle in found)


def test_a_cycle_of_lazy_and_type_only_imports_is_found_and_named(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.sub import b\n")
    (package / "sub" / "b.py").write_text("def f():\n    from ..c import g\n")
    (package / "c.py").write_text("import pkg.a\nimport os\n")
    (package / "d.py").write_text("from pkg import a, c\n")  # imports into the cycle, is not on it
    graph = import_graph(module_files(tmp_path, {"pkg": "pkg"}))
    assert graph["pkg.sub.b"] == {"pkg.c"}
    assert graph["pkg.d"] == {"pkg", "pkg.a", "pkg.c"}
    assert cycles(graph) == [["pkg.a", "pkg.sub.b", "pkg.c", "pkg.a"]]


def test_modules_that_only_import_each_other_one_way_have_no_cycle(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("from pkg import b\n")
    (tmp_path / "pkg" / "b.py").write_text("import os\n")
    assert cycles(import_graph(module_files(tmp_path, {"pkg": "pkg"}))) == []


def test_every_import_docs_plugins_md_shows_works():
    """Plugins written against docs/plugins.md work: each ``from vitaplace... import`` line of
    its examples imports, and every one imports from the stable home `vitaplace.plugin` (or
    the contract suite `vitaplace.testing`)."""
    lines = sorted(set(re.findall(r"^from vitaplace[\w.]* import [^\n]+$", (ROOT / "docs" / "plugins.md").read_text(),
                                  re.MULTILINE)))
    assert any("vitaplace.plugin import" in line and "FeatureExtractor" in line for line in lines)
    for line in lines:
        assert line.startswith(("from vitaplace.plugin import", "from vitaplace.testing import")), line
        exec(line, {})  # noqa: S102 - the documented line itself


def test_the_shipped_plugins_import_the_plugin_api_from_its_home():
    graph = import_graph(module_files(ROOT, PACKAGES))
    for module in (m for m in graph if m.startswith("vitaplace.plugins.")):
        reached = graph[module] & {"vitaplace.engine.extension.features", "vitaplace.engine.extension.hookspecs",
                                   "vitaplace.engine.extension.registry"}
        assert not reached, f"{module} imports {sorted(reached)}: import them from vitaplace.plugin"


def long_functions(root: Path, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """``file:line name (N lines)`` of every function or method under the source folders
    longer than ``limit`` lines, from its ``def`` (or first decorator) to its last line."""
    found = []
    for file in module_files(root, PACKAGES).values():
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                length = node.end_lineno - first + 1
                if length > limit:
                    found.append(f"{file.relative_to(root)}:{first} {node.name} ({length} lines)")
    return found


def test_no_function_of_the_package_is_over_80_lines(tmp_path):
    assert long_functions(ROOT) == []
    (tmp_path / "engine").mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES - 1))
    (tmp_path / "engine" / "long.py").write_text(f"def fits():\n{body}\n\ndef too_long():\n{body}    return 0\n")
    assert long_functions(tmp_path) == [
        f"engine/long.py:{MAX_FUNCTION_LINES + 3} too_long ({MAX_FUNCTION_LINES + 1} lines)"]


def test_every_package_folder_is_installed():
    """A subpackage missing from pyproject.toml's ``packages`` works in an editable install and
    is absent from a wheel (``pip install .``, the README's quickstart): every folder holding an
    ``__init__.py`` under the source folders is listed, and nothing else is."""
    installed = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    found = sorted({module for module, file in module_files(ROOT, PACKAGES).items() if file.name == "__init__.py"})
    assert sorted(installed) == found
