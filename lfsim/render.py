"""High-level rendering: particles, a white (uniformly fluorescent) slide, a stage micrometer.

These functions turn object-space descriptions into noise-free light-field images with one of
the tracers of :mod:`lfsim.tracer`; :mod:`lfsim.noise` then makes them camera-like.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.validate import positive_float

from .errors import ConfigError
from .particles import Particles
from .tracer import RenderSettings, Sources, trace_mitsuba, trace_paraxial

log = logging.getLogger(__name__)

TRACERS = ("mitsuba", "paraxial")


def _trace(scene, sources: Sources, settings: RenderSettings, tracer: str) -> np.ndarray:
    if tracer not in TRACERS:
        raise ConfigError(f"tracer must be one of {TRACERS}, got {tracer!r}")
    if tracer == "mitsuba":
        return trace_mitsuba(scene, sources, settings)
    optics = getattr(scene, "optics", scene)
    if optics.mla_kind != "ideal":
        raise ConfigError(
            f"tracer 'paraxial' models ideal lenslets only, but the scene has a "
            f"{optics.mla_kind!r} microlens array: use tracer 'mitsuba'"
        )
    return trace_paraxial(optics, sources, settings)


def max_depth_um(optics) -> float:
    """Largest ``|z|`` (µm) whose light still falls mostly on the sensor.

    A point at depth ``z`` from the native focal plane spreads its light over a disc of
    object-space diameter ``2 |z| a tan θ`` (θ the acceptance half-angle in the immersion
    medium, ``a`` the ratio of apparent to true depth in the specimen: ``2 |z| tan(asin NA)``
    in air); beyond the depth where that disc is as wide as the narrower side of the field of
    view (``Optics.field_of_view_xy_um``), a particle is no longer imaged, only a faint uniform
    background.
    """
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    width = min(x1 - x0, y1 - y0)
    return width / (2.0 * math.tan(optics.theta_max) * optics.axial_scale)


def check_depths(optics, positions_um: np.ndarray, ids=None, what: str = "particles") -> None:
    """Raise :class:`ConfigError` for points behind the objective or beyond
    :func:`max_depth_um` from the focal plane (the message gives the first and the limit)."""
    p = np.asarray(positions_um, dtype=np.float64).reshape(-1, 3)
    limit = max_depth_um(optics)
    behind = p[:, 2] <= -optics.f_objective_um
    far = np.abs(p[:, 2]) > limit
    outside = p[:, 2] < optics.surface_z_um if optics.has_interfaces else np.zeros(len(p), bool)
    for bad, why in (
        (behind, f"lie behind the objective (z <= -{optics.f_objective_um:.0f} µm)"),
        (
            outside,
            f"lie in front of the specimen's near surface (z < {optics.surface_z_um:.1f} µm; "
            "focus_depth_um sets it)",
        ),
        (far, f"lie outside the imaged depth range |z| <= {limit:.0f} µm"),
    ):
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            ident = int(ids[k]) if ids is not None else k
            raise ConfigError(
                f"{int(bad.sum())} {what} {why} (first: id {ident} at z={p[k, 2]:.1f} µm); "
                "positions are in µm from the native focal plane"
            )


def check_in_field(optics, positions_um: np.ndarray, ids=None, what: str = "particles") -> None:
    """Raise :class:`ConfigError` if any point lies outside the object-space field of view.

    The field is the sensor's footprint in object space, ``Optics.field_of_view_xy_um``, and the
    depth range of :func:`check_depths`.
    """
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    p = np.asarray(positions_um)
    check_depths(optics, p, ids, what)
    out = (p[:, 0] < x0) | (p[:, 0] > x1) | (p[:, 1] < y0) | (p[:, 1] > y1)
    if np.any(out):
        k = int(np.flatnonzero(out)[0])
        ident = int(ids[k]) if ids is not None else k
        raise ConfigError(
            f"{int(out.sum())} {what} lie outside the field of view x ∈ [{x0:.1f}, {x1:.1f}] µm, "
            f"y ∈ [{y0:.1f}, {y1:.1f}] µm (first: id {ident} at x={p[k, 0]:.1f}, "
            f"y={p[k, 1]:.1f} µm)"
        )


def render_particles(
    scene,
    particles: Particles,
    settings: RenderSettings | None = None,
    *,
    tracer: str = "mitsuba",
    check_field: bool = True,
) -> np.ndarray:
    """Render fluorescent spheres into a noise-free light-field image.

    Parameters
    ----------
    scene : LightFieldScene or Optics
        A loaded scene (``tracer="mitsuba"``), or a scene/optics for ``"paraxial"``.
    particles : Particles
        Positions (µm, object frame), diameters (µm) and relative brightnesses.
    settings : RenderSettings
        ``settings.model`` ``"wave"`` renders with the wave-optics model
        (:func:`lfsim.wave_render.render_wave`; the optics must have ideal lenslets) and
        ignores ``tracer``.
    tracer : {"mitsuba", "paraxial"}
    check_field : bool
        Refuse particles outside the field of view (default).

    Returns
    -------
    ndarray, shape (height, width)
        Photon counts (``uint32``) or expected photons (``float32``).
    """
    settings = settings or RenderSettings()
    optics = getattr(scene, "optics", scene)
    if check_field and len(particles):
        check_in_field(optics, particles.positions_um, particles.ids)
    src = Sources.spheres(particles.positions_um, particles.diameter_um, particles.brightness)
    if settings.model == "wave":
        from .wave_render import render_wave

        return render_wave(optics, src, settings)
    return _trace(scene, src, settings, tracer)


def white_sources(optics, thickness_um: float = 2.0, margin_um: float | None = None) -> Sources:
    """A uniformly fluorescent slide at the native object plane covering the field.

    One box source per lenslet footprint (so ray counts per box stay small), extended by
    ``margin_um`` (default: the cone's lateral reach over the slide plus two lenslets) so that
    the edge of the sensor sees a full cone of light.
    """
    if thickness_um <= 0:
        raise ConfigError(f"thickness_um must be > 0, got {thickness_um!r}")
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    step = optics.lenslet_object_um
    if margin_um is None:
        margin_um = 2 * step
    xs = np.arange(x0 - margin_um, x1 + margin_um, step) + step / 2
    ys = np.arange(y0 - margin_um, y1 + margin_um, step) + step / 2
    gx, gy = np.meshgrid(xs, ys)
    # In a specimen whose surface is within half a slide of the native plane, the slide lies
    # just inside the specimen.
    z = max(0.0, optics.surface_z_um + thickness_um / 2) if optics.has_interfaces else 0.0
    centers = np.c_[gx.ravel(), gy.ravel(), np.full(gx.size, z)]
    return Sources.boxes(centers, (step, step, thickness_um))


#: Rays per lenslet footprint of a white image (the default of the CLI and experiment files).
WHITE_RAYS_PER_LENSLET = 20_000
#: Stage micrometer defaults: line spacing and width (µm) and rays per line.
MICROMETER_DIVISION_UM = 10.0
MICROMETER_LINE_WIDTH_UM = 2.0
MICROMETER_RAYS_PER_LINE = 50_000


def render_white(
    scene,
    rays_per_lenslet: int = WHITE_RAYS_PER_LENSLET,
    *,
    seed: int = 0,
    diffraction: bool = True,
    tracer: str = "mitsuba",
    progress: bool = False,
) -> np.ndarray:
    """Image of a uniformly fluorescent slide (lenslet calibration, paper Fig. 1b inset).

    Returns
    -------
    ndarray, shape (height, width), uint32 photon counts.
    """
    optics = getattr(scene, "optics", scene)
    settings = RenderSettings(
        rays_per_particle=rays_per_lenslet, seed=seed, diffraction=diffraction, progress=progress
    )
    return _trace(scene, white_sources(optics), settings, tracer)


def micrometer_sources(
    optics,
    division_um: float = 10.0,
    line_width_um: float = 2.0,
    axis: str = "x",
    z_um: float = 0.0,
    rotation_deg: float = 0.0,
) -> Sources:
    """A fluorescent stage-micrometer reticle: lines every ``division_um`` across the field.

    Lines are perpendicular to ``axis`` (``"x"``: vertical lines at x = k · division);
    every 5th line is 1.5× and every 10th 2× longer, as on a real reticle. The scale is
    centred on the optical axis.

    Parameters
    ----------
    optics : Optics
    division_um, line_width_um : float
        Line spacing and line width (µm), ``0 < line_width_um < division_um``.
    axis : {"x", "y"}
        Direction along which the divisions are counted.
    z_um : float
        Depth of the reticle (µm; 0 = native object plane).
    rotation_deg : float
        Rotation of the whole reticle about the optical axis (degrees, from +x towards +y,
        in [-90, 90]). A rotated line is a row of short axis-aligned boxes whose centres
        follow the rotated line; each is short enough that the steps between them stay below
        5 % of the line width. Beyond ±45° the reticle is drawn as the one along the other
        axis rotated by ``rotation_deg ∓ 90`` (the same ruling: its scale runs at
        ``rotation_deg`` from ``axis``), so that the boxes stay within 45° of their line.

    Returns
    -------
    Sources
        Box sources, brightness proportional to their length (uniform line brightness).
    """
    with raised_as(ConfigError):
        division_um = positive_float(division_um, "division_um")
        line_width_um = positive_float(line_width_um, "line_width_um")
    if line_width_um >= division_um:
        raise ConfigError(
            f"line_width_um must be smaller than division_um, got {line_width_um:g} and "
            f"{division_um:g} µm"
        )
    if axis not in ("x", "y"):
        raise ConfigError(f"axis must be 'x' or 'y', got {axis!r}")
    if not np.isfinite(rotation_deg) or abs(rotation_deg) > 90.0:
        raise ConfigError(f"rotation_deg must lie in [-90, 90] degrees, got {rotation_deg!r}")
    if abs(rotation_deg) > 45.0:
        # The scale at rotation_deg from axis is the scale along the other axis at
        # rotation_deg ∓ 90: drawn that way, its boxes stay within 45° of their line.
        axis = "y" if axis == "x" else "x"
        rotation_deg = rotation_deg - math.copysign(90.0, rotation_deg)
    if not np.isfinite(z_um):
        raise ConfigError(f"z_um must be a finite depth in µm, got {z_um!r}")
    if z_um <= -optics.f_objective_um or abs(z_um) > max_depth_um(optics):
        raise ConfigError(
            f"z_um {z_um:g} µm puts the reticle outside the imaged depth range "
            f"|z| <= {max_depth_um(optics):.0f} µm (µm from the native focal plane)"
        )
    x0, x1, y0, y1 = optics.field_of_view_xy_um
    other = (y1 - y0) if axis == "x" else (x1 - x0)
    t = np.radians(rotation_deg)
    c, s = np.cos(t), np.sin(t)
    # Unit vectors of the scale and of the lines in the object frame (x, y).
    e_scale = np.array([c, s]) if axis == "x" else np.array([-s, c])
    e_line = np.array([-s, c]) if axis == "x" else np.array([c, s])
    corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]) @ e_scale
    lo, hi = corners.min(), corners.max()
    ks = np.arange(np.ceil(lo / division_um - 1e-9), np.floor(hi / division_um + 1e-9) + 1)
    if len(ks) < 2:
        raise ConfigError(
            f"division_um {division_um:g} µm puts {len(ks)} line(s) in the {hi - lo:.4g} µm "
            f"field of view along {axis}; a scale needs at least 2 (choose a smaller division)"
        )
    base = 0.2 * other
    lengths = np.where(ks % 10 == 0, 2.0 * base, np.where(ks % 5 == 0, 1.5 * base, base))
    pos = ks * division_um
    mid = -(lengths / 2) + base  # line centre along the line direction
    if rotation_deg == 0.0:
        n_seg = np.ones(len(ks), dtype=int)
    else:
        seg_max = 0.05 * line_width_um / abs(s)
        n_seg = np.maximum(np.ceil(lengths / seg_max).astype(int), 1)
    line = np.repeat(np.arange(len(ks)), n_seg)
    first = np.repeat(np.cumsum(n_seg) - n_seg, n_seg)
    j = np.arange(len(line)) - first  # segment number along its line
    seg_len = lengths[line] / n_seg[line]
    along = mid[line] - lengths[line] / 2 + (j + 0.5) * seg_len
    xy = pos[line, None] * e_scale + along[:, None] * e_line
    n = len(line)
    centers = np.zeros((n, 3))
    sizes = np.zeros((n, 3))
    centers[:, :2] = xy
    if axis == "x":
        sizes[:, 0], sizes[:, 1] = line_width_um, seg_len
    else:
        sizes[:, 1], sizes[:, 0] = line_width_um, seg_len
    centers[:, 2] = z_um
    sizes[:, 2] = RETICLE_THICKNESS_UM
    return Sources.boxes(centers, sizes, weights=seg_len / base)


def micrometer_optics(optics):
    """The optics a stage micrometer is imaged with in a microscope with a specimen.

    The reticle is a calibration slide laid on the cover glass (or dish bottom) in place of
    the specimen: beyond the cover glass lies air (the immersion medium when there is no
    cover glass, as for a dipping objective), and the focus is set on the cover glass. The
    lateral magnification of a focused plane does not depend on the planar interfaces, so
    the pixel size measured on the reticle is the specimen's.

    Parameters
    ----------
    optics : Optics

    Returns
    -------
    Optics
        ``optics`` itself without interfaces; otherwise the same microscope with
        ``medium_ior`` 1 (or ``immersion_ior``) and ``focus_depth_um`` the cover glass's
        paraxial focal shift the other way, so that the native object plane lies on the cover
        glass (``surface_z_um`` ≈ 0; the rays of the full aperture focus a little deeper).
    """
    from dataclasses import replace

    if not optics.has_interfaces:
        return optics
    medium = 1.0 if optics.coverslip_thickness_um > 0 else optics.immersion_ior
    dry = replace(optics, medium_ior=medium, focus_depth_um=0.0)
    if not dry.has_interfaces:
        return dry
    return replace(dry, focus_depth_um=-dry._coverslip_residual_um)


#: Thickness of the reticle's lines along z (µm): the boxes of :func:`micrometer_sources`.
RETICLE_THICKNESS_UM = 1.0


def micrometer_placement(optics, z_um: float = 0.0):
    """The optics a micrometer is imaged with (:func:`micrometer_optics`) and the depth of
    its reticle in them (µm): ``z_um`` itself without a specimen; with one, the reticle lies
    on the cover glass, ``z_um`` (≥ 0, else :class:`ConfigError`) beyond it."""
    slide = micrometer_optics(optics)
    if slide is optics:
        return slide, z_um
    if not z_um >= 0:
        raise ConfigError(
            f"z_um {z_um:g} µm puts the reticle inside the cover glass it lies on (the "
            "microscope has a specimen: the reticle lies on its cover glass); give z_um >= 0"
        )
    return slide, slide.surface_z_um + RETICLE_THICKNESS_UM / 2 + z_um


def render_micrometer(
    scene,
    division_um: float = MICROMETER_DIVISION_UM,
    *,
    line_width_um: float = MICROMETER_LINE_WIDTH_UM,
    axis: str = "x",
    rays_per_line: int = MICROMETER_RAYS_PER_LINE,
    seed: int = 0,
    tracer: str = "mitsuba",
    rotation_deg: float = 0.0,
    z_um: float = 0.0,
) -> np.ndarray:
    """Light-field image of a stage micrometer (paper §4), by default in the native object
    plane; see :func:`micrometer_sources` for the reticle, its rotation and depth.

    In a microscope with a specimen (``Optics.has_interfaces``) the reticle lies on the
    cover glass in place of the specimen (:func:`micrometer_optics`), ``z_um`` (≥ 0) beyond
    the plane in focus."""
    optics = getattr(scene, "optics", scene)
    slide, z_um = micrometer_placement(optics, z_um)
    if slide is not optics:
        if tracer == "mitsuba":
            from .scene import scene_from_optics

            scene = scene_from_optics(slide)
        else:
            scene = slide
    src = micrometer_sources(
        slide,
        division_um,
        line_width_um,
        axis,
        z_um=z_um,
        rotation_deg=rotation_deg,
    )
    settings = RenderSettings(rays_per_particle=rays_per_line, seed=seed)
    return _trace(scene, src, settings, tracer)
