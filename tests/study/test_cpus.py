"""The CPUs this process may use: affinity, SLURM's allocation and the user's override, and
the worker pools and BLAS threads sized from them."""

import os
import subprocess
import sys

import pytest
import yaml

import vitaplace.engine.cli.sweep as sweep
from vitaplace.engine.base import cpus
from vitaplace.engine.base.errors import UserError


@pytest.fixture
def four_cpus(monkeypatch):
    """A process pinned to CPUs 0-3 of a larger machine, with no SLURM or override variables."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 64)
    for name in (cpus.SLURM_ENV, cpus.OVERRIDE_ENV):
        monkeypatch.delenv(name, raising=False)


def test_usable_cpus_is_the_smallest_of_affinity_slurm_and_override(four_cpus, monkeypatch):
    assert cpus.usable_cpus() == 4  # the affinity, not the machine's 64
    monkeypatch.setenv(cpus.SLURM_ENV, "3")
    assert cpus.usable_cpus() == 3
    monkeypatch.setenv(cpus.OVERRIDE_ENV, "2")
    assert cpus.usable_cpus() == 2
    monkeypatch.setenv(cpus.SLURM_ENV, "16")  # an allocation larger than the affinity: the affinity
    monkeypatch.delenv(cpus.OVERRIDE_ENV)
    assert cpus.usable_cpus() == 4
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(cpus.OVERRIDE_ENV, bad)
        with pytest.raises(UserError, match=f"{cpus.OVERRIDE_ENV}='{bad}': expected a positive whole number"):
            cpus.usable_cpus()


def test_a_local_sweep_starts_one_worker_per_usable_cpu(four_cpus, tmp_path, monkeypatch):
    from vitaplace.engine.config.loading import load_scenario

    data = {"name": "tiny", "train": {"environment": "e1", "run": {"kind": "foraging", "n_samples": 5}},
            "evaluations": [{"name": "E1", "environment": "e1", "run": {"kind": "route", "n_samples": 5}}],
            "methods": [{"name": "H", "plugin": "handcrafted"}]}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    scenario, resolved = load_scenario(tmp_path / "s.yaml")
    widths = []

    def ended(jobs, workers):  # stands in for the pool: records its width, runs nothing
        widths.append(workers)
        return iter(())

    monkeypatch.setattr(sweep, "_local", ended)
    for cpus_per_job, seeds, expected in ((1, range(8), 4), (2, range(8), 2), (1, range(3), 3), (8, range(8), 1)):
        sweep.run_sweep(scenario, resolved, list(seeds), tmp_path / "out", progress=False, cpus_per_job=cpus_per_job)
        assert widths.pop() == expected, (cpus_per_job, seeds)


BLAS_THREADS = """
import threadpoolctl
print("BLAS", sorted({p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"}),
      os.environ.get("OPENBLAS_NUM_THREADS"))
"""


@pytest.mark.parametrize("variables, expected", [
    ({cpus.SLURM_ENV: "1"}, "BLAS [1] 1"),  # SLURM's allocation, applied by the CLI
    ({cpus.SLURM_ENV: "2", "OPENBLAS_NUM_THREADS": "1"}, "BLAS [1] 1"),  # the user's lower setting stays
])
def test_the_cli_sizes_blas_threads_to_the_allocation(variables, expected):
    env = {k: v for k, v in os.environ.items() if k not in (*cpus.THREAD_ENVS, cpus.OVERRIDE_ENV)}
    code = f"import os, sys\nfrom vitaplace.engine.cli.main import main\nmain(['plugins'])\n{BLAS_THREADS}"
    result = subprocess.run([sys.executable, "-c", code], env={**env, **variables}, capture_output=True, text=True,
                            timeout=120)
    assert expected in result.stdout, result.stdout + result.stderr


def test_a_pool_worker_keeps_its_share_when_its_seed_asks_for_the_allocation():
    """The driver set 2 BLAS threads; a worker's initializer caps it at 1, and the seed's own
    call for every usable CPU (2) must not raise it again: a cap only goes down."""
    env = {k: v for k, v in os.environ.items() if k not in (*cpus.THREAD_ENVS, cpus.OVERRIDE_ENV)}
    code = (f"import os\nfrom vitaplace.engine.base.cpus import limit_blas_threads\n"
            f"print('CAPS', limit_blas_threads(1), limit_blas_threads(2))\n{BLAS_THREADS}")
    result = subprocess.run([sys.executable, "-c", code], env={**env, "OPENBLAS_NUM_THREADS": "2"},
                            capture_output=True, text=True, timeout=120)
    assert "CAPS 1 1" in result.stdout and "BLAS [1] 1" in result.stdout, result.stdout + result.stderr


def test_the_first_library_the_loader_finds_is_loaded_and_none_when_none_is():
    import ctypes

    from vitaplace.engine.base.libraries import first_loadable

    libc = first_loadable([None, "", "libvitaplace-missing.so.9", "libc.so.6"])
    assert isinstance(libc, ctypes.CDLL) and libc._name == "libc.so.6"
    assert first_loadable(["libvitaplace-missing.so.9", None]) is None and first_loadable([]) is None
