"""The specimen in the optics: indices, cover glass, focus setting; exact refraction in both
tracers; the focal shift against an independent ray computation."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from lfsim import ConfigError, Optics, paper_optics, small_optics
from lfsim.optics import WATER_40X_OPTICS
from lfsim.scene import load_scene, read_optics, write_scene
from lfsim.tracer import RenderSettings, Sources, to_immersion, trace_mitsuba, trace_paraxial

#: The paper's specimen: a 10 % polyacrylamide gel on a 170 µm glass-bottomed dish, seen by a
#: dry objective not corrected for cover glass, focused 300 µm into the gel.
GEL = {
    "medium_ior": 1.35,
    "coverslip_thickness_um": 170.0,
    "coverslip_ior": 1.523,
    "focus_depth_um": 300.0,
}


def gel_optics(**kw) -> Optics:
    return small_optics(**{**GEL, **kw})


# -- the optics ---------------------------------------------------------------------------------
def test_air_is_unchanged():
    o = paper_optics()
    assert not o.has_interfaces
    assert o.focal_shift_um == 0.0
    assert o.axial_scale == 1.0
    assert o.theta_max == pytest.approx(math.asin(0.2))
    assert o.emission_half_angle == pytest.approx(math.asin(0.2))


def test_paraxial_focal_shift_of_a_gel_behind_a_cover_glass():
    o = gel_optics()
    residual = 170.0 * (1 - 1 / 1.523)  # the uncorrected cover glass, in air
    assert o.paraxial_native_plane_depth_um == pytest.approx(1.35 * (300.0 + residual))
    # The rays of 0.2 NA focus deeper than the paraxial ones (1.36 instead of 1.35 per µm).
    paraxial_shift = 0.35 * 300.0 + 1.35 * residual
    assert o.focal_shift_um == pytest.approx(paraxial_shift, rel=0.04)
    assert o.focal_shift_um > paraxial_shift
    assert o.surface_z_um == pytest.approx(-o.native_plane_depth_um)
    assert o.axial_scale == pytest.approx(1 / 1.35, rel=0.02)
    # The rays of 0.2 NA, not the paraxial ones, set the scale: 1.36 µm of true depth per µm
    # of apparent depth (a paraxial 1.35 would fail this; its value is 1.3583 by the
    # closed-form quadrature of Optics._focus_terms).
    assert 1 / o.axial_scale == pytest.approx(1.36, abs=0.005)
    assert 1 / o.axial_scale > 1.355
    # A cover glass the objective is corrected for shifts nothing.
    c = gel_optics(coverslip_corrected_um=170.0)
    assert c.focal_shift_um == pytest.approx(
        small_optics(**{**GEL, "coverslip_thickness_um": 0.0}).focal_shift_um, rel=1e-3
    )
    # A water objective into water: no shift at all, only the cover glass it is corrected for.
    w = small_optics(
        na=0.8,
        immersion_ior=1.333,
        medium_ior=1.333,
        coverslip_thickness_um=170.0,
        coverslip_corrected_um=170.0,
        focus_depth_um=50.0,
    )
    assert w.focal_shift_um == pytest.approx(0.0, abs=1e-6)
    assert w.theta_max == pytest.approx(math.asin(0.8 / 1.333))


def test_max_axial_scale_is_the_paraxial_ratio_or_the_cone_edge():
    """Apparent / true depth: paraxially n_imm / n_medium; at the edge of the cone
    tan θ_medium / tan θ_immersion, larger for an oil objective into water (exact values)."""
    assert small_optics().max_axial_scale == 1.0
    dry_gel = paper_optics(medium_ior=1.35)
    assert dry_gel.max_axial_scale == pytest.approx(1 / 1.35, rel=1e-12)
    oil_water = paper_optics(na=1.2, immersion_ior=1.518, medium_ior=1.333)
    sin_m = oil_water.emission_half_angle
    edge = math.tan(sin_m) / math.tan(math.asin(1.333 * math.sin(sin_m) / 1.518))
    assert edge > 1.518 / 1.333
    assert oil_water.max_axial_scale == pytest.approx(edge, rel=1e-12)
    assert oil_water.max_axial_scale == pytest.approx(1.602, abs=0.01)


def test_high_na_immersion_objectives_are_accepted():
    o = small_optics(na=1.4, immersion_ior=1.518, medium_ior=1.33, focus_depth_um=10.0)
    # n sin θ is conserved: water caps what an oil objective of NA 1.4 collects at 1.33.
    assert o.emission_half_angle == pytest.approx(math.pi / 2)
    assert o.theta_max == pytest.approx(math.asin(1.4 / 1.518))


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"na": 1.0}, "immersion_ior"),
        ({"na": 1.2, "immersion_ior": 1.0}, "immersion_ior"),
        ({"medium_ior": 0.9}, "medium_ior"),
        ({"immersion_ior": float("nan")}, "immersion_ior"),
        ({"coverslip_ior": 5.0}, "coverslip_ior"),
        ({"coverslip_thickness_um": -1.0}, "coverslip_thickness_um"),
        ({"coverslip_corrected_um": float("inf")}, "coverslip_corrected_um"),
        ({"focus_depth_um": float("nan")}, "focus_depth_um"),
    ],
)
def test_contradictions_are_refused_by_name(kw, needle):
    with pytest.raises(ConfigError, match=needle):
        small_optics(**kw)


def test_scene_files_carry_the_specimen(tmp_path, backend):
    for o in (gel_optics(), gel_optics(coverslip_corrected_um=170.0, mla_kind="glass")):
        path = write_scene(o, tmp_path / f"{o.mla_kind}.xml")
        assert read_optics(path) == o
        scene = load_scene(path)
        assert (scene.correction is not None) == (o.coverslip_corrected_um > 0)
    text = path.read_text()
    assert 'id="specimen_surface"' in text and 'id="coverslip_front"' in text
    # An edited specimen plane is refused by name.
    bad = tmp_path / "bad.xml"
    bad.write_text(text.replace('name="int_ior" value="1.35"', 'name="int_ior" value="1.33"'))
    with pytest.raises(Exception, match="specimen_surface"):
        read_optics(bad)


def test_scene_files_without_the_specimen_fields_describe_air(tmp_path):
    path = write_scene(small_optics(), tmp_path / "air.xml")
    text = path.read_text()
    for name in ("immersion_ior", "coverslip_thickness_um", "focus_depth_um"):
        text = "\n".join(ln for ln in text.splitlines() if f'name="{name}"' not in ln)
    old = tmp_path / "old.xml"
    old.write_text(text)
    assert read_optics(old) == small_optics()


def test_a_native_plane_in_front_of_the_specimen_continues_its_depth_scale():
    """Focused into the glass bottom, the native plane lies in front of the gel: ``z`` is the
    gel's depth scale continued through it, so a point ``d`` below the surface lies at
    ``z = surface_z_um + d`` and the depths stay linear in the focus setting."""
    far = gel_optics(focus_depth_um=-130.0)
    residual = 170.0 * (1 - 1 / 1.523)
    assert far.paraxial_native_plane_depth_um == pytest.approx(1.35 * (-130.0 + residual))
    assert far.native_plane_depth_um < 0 and far.surface_z_um > 0
    assert far.surface_z_um == pytest.approx(-far.native_plane_depth_um)
    assert far.axial_scale == pytest.approx(gel_optics().axial_scale, rel=1e-12)
    # The focus moves the native plane by 1/axial_scale per µm of stage travel on either side
    # of the surface.
    shift = gel_optics().native_plane_depth_um - far.native_plane_depth_um
    assert shift == pytest.approx(430.0 / far.axial_scale, rel=1e-9)


def test_sources_in_front_of_the_specimen_are_refused(backend):
    o = gel_optics()
    z_surface = o.surface_z_um
    src = Sources.spheres([[0.0, 0.0, z_surface + 5.0]], 15.0)  # reaches 2.5 µm out
    with pytest.raises(ConfigError, match="front of the specimen"):
        trace_paraxial(o, src, RenderSettings(rays_per_particle=1000))


# -- refraction -----------------------------------------------------------------------------
def _rays(n: int, half_angle: float, z_um: float, seed: int = 0):
    import drjit as dr  # noqa: F401
    import mitsuba as mi

    rng = np.random.default_rng(seed)
    cos = rng.uniform(math.cos(half_angle), 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    sin = np.sqrt(1 - cos**2)
    d = np.c_[sin * np.cos(phi), sin * np.sin(phi), cos]
    o = np.c_[rng.uniform(-20, 20, (n, 2)), np.full(n, z_um)]
    return (
        mi.Point3f(*(mi.Float(o[:, k].astype(np.float32)) for k in range(3))),
        mi.Vector3f(*(mi.Float(d[:, k].astype(np.float32)) for k in range(3))),
        d,
    )


@pytest.mark.parametrize(
    "kw",
    [
        GEL,
        {**GEL, "coverslip_thickness_um": 0.0},
        {"na": 0.8, "immersion_ior": 1.333, "medium_ior": 1.35, "focus_depth_um": 40.0},
    ],
    ids=["gel-cover-glass", "gel-bare", "water-objective"],
)
def test_snell_law_at_every_interface(backend, kw):
    import drjit as dr
    import mitsuba as mi

    o = small_optics(**kw)
    origin, direction, d = _rays(4000, o.emission_half_angle, 50.0)
    _x, _y, _z, u, v, trans = to_immersion(o, origin, direction, dr, mi)
    u, v, trans = (np.asarray(a.numpy(), np.float64) for a in (u, v, trans))
    # n sin θ is the same in the specimen and in the immersion medium (slopes → sines).
    sin_out = np.hypot(u, v) / np.sqrt(1 + u**2 + v**2)
    sin_in = np.hypot(d[:, 0], d[:, 1])
    ok = trans > 0
    assert ok.all()
    np.testing.assert_allclose(o.immersion_ior * sin_out, o.medium_ior * sin_in, atol=1e-6)
    # The plane of incidence is kept.
    np.testing.assert_allclose(np.arctan2(v, u), np.arctan2(d[:, 1], d[:, 0]), atol=1e-5)
    # Fresnel: normal incidence loses ((n1 − n2)/(n1 + n2))² per interface.
    assert trans.max() <= 1.0
    n = [o.medium_ior, *([o.coverslip_ior] if o.coverslip_thickness_um else []), o.immersion_ior]
    normal = np.prod([1 - ((a - b) / (a + b)) ** 2 for a, b in itertools.pairwise(n)])
    assert trans[np.argmin(sin_in)] == pytest.approx(normal, rel=1e-3)


def test_mitsuba_dielectric_planes_obey_snell(tmp_path, backend):
    import mitsuba as mi

    o = gel_optics()
    scene = load_scene(write_scene(o, tmp_path / "gel.xml"))
    lay = scene.layout
    by_id = {s.id(): s for s in scene.mi_scene.shapes()}
    ctx = mi.BSDFContext()
    for sid, z, n1, n2 in [
        ("specimen_surface", lay.surface_z, o.medium_ior, o.coverslip_ior),
        ("coverslip_front", lay.coverslip_front_z, o.coverslip_ior, o.immersion_ior),
    ]:
        for sin_in in (0.05, 0.12, 0.19):
            d = mi.Vector3f(sin_in, 0.0, math.sqrt(1 - sin_in**2))
            ray = mi.Ray3f(mi.Point3f(0.0, 0.0, z - 1e-3), d)
            si = scene.mi_scene.ray_intersect(ray)
            assert si.shape == mi.ShapePtr(by_id[sid])
            bs, _w = si.bsdf(ray).sample(ctx, si, 0.999, mi.Point2f(0.5))  # transmission
            out = si.to_world(bs.wo)
            assert out.z[0] > 0
            assert n2 * out.x[0] == pytest.approx(n1 * sin_in, abs=1e-6)


# -- the two tracers agree --------------------------------------------------------------------
@pytest.mark.parametrize(
    "kw",
    [
        {**GEL, "coverslip_thickness_um": 0.0},
        GEL,
        {**GEL, "coverslip_corrected_um": 170.0},
        {"na": 0.8, "immersion_ior": 1.333, "medium_ior": 1.35, "focus_depth_um": 40.0},
        {**GEL, "focus_depth_um": -130.0},
    ],
    ids=["gel-bare", "gel-cover-glass", "gel-corrected-glass", "water-objective", "focus-in-glass"],
)
def test_mitsuba_and_direct_tracers_agree_through_the_specimen(tmp_path, backend, kw):
    o = small_optics(**kw)
    scene = load_scene(write_scene(o, tmp_path / "specimen.xml"))
    dz = max(0.0, o.surface_z_um + 40.0) if o.has_interfaces else 0.0  # beyond the surface
    src = Sources.spheres([[10.0, -20.0, 120.0 + dz], [-60.0, 40.0, -30.0 + dz]], 5.0)
    s0 = RenderSettings(rays_per_particle=100_000, seed=0)
    s1 = RenderSettings(rays_per_particle=100_000, seed=1)
    mit = trace_mitsuba(scene, src, s0)
    par0 = trace_paraxial(o, src, s0)
    noise = l1(par0, trace_paraxial(o, src, s1))  # sampling noise of two independent renders
    # The same rays up to the Fresnel draws (Mitsuba samples the interfaces' reflections,
    # the direct tracer their transmittance): far below the sampling noise.
    assert l1(mit, par0) < 0.5 * noise
    # Fresnel losses alike: ≈ 2.6 % at two glass interfaces, 0.3 % at a bare gel.
    assert abs(int(mit.sum()) - int(par0.sum())) < 4 * math.sqrt(par0.sum())
    assert par0.sum() < 2 * 100_000


def l1(a, b) -> float:
    return float(np.abs(a.astype(np.float64) - b).sum() / b.sum())


# -- the focal shift ----------------------------------------------------------------------------
def _least_squares_focus_um(o: Optics, z_um: float, virtual_front: bool = False) -> float:
    """Nominal-frame depth where the tracer's rays from a point at true ``z_um`` converge best
    (least-squares distance of the immersion-space rays to the axis point)."""
    import drjit as dr
    import mitsuba as mi

    origin, direction, _d = _rays(20000, o.emission_half_angle, z_um, seed=3)
    origin = mi.Point3f(origin.x * 0, origin.y * 0, origin.z)
    x, _y, z, u, _v, _t = to_immersion(o, origin, direction, dr, mi, virtual_front=virtual_front)
    x, z, u = (np.asarray(a.numpy(), np.float64) for a in (x, z, u))
    # x(Z) = x + u (z − Z): the Z that minimises Σ x(Z)² (uniform over the emission cone).
    return float(np.sum(u * (x + u * z)) / np.sum(u * u))


@pytest.mark.parametrize(
    "kw",
    [
        GEL,
        {**GEL, "coverslip_corrected_um": 170.0},
        {"na": 0.8, "immersion_ior": 1.333, "medium_ior": 1.333, "focus_depth_um": 100.0},
        {"na": 0.8, "immersion_ior": 1.333, "medium_ior": 1.38, "focus_depth_um": 100.0},
        {**GEL, "focus_depth_um": -130.0},
    ],
    ids=["dry-gel", "dry-gel-corrected", "water-water", "water-gel", "dry-gel-focus-in-glass"],
)
def test_focal_shift_agrees_with_the_exact_ray_optics(backend, kw):
    o = small_optics(**kw)
    # The tracer's rays from a point converge where the optics' closed-form Snell optics
    # (Optics._focus_terms) says they do: a point at true z at the apparent depth
    # axial_scale · z. Points in the specimen: on the native plane (apparent depth 0, the
    # nominal focal plane), or 50 µm past the surface where the native plane lies in front of it.
    z_a = max(0.0, o.surface_z_um + 50.0)
    traced = _least_squares_focus_um(o, z_a)
    assert traced == pytest.approx(o.axial_scale * z_a, abs=0.05)
    # The measured focal shift (the nominal-frame depth of the point whose rays converge on the
    # nominal focal plane) agrees with the optics' value within 1 %.
    z_star = z_a - traced / (_least_squares_focus_um(o, z_a + 50.0) - traced) * 50.0
    measured = o.focal_shift_um + z_star
    assert measured == pytest.approx(o.focal_shift_um, rel=0.01, abs=0.1)


def _lenslet_spread_um2(o: Optics, z_um: float) -> float:
    """Second moment (object µm²) of a rendered point image's light over the lenslets.

    The sensor image of a point on the axis at true depth ``z_um`` (direct tracer, ideal
    lenslets, no diffraction blur, which would carry light across the lenslets' edges), summed
    per lenslet; its variance about its centroid in lenslet pitches, scaled to the object.
    Beyond a lenslet of blur it grows as the square of the apparent defocus, and as the same
    function on both sides of the native plane."""
    settings = RenderSettings(rays_per_particle=400_000, mode="expected", seed=5, diffraction=False)
    img = trace_paraxial(o, Sources.spheres([[0.0, 0.0, z_um]], 0.0), settings)
    p = round(o.px_per_lenslet)
    h, w = img.shape
    per_lenslet = img[: h // p * p, : w // p * p].reshape(h // p, p, w // p, p).sum(axis=(1, 3))
    ky, kx = np.indices(per_lenslet.shape, dtype=np.float64)
    total = per_lenslet.sum()
    var = 0.0
    for k in (ky, kx):
        mean = (per_lenslet * k).sum() / total
        var += (per_lenslet * (k - mean) ** 2).sum() / total
    return var * o.lenslet_object_um**2


def _sharpest_depth_um(o: Optics, offsets_um) -> float:
    """True depth (µm, from ``z = 0``) where rendered point images are sharpest on the array:
    the vertex of a parabola through the lenslet spreads at ``z = ±offsets_um``."""
    depths = np.array([-d for d in offsets_um[::-1]] + list(offsets_um), dtype=np.float64)
    spread = np.array([_lenslet_spread_um2(o, z) for z in depths])
    a, b, _c = np.polyfit(depths, spread, 2)
    assert a > 0
    # Sharper towards the native plane on both sides (the lenslets quantise the spread, so it is
    # a parabola only on average; the vertex rests on the symmetry of the two sides).
    n = len(offsets_um)
    assert np.all(np.diff(spread[:n]) < 0) and np.all(np.diff(spread[n:]) > 0)
    return float(-b / (2 * a))


@pytest.mark.parametrize(
    "kw, offsets_um, tol",
    [
        (GEL, (100.0, 200.0, 300.0), 0.01),
        (WATER_40X_OPTICS, (4.0, 8.0, 12.0), 0.01),
        ({**WATER_40X_OPTICS, "medium_ior": 1.38, "focus_depth_um": 100.0}, (4.0, 8.0, 12.0), 0.03),
    ],
    ids=["dry-4x-into-gel", "water-40x-into-water", "water-40x-into-gel"],
)
def test_focal_shift_measured_on_rendered_point_images(backend, kw, offsets_um, tol):
    """Where rendered point images are sharpest on the lenslets: the native object plane.

    A point on the axis is rendered (direct tracer, ideal lenslets, no diffraction blur) at
    true depths symmetric about the optics' native plane (``z = 0``), beyond a lenslet of blur;
    the vertex of a parabola through the second moments of its light over the lenslets is
    where the images focus on the array. Its depth below the specimen's surface agrees with
    the analytic ``native_plane_depth_um`` (closed-form Snell optics, ``Optics._focus_terms``)
    within 1 % of the focal shift at 4×/0.2 into the gel, and of the native plane's depth in
    water under the water objective, where the shift is 0.

    The measure has an offset of its own: the dry objective maps ``f tan θ``, so its marginal
    rays reach the array 2 % steeper than an f/10 lenslet's half-width and cross into the next
    lenslet on one side of focus only (−1.6 µm in air, where the native plane is the nominal
    focal plane exactly: 4f slope lenses image depth without aberration). It is measured on
    the same optics without the specimen at the same apparent defocus and removed. At NA 0.8
    into a gel the sharpest images (a least-squares focus over the source's depth) and the
    analytic least-squares focus over the image's depth part by 2 % of the 4.7 µm shift: there
    the bound is 3 %. Both specimens tell the exact shift from the paraxial one (2.2 % and
    26 % of the shift apart)."""
    o = small_optics(**kw)
    assert o.has_interfaces
    bare = small_optics(
        **{
            **kw,
            "medium_ior": o.immersion_ior,
            "coverslip_thickness_um": 0.0,
            "coverslip_corrected_um": 0.0,
        }
    )
    assert not bare.has_interfaces and bare.native_plane_depth_um == bare.focus_depth_um
    offset = _sharpest_depth_um(bare, tuple(d * o.axial_scale for d in offsets_um))
    if o.is_immersion:
        assert abs(offset) < 0.001 * offsets_um[0]  # the aplanatic objective: no cross-talk
    vertex = _sharpest_depth_um(o, offsets_um) - offset / o.axial_scale
    measured_depth = o.native_plane_depth_um + vertex  # below the specimen's surface
    shift = o.focal_shift_um
    scale = abs(shift) if abs(shift) > 1.0 else o.native_plane_depth_um
    assert measured_depth == pytest.approx(o.native_plane_depth_um, abs=tol * scale)
    if abs(shift) > 1.0:
        paraxial = o.paraxial_native_plane_depth_um
        assert abs(measured_depth - paraxial) > 2 * tol * abs(shift)


def test_guard_planes_in_front_of_the_surface_continue_the_specimen(backend):
    """A source in front of the specimen's near surface (a guard plane of a PSF bank) is traced
    as if the specimen went on: its rays converge at the apparent depth the linear Snell optics
    gives inside the specimen (``axial_scale · z``), its pattern is as bright as one just
    behind the surface, and without ``virtual_front`` the source is refused by name."""
    o = small_optics(**{**GEL, "focus_depth_um": -130.0})  # surface at z = 96 µm
    for dz in (-30.0, -80.0):
        z = o.surface_z_um + dz
        traced = _least_squares_focus_um(o, z, virtual_front=True)
        assert traced == pytest.approx(o.axial_scale * z, abs=0.05)
    settings = RenderSettings(rays_per_particle=20_000, mode="expected", seed=1)
    front = Sources.spheres([[0.0, 0.0, o.surface_z_um - 5.0]], 0.0)
    behind = Sources.spheres([[0.0, 0.0, o.surface_z_um + 5.0]], 0.0)
    a = trace_paraxial(o, front, settings, virtual_front=True)
    b = trace_paraxial(o, behind, settings)
    assert a.sum() == pytest.approx(b.sum(), rel=0.01)  # the same Fresnel losses
    with pytest.raises(ConfigError, match="in front of the specimen's near surface"):
        trace_paraxial(o, front, settings)


def test_lfsim_micrometer_in_a_specimen_scene_lies_on_the_cover_glass(tmp_path, capsys):
    """``lfsim micrometer`` on a gel scene: the reticle lies on the cover glass, so a depth
    into the glass is one line naming the option, and nothing is written."""
    from pathlib import Path

    from lfsim.cli import main

    scene = Path(__file__).resolve().parents[2] / "scenes" / "medium_gel.xml"
    out = tmp_path / "m.tif"
    rc = main(["-q", "micrometer", str(scene), "-o", str(out), "--z-um", "-5"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and not out.exists()
    assert len(err.splitlines()) == 1 and "--z-um" in err and "cover glass" in err


# -- an immersion objective is aplanatic ----------------------------------------------------
def test_an_immersion_objective_obeys_the_sine_condition_and_images_depth_over_n(backend):
    """A water objective (NA 0.8) into water: every ray crosses the back focal plane at
    ``f · n sin θ`` (the stop, ``f · NA``, passes exactly the cone of NA 0.8), and a point at
    depth z is imaged where a point at z / n would be in air: the air-equivalent rays of the
    paraxial cone converge z / (n cos θ) from the nominal plane (Abbe: M² / n)."""
    import drjit as dr
    import mitsuba as mi

    from lfsim.tracer import objective_rays

    o = small_optics(na=0.8, immersion_ior=1.333, medium_ior=1.333)
    assert o.is_immersion and not o.has_interfaces
    assert o.stop_radius_um == pytest.approx(o.f_objective_um * 0.8)
    z = 60.0
    origin, direction, d = _rays(4000, o.emission_half_angle, z)
    x, y, z0, u, v, _t = objective_rays(o, origin, direction, dr, mi)
    x, y, z0, u, v = (np.asarray(a.numpy(), np.float64) for a in (x, y, z0, u, v))
    o_np = np.c_[origin.x.numpy(), origin.y.numpy()]
    sin = np.hypot(d[:, 0], d[:, 1])
    cos = d[:, 2]
    np.testing.assert_allclose(np.hypot(u, v), o.immersion_ior * sin, atol=1e-5)
    assert np.hypot(u, v).max() <= o.na + 1e-5  # the stop at f · NA passes every ray
    np.testing.assert_allclose(z0, 0.0)
    # The intercept with the nominal plane: the straight ray in water.
    np.testing.assert_allclose(x, o_np[:, 0] + d[:, 0] / cos * z, atol=1e-3)
    # Each air-equivalent ray crosses the line through its source point parallel to the axis
    # at Z = −z / (n cos θ): paraxially the point images as z / n in air.
    off = np.abs(u) > 0.05  # single precision: rays near the axis cross anywhere
    crossing = -(x - o_np[:, 0])[off] / u[off]
    np.testing.assert_allclose(crossing, -z / (o.immersion_ior * cos[off]), rtol=1e-4)
    # A dry objective is the thin lens itself: objective_rays is to_immersion.
    dry = small_optics()
    a = objective_rays(dry, origin, direction, dr, mi)
    b = to_immersion(dry, origin, direction, dr, mi)
    for p, q in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(p.numpy()), np.asarray(q.numpy()))
