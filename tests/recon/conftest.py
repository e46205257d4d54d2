"""Small seeded reconstruction fixtures on the 20 × 20-lenslet test scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from recon.geometry import ReconGrid, depth_range


@pytest.fixture(scope="session")
def small_optics_():
    from lfsim import small_optics

    return small_optics()


@pytest.fixture(scope="session")
def small_bank(backend, small_optics_, tmp_path_factory):
    from recon.psf import compute_psf_bank

    depths = depth_range(-80, 400, 10)
    cache = tmp_path_factory.mktemp("psf")
    return compute_psf_bank(small_optics_, depths, 3, rays_per_pattern=50_000, cache_dir=cache)


@pytest.fixture(scope="session")
def small_projector(small_bank):
    from recon.projector import LightFieldProjector

    return LightFieldProjector(small_bank, (20, 20))


@pytest.fixture(scope="session")
def small_grid(small_optics_, small_bank):
    o = small_optics_
    return ReconGrid(
        o.lenslet_object_um,
        small_bank.depths_um,
        small_bank.s,
        (20, 20),
        origin_xy_um=(-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um),
    )


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def psf_cache(tmp_path_factory):
    """A private PSF cache (``HRVPTM_CACHE``) for the tests that ask for it, never the user's."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HRVPTM_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="session")
def base_frame() -> np.ndarray:
    """Integer light-field-like pixels (uint16) of the small scene's 300 × 300 px sensor."""
    from recon import LensletGrid

    from .synthetic import synthetic_white

    grid = LensletGrid(15.0, 0.0, (157.5, 157.5), (300, 300))
    img = synthetic_white((300, 300), grid, noise_sigma=0.02, rng=5)
    return np.rint(50 + 1000 * np.clip(img, 0, None)).astype(np.uint16)


@pytest.fixture(scope="session")
def calib(backend, psf_cache, base_frame, tmp_path_factory) -> Path:
    """``recon calibrate`` of ``base_frame`` as white image with ``scenes/small.xml``."""
    import tifffile

    from recon.cli import main

    d = tmp_path_factory.mktemp("calib")
    white = d / "white.tif"
    tifffile.imwrite(white, base_frame)
    out = d / "calib.json"
    scene = Path(__file__).resolve().parents[2] / "scenes" / "small.xml"
    assert main(["-q", "calibrate", str(white), "--scene", str(scene), "-o", str(out)]) == 0
    return out
