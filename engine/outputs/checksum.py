"""Seals on stage outputs: one "done" rule for every stage, and a cache that verifies itself.

When a stage has written its output (a file, or a folder of files) it *seals* it:
``<output>.seal`` beside it, written atomically after the output, holds the stage key the
output was made for and the SHA-256 of its content. A stage counts as done only when its
output is there and its seal holds the same key and a matching digest; a missing seal, a
different key, a truncated file, a flipped byte or a file missing from a folder means the
stage runs again, with one log line saying why.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from vitaplace.engine.base.atomic import write_text_atomic

_CHUNK = 1 << 22


def digest(path: Path) -> str:
    """SHA-256 of a file's bytes, or of a folder's files (relative names and contents, in order)."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for file in files:
        if file != path:
            h.update(str(file.relative_to(path)).encode() + b"\0")
        with open(file, "rb") as f:
            while chunk := f.read(_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def seal_path(path: Path) -> Path:
    return path.with_name(path.name + ".seal")


def seal(path: Path, key: str) -> None:
    """Record that ``path`` is the output of the stage with ``key``, and its digest."""
    write_text_atomic(seal_path(path), json.dumps({"key": key, "sha256": digest(path)}))


def sealed_digest(path: Path) -> str:
    """The digest recorded in ``path``'s seal (call once the stage is done, i.e. `check` passed
    or `seal` was just written)."""
    return str(json.loads(seal_path(path).read_text())["sha256"])


def check(path: Path, key: str) -> str | None:
    """None when ``path`` is the intact output for ``key``; else why it cannot be used
    ("absent" when neither output nor seal exists: simply not made yet)."""
    sealed = seal_path(path)
    if not sealed.exists():
        return "absent" if not path.exists() else "not sealed (written by an interrupted or older run)"
    if not path.exists():
        return "missing"
    try:
        record = json.loads(sealed.read_text())
    except (OSError, ValueError):
        return "sealed unreadably"
    if record.get("key") != key:
        return "made for other settings"
    if record.get("sha256") != digest(path):
        return "damaged (its content no longer matches its checksum)"
    return None
