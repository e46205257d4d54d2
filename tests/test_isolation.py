"""The test session never touches the user's caches."""

from __future__ import annotations

from pathlib import Path


def test_psf_cache_is_private_to_the_session(tmp_path_factory):
    from recon.psf import default_cache_dir

    base = Path(tmp_path_factory.getbasetemp()).resolve()
    cache = Path(default_cache_dir()).resolve()
    assert cache.is_relative_to(base), cache
    assert Path.home().resolve() / ".cache" not in cache.parents
