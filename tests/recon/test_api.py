"""The package's public API: every exported name exists and the docstring lists it."""

from __future__ import annotations

import subprocess
import sys

import recon


def test_exports_exist_and_are_documented():
    for name in recon.__all__:
        assert hasattr(recon, name), name
        if name not in ("__version__", "errors"):
            assert f"`{name}`" in recon.__doc__, f"{name} missing from recon's docstring"


def test_import_loads_neither_drjit_nor_mitsuba():
    code = "import sys, recon; print(sorted({'drjit', 'mitsuba'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
