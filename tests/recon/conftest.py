"""Small seeded reconstruction fixtures on the 20 × 20-lenslet test scene."""

from __future__ import annotations

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
        origin_um=(-o.axis_px[0] * o.object_pixel_um, -o.axis_px[1] * o.object_pixel_um),
    )


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
