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
    return trace_paraxial(optics, sources, settings)


def max_depth_um(optics) -> float:
    """Largest ``|z|`` (µm) whose light still falls mostly on the sensor.

    A point at depth ``z`` from the native focal plane spreads its light over a disc of
    object-space diameter ``2 |z| tan(asin NA)``; beyond the depth where that disc is as wide
    as the narrower side of the field of view (``Optics.field_of_view_um``), a particle is no
    longer imaged, only a faint uniform background.
    """
    x0, x1, y0, y1 = optics.field_of_view_um
    width = min(x1 - x0, y1 - y0)
    return width / (2.0 * math.tan(math.asin(optics.na)))


def check_depths(optics, positions_um: np.ndarray, ids=None, what: str = "particles") -> None:
    """Raise :class:`ConfigError` for points behind the objective or beyond
    :func:`max_depth_um` from the focal plane (the message gives the first and the limit)."""
    p = np.asarray(positions_um, dtype=np.float64).reshape(-1, 3)
    limit = max_depth_um(optics)
    behind = p[:, 2] <= -optics.f_objective_um
    far = np.abs(p[:, 2]) > limit
    for bad, why in (
        (behind, f"lie behind the objective (z <= -{optics.f_objective_um:.0f} µm)"),
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

    The field is the sensor's footprint in object space, ``Optics.field_of_view_um``, and the
    depth range of :func:`check_depths`.
    """
    x0, x1, y0, y1 = optics.field_of_view_um
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
    return _trace(scene, src, settings, tracer)


def white_sources(optics, thickness_um: float = 2.0, margin_um: float | None = None) -> Sources:
    """A uniformly fluorescent slide at the native object plane covering the field.

    One box source per lenslet footprint (so ray counts per box stay small), extended by
    ``margin_um`` (default: the cone's lateral reach over the slide plus two lenslets) so that
    the edge of the sensor sees a full cone of light.
    """
    if thickness_um <= 0:
        raise ConfigError(f"thickness_um must be > 0, got {thickness_um!r}")
    x0, x1, y0, y1 = optics.field_of_view_um
    step = optics.lenslet_object_um
    if margin_um is None:
        margin_um = 2 * step
    xs = np.arange(x0 - margin_um, x1 + margin_um, step) + step / 2
    ys = np.arange(y0 - margin_um, y1 + margin_um, step) + step / 2
    gx, gy = np.meshgrid(xs, ys)
    centers = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    return Sources.boxes(centers, (step, step, thickness_um))


def render_white(
    scene,
    rays_per_lenslet: int = 20_000,
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
) -> Sources:
    """A fluorescent stage-micrometer reticle: lines every ``division_um`` across the field.

    Lines are perpendicular to ``axis`` (``"x"``: vertical lines at x = k · division);
    every 5th line is 1.5× and every 10th 2× longer, as on a real reticle. The scale is
    centred on the optical axis.
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
    x0, x1, y0, y1 = optics.field_of_view_um
    lo, hi = (x0, x1) if axis == "x" else (y0, y1)
    other = (y1 - y0) if axis == "x" else (x1 - x0)
    ks = np.arange(np.ceil(lo / division_um), np.floor(hi / division_um) + 1)
    if len(ks) < 2:
        raise ConfigError(
            f"division_um {division_um:g} µm puts {len(ks)} line(s) in the {hi - lo:.4g} µm "
            f"field of view along {axis}; a scale needs at least 2 (choose a smaller division)"
        )
    base = 0.2 * other
    lengths = np.where(ks % 10 == 0, 2.0 * base, np.where(ks % 5 == 0, 1.5 * base, base))
    n = len(ks)
    pos = ks * division_um
    centers = np.zeros((n, 3))
    sizes = np.zeros((n, 3))
    if axis == "x":
        centers[:, 0] = pos
        centers[:, 1] = -(lengths / 2) + base
        sizes[:, 0], sizes[:, 1] = line_width_um, lengths
    else:
        centers[:, 1] = pos
        centers[:, 0] = -(lengths / 2) + base
        sizes[:, 1], sizes[:, 0] = line_width_um, lengths
    centers[:, 2] = z_um
    sizes[:, 2] = 1.0
    return Sources.boxes(centers, sizes, weights=lengths / base)


def render_micrometer(
    scene,
    division_um: float = 10.0,
    *,
    line_width_um: float = 2.0,
    axis: str = "x",
    rays_per_line: int = 50_000,
    seed: int = 0,
    tracer: str = "mitsuba",
) -> np.ndarray:
    """Light-field image of a stage micrometer at the native object plane (paper §4)."""
    src = micrometer_sources(getattr(scene, "optics", scene), division_um, line_width_um, axis)
    settings = RenderSettings(rays_per_particle=rays_per_line, seed=seed)
    return _trace(scene, src, settings, tracer)
