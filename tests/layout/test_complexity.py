"""Lint: no function of the package is too branchy to follow, no module of it too long to read.

Cyclomatic complexity is radon's (`radon.complexity.cc_visit`): 1 for the function, plus 1
for every ``if``, ``elif``, ``for``, ``while``, ``except``, ``with``, ``assert``, comprehension
and boolean operator (``and``/``or``), as radon's documentation counts it. Every function and
method under api/, engine/, kernels/ and plugins/ counts, closures included; a failure names
each as ``file:line name (complexity)``. A module under those folders over `MAX_MODULE_LINES`
lines fails as ``file (N lines)``. radon >= 1.3 (the test extra): the first with the closures and
inner classes of a block (``Function.closures``, ``Class.inner_classes``).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from radon.complexity import cc_visit
from radon.visitors import Class, Function

ROOT = Path(__file__).resolve().parents[2]
#: the package's source folders
FOLDERS = ("api", "engine", "kernels", "plugins")
#: the highest cyclomatic complexity a function or method may have
MAX_COMPLEXITY = 20
#: the most lines a module of the package may have
MAX_MODULE_LINES = 600


def _functions(blocks) -> Iterator[Function]:
    """Every function, method and closure among radon's ``blocks``, each once."""
    for block in blocks:
        if isinstance(block, Function):
            yield block
            yield from _functions(block.closures)
        elif isinstance(block, Class):
            yield from _functions(block.inner_classes)
            # a class's methods: cc_visit lists those of a top-level class at the top level too
            if block.methods and block.methods[0] not in blocks:
                yield from _functions(block.methods)


def complex_functions(root: Path, limit: int = MAX_COMPLEXITY) -> list[str]:
    """``file:line name (complexity)`` of every function or method under the source folders
    of ``root`` whose cyclomatic complexity is over ``limit``."""
    found = []
    for folder in FOLDERS:
        for file in sorted((root / folder).rglob("*.py")):
            for function in sorted(_functions(cc_visit(file.read_text())), key=lambda f: f.lineno):
                if function.complexity > limit:
                    found.append(f"{file.relative_to(root).as_posix()}:{function.lineno} {function.fullname} "
                                 f"({function.complexity})")
    return found


def long_modules(root: Path, limit: int = MAX_MODULE_LINES) -> list[str]:
    """``file (N lines)`` of every module under the source folders of ``root`` longer than
    ``limit`` lines."""
    found = []
    for folder in FOLDERS:
        for file in sorted((root / folder).rglob("*.py")):
            length = len(file.read_text().splitlines())
            if length > limit:
                found.append(f"{file.relative_to(root).as_posix()} ({length} lines)")
    return found


def test_no_function_of_the_package_is_over_complexity_20():
    assert complex_functions(ROOT) == []


def test_no_module_of_the_package_is_over_600_lines():
    assert long_modules(ROOT) == []


def _branches(n: int) -> str:
    """The body of a function with ``n`` ``if`` statements in a row and nothing else that
    branches: by radon's rule (1, plus 1 per ``if``) its complexity is 1 + n."""
    return "".join(f"    if x == {i}:\n        x += 1\n" for i in range(n)) + "    return x\n"


def test_the_complexity_check_bites(tmp_path):
    (tmp_path / "engine").mkdir()
    (tmp_path / "plugins").mkdir()
    # fits: 1 + 19 ifs = 20, the limit itself; too_complex: 1 + 20 ifs = 21
    (tmp_path / "engine" / "branchy.py").write_text(
        f"def fits(x):\n{_branches(MAX_COMPLEXITY - 1)}\n\ndef too_complex(x):\n{_branches(MAX_COMPLEXITY)}"
    )
    # a method and a closure count too: 1 + 20 ifs = 21 each; the enclosing function is 1
    method = "".join(f"    {line}\n" if line else "\n" for line in
                     f"def method(self, x):\n{_branches(MAX_COMPLEXITY)}".splitlines())
    closure = "".join(f"    {line}\n" for line in f"def inner(x):\n{_branches(MAX_COMPLEXITY)}".splitlines())
    (tmp_path / "plugins" / "nested.py").write_text(
        f"class Plugin:\n{method}\n\ndef outer():\n{closure}    return inner\n"
    )
    fits_lines = 1 + 2 * (MAX_COMPLEXITY - 1) + 1
    assert complex_functions(tmp_path) == [
        f"engine/branchy.py:{fits_lines + 3} too_complex ({MAX_COMPLEXITY + 1})",
        f"plugins/nested.py:2 Plugin.method ({MAX_COMPLEXITY + 1})",
        f"plugins/nested.py:{2 + 2 * MAX_COMPLEXITY + 1 + 3 + 1} inner ({MAX_COMPLEXITY + 1})",
    ]


def test_the_module_length_check_bites(tmp_path):
    for folder in ("engine/sub", "kernels", "docs"):
        (tmp_path / folder).mkdir(parents=True)
    lines = "".join(f"x{i} = {i}\n" for i in range(MAX_MODULE_LINES))
    (tmp_path / "engine" / "fits.py").write_text(lines)
    for long in ("engine/sub/long.py", "kernels/long.py", "docs/long.py"):  # docs/ is not the package's
        (tmp_path / long).write_text(lines + "y = 0\n")
    assert long_modules(tmp_path) == [f"{folder}/long.py ({MAX_MODULE_LINES + 1} lines)"
                                      for folder in ("engine/sub", "kernels")]
