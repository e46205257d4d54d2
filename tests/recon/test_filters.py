"""The depth-adaptive anti-aliasing filter."""

from __future__ import annotations

import numpy as np
import pytest

from recon.filters import DepthFilter, cutoff_cycles_per_voxel, lanczos_kernel


def test_cutoff_follows_the_optics(backend):
    from lfsim import paper_optics

    o = paper_optics()
    s = 5
    z = np.array([0.0, 20.0, 62.5, 100.0, 2000.0])
    c = cutoff_cycles_per_voxel(o, z, s)
    # In focus and near it: one lenslet is the finest period (s voxels).
    assert c[0] == pytest.approx(1 / s)
    assert c[1] == pytest.approx(1 / s)
    # D = M² z = f_l at z = 62.5 µm; beyond, the period shrinks as f_l / D.
    assert c[2] == pytest.approx(1 / s)
    assert c[3] == pytest.approx(min(0.5, 1 / (s * 1000 / (16 * 100))))
    # Far out, diffraction (paper Eq. 2) limits: ν = p / (0.94 λ M z) per µm.
    nu = 100 / (0.94 * 0.605 * 4 * 2000) * (25 / s)
    assert c[4] == pytest.approx(min(0.5, nu))


def test_lanczos_kernel_properties():
    h = lanczos_kernel(0.2, 2.0)
    assert h.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(h, h[::-1])
    assert len(h) == 2 * int(np.floor(2 / 0.4)) + 1
    # Passes DC, attenuates the Nyquist frequency strongly.
    x = np.cos(np.pi * np.arange(64))
    assert np.abs(np.convolve(x, h, mode="same")[20:40]).max() < 0.1


def test_filter_keeps_flux_and_leaves_resolved_depths(rng):
    f = DepthFilter([0.2, 0.5])
    v = rng.random((2, 30, 30)).astype(np.float32) + 1
    out = f(v)
    np.testing.assert_array_equal(out[1], v[1])
    assert out[0].sum() == pytest.approx(v[0].sum(), rel=0.01)
    assert out[0].std() < 0.5 * v[0].std()
