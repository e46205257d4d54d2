"""The depth-adaptive anti-aliasing filter."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import InputError
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


@pytest.mark.parametrize("world", ["numpy", "drjit"])
def test_channel_filter_equals_the_volume_filter(world, rng, backend):
    """On the projectors' flat channel layout, in either array world, the filter is the
    volume filter (including the clamped edges and the clipping of negative ringing)."""
    from recon.arrays import NUMPY, drjit_arrays
    from recon.projector import LightFieldProjector

    nz, s, ny, nx = 3, 3, 5, 7
    arrays = NUMPY if world == "numpy" else drjit_arrays()
    layout = LightFieldProjector.__new__(LightFieldProjector)
    layout.__dict__.update(nz=nz, s=s, ny=ny, nx=nx, arrays=arrays)
    f = DepthFilter([0.15, 0.5, 0.3])
    vol = rng.random((nz, ny * s, nx * s)).astype(np.float32)
    vol[0, 4:6, 4:6] = 50.0  # sharp peaks: ringing goes negative and is clipped
    ref = f(vol)
    assert ref[0].min() == 0.0
    flat = arrays.from_numpy(layout.volume_to_channels(vol))
    out = layout.channels_to_volume(arrays.to_numpy(f.channel_filter(layout)(flat)))
    np.testing.assert_allclose(out, ref, rtol=0, atol=2e-6 * ref.max())
    np.testing.assert_array_equal(out[1], vol[1])
    np.testing.assert_array_equal(arrays.to_numpy(flat), layout.volume_to_channels(vol))
    with pytest.raises(InputError, match="depths"):
        DepthFilter([0.2, 0.2]).channel_filter(layout)
