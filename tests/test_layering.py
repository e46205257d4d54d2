"""Dependency direction (README "Architecture"): hrvbase imports none of the packages; track
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
