"""Texture image files, checked before MuJoCo reads them.

MuJoCo picks a texture file's decoder by the file's extension (``.png``, in any case, is
PNG; a name without an extension it knows is "unsupported content type: ''") and finds a
missing file, a folder or bytes that are not a PNG only when it compiles the model.
`png_problem` says the same in words when an environment is loaded, from the file's name and
its first 24 bytes: the PNG signature and the ``IHDR`` chunk that must follow it (the PNG
specification, sections 5.2 and 11.2.2). A PNG damaged past its header passes here and is
MuJoCo's to refuse when it compiles the model (`vitaplace.engine.sim.model.ModelCompileError`).
"""

from __future__ import annotations

import stat
import struct
from pathlib import Path

__all__ = ["PNG_SIGNATURE", "png_problem"]

#: the eight bytes every PNG file starts with
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(path: Path) -> str | None:
    """Why MuJoCo cannot read ``path`` as a PNG texture (a few words: "no such file", "is a
    folder", ...), or None: a regular, readable file whose name ends in ``.png`` (any case),
    starting with PNG's signature and an ``IHDR`` chunk of non-zero width and height."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return "no such file"
    except (OSError, ValueError) as exc:  # ValueError: a name holding a NUL byte
        return f"cannot be read ({getattr(exc, 'strerror', None) or exc})"
    if stat.S_ISDIR(mode):
        return "is a folder"
    if not stat.S_ISREG(mode):
        return "is not a regular file"
    if path.suffix.lower() != ".png":
        return "does not end in .png (MuJoCo reads a texture file by its extension)"
    try:
        with path.open("rb") as file:
            head = file.read(24)
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if not head.startswith(PNG_SIGNATURE):
        return "is empty" if not head else "is not a PNG image (it does not start with PNG's signature)"
    if len(head) < 24 or head[12:16] != b"IHDR" or 0 in struct.unpack(">II", head[16:24]):
        return "is a damaged PNG image (no header giving its width and height)"
    return None
