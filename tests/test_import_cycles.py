"""Lint: the package's import graph has no cycle; no function is longer than `MAX_FUNCTION_LINES`;
the plugin API keeps its documented import paths.

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
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

ROOT = Path(__file__).resolve().parent.parent
#: source folder -> the package it installs as (pyproject's package-dir)
PACKAGES = {"api": "vitaplace", "engine": "vitaplace.engine", "kernels": "vitaplace.kernels",
            "plugins": "vitaplace.plugins"}
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
    """Plugins written against docs/plugins.md keep working: each ``from vitaplace... import``
    line of its examples imports (``vitaplace.engine.dataset`` re-exports `Run` from
    ``vitaplace.engine.data.dataset``)."""
    lines = sorted(set(re.findall(r"^from vitaplace[\w.]* import [^\n]+$", (ROOT / "docs" / "plugins.md").read_text(),
                                  re.MULTILINE)))
    assert any("vitaplace.engine.dataset import Run" in line for line in lines)
    for line in lines:
        exec(line, {})  # noqa: S102 - the documented line itself
    from vitaplace.engine.data.dataset import Run as RunFile
    from vitaplace.engine.dataset import Run

    assert Run is RunFile


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
    assert long_functions(tmp_path) == [f"engine/long.py:{MAX_FUNCTION_LINES + 3} too_long ({MAX_FUNCTION_LINES + 1} lines)"]
