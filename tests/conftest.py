"""Shared fixtures: one backend for the whole test session, small seeded scenes."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def backend():
    """Initialise Dr.Jit/Mitsuba once (LLVM on CPU machines)."""
    from lfsim import init_backend

    return init_backend()
