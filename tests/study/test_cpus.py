"""The CPUs this process may use: affinity, SLURM's allocation and the user's override, and
the worker pools and BLAS threads sized from them."""

import json
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
    for name in (cpus.SLURM_ENV, cpus.OVERRIDE_ENV, cpus.BLAS_ENV, "LOKY_MAX_CPU_COUNT"):
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


def test_a_container_s_cpu_quota_counts_as_the_affinity_does(four_cpus, monkeypatch):
    """A cgroup quota of 1.5 CPUs (cpu.max "150000 100000") on the 4 pinned CPUs: 2, rounded up
    as loky rounds it (a quota of 1.5 keeps two threads busy 75 % of the time each)."""
    from joblib.externals.loky.backend import context

    real_exists, real_open = os.path.exists, open
    monkeypatch.setattr(os.path, "exists", lambda path: path == "/sys/fs/cgroup/cpu.max" or real_exists(path))

    def quota(path, *args, **kwargs):
        if path == "/sys/fs/cgroup/cpu.max":
            import io
            return io.StringIO("150000 100000\n")
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(context, "open", quota, raising=False)
    assert cpus.usable_cpus() == 2
    monkeypatch.setenv(cpus.OVERRIDE_ENV, "1")
    assert cpus.usable_cpus() == 1


def test_one_blas_thread_per_process_unless_asked_and_never_more_than_the_share(four_cpus, monkeypatch):
    assert cpus.blas_threads() == 1 and cpus.blas_threads(processes=4) == 1
    monkeypatch.setenv(cpus.BLAS_ENV, "3")
    assert cpus.blas_threads() == 3  # asked for, and 3 <= 4 usable CPUs
    assert cpus.blas_threads(processes=2) == 2  # 2 processes x 2 threads = the 4 CPUs
    assert cpus.blas_threads(processes=3) == 1 and cpus.blas_threads(processes=8) == 1
    monkeypatch.setenv(cpus.BLAS_ENV, "16")
    assert cpus.blas_threads() == 4
    monkeypatch.setenv(cpus.OVERRIDE_ENV, "2")
    assert cpus.blas_threads() == 2
    for bad in ("0", "all", "-2"):
        monkeypatch.setenv(cpus.BLAS_ENV, bad)
        with pytest.raises(UserError, match=f"{cpus.BLAS_ENV}='{bad}': expected a positive whole number"):
            cpus.blas_threads()


def test_the_api_and_the_gymnasium_environment_set_blas_threads_first(monkeypatch, tmp_path):
    """`vitaplace.run`, `simulate`, `fit_extractor` and `WhiskEyeEnv` configure BLAS threads
    before anything else, even before they check their arguments (each call here has a bad one,
    so without the configuration it fails at once, some other way); the CLI's test is below."""
    import vitaplace
    from vitaplace.engine.sim import gym_env

    class Configured(Exception):
        pass

    def configure(processes: int = 1) -> int:
        raise Configured

    monkeypatch.setattr(cpus, "configure_blas_threads", configure)
    monkeypatch.setattr(gym_env, "configure_blas_threads", configure)
    for call in (lambda: vitaplace.run("quickstart", out=tmp_path / "out", until="nowhere"),
                 lambda: vitaplace.simulate("e1", kind="nowhere"), lambda: vitaplace.fit_extractor("handcrafted", None),
                 lambda: gym_env.WhiskEyeEnv(tmp_path / "nowhere.yaml")):
        with pytest.raises(Configured):
            call()


SMALL_BATCH_THREADS = """
import numpy, threadpoolctl
from vitaplace.engine.base import cpus
def threads():
    return sorted({p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"})
seen = [threads()]
for rows in (cpus.SMALL_BATCH + 1, cpus.SMALL_BATCH, 1):
    with cpus.small_batch_threads(rows):
        seen.append(threads())
seen.append(threads())
print("SEEN", seen)
"""


@pytest.mark.parametrize("pool, expected", [
    ("2", "SEEN [[2], [2], [1], [1], [2]]"),  # a small batch on one thread, the pool's two restored after
    ("1", "SEEN [[1], [1], [1], [1], [1]]"),
], ids=["two", "one"])
def test_small_batches_run_on_one_blas_thread(pool, expected):
    env = {k: v for k, v in os.environ.items() if k not in (*cpus.THREAD_ENVS, cpus.OVERRIDE_ENV)}
    result = subprocess.run([sys.executable, "-c", SMALL_BATCH_THREADS], env={**env, "OPENBLAS_NUM_THREADS": pool},
                            capture_output=True, text=True, timeout=120)
    assert expected in result.stdout, result.stdout + result.stderr


def test_the_settling_solver_s_compacted_batches_ask_for_small_batch_threads(monkeypatch):
    """Every chunk of steps runs inside `small_batch_threads` of its batch's size: the full
    batch of 8 first, then the compacted ones as samples stop."""
    import contextlib

    import numpy as np

    import vitaplace.engine.network.inference as inference
    from vitaplace.engine.network.backends import NumpyBackend
    from vitaplace.engine.network.pc import Network
    from vitaplace.engine.network.solver import make_solver

    sizes: list[int] = []

    @contextlib.contextmanager
    def recorded(rows: int):
        sizes.append(rows)
        yield

    monkeypatch.setattr(inference, "small_batch_threads", recorded)
    config = {"modalities": {"visual": {"input_size": 9, "layers": [6], "eta_y": 0.02, "eta_w": 0.0,
                                        "threshold": 0.0}},
              "joint": {"size": 3, "eta_y": 0.02, "eta_w": 0.0, "threshold": 0.0}, "activation": "tanh", "slope": 0.2}
    net = Network(config, seed=5, backend=NumpyBackend(np.float64))
    x = {"visual": np.random.default_rng(2).random((8, 9)) * np.linspace(0.05, 1.0, 8)[:, None]}
    result = net.infer(x, max_steps=2000, solver=make_solver("gd", rtol=1e-3), latent_prior=0.1)
    assert result.settled.all() and sizes[0] == 8 and min(sizes) < 8, sizes
    assert sizes == sorted(sizes, reverse=True)  # a batch only shrinks


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
    ({}, "BLAS [1] 1"),  # one thread unless asked
    ({cpus.BLAS_ENV: "2"}, "BLAS [2] 2"),  # asked for two (this machine has 2 usable CPUs)
    ({cpus.BLAS_ENV: "2", cpus.SLURM_ENV: "1"}, "BLAS [1] 1"),  # SLURM's allocation caps the request
    ({cpus.BLAS_ENV: "2", "OPENBLAS_NUM_THREADS": "1"}, "BLAS [1] 1"),  # the user's lower setting stays
], ids=["default", "asked", "slurm", "user"])
def test_the_cli_sets_one_blas_thread_or_the_request_within_the_allocation(variables, expected):
    if cpus.BLAS_ENV in variables and len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs 2 usable CPUs")
    env = {k: v for k, v in os.environ.items() if k not in (*cpus.THREAD_ENVS, cpus.OVERRIDE_ENV, cpus.BLAS_ENV)}
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


def test_the_blas_libraries_name_the_kernel_openblas_runs():
    """``OPENBLAS_CORETYPE`` picks OpenBLAS's kernel family: a process started with Sandybridge
    and one thread lists numpy's OpenBLAS with that architecture and thread count."""
    code = "import json; from vitaplace.engine.base import cpus; print(json.dumps(cpus.blas_libraries()))"
    env = {**os.environ, "OPENBLAS_CORETYPE": "Sandybridge", "OPENBLAS_NUM_THREADS": "1"}
    listed = json.loads(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                       check=True).stdout)
    assert {"library": "openblas", "architecture": "Sandybridge", "threads": 1} in [
        {k: lib[k] for k in ("library", "architecture", "threads")} for lib in listed]
