"""The revision of the source tree a result was made with (provenance of stored reports)."""

from __future__ import annotations

import subprocess
from functools import lru_cache
from pathlib import Path

#: The repository root of an installed-in-place (editable) checkout.
_ROOT = Path(__file__).resolve().parent.parent


@lru_cache(maxsize=1)
def source_revision() -> dict | None:
    """``{"commit": SHA-1, "modified": bool}`` of the git checkout the toolkit runs from.

    ``modified`` is True when tracked files differ from the commit (a result made with
    uncommitted code). None when the toolkit is not run from a git checkout (an installed
    wheel) or git is missing.
    """
    if not (_ROOT / ".git").exists():
        return None

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(_ROOT), *args],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()

    try:
        commit = git("rev-parse", "HEAD")
        modified = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "modified": modified}
