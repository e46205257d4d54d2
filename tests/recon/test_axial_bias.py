"""The reconstruction's axial bias against the lateral lenslet phase.

A particle's axial position in a Richardson–Lucy light-field volume is biased by an amount
that depends on its depth and on where it sits under its lenslet. In a translation that
part does not cancel between frames: it is the axial displacement error of Fig. 5a. With the
paper's 3 iterations it is several µm near the native plane, and more iterations shrink it
only a little (``benchmarks/axial_budget.py --phase-scan``). This test pins its size, on
noise-free spheres rendered through ideal lenslets (no noise, no model mismatch: only the
reconstruction's own bias) and shifted across one lenslet.
"""

from __future__ import annotations

import numpy as np
import pytest

from recon.deconvolve import richardson_lucy
from recon.filters import DepthFilter

DEPTHS_UM = (120.0, 200.0, 240.0, 320.0)  # where 3 iterations are biased most (measured)
CORNERS_UM = np.array([[-120.0, -120.0], [120.0, -120.0], [-120.0, 120.0], [120.0, 120.0]])
PHASES_UM = (0.0, 10.0, 20.0)  # across one 25 µm lenslet (object side)


@pytest.fixture(scope="module")
def sphere_images(small_optics_):
    """Noise-free images of four 15 µm spheres (one per depth), shifted along x."""
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    out = []
    for ph in PHASES_UM:
        pts = np.c_[CORNERS_UM + np.array([3.0 + ph, 7.0]), DEPTHS_UM]
        img = trace_paraxial(
            small_optics_,
            Sources.spheres(pts, 15.0),
            RenderSettings(rays_per_particle=100_000, mode="expected", seed=3),
        )
        out.append((pts, img / 2000.0))
    return out


def _axial_errors(images, projector, grid, optics, bank, iterations):
    """(phases, depths) axial error (µm) of the radial-symmetry centre of each sphere."""
    from track.localize import radial_symmetry_3d

    filt = DepthFilter.for_optics(optics, bank.depths_um, bank.s)
    xs, ys, zs = grid.x_um(), grid.y_um(), np.asarray(grid.depths_um)
    dz, vx = grid.z_step_um, grid.voxel_um
    hz = round(60.0 / dz)
    err = np.empty((len(images), len(DEPTHS_UM)))
    for a, (pts, img) in enumerate(images):
        vol = richardson_lucy(img, projector, iterations, depth_filter=filt, track_kl=False).volume
        for b, p in enumerate(pts):
            i, j, k = (
                int(np.argmin(np.abs(ax - v))) for ax, v in ((xs, p[0]), (ys, p[1]), (zs, p[2]))
            )
            sub = vol[k - hz : k + hz + 1, j - 2 : j + 3, i - 2 : i + 3]
            c = radial_symmetry_3d(sub, (dz, vx, vx))
            err[a, b] = zs[k - hz] + c[0] * dz - p[2]
    return err


@pytest.mark.slow
def test_axial_bias_across_the_lenslet_stays_pinned(
    sphere_images, small_projector, small_grid, small_optics_, small_bank
):
    """The part of the axial error that changes as a sphere moves across its lenslet (what a
    translation sees), its worst peak-to-peak over one lenslet, and the RMS of the per-depth
    mean error, at 10 iterations (s = 3, 10 µm steps), three shifts 10 µm apart. Measured:
    1.01 µm, 2.9 µm (at 200 µm) and 1.50 µm; the bounds are 25 % above, so that a change of the
    reconstruction (PSF bank, depth filter, update) or of the localiser that makes this bias
    grow fails here. (On the s = 5 grid, 3 → 10 iterations shrink the phase-varying part only
    from 1.44 to 1.29 µm: it is a fixed pattern of the optics and the reconstruction.)"""
    e = _axial_errors(sphere_images, small_projector, small_grid, small_optics_, small_bank, 10)
    assert np.all(np.isfinite(e))
    vary_um = float(np.sqrt(np.mean((e - e.mean(axis=0)) ** 2)))
    assert vary_um <= 1.3
    assert np.ptp(e, axis=0).max() <= 3.6
    assert float(np.sqrt(np.mean(e.mean(axis=0) ** 2))) <= 1.9
