"""hrvptm runs track through its library (track.pipeline), never its command line."""

from __future__ import annotations

import ast
from pathlib import Path


def test_hrvptm_uses_the_track_library_not_its_command_line():
    """No module of hrvptm imports track.cli (the study runner calls track.pipeline)."""
    root = Path(__file__).resolve().parents[2] / "hrvptm"
    offenders = []
    for path in sorted(root.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            offenders += [f"{path.name}: {n}" for n in names if n == "track.cli"]
    assert offenders == []
    assert "track.pipeline" in (root / "stages.py").read_text(encoding="utf-8")
