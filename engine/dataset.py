"""Plugin-API import path kept for plugins written against the earlier docs/plugins.md:
``from vitaplace.engine.dataset import Run``. Run files live in `vitaplace.engine.data.dataset`."""

from vitaplace.engine.data.dataset import Run

__all__ = ["Run"]
