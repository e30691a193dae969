"""Joining clusters safely: Ray's token authentication, the installation every node must
share with the driver (Ray's probe and each SLURM task), and SLURM arrays driven through
stand-in ``sbatch`` / ``squeue`` / ``scancel`` commands on PATH (small shell scripts written
into the test's folder), as a cluster without accounting (no ``sacct``) would answer."""

from __future__ import annotations

import json
import os
import re
import socket
import time
from types import SimpleNamespace

import pytest
import yaml
from test_sweep import tiny_scenario

from vitaplace.engine.cli.main import main

#: what Ray 2.60's GCS client writes to stderr, once a second, when a driver without
#: RAY_AUTH_MODE=token connects to a cluster that requires a token (seen on a real head)
GCS_REFUSAL = ("[2026-12-03 14:43:13,106 W 10031 10031] gcs_client.cc:210: Failed to get cluster ID from GCS server: "
               "Unauthenticated: RPC error: InvalidAuthToken: Authentication token is missing or incorrect\n")

#: Ray 2.60's AuthenticationError message in token mode without a token
NO_TOKEN = "Token authentication is enabled but no authentication token was found"


@pytest.fixture
def listening(tmp_path):
    """A scenario file and a local address something listens on (the reachability check passes)."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**tiny_scenario(),
                                                     "methods": [{"name": "H", "plugin": "handcrafted"}]}))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield tmp_path, f"127.0.0.1:{s.getsockname()[1]}"


def test_a_ray_cluster_that_requires_a_token_is_named_in_one_line(listening, monkeypatch, capfd):
    """Both ways Ray reports a refused token: a ConnectionError after the GCS client's
    'Unauthenticated' lines on stderr (driver without RAY_AUTH_MODE=token), and Ray's own
    AuthenticationError (token mode, no token). A ConnectionError for another reason keeps
    Ray's message and says nothing of authentication."""
    ray = pytest.importorskip("ray")
    folder, address = listening

    def refused_by_gcs(address):
        os.write(2, GCS_REFUSAL.encode() * 3)
        raise ConnectionError(f"Failed to connect to Ray cluster at {address}")

    def no_token(address):
        raise ray.exceptions.AuthenticationError(NO_TOKEN)

    def down(address):
        os.write(2, b"gcs_client.cc:210: Failed to get cluster ID from GCS server: Unavailable\n")
        raise ConnectionError(f"Failed to connect to Ray cluster at {address}")

    args = ["sweep", str(folder / "s.yaml"), "--out", str(folder / "out"), "--ray", address]
    # Ray before token authentication (2.9, the declared minimum) has no AuthenticationError
    refusals = (refused_by_gcs, no_token) if hasattr(ray.exceptions, "AuthenticationError") else (refused_by_gcs,)
    for init in refusals:
        monkeypatch.setattr(ray, "init", lambda address, init=init, **_: init(address))
        monkeypatch.setattr(ray, "is_initialized", lambda: False)
        assert main(args) == 2
        lines = capfd.readouterr().err.strip().splitlines()
        assert len(lines) == 1, lines
        assert f"--ray {address}: the cluster requires token authentication" in lines[0], lines
        assert "set RAY_AUTH_MODE=token" in lines[0] and "RAY_AUTH_TOKEN" in lines[0], lines
    monkeypatch.setattr(ray, "init", lambda address, **_: down(address))
    assert main(args) == 2
    lines = capfd.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"Failed to connect to Ray cluster at {address}" in lines[0], lines
    assert "authentication" not in lines[0]
    assert not (folder / "out" / "seed-0").exists()


class OneNodeRay:
    """Stands in for a connected ``ray`` with one node; a task runs in this process when it is
    submitted; ``other_version`` makes the node answer with another vitaplace version."""

    def __init__(self, other_version: bool):
        self.other_version = other_version

    def nodes(self):
        return [{"Alive": True, "NodeID": "ab" * 28, "Resources": {"CPU": 2.0}}]

    def remote(self, function):
        task = SimpleNamespace(remote=function)
        return SimpleNamespace(options=lambda **_: task)

    def get(self, refs, timeout):
        return [{**found, "version": "0.0.0"} if self.other_version else found for found in refs]


def test_the_ray_installation_check_shows_native_stderr_only_when_it_fails(monkeypatch, capfd):
    """What the check writes to file descriptor 2 (as Ray's native stack traces are), on the
    driver and in the probe task, is held back when every node matches and shown when one
    does not, above the one-line reason."""
    pytest.importorskip("ray")
    import vitaplace.engine.cli.sweep as sweep
    from vitaplace.engine.base.errors import UserError

    same = {"version": "1.0", "commit": "abc", "dirty": False, "plugins": ["p=dist==1"]}

    def noisy_installation():
        os.write(2, b"*** SIGABRT received at time=1 on cpu 0 ***\n")
        return dict(same)

    monkeypatch.setattr(sweep, "installation", noisy_installation)
    assert sweep.check_ray_cluster(OneNodeRay(other_version=False), "n:1", 1, 0) is None
    assert "SIGABRT" not in capfd.readouterr().err
    with pytest.raises(UserError, match="node .* runs vitaplace 0.0.0"):
        sweep.check_ray_cluster(OneNodeRay(other_version=True), "n:1", 1, 0)
    assert capfd.readouterr().err.count("*** SIGABRT received at time=1 on cpu 0 ***\n") == 2  # driver and node


def test_installations_differ_by_version_commit_uncommitted_changes_or_plugins():
    from vitaplace.engine.cli.installation import installation, mismatch

    driver = {"version": "1.0", "commit": "abc", "dirty": False, "plugins": ["p=dist==1"]}
    assert mismatch(driver, {**driver, "host": "n1"}, "node n1") is None
    for key, value in {"version": "1.1", "commit": "abd", "dirty": True, "plugins": []}.items():
        reason = mismatch(driver, {**driver, key: value}, "node n1")
        assert reason is not None and reason.startswith("node n1 runs vitaplace")
        assert "this driver runs vitaplace 1.0" in reason
    changed = {**driver, "dirty": True, "plugins": []}
    assert "commit abc, with uncommitted changes; plugins none" in mismatch(driver, changed, "n")
    assert set(installation()) == set(driver)


# ---------------------------------------------------------------------- SLURM without a cluster

@pytest.fixture
def fake_slurm(tmp_path, monkeypatch):
    """Stand-ins for srun, sbatch, squeue and scancel on PATH. ``sbatch`` runs
    ``FOLDER/sbatch.sh`` (the test writes it), ``squeue`` prints ``FOLDER/queue`` (lines
    ``12_3 RUNNING``; then ``FOLDER/queue.next``, when there is one, replaces it) or, when
    ``FOLDER/squeue.err`` exists, prints that and fails, and ``scancel`` appends its arguments to
    ``FOLDER/scancelled``. Returns FOLDER."""
    pytest.importorskip("submitit", reason="submitit is not installed (pip install 'vitaplace[slurm]')")
    fake = tmp_path / "fake-slurm"
    fake.mkdir()
    scripts = {
        "srun": "exit 0",
        "sbatch": f'exec sh "{fake}/sbatch.sh" "$@"',
        "squeue": f'if [ -f "{fake}/squeue.err" ]; then cat "{fake}/squeue.err" >&2; exit 1; fi; '
                  f'cat "{fake}/queue" 2>/dev/null; '
                  f'[ -f "{fake}/queue.next" ] && mv "{fake}/queue.next" "{fake}/queue"; '
                  'exit 0',
        "scancel": f'echo "$@" >> "{fake}/scancelled"',
    }
    for name, body in scripts.items():
        (fake / name).write_text(f"#!/bin/sh\n{body}\n")
        (fake / name).chmod(0o755)
    (fake / "sbatch.sh").write_text(f'cp "$1" "{fake}/submitted.sh"; echo "Submitted batch job 4242"\n')
    monkeypatch.setenv("PATH", f"{fake}{os.pathsep}{os.environ['PATH']}")
    return fake


@pytest.fixture
def scenario_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}))
    return path


#: what sbatch (SLURM 22.05) writes when it refuses a job: a partition that does not exist,
#: GPUs on a partition without GRES, no slurm.conf (nor DNS SRV records), no controller
SBATCH_REFUSALS = {
    "partition": "sbatch: error: invalid partition specified: gpu\n"
                 "sbatch: error: Batch job submission failed: Invalid partition name specified",
    "gres": "sbatch: error: Batch job submission failed: Invalid generic resource (gres) specification",
    "no slurm.conf": "sbatch: error: resolve_ctls_from_dns_srv: res_nsearch error: Unknown host\n"
                     "sbatch: error: fetch_config: DNS SRV lookup failed\n"
                     "sbatch: error: _establish_config_source: failed to fetch config\n"
                     "sbatch: fatal: Could not establish a configuration source",
    "no controller": "sbatch: error: Batch job submission failed: Unable to contact slurm controller (connect failure)",
}


@pytest.mark.parametrize("case", sorted(SBATCH_REFUSALS))
def test_sbatch_refusing_the_array_is_one_line_with_its_own_message_and_exit_2(case, fake_slurm, scenario_file, capsys):
    message = SBATCH_REFUSALS[case]
    (fake_slurm / "sbatch.sh").write_text(f"cat >&2 <<'END'\n{message}\nEND\nexit 1\n")
    out = scenario_file.parent / "out"
    assert main(["sweep", str(scenario_file), "--seeds", "0", "1", "--out", str(out), "--no-progress",
                 "--slurm", "--time", "10", "--partition", "gpu"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "--slurm: sbatch refused the array job: " + "; ".join(message.splitlines()) in lines[0], lines
    assert not list(out.glob("seed-*")) and not list(out.glob(".sweep-marker-*"))
    assert not (out / "slurm").exists()  # no script or pickled job of the refused array left behind


def test_a_short_time_limit_and_a_bad_throttle_are_refused_before_anything_runs(scenario_file, capsys):
    base = ["sweep", str(scenario_file), "--out", str(scenario_file.parent / "out")]
    cases = {
        "--time 4: at least 5 minutes; submitit signals a task 90 s before its limit": ["--slurm", "--time", "4"],
        "--time 0:02:00: at least 5 minutes": ["--slurm", "local", "--time", "0:02:00"],
        "--max-parallel 0: expected a number of tasks at once, at least 1":
            ["--slurm", "--time", "5", "--max-parallel", "0"],
        "--max-parallel: only with --slurm": ["--max-parallel", "2"],
        "--max-parallel: throttles an array on a SLURM cluster":
            ["--slurm", "local", "--time", "5", "--max-parallel", "2"],
    }
    for message, extra in cases.items():
        code = main([*base, *extra])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and message in lines[0], (extra, lines)
    assert not (scenario_file.parent / "out").exists()


def test_a_task_on_a_node_with_other_code_fails_its_seed_in_one_line():
    from vitaplace.engine.cli.installation import installation
    from vitaplace.engine.cli.slurm import CheckedTask

    job = SimpleNamespace(seed=3)
    mine = installation()
    assert CheckedTask(lambda j: {"seed": j.seed, "rows": []}, mine)(job) == {"seed": 3, "rows": []}
    for key, value in {"version": "0.0.0+driver", "dirty": not mine["dirty"], "plugins": ["x=y==1"]}.items():
        result = CheckedTask(lambda j: pytest.fail("ran on a node with other code"), {**mine, key: value})(job)
        assert set(result) == {"seed", "failure"} and result["seed"] == 3
        assert re.fullmatch(r"node \S+ runs vitaplace .* but this driver runs vitaplace .*; install the same "
                            r"vitaplace and plugins on every node", result["failure"]), result


def result_of(folder, task_id, value):
    """Write task ``task_id``'s result file as a submitit task would."""
    from submitit.core.utils import JobPaths, cloudpickle_dump

    cloudpickle_dump(("success", value), JobPaths(folder, job_id=task_id, task_id=0).result_pickle)


def test_an_array_is_throttled_watched_by_squeue_alone_and_blocks_a_rerun_while_queued(
        fake_slurm, scenario_file, monkeypatch, capsys):
    """Three seeds, at most two at once, on a cluster without sacct: task 1 ends with a
    result, tasks 0 and 2 leave the queue without one and are lost after the margin (not
    waited for forever); the job id is recorded, and a rerun into OUT is refused while squeue
    still lists one of its tasks, allowed once it lists none."""
    import submitit

    import vitaplace.engine.cli.slurm as slurm
    from vitaplace.engine.cli.installation import installation
    from vitaplace.engine.cli.sweep import run_seed_reported

    monkeypatch.setattr(slurm, "LOST_MARGIN_S", 0.3)
    monkeypatch.setitem(slurm.POLL_S, "slurm", 0.05)
    polls = []

    def sleep(seconds):  # a driver that would wait forever fails the test within seconds
        polls.append(seconds)
        assert len(polls) < 200, "the driver is still waiting for tasks squeue no longer lists"
        time.sleep(seconds)

    monkeypatch.setattr(slurm, "time", SimpleNamespace(sleep=sleep, monotonic=time.monotonic))
    out = scenario_file.parent / "out"
    folder = out / "slurm"
    (fake_slurm / "queue").write_text("4242_1 RUNNING\n4242_2 RUNNING\n")
    ended = slurm.run_array(run_seed_reported, [0, 1, 2], slurm.SlurmSettings("slurm", 10, max_parallel=2), folder,
                            "vp")
    script = (fake_slurm / "submitted.sh").read_text()
    assert "#SBATCH --array=0-2%2\n" in script and f"#SBATCH --chdir={folder}\n" in script, script
    assert json.loads((folder / "job.json").read_text())["job"] == "4242"
    task = submitit.core.utils.DelayedSubmission.load(folder / "4242_0_submitted.pkl").function
    assert isinstance(task, slurm.CheckedTask) and task.task is run_seed_reported and task.driver == installation()
    result_of(folder, "4242_1", {"seed": 1, "rows": []})
    outcomes = {}
    for job, result, failure in ended:
        outcomes[job] = result if failure is None else failure
        (fake_slurm / "queue").write_text("")  # task 2 leaves the queue without a result
    assert outcomes[1] == {"seed": 1, "rows": []}
    for job in (0, 2):
        assert outcomes[job].startswith(f"its task 4242_{job} left the queue without a result"), outcomes
        assert outcomes[job].endswith(f"log: {folder}/4242_{job}_0_log.err"), outcomes
    assert sorted((fake_slurm / "scancelled").read_text().split()) == ["4242_0", "4242_2"]

    rerun = ["sweep", str(scenario_file), "--seeds", "0", "--out", str(out), "--no-progress", "--slurm", "--time", "10"]
    (fake_slurm / "queue").write_text("4242_2 COMPLETING\n")
    writing = out / "seed-2" / ".results.json.1a2b.part"  # what task 2 may still be writing
    writing.parent.mkdir(parents=True)
    writing.write_text("{")
    capsys.readouterr()
    assert main(rerun) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and (f"--out {out}: 1 task(s) of SLURM job 4242, an earlier sweep into this folder, are "
                                "still in the queue (COMPLETING)") in lines[0], lines
    assert writing.read_text() == "{" and [p.name for p in out.glob("seed-*")] == ["seed-2"]
    (fake_slurm / "squeue.err").write_text("squeue: error: Unable to contact slurm controller (connect failure)\n")
    with pytest.raises(slurm.UserError, match="cannot tell whether SLURM job 4242 .* is still running"):
        slurm.check_queue_clear(folder)
    (fake_slurm / "squeue.err").write_text("slurm_load_jobs error: Invalid job id specified\n")
    slurm.check_queue_clear(folder)  # squeue has forgotten the job: it ended


class QueuedTask:
    """A submitit task as `_wait` sees it under a `QueueWatch`: a result file, or none yet."""

    def __init__(self, folder, job_id):
        from submitit.core.utils import JobPaths

        self.job_id, self.paths, self.cancelled = job_id, JobPaths(folder, job_id=job_id, task_id=0), False

    def result(self):
        import pickle

        return pickle.loads(self.paths.result_pickle.read_bytes())[1]

    def cancel(self, check=True):
        self.cancelled = True


def test_a_task_running_past_its_limit_is_lost_and_an_interrupt_waits_for_the_queue(
        fake_slurm, tmp_path, monkeypatch, caplog):
    import vitaplace.engine.cli.slurm as slurm

    now = [0.0]
    watch = slurm.QueueWatch("7", limit_s=300.0, clock=lambda: now[0])
    (fake_slurm / "queue").write_text("7_0 RUNNING\n7_1 PENDING\n")
    assert watch.lost(["7_0", "7_1"]) == {}
    now[0] = 300.0 + slurm.LOST_MARGIN_S - 1
    assert watch.lost(["7_0", "7_1"]) == {}
    now[0] += 1  # the limit plus the margin since squeue first listed it running
    assert set(watch.lost(["7_0", "7_1"])) == {"7_0"}  # a pending task has no limit running yet
    (fake_slurm / "squeue.err").write_text("squeue: error: Unable to contact slurm controller\n")
    now[0] += 10 * slurm.LOST_MARGIN_S
    assert watch.lost(["7_0", "7_1"]) == {}  # squeue failed: nothing is declared lost on no news
    (fake_slurm / "squeue.err").unlink()

    (fake_slurm / "queue").write_text("7_1 RUNNING\n")  # ignores SIGTERM until SLURM's KillWait
    monkeypatch.setattr(slurm, "DRAIN_S", 0.2)
    tasks = [QueuedTask(tmp_path, "7_0"), QueuedTask(tmp_path, "7_1")]
    result_of(tmp_path, "7_0", {"seed": 0, "rows": []})
    waiting = slurm._wait(tasks, ["job0", "job1"], 0.01, slurm.QueueWatch("7", 300.0))
    assert next(waiting) == ("job0", {"seed": 0, "rows": []}, None)
    with caplog.at_level("INFO", logger="vitaplace"):
        waiting.close()  # what Ctrl-C in the driver's loop does to the iterator
    assert [t.cancelled for t in tasks] == [False, True]
    assert "1 task(s) of job 7 are still in the queue 0 s after cancelling" in caplog.text
    assert "KillWait" in caplog.text and "a rerun into this OUT is refused" in caplog.text
    caplog.clear()
    monkeypatch.setattr(slurm, "DRAIN_S", 5.0)
    (fake_slurm / "queue").write_text("7_1 RUNNING\n")
    (fake_slurm / "queue.next").write_text("")  # gone at the next look
    with caplog.at_level("INFO", logger="vitaplace"):
        slurm.QueueWatch("7", 300.0).drain()
    assert "the cancelled tasks of job 7 have left the queue" in caplog.text and "KillWait" not in caplog.text
