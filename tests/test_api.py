"""Every package's public API: each exported name exists and its docstring lists it."""

from __future__ import annotations

import importlib

import pytest

#: Names exported for convenience that a package docstring need not list.
UNLISTED = {"__version__", "errors", "io"}


@pytest.mark.parametrize("package", ["hrvbase", "lfsim", "recon", "track", "hrvptm"])
def test_exports_exist_and_are_documented(package):
    mod = importlib.import_module(package)
    missing = [name for name in mod.__all__ if not hasattr(mod, name)]
    assert not missing, f"{package}.__all__ names {missing}, which do not exist"
    undocumented = [
        name for name in mod.__all__ if name not in UNLISTED and name not in (mod.__doc__ or "")
    ]
    assert not undocumented, f"{package}'s docstring does not mention {undocumented}"
