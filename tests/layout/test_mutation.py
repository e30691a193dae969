"""The mutation script's list stays true to the code (fast: no mutant is run).

Every module of the package over `MIN_LINES` lines has a mutant, every mutant's snippet
occurs exactly once in its module, and every test a mutant names exists.
"""

import ast
import importlib.util
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mutation():
    spec = importlib.util.spec_from_file_location("mutation", ROOT / "tests" / "mutation.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["mutation"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    del sys.modules["mutation"]


def test_every_module_over_40_lines_has_a_mutant(mutation):
    needing = mutation.modules_needing_mutants()
    assert "engine/network/pc.py" in needing and "engine/base/errors.py" not in needing  # 606 and 7 lines
    assert mutation.uncovered() == []


def test_every_snippet_applies_exactly_once(mutation):
    assert mutation.stale(mutation.MUTANTS + [mt for mt, _ in mutation.EQUIVALENT]) == []


def test_a_snippet_that_no_longer_applies_is_named(mutation, tmp_path):
    (tmp_path / "engine" / "network").mkdir(parents=True)
    (tmp_path / "engine" / "network" / "pc.py").write_text("LATENT_INIT = 0.2\n")
    gone = mutation.Mutant("pc: latent init", "pc", "LATENT_INIT = 0.1", "LATENT_INIT = 0.0", ())
    assert mutation.stale([gone], tmp_path) == [
        "'pc: latent init': its snippet occurs not exactly once in engine/network/pc.py (0 times)"]


def test_every_named_test_exists(mutation):
    defined: dict[str, set[str]] = {}
    for mt in mutation.MUTANTS:
        assert mt.tests, mt.name
        for node in mt.tests:
            file, _, name = node.partition("::")
            name = name.partition("[")[0]  # a parametrised test's id
            if file not in defined:
                tree = ast.parse((ROOT / file).read_text())
                defined[file] = {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
            assert not name or name in defined[file], f"{mt.name}: {node} does not exist"


def test_a_known_defect_is_marked_bug_and_fails_while_xfail_stops_the_session(tmp_path):
    """The suite's conftest refuses ``xfail``; a ``bug``-marked test runs and fails like any other."""
    import subprocess
    import sys

    tests = Path(__file__).resolve().parents[1]
    (tmp_path / "test_defects.py").write_text(
        "import pytest\n\n@pytest.mark.bug('adds wrong')\ndef test_known():\n    assert 1 + 1 == 3\n")
    run = [sys.executable, "-m", "pytest", "-q", "-p", "conftest", "--rootdir", str(tmp_path), "-c",
           str(tests.parent / "pyproject.toml")]
    env = {**os.environ, "PYTHONPATH": str(tests)}
    bug = subprocess.run([*run, str(tmp_path / "test_defects.py")], capture_output=True, text=True, env=env,
                         cwd=tmp_path)
    assert bug.returncode == 1 and "1 failed" in bug.stdout, bug.stdout + bug.stderr
    (tmp_path / "test_defects.py").write_text(
        "import pytest\n\n@pytest.mark.xfail\ndef test_hidden():\n    assert 1 + 1 == 3\n")
    hidden = subprocess.run([*run, str(tmp_path / "test_defects.py")], capture_output=True, text=True, env=env,
                            cwd=tmp_path)
    output = hidden.stdout + hidden.stderr
    assert hidden.returncode == 4 and "xfail hides a known defect" in output, output
