"""Dependency direction (docs/user_guide): hrvbase imports none of the packages; track
imports neither lfsim nor recon (only hrvbase); recon may import lfsim; nothing below hrvptm
imports hrvptm; hrvptm uses track through its library, never its command line."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = {
    "hrvbase": {"lfsim", "recon", "track", "hrvptm", "mitsuba", "drjit", "scipy", "skimage"},
    "lfsim": {"recon", "track", "hrvptm"},
    "recon": {"track", "hrvptm"},
    "track": {"lfsim", "recon", "hrvptm"},
}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_does_not_import_layers_above_or_beside_it(package):
    for path in sorted((ROOT / package).rglob("*.py")):
        bad = _imports(path) & FORBIDDEN[package]
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def _imports_track_cli(source: str) -> list[str]:
    """The statements of ``source`` that import ``track.cli`` (``import track.cli``, ``from
    track.cli import ...``, ``from track import cli``, ``import_module("track.cli")``)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.startswith(("track.cli.", "track.cli"))]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "track.cli" or node.module.startswith("track.cli."):
                found.append(node.module)
            elif node.module == "track" and any(a.name == "cli" for a in node.names):
                found.append("track.cli")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if node.value == "track.cli" or node.value.startswith("track.cli."):
                found.append(node.value)
    return [f for f in found if f == "track.cli" or f.startswith("track.cli.")]


def test_hrvptm_never_imports_the_track_command_line():
    examples = [
        "import track.cli",
        "from track.cli import main",
        "from track import cli",
        "import importlib\nimportlib.import_module('track.cli')",
    ]
    assert all(_imports_track_cli(src) for src in examples)
    assert not _imports_track_cli("import track.client\nfrom track import pipeline")
    for path in sorted((ROOT / "hrvptm").rglob("*.py")):
        bad = _imports_track_cli(path.read_text(encoding="utf-8"))
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
