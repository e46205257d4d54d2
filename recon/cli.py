"""The ``recon`` command line (light-field volume reconstruction)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``recon``; the reconstruction commands are not built yet."""
    sys.stderr.write(
        "recon: volume reconstruction is not implemented yet in this version of hrvptm "
        "(tracked in the project's recon issue)\n"
    )
    return 2
