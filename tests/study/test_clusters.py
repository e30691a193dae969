"""Joining clusters safely: Ray's token authentication, the installation every node must
share with the driver (Ray's probe and each SLURM task), and SLURM arrays driven through
stand-in ``sbatch`` / ``squeue`` / ``scancel`` commands on PATH (small shell scripts written
into the test's folder), as a cluster without accounting (no ``sacct``) would answer."""

from __future__ import annotations

import os
import socket

import pytest
import yaml
from test_sweep import tiny_scenario

from vitaplace.engine.cli.main import main

#: what Ray 2.60's GCS client writes to stderr, once a second, when a driver without
#: RAY_AUTH_MODE=token connects to a cluster that requires a token (seen on a real head)
GCS_REFUSAL = ("[2026-12-03 14:43:13,106 W 10031 10031] gcs_client.cc:210: Failed to get cluster ID from GCS server: "
               "Unauthenticated: RPC error: InvalidAuthToken: Authentication token is missing or incorrect\n")


@pytest.fixture
def listening(tmp_path):
    """A scenario file and a local address something listens on (the reachability check passes)."""
    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**tiny_scenario(), "methods": [{"name": "H", "plugin": "handcrafted"}]}))
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
    from ray._private.authentication.authentication_constants import TOKEN_AUTH_ENABLED_BUT_NO_TOKEN_FOUND_ERROR_MESSAGE

    folder, address = listening

    def refused_by_gcs(address):
        os.write(2, GCS_REFUSAL.encode() * 3)
        raise ConnectionError(f"Failed to connect to Ray cluster at {address}")

    def no_token(address):
        raise ray.exceptions.AuthenticationError(TOKEN_AUTH_ENABLED_BUT_NO_TOKEN_FOUND_ERROR_MESSAGE)

    def down(address):
        os.write(2, b"gcs_client.cc:210: Failed to get cluster ID from GCS server: Unavailable\n")
        raise ConnectionError(f"Failed to connect to Ray cluster at {address}")

    args = ["sweep", str(folder / "s.yaml"), "--out", str(folder / "out"), "--ray", address]
    for init in (refused_by_gcs, no_token):
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


def test_installations_differ_by_version_commit_uncommitted_changes_or_plugins():
    from vitaplace.engine.cli.installation import installation, mismatch

    driver = {"version": "1.0", "commit": "abc", "dirty": False, "plugins": ["p=dist==1"]}
    assert mismatch(driver, {**driver, "host": "n1"}, "node n1") is None
    for key, value in {"version": "1.1", "commit": "abd", "dirty": True, "plugins": []}.items():
        reason = mismatch(driver, {**driver, key: value}, "node n1")
        assert reason is not None and reason.startswith("node n1 runs vitaplace") and "this driver runs vitaplace 1.0" in reason
    assert "commit abc, with uncommitted changes; plugins none" in mismatch(driver, {**driver, "dirty": True, "plugins": []}, "n")
    assert set(installation()) == set(driver)
