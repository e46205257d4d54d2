"""Reconstruction in a specimen: point sources in a gel behind a cover glass are found at their
true depths with the specimen in the bank, and 26 % too shallow without it."""

from __future__ import annotations

import numpy as np
import pytest

from recon.geometry import depth_range

#: A 10 % polyacrylamide gel on a 170 µm glass bottom, dry 0.2-NA objective focused 300 µm in.
GEL = {
    "medium_ior": 1.35,
    "coverslip_thickness_um": 170.0,
    "coverslip_ior": 1.523,
    "focus_depth_um": 300.0,
}
POINTS = np.array([[0.0, 0.0, 140.0], [-100.0, 75.0, 230.0], [100.0, -75.0, 320.0]])


def _peak_depths(vol: np.ndarray, depths: np.ndarray, s: int, optics) -> np.ndarray:
    """Depth of each point's peak (parabola through the brightest plane and its neighbours)."""
    out = []
    lateral = optics.lenslet_object_um / s
    x0 = -optics.axis_xy_px[0] * optics.object_pixel_um
    y0 = -optics.axis_xy_px[1] * optics.object_pixel_um
    dz = depths[1] - depths[0]
    for x, y, _z in POINTS:
        j, i = round((y - y0) / lateral - 0.5), round((x - x0) / lateral - 0.5)
        col = vol[:, max(j - 2, 0) : j + 3, max(i - 2, 0) : i + 3].sum(axis=(1, 2))
        k = int(np.argmax(col))
        k = min(max(k, 1), len(col) - 2)
        a, b, c = col[k - 1 : k + 2]
        shift = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else 0.0
        out.append(depths[k] + shift * dz)
    return np.array(out)


def _reconstruct(optics, image, depths, s, cache):
    from recon.deconvolve import richardson_lucy
    from recon.filters import DepthFilter
    from recon.projector import LightFieldProjector
    from recon.psf import compute_psf_bank

    bank = compute_psf_bank(optics, depths, s, rays_per_pattern=60_000, cache_dir=cache)
    proj = LightFieldProjector(bank, (20, 20))
    f = DepthFilter.for_optics(optics, bank.depths_um, bank.s)
    return richardson_lucy(image.astype(np.float32), proj, 8, depth_filter=f).volume


@pytest.mark.studies  # about a minute per case: the long tier
@pytest.mark.parametrize(
    "kw",
    [GEL, {"na": 0.5, "immersion_ior": 1.333, "medium_ior": 1.333, "focus_depth_um": 100.0}],
    ids=["dry-into-gel", "water-into-water"],
)
def test_points_in_a_specimen_found_at_their_true_depths(backend, tmp_path, kw):
    from lfsim import small_optics
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    o = small_optics(**kw)
    image = trace_paraxial(
        o,
        Sources.spheres(POINTS, 2.0),
        RenderSettings(rays_per_particle=400_000, mode="expected", seed=2),
    )
    depths = depth_range(20, 440, 10)
    vol = _reconstruct(o, image, depths, 3, tmp_path)
    found = _peak_depths(vol, depths, 3, o)
    # Within two depth steps, as in air (tests/recon/test_deconvolve.py), on average within a
    # third of a step.
    err = found - POINTS[:, 2]
    assert np.abs(err).max() < 2 * 10.0, found
    assert abs(err.mean()) < 4.0, found
    if o.medium_ior != o.immersion_ior:
        # The same image reconstructed as if the gel were air (focus_depth unchanged, so the
        # native plane lies at the nominal focal plane): depths come out ≈ 26 % too small.
        air = small_optics(**{**kw, "medium_ior": 1.0, "coverslip_thickness_um": 0.0})
        shallow = _peak_depths(_reconstruct(air, image, depths, 3, tmp_path), depths, 3, air)
        scale = np.polyfit(POINTS[:, 2], shallow, 1)[0]
        assert scale == pytest.approx(o.axial_scale, abs=0.05), shallow


def test_the_depth_range_starts_with_guard_planes_in_front_of_the_specimens_surface():
    """Where the specimen's surface cuts the default range, the range starts the guard depth
    in front of it (1.2 z₁: 105 µm in the paper's gel at its 7 µm default step); a given
    range reaching in front of the surface is taken as it is."""
    import math

    from lfsim import small_optics
    from recon.settings import (
        FRONT_GUARD_Z1,
        ReconSettings,
        default_front_guard_um,
        default_z_limit_um,
    )

    air = ReconSettings().resolved(small_optics())
    zlim = default_z_limit_um(small_optics(), air.z_step_um)
    assert (air.z_min_um, air.z_max_um) == (-zlim, zlim)
    deep = small_optics(**{**GEL, "focus_depth_um": 1000.0})  # surface 1440 µm in front
    r = ReconSettings().resolved(deep)
    assert r.z_min_um == -default_z_limit_um(deep, r.z_step_um) > deep.surface_z_um
    # The surface 487 and 80 µm in front of z = 0, and 96 µm beyond it.
    for focus in (300.0, 0.0, -130.0):
        o = small_optics(**{**GEL, "focus_depth_um": focus})
        r = ReconSettings().resolved(o)
        guard = default_front_guard_um(o, r.z_step_um)
        # z₁ in the gel: the 25 µm object-space pitch over 2 tan θ, in true depth
        z1 = 25.0 / (2 * math.tan(math.asin(0.2)) * o.axial_scale)
        assert z1 == pytest.approx(83.2, abs=0.1)
        assert guard == math.ceil(FRONT_GUARD_Z1 * z1 / r.z_step_um) * r.z_step_um == 105.0
        first = o.surface_z_um - guard
        assert first <= r.z_min_um < first + r.z_step_um
        assert r.z_max_um == default_z_limit_um(o, r.z_step_um)
        z0 = o.surface_z_um - 10.0
        given = ReconSettings(z_min_um=z0, z_max_um=600.0, z_step_um=5.0).resolved(o)
        assert given.z_min_um == z0
