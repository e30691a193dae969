"""Content checksums of cached artifacts, so the cache verifies itself.

After a stage writes an artifact (a file, or a folder of files) it *seals* it: the SHA-256
of its content goes to ``<artifact>.sha256`` beside it, written atomically after the
artifact. Before a stage trusts a cached artifact it checks the seal: a missing seal, a
missing artifact or a different digest (a truncated file, a flipped byte, a file deleted
from a model folder) means the artifact is recomputed, with one log line saying why.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from vitaplace.engine.atomic import write_text_atomic

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
    return path.with_name(path.name + ".sha256")


def seal(path: Path) -> None:
    """Record ``path``'s digest beside it."""
    write_text_atomic(seal_path(path), digest(path))


def check(path: Path) -> str | None:
    """None when ``path`` is intact (present and matching its seal), else why it is not."""
    if not path.exists():
        return None if not seal_path(path).exists() else "missing"
    if not seal_path(path).exists():
        return "not sealed (written by an interrupted or older run)"
    if digest(path) != seal_path(path).read_text().strip():
        return "damaged (its content no longer matches its checksum)"
    return None
