"""Joining a Ray cluster that requires token authentication (Ray's ``RAY_AUTH_MODE=token``).

A driver without ``RAY_AUTH_MODE=token`` gets only ``ConnectionError: Failed to connect to
Ray cluster at ...`` from ``ray.init``; the reason, ``Unauthenticated: ... InvalidAuthToken``,
is in the warning lines Ray's GCS client writes to the process's stderr while it retries. A
driver with it but without the token gets ``ray.exceptions.AuthenticationError``. `init_ray`
holds stderr back while connecting (`held_stderr`), so that either case becomes one line naming
authentication and what to set.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from vitaplace.engine.base.errors import UserError

#: what Ray's GCS client writes when the cluster rejects a connection without a valid token
AUTH_SIGNS = ("Unauthenticated", "InvalidAuthToken")
#: what a driver needs to join such a cluster
HOW = ("set RAY_AUTH_MODE=token and give this driver the cluster's token: RAY_AUTH_TOKEN, a file named by "
       "RAY_AUTH_TOKEN_PATH, or ~/.ray/auth_token (`ray get-auth-token` on the head node prints it)")


@dataclass
class Held:
    """What the process wrote to stderr inside a `held_stderr` block (set when the block ends)."""

    text: str = ""


@contextlib.contextmanager
def held_stderr() -> Iterator[Held]:
    """Hold back everything written to file descriptor 2 inside the block, native code's too
    (Ray's C++ warnings and stack traces), in a temporary file; the caller decides from
    ``Held.text`` whether to show it."""
    held = Held()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as scratch:
        sys.stderr.flush()
        os.dup2(scratch.fileno(), 2)
        try:
            yield held
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            scratch.seek(0)
            held.text = scratch.read().decode(errors="replace")


def init_ray(ray: Any, address: str, option: str) -> None:
    """``ray.init(address=address)``; a failure caused by the cluster's token authentication is
    a `UserError` naming ``option`` (e.g. ``--ray HOST:PORT``) and `HOW`; any other failure is
    raised as Ray raised it. What Ray wrote to stderr meanwhile is passed on when it connected."""
    failure: BaseException | None = None
    with held_stderr() as held:
        try:
            ray.init(address=address)
        except Exception as exc:  # noqa: BLE001 - raised again below unless it is authentication
            failure = exc
    if failure is None:
        sys.stderr.write(held.text)
        return
    auth_error = getattr(getattr(ray, "exceptions", None), "AuthenticationError", ())
    if isinstance(failure, auth_error) or any(sign in held.text for sign in AUTH_SIGNS):
        raise UserError(f"{option}: the cluster requires token authentication and did not accept this driver; "
                        f"{HOW}") from None
    raise failure
