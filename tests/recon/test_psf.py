"""The PSF bank: energy, agreement with the simulator, lenslet periodicity, caching."""

from __future__ import annotations

import numpy as np
import pytest

from recon.psf import PSFBank, compute_psf_bank


def test_patterns_hold_the_collected_light(small_bank):
    sums = np.add.reduceat(small_bank.w.astype(np.float64), small_bank.offsets[:-1])
    # Ideal optics collect every ray of the cone; the sparsity threshold drops < 0.5 %.
    assert np.all(sums > 0.995)
    assert np.all(sums <= 1.0 + 1e-5)
    assert small_bank.n_channels == len(small_bank.depths_um) * 9


def test_pattern_equals_a_traced_point(small_bank, small_optics_):
    """Channel (depth k, centre sub-position) is the lfsim image of a point on the axis."""
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    o = small_optics_
    k = 30  # z = 220 µm
    z = small_bank.depths_um[k]
    c = k * 9 + 1 * 3 + 1
    img, y0, x0 = small_bank.dense_pattern(c)

    def traced(n_rays, seed):
        src = Sources.spheres([[0, 0, z]], 0.0)
        im = trace_paraxial(o, src, RenderSettings(rays_per_particle=n_rays, seed=seed))
        # The axis lenslet's top-left pixel in the small scene is (150, 150).
        ly, lx = 150 + y0, 150 + x0
        return im[ly : ly + img.shape[0], lx : lx + img.shape[1]] / float(n_rays)

    ref = traced(400_000, 9)
    assert ref.sum() == pytest.approx(1.0, abs=0.01)
    # Same ray count as the bank, independent seed: the Monte Carlo noise floor of the test.
    noise = np.abs(traced(50_000, 10) - ref).sum()
    assert np.abs(img - ref).sum() < 1.2 * noise + 0.01
    # A pattern one pixel off would be far outside that.
    assert np.abs(np.roll(img, 1, axis=1) - ref).sum() > 3 * noise


def test_sub_positions_shift_the_pattern_the_right_way(small_bank):
    """Moving a source +x inside its lenslet moves its defocused spot grid envelope +x."""
    k = 40  # z = 320 µm, well out of focus
    left, right = k * 9 + 3 + 0, k * 9 + 3 + 2
    cx = []
    for c in (left, right):
        _dy, dx, w = small_bank.pattern(c)
        cx.append(np.sum(dx * w) / np.sum(w))
    assert cx[1] > cx[0] + 1.0


def test_cache_round_trip(backend, small_optics_, tmp_path):
    a = compute_psf_bank(
        small_optics_, [100.0, 200.0], 3, rays_per_pattern=5000, cache_dir=tmp_path
    )
    files = list(tmp_path.glob("psf_*.npz"))
    assert len(files) == 1
    b = compute_psf_bank(
        small_optics_, [100.0, 200.0], 3, rays_per_pattern=5000, cache_dir=tmp_path
    )
    np.testing.assert_array_equal(a.w, b.w)
    np.testing.assert_array_equal(a.dx, b.dx)
    c = PSFBank.load(files[0])
    assert c.optics == small_optics_.to_dict()
    # A different s is a different bank.
    compute_psf_bank(small_optics_, [100.0, 200.0], 1, rays_per_pattern=5000, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("psf_*.npz"))) == 2


def test_non_integer_pitch_rejected(backend):
    from lfsim import small_optics
    from recon.errors import InputError

    with pytest.raises(InputError, match="rectify"):
        compute_psf_bank(small_optics(pixel_um=7.0), [0.0], 1, cache_dir="")
