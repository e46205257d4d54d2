"""lfsim.wave against analytic results of scalar diffraction."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import j0, j1

from lfsim.errors import ConfigError
from lfsim.optics import paper_optics
from lfsim.wave import (
    WaveSampling,
    converged_light_field,
    lenslet_phase,
    light_field,
    native_field,
    pattern_stack,
    propagate,
    pupil_phase,
)

LAM = 0.605


def _low_na(**kw):
    """A 10×/0.1 dry objective (f-matched 100 µm lenslets) on a small sensor."""
    base = dict(
        na=0.1,
        f_objective_um=20_000.0,
        f_tube_um=200_000.0,
        mla_focal_um=5000.0,
        sensor_xy_px=(135, 135),
    )
    base.update(kw)
    return paper_optics(**base)


def test_in_focus_native_field_is_the_airy_pattern():
    o = _low_na()
    m = o.magnification
    r = np.linspace(1e-6, 1.5 * m * LAM / o.na, 3001)  # image plane, past the second zero
    e = native_field(o, r, [0.0])[0]
    inten = np.abs(e) ** 2
    v = 2 * math.pi * o.na * r / (m * LAM)  # object-space optical radius
    airy = (2 * j1(v) / v) ** 2
    np.testing.assert_allclose(inten / inten[0], airy, atol=2e-3)
    # first zero at 0.61 λ/NA in object space
    lo = np.searchsorted(r, 0.4 * m * LAM / o.na)
    hi = np.searchsorted(r, 0.8 * m * LAM / o.na)
    r0 = r[lo + np.argmin(inten[lo:hi])] / m
    assert r0 == pytest.approx(0.6098 * LAM / o.na, rel=2e-3)
    # normalised to unit power: the Airy pattern's encircled energy 1 − J0(v)² − J1(v)²
    r_big = np.linspace(0, 20 * m * LAM / o.na, 20_001)
    ib = np.abs(native_field(o, r_big, [0.0])[0]) ** 2
    power = np.trapezoid(ib * 2 * math.pi * r_big, r_big)
    v_edge = 2 * math.pi * 20
    assert power == pytest.approx(1 - j0(v_edge) ** 2 - j1(v_edge) ** 2, abs=1e-3)


def test_axial_intensity_follows_the_paraxial_sinc_law():
    o = _low_na()
    z_zero = 2 * LAM / o.na**2  # first axial zero of the paraxial focus (n = 1)
    z = np.linspace(-1.5 * z_zero, 1.5 * z_zero, 61)
    i0 = np.abs(native_field(o, np.array([0.0]), z)[:, 0]) ** 2
    i0 = i0 / i0[30]
    u = 2 * math.pi / LAM * z * o.na**2  # u = k n z sin²α (paraxial)
    np.testing.assert_allclose(i0, np.sinc(u / (4 * math.pi)) ** 2, atol=1e-2)
    # the zeros sit at ±2λ/NA² (within the 0.25 % of the non-paraxial cos α)
    assert i0[10] < 2e-3 and i0[50] < 2e-3


def test_immersion_defocus_scales_with_the_index():
    """In water the axial zero moves to 2 n λ / NA² (the medium's wavelength is shorter)."""
    o = _low_na(medium_ior=1.333, immersion_ior=1.333)
    z = np.linspace(0.5, 1.5, 201) * 2 * 1.333 * LAM / o.na**2
    i0 = np.abs(native_field(o, np.array([0.0]), z)[:, 0]) ** 2
    z_min = z[np.argmin(i0)]
    assert z_min == pytest.approx(2 * 1.333 * LAM / o.na**2, rel=5e-3)


def test_single_lenslet_focuses_a_plane_wave_at_its_focal_length():
    f, p, dx, n = 500.0, 100.0, 1.0, 1024  # N dx² / λ = 1.7 mm > f: no aliased chirp
    o = paper_optics(mla_focal_um=f)
    x = (np.arange(n) - n / 2 + 0.5) * dx
    inside = (np.abs(x) < p / 2)[None, :] & (np.abs(x) < p / 2)[:, None]
    field = np.where(inside, lenslet_phase(o, x[None, :], x[:, None]), 0)
    c = slice(n // 2 - 1, n // 2 + 1)
    dists = np.linspace(0.9 * f, 1.1 * f, 5)
    axial = [np.abs(propagate(field, dx, d, LAM))[c, c].mean() for d in dists]
    assert dists[int(np.argmax(axial))] == pytest.approx(f, abs=1e-6)
    out = propagate(field, dx, f, LAM)
    focal = np.abs(out) ** 2
    # the square aperture's focus: sinc² with its first zero at λ f / p
    row = focal[c].mean(axis=0)
    sinc2 = np.sinc(p * x / (LAM * f)) ** 2
    np.testing.assert_allclose(row / row.max(), sinc2 / sinc2.max(), atol=0.01)
    # against the Rayleigh–Sommerfeld integral summed directly over the aperture
    xx, yy = np.meshgrid(x, x)
    k = 2 * np.pi / LAM
    for i, j in ((512, 512), (512, 513), (512, 515), (509, 512)):
        r = np.sqrt((xx[inside] - x[j]) ** 2 + (yy[inside] - x[i]) ** 2 + f * f)
        kern = np.exp(1j * k * (r - f)) / r * (f / r) * (1 - 1 / (1j * k * r))
        e = np.sum(field[inside] * kern) * dx * dx / (1j * LAM)
        assert focal[i, j] == pytest.approx(abs(e) ** 2, rel=1e-3)
    # power is conserved
    assert focal.sum() == pytest.approx(inside.sum(), rel=1e-12)
    # the paraxial phase focuses with the Strehl ratio |<exp(i Δφ)>|² of its departure from
    # the perfect lens (spherical aberration ≈ ρ⁴/(8 f³), 0.04 λ at the corners)
    par = np.where(inside, lenslet_phase(o, x[None, :], x[:, None], paraxial=True), 0)
    strehl = (np.abs(propagate(par, dx, f, LAM)) ** 2)[c, c].max() / focal[c, c].max()
    dphi = np.angle(par[inside] / field[inside])
    expected = abs(np.mean(np.exp(1j * dphi))) ** 2
    assert expected < 0.999
    assert strehl == pytest.approx(expected, abs=3e-4)


def test_propagation_conserves_energy_and_is_reversible():
    rng = np.random.default_rng(1)
    field = rng.normal(size=(2, 128, 128)) + 1j * rng.normal(size=(2, 128, 128))
    dx = 2.0  # all components propagate (1/(2 dx) < 1/λ)
    out = propagate(field, dx, 1000.0, LAM)
    assert np.sum(np.abs(out) ** 2) == pytest.approx(np.sum(np.abs(field) ** 2), rel=1e-12)
    back = propagate(out, dx, -1000.0, LAM)
    np.testing.assert_allclose(back, field, atol=1e-10)


def _small_paper():
    return paper_optics(sensor_xy_px=(135, 135))


def test_light_field_keeps_the_light_and_follows_the_axes():
    o = _small_paper()
    ws = WaveSampling(oversample=2)
    img = light_field(o, [[0, 0, 300.0], [0, 0, -300.0], [25.0, 0, 300.0]], ws)
    assert img.shape == (3, 135, 135)
    # the power emitted into the cone reaches the sensor (what misses is the far tail)
    np.testing.assert_allclose(img.sum(axis=(1, 2)), 1.0, atol=8e-3)
    assert np.all(img.sum(axis=(1, 2)) <= 1.0 + 1e-9)
    # one lenslet of object motion along +x = one lenslet (15 px) along +columns (up to the
    # radial interpolation)
    np.testing.assert_allclose(img[2][:, 30:120], img[0][:, 15:105], atol=2e-4 * img[0].max())
    # z > 0 images in front of the array: spots spread outwards (spacing p (1 + f_l/(M² z)));
    # z < 0 behind it: inwards
    c0, n = 67.5, 15
    for k, sign in ((0, 1), (1, -1)):
        row = img[k][60:75].sum(axis=0)
        seg = slice(int(c0 + n - 7.5), int(c0 + n + 7.5))
        cols = np.arange(135)[seg] + 0.5
        offset = (cols * row[seg]).sum() / row[seg].sum() - (c0 + n)
        geometric = 100.0 * 1000.0 / (16 * 300.0) / o.pixel_um  # 3.1 px
        # (diffraction spreads the spot over the lenslet's patch, pulling its centroid inwards)
        assert sign * offset == pytest.approx(geometric, abs=0.6)


def test_convergence_check_doubles_until_the_tolerance():
    o = paper_optics(sensor_xy_px=(45, 45))
    _img, ws, hist = converged_light_field(o, [[0, 0, 30.0]], WaveSampling(oversample=1), tol=0.03)
    assert hist[-1][1] < 0.03
    assert len(hist) >= 2  # oversample 1 is aliased
    assert [h[0] for h in hist] == [2**i for i in range(1, len(hist) + 1)]
    assert ws.oversample == hist[-1][0]
    assert all(h[1] >= 0.03 for h in hist[:-1])
    with pytest.raises(ConfigError, match="not converged"):
        converged_light_field(
            o, [[0, 0, 100.0]], WaveSampling(oversample=1), tol=1e-9, max_oversample=2
        )


def test_pattern_stack_matches_the_bank_layout():
    o = paper_optics(sensor_xy_px=(75, 75))
    stack = pattern_stack(o, [50.0], 3, 2, WaveSampling(oversample=2))
    assert stack.shape == (9, 75, 75)
    # sub-lenslet position a along x: the pattern of a = 2 is that of a = 0 moved right
    cx = [(s.sum(axis=0) * (np.arange(75) + 0.5)).sum() / s.sum() for s in stack[:3]]
    assert cx[0] < cx[1] < cx[2]
    # b along y
    cy = [(s.sum(axis=1) * (np.arange(75) + 0.5)).sum() / s.sum() for s in stack[[0, 3, 6]]]
    assert cy[0] < cy[1] < cy[2]
    # the centre voxel sits on the source lenslet (top-left pixel (30, 30), centre 37.5)
    assert cx[1] == pytest.approx(37.5, abs=0.05)


def test_sampling_is_validated():
    with pytest.raises(ConfigError, match="oversample"):
        WaveSampling(oversample=0)
    with pytest.raises(ConfigError, match="ideal"):
        light_field(paper_optics(sensor_xy_px=(45, 45), mla_kind="glass"), [[0, 0, 0]])


def test_gibson_lanni_phase_reduces_to_debye_for_a_corrected_cover_glass():
    """A cover glass of the thickness the objective is corrected for, over a specimen of the
    immersion index, adds nothing to the defocus phase."""
    s = np.linspace(0, 0.79, 50)
    z = np.array([-20.0, 0.0, 35.0])
    plain = _low_na(na=0.8, medium_ior=1.333, immersion_ior=1.333)
    glass = _low_na(
        na=0.8,
        medium_ior=1.333,
        immersion_ior=1.333,
        coverslip_thickness_um=170.0,
        coverslip_corrected_um=170.0,
        focus_depth_um=40.0,
    )
    assert glass.has_interfaces and not plain.has_interfaces
    np.testing.assert_allclose(pupil_phase(glass, s, z), pupil_phase(plain, s, z), atol=1e-9)


def test_index_mismatch_focuses_on_the_native_plane():
    """Dry 0.1-NA objective focused 300 µm into water: the brightest axial point lies at the
    native object plane z = 0 (paraxially 1.333 × 300 µm deep), not at the nominal focus."""
    o = _low_na(medium_ior=1.333, focus_depth_um=300.0)
    assert o.native_plane_depth_um == pytest.approx(1.333 * 300.0, rel=2e-3)
    z = np.linspace(-60.0, 60.0, 241)
    i0 = np.abs(native_field(o, np.array([0.0]), z)[:, 0]) ** 2
    dof = 2 * 1.333 * LAM / o.na**2  # first axial zero, 161 µm
    assert abs(z[np.argmax(i0)]) < 0.02 * dof
    # and the focus is the sharp one of a matched medium: peak within 1 % of the matched case
    matched = _low_na(medium_ior=1.333, immersion_ior=1.333)
    i_m = np.abs(native_field(matched, np.array([0.0]), [0.0])[0, 0]) ** 2
    assert i0.max() == pytest.approx(i_m, rel=0.01)
