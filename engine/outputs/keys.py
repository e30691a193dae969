"""Cache keys: a stage's output is named by a hash of everything it depends on."""

from __future__ import annotations

import hashlib
import json
from typing import Any


def content_hash(*parts: Any) -> str:
    """A short, stable hash of JSON-serialisable parts (the cache key of a stage)."""
    text = json.dumps(parts, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]
