"""The benchmark as data (``vitaplace export``, docs/DATA.md): a scenario's evaluations in the
layout VPR tools read (`vitaplace.engine.export.vpr`) and its runs as a versioned,
checksummed package (`vitaplace.engine.export.package`) with its reader, `read_package`."""

from vitaplace.engine.export.package import Package, read_package

__all__ = ["Package", "read_package"]
