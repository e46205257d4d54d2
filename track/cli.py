"""The ``track`` command line (light-field volume trackstruction)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``track``; the trackstruction commands are not built yet."""
    sys.stderr.write(
        "track: volume trackstruction is not implemented yet in this version of hrvptm "
        "(tracked in the project's track issue)\n"
    )
    return 2
