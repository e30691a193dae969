"""Shared libraries found as the dynamic loader finds them: the one probe behind the GL
backend choice (EGL, OSMesa), the CUDA driver check and libcublas."""

from __future__ import annotations

import ctypes
from collections.abc import Iterable


def first_loadable(names: Iterable[str | None]) -> ctypes.CDLL | None:
    """The first of ``names`` (sonames or paths; None and "" skipped) that loads, loaded, or
    None when none does. The loader's own search applies, so LD_LIBRARY_PATH counts."""
    for name in names:
        if not name:
            continue
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None
