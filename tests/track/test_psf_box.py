"""The automatic particle-PSF box follows the particles' widths (no built-in microscope)."""

from __future__ import annotations

import numpy as np
import pytest

from track.psf_estimate import BOX_FWHM, auto_box_um


@pytest.mark.parametrize("sigma_vox", [(6.0, 1.5, 1.5), (3.0, 2.0, 2.0)])
def test_box_is_three_fwhm_of_the_particles(sigma_vox):
    rng = np.random.default_rng(0)
    shape = (120, 80, 80)
    vol = rng.normal(0.0, 0.01, shape)
    zz, yy, xx = np.indices(shape)
    for c in [(30, 20, 20), (60, 55, 30), (90, 25, 60), (40, 60, 60)]:
        r2 = sum(((g - ci) / s) ** 2 for g, ci, s in zip((zz, yy, xx), c, sigma_vox, strict=True))
        vol += np.exp(-0.5 * r2)
    spacing = (5.0, 1.6, 1.6)
    box = auto_box_um(vol, spacing)
    fwhm_um = [2.3548 * s * d for s, d in zip(sigma_vox, spacing, strict=True)]
    for b, f, d in zip(box, fwhm_um, spacing, strict=True):
        # widths are counted in whole voxels: within one voxel per side of BOX_FWHM × FWHM
        assert abs(b - BOX_FWHM * f) <= BOX_FWHM * 2 * d, (box, fwhm_um)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_box_never_exceeds_half_the_volume(axis):
    """A streak through the whole volume along ``axis``: the box is cut to exactly half the
    volume along it, and stays within half the volume along all three axes."""
    shape, spacing = (20, 30, 40), (5.0, 2.0, 1.5)
    vol = np.zeros(shape)
    vol[10, 15, 20] = 1.0
    line = [10, 15, 20]
    line[axis] = slice(None)
    vol[tuple(line)] += 0.9
    box = np.array(auto_box_um(vol, spacing))
    half_um = np.array(shape) / 2.0 * np.array(spacing)
    assert box[axis] == pytest.approx(half_um[axis], rel=1e-12), box
    assert np.all(box <= half_um + 1e-9), (box, half_um)
    others = [a for a in range(3) if a != axis]
    assert np.all(box[others] < half_um[others]), box  # only the streak's axis is cut
