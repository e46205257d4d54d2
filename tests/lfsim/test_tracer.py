"""Physics of the light tracers against the lenslet geometry, energy and each other.

Acceptance points of the simulator (paper §2.2, docs/conventions.md §2) at the paper's optics.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage as ndi

from lfsim.scene import load_scene
from lfsim.tracer import RenderSettings, Sources, trace_mitsuba, trace_paraxial

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.fixture(scope="module")
def paper(backend):
    return load_scene(SCENES / "paper_4x.xml")


@pytest.fixture(scope="module")
def small(backend):
    return load_scene(SCENES / "small.xml")


@pytest.fixture(scope="module")
def small_glass(backend):
    return load_scene(SCENES / "small_glass.xml")


def point(x=0.0, y=0.0, z=0.0):
    return Sources.spheres([[x, y, z]], 0.0)


def moments(im):
    im = im.astype(np.float64)
    yy, xx = np.indices(im.shape)
    m = im.sum()
    mx, my = (im * xx).sum() / m, (im * yy).sum() / m
    vx = (im * (xx - mx) ** 2).sum() / m
    vy = (im * (yy - my) ** 2).sum() / m
    return mx, my, vx, vy


def spot_centroids(im, rel=0.05):
    lab, n = ndi.label(im > rel * im.max())
    idx = np.arange(1, n + 1)
    cy, cx = np.array(ndi.center_of_mass(im, lab, idx)).T
    return cx, cy, np.asarray(ndi.sum(im, lab, idx))


def l1(a, b):
    a = a.astype(np.float64) / a.sum()
    b = b.astype(np.float64) / b.sum()
    return np.abs(a - b).sum()


def test_in_focus_point_fills_one_lenslet_disc(paper):
    o = paper.optics
    im = trace_mitsuba(paper, point(), RenderSettings(rays_per_particle=200_000))
    mx, my, vx, vy = moments(im)
    # A uniform disc of diameter D has <x²> = D²/16; remove the pixel's own variance 1/12.
    diameter = 4 * np.sqrt((vx + vy) / 2 - 1 / 12)
    assert abs(diameter - 15.0) <= 1.0
    slope = np.tan(np.arcsin(o.image_na))
    assert diameter == pytest.approx(2 * o.mla_focal_um * slope / o.pixel_um, rel=0.02)
    # Centred on the lenslet on the axis, and (up to the diffraction blur) inside its cell.
    ax, ay = o.axis_xy_px
    assert mx + 0.5 == pytest.approx(ax, abs=0.05)
    assert my + 0.5 == pytest.approx(ay, abs=0.05)
    c0, r0 = int(ax - 7.5), int(ay - 7.5)
    assert im[r0 : r0 + 15, c0 : c0 + 15].sum() / im.sum() > 0.97
    # Geometric optics alone: the thin-lens objective's image-side slope tan(asin NA)/M is 2 %
    # above the lenslet's p / 2 f_l, so a thin rim (< 1 %) spills into the neighbours.
    s = RenderSettings(rays_per_particle=50_000, diffraction=False)
    no_blur = trace_mitsuba(paper, point(), s)
    assert 0.99 < no_blur[r0 : r0 + 15, c0 : c0 + 15].sum() / no_blur.sum() < 1.0


@pytest.mark.parametrize("z", [300.0, -300.0])
def test_defocused_point_makes_spot_grid_with_lenslet_spacing(paper, z):
    o = paper.optics
    im = trace_mitsuba(paper, point(z=z), RenderSettings(rays_per_particle=400_000))
    cx, cy, _ = spot_centroids(im)
    predicted = o.spot_spacing_px(z)
    assert predicted == pytest.approx(15 * (1 + np.sign(z) * 1000 / (16 * 300)))
    assert len(cx) >= 20  # the 5 x 5 grid (corners may be faint)
    # Fully illuminated lenslets: the 3 x 3 spots nearest the pattern centre.
    ax, ay = o.axis_xy_px[0] - 0.5, o.axis_xy_px[1] - 0.5
    near = np.hypot(cx - ax, cy - ay) < 1.5 * predicted
    assert near.sum() == 9
    kx = np.round((cx[near] - ax) / predicted)
    ky = np.round((cy[near] - ay) / predicted)
    sx = np.polyfit(kx, cx[near], 1)[0]
    sy = np.polyfit(ky, cy[near], 1)[0]
    assert sx == pytest.approx(predicted, rel=0.005)
    assert sy == pytest.approx(predicted, rel=0.005)


def test_lateral_shift_of_one_lenslet_moves_pattern_one_lenslet(paper):
    o = paper.optics
    assert o.lenslet_object_um == pytest.approx(25.0)
    s = RenderSettings(rays_per_particle=200_000, seed=3)
    a = trace_mitsuba(paper, point(0, 0, 120.0), s)
    bx = trace_mitsuba(paper, point(25.0, 0, 120.0), s)
    by = trace_mitsuba(paper, point(0, 25.0, 120.0), s)
    assert l1(np.roll(a, 15, axis=1), bx) < 0.01  # object +x -> +columns
    assert l1(np.roll(a, 15, axis=0), by) < 0.01  # object +y -> +rows
    # ... and exactly one lenslet, not 14 or 16 pixels.
    assert l1(np.roll(a, 14, axis=1), bx) > 0.2
    assert l1(np.roll(a, 16, axis=1), bx) > 0.2


@pytest.mark.parametrize("xyz", [(0, 0, 0), (500.0, -300.0, 0), (-700.0, 400.0, 350.0)])
def test_collected_energy_is_the_na_cone_fraction(paper, xyz):
    o = paper.optics
    n = 100_000
    exact = trace_mitsuba(paper, point(*xyz), RenderSettings(rays_per_particle=n))
    # Sampled cone == accepted cone: no ray wasted, none lost (but for float32 rounding of the
    # few rays grazing the stop's rim).
    assert n * (1 - 1e-4) <= exact.sum() <= n
    # Sample a wider cone: the aperture stop must clip it back to the NA cone.
    margin = 0.1
    wide = trace_mitsuba(
        paper, point(*xyz), RenderSettings(rays_per_particle=n, cone_margin=margin)
    )
    theta_wide = o.theta_max * (1 + margin)
    fraction_wide = 0.5 * (1 - np.cos(theta_wide))
    collected = wide.sum() / n * fraction_wide
    assert collected == pytest.approx(o.cone_fraction, rel=0.01)
    assert wide.sum() < 0.9 * n  # the test is not vacuous: the stop did clip


def test_glass_array_loses_only_fresnel_reflection(small, small_glass):
    n_glass = small_glass.optics.mla_ior
    r = ((n_glass - 1) / (n_glass + 1)) ** 2
    n = 200_000
    s = RenderSettings(rays_per_particle=n)
    for z in (0.0, 200.0):
        glass = trace_mitsuba(small_glass, point(z=z), s).sum() / n
        # Two interfaces at near-normal incidence; ghosts (two extra reflections) add <= R².
        assert (1 - r) ** 2 - 0.003 < glass < (1 - r) ** 2 + r**2 + 0.003


@pytest.mark.parametrize("z", [150.0, 300.0, -200.0])
def test_glass_and_ideal_arrays_agree_out_of_focus(small, small_glass, z):
    s = RenderSettings(rays_per_particle=400_000, seed=1)
    ideal = trace_mitsuba(small, point(10.0, -5.0, z), s)
    glass = trace_mitsuba(small_glass, point(10.0, -5.0, z), s)
    assert l1(ideal, glass) < 0.05


def test_mitsuba_and_direct_drjit_tracers_agree(small):
    src = Sources.spheres([[0, 0, 0], [40.0, -30.0, 150.0], [-60.0, 80.0, -120.0]], 15.0)
    s0 = RenderSettings(rays_per_particle=100_000, seed=0)
    s1 = RenderSettings(rays_per_particle=100_000, seed=1)
    mit = trace_mitsuba(small, src, s0)
    par0 = trace_paraxial(small.optics, src, s0)
    par1 = trace_paraxial(small.optics, src, s1)
    noise = l1(par0, par1)  # pure sampling noise between two independent renders
    assert l1(mit, par0) < 0.25 * noise  # same rays: far below the sampling noise
    # Different seeds: as different as two paraxial renders, no more.
    assert l1(trace_mitsuba(small, src, s1), par0) < 1.1 * noise
    assert abs(int(mit.sum()) - int(par0.sum())) <= 1e-4 * par0.sum()


def test_same_seed_identical_and_thread_count_independent(small):
    import drjit as dr

    from lfsim import init_backend

    src = Sources.spheres([[0, 0, 50.0], [30.0, 30.0, 200.0]], 15.0, [1.0, 0.5])
    s = RenderSettings(rays_per_particle=100_000, seed=7, batch_rays=1 << 16)
    before = dr.thread_count()
    try:
        init_backend(threads=1)
        one = trace_mitsuba(small, src, s)
        one_p = trace_paraxial(small.optics, src, s)
        init_backend(threads=2)
        two = trace_mitsuba(small, src, s)
        two_p = trace_paraxial(small.optics, src, s)
    finally:
        init_backend(threads=before)
    np.testing.assert_array_equal(one, two)
    np.testing.assert_array_equal(one_p, two_p)
    # batch size does not change the image either
    big = RenderSettings(rays_per_particle=100_000, seed=7, batch_rays=1 << 22)
    np.testing.assert_array_equal(trace_mitsuba(small, src, big), one)
    assert one.dtype == np.uint32
    assert one.sum() == 150_000  # brightness 0.5 emits half the photons
    other = trace_mitsuba(small, src, RenderSettings(rays_per_particle=100_000, seed=8))
    assert not np.array_equal(other, one)


def test_expected_mode_is_float_and_matches_counts(small):
    src = Sources.spheres([[0, 0, 80.0]], 15.0, [2.0])
    counts = trace_paraxial(small.optics, src, RenderSettings(rays_per_particle=50_000))
    expected = trace_paraxial(
        small.optics, src, RenderSettings(rays_per_particle=50_000, mode="expected")
    )
    assert expected.dtype == np.float32
    # photons mode: 2 x 50 000 rays of weight 1; expected: 50 000 rays of weight 2.
    assert counts.sum() == 100_000
    assert expected.sum() == pytest.approx(100_000, rel=1e-5)
    assert l1(counts, expected) < 0.15


def test_particle_size_widens_the_in_focus_image(small):
    s = RenderSettings(rays_per_particle=100_000)
    _, _, vp, _ = moments(trace_paraxial(small.optics, point(z=300.0), s))
    big = trace_paraxial(small.optics, Sources.spheres([[0, 0, 300.0]], 40.0), s)
    _, _, vb, _ = moments(big)
    assert vb > vp


def test_a_numpy_integer_seed_draws_the_same_rays_as_the_python_int(small):
    """Seeds computed with numpy (``np.int64``) are the same seeds, not an overflow."""
    s = Sources.spheres([[0.0, 0.0, 30.0]], 5.0)
    a = trace_paraxial(small.optics, s, RenderSettings(rays_per_particle=2000, seed=12345))
    b = trace_paraxial(
        small.optics, s, RenderSettings(rays_per_particle=2000, seed=np.int64(12345))
    )
    assert np.array_equal(a, b)
