"""Shared fixtures: the devices kernel and backend tests run on.

Every device test is parametrised over ``cpu`` and ``cuda``; the ``cuda`` half carries the
``cuda`` marker and is skipped where no CUDA driver and device exist (CI), so a GPU machine
runs both halves with the same command (``pytest -m cuda`` for the GPU half alone).
"""

import functools

import pytest


@functools.cache
def cuda_present() -> bool:
    from vitaplace.engine.backends import cuda_available

    return cuda_available()


DEVICES = [
    pytest.param("cpu", id="cpu"),
    pytest.param("cuda", id="cuda", marks=pytest.mark.cuda),
]


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    """A Warp device name; the cuda half skips without a CUDA device."""
    if request.param == "cuda" and not cuda_present():
        pytest.skip("no CUDA device")
    return request.param
