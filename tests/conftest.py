"""Shared fixtures: one backend for the whole test session, small seeded scenes, and a private
PSF-bank cache so that no test reads or writes the user's cache."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session", autouse=True)
def _private_psf_cache(tmp_path_factory):
    """Point ``HRVPTM_CACHE`` (PSF banks, :func:`recon.psf.default_cache_dir`) at a fresh
    session folder: test results and times never depend on what ``~/.cache/hrvptm`` holds."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HRVPTM_CACHE", str(tmp_path_factory.mktemp("hrvptm_cache")))
        yield


@pytest.fixture(scope="session")
def backend():
    """Initialise Dr.Jit/Mitsuba once (LLVM on CPU machines)."""
    from lfsim import init_backend

    return init_backend()


@pytest.fixture(scope="session")
def corpus_base(backend, tmp_path_factory):
    """The bad-input corpus's shared valid inputs (:func:`tests.corpus.build_base`), built once
    for every corpus module."""
    from tests.corpus import build_base

    return build_base(tmp_path_factory)
