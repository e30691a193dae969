"""Command-line interface: `vitaplace run|simulate|train|evaluate|report|validate|plugins`."""
import argparse
import sys

from vitaplace.engine import __version__


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vitaplace", description=__doc__)
    parser.add_argument("--version", action="version", version=f"vitaplace {__version__}")
    parser.parse_args(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
