"""Wave-optics images of fluorescent particles (the ``"wave"`` model of :func:`render_particles`).

A particle is a sphere of uniformly and incoherently emitting dye, as for the ray tracers
(:meth:`lfsim.tracer.Sources.spheres`); its image is the incoherent sum of the wave-optics
light fields of point sources (:mod:`lfsim.wave`) at the nodes of a quadrature over its
volume:

- **depth** — Gauss–Legendre nodes across the sphere's diameter
  (:meth:`SphereSampling.layers`), each layer weighted by its node weight times the area of
  the sphere's cross-section there;
- **lateral** — the cross-section (a disc) is cut by a square lattice of step ``p_obj / k``
  aligned with the lenslets (``p_obj`` the lenslet pitch in object space, ``k`` cells per
  lenslet, :meth:`SphereSampling.cells`); each cell the disc touches contributes one point,
  weighted by the area of its part of the disc (measured on ``SUBCELL²`` sub-samples of the
  cell), at the cell's centre, or, for a disc less than two cells in radius, at the
  centroid of that part where the cell is not wholly inside. Points on the lattice at one
  depth a whole number of lenslets apart share one light field.

A point-size particle (diameter 0) is the point source at its centre.

Each distinct point source (depth and position within its lenslet) is computed once, on a
window of ``2R + 1`` lenslets around its lenslet (``R`` from the geometric cone of its depth,
:func:`window_radius_lenslets`), and added to the image shifted by its lenslet's whole
number of pixels: the objective images every lateral position alike and the lenslet array
is periodic, so a source a whole lenslet further along gives the same pattern that many
pixels further along. This needs an integer number of pixels per lenslet. The windows'
sources are propagated in batches of ``complex64`` FFTs.

Photometry: the light field of a point is the fraction of the light emitted into the
collection cone that reaches each pixel (:func:`lfsim.wave.light_field`), so a particle of
brightness ``b`` rendered with ``rays_per_particle = N`` receives ``b N`` expected photons
into the cone, as with the ray tracers' ``"expected"`` mode. Mode ``"photons"`` draws
Poisson counts of that expected image (``uint32``, from ``RenderSettings.seed``). The wave
model has no Fresnel losses at the specimen's interfaces and no vignetting by the lens
mounts (the ray tracers have both).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import ConfigError

log = logging.getLogger(__name__)

__all__ = [
    "SUBCELL",
    "SphereSampling",
    "point_image",
    "render_wave",
    "sphere_points",
    "wave_render_sampling",
    "window_radius_lenslets",
]

#: Sub-samples per lattice cell along each axis that measure a cell's part of a disc.
SUBCELL = 8
#: Bytes of complex fields one batch of propagated sources may hold.
BATCH_BYTES = 192 << 20


@dataclass(frozen=True, kw_only=True)
class SphereSampling:
    """Quadrature of a sphere's volume (module docstring).

    Parameters
    ----------
    cells_per_lenslet : int, optional
        Lattice cells per object-space lenslet pitch along x and y; default: from
        ``lateral_step_um`` (:meth:`cells`).
    lateral_step_um : float, optional
        Largest lattice step (µm, object space); default ``λ / NA``.
    min_cells : int
        Fewest lattice cells per lenslet (a point's light field changes wholly within one
        lenslet).
    axial_step_um : float, optional
        Largest mean spacing (µm) of the depth layers; default ``λ n / (2 NA²)`` (half the
        depth of field, ``n`` the specimen's index).
    min_layers : int
        Fewest Gauss–Legendre depth layers across a sphere.
    """

    cells_per_lenslet: int | None = None
    lateral_step_um: float | None = None
    min_cells: int = 5
    axial_step_um: float | None = None
    min_layers: int = 5

    def __post_init__(self) -> None:
        for name in ("cells_per_lenslet", "min_cells", "min_layers"):
            k = getattr(self, name)
            if k is None and name == "cells_per_lenslet":
                continue
            if isinstance(k, bool) or int(k) != k or k < 1:
                raise ConfigError(f"SphereSampling.{name} must be an integer >= 1, got {k!r}")
        for name in ("lateral_step_um", "axial_step_um"):
            v = getattr(self, name)
            if v is not None and (not math.isfinite(v) or v <= 0):
                raise ConfigError(f"SphereSampling.{name} must be positive (µm), got {v!r}")

    def cells(self, optics, oversample: int = 1) -> int:
        """Lattice cells per lenslet for ``optics``: ``cells_per_lenslet``, else the fewest
        (at least ``min_cells``) with a step of at most ``lateral_step_um`` that put every
        lattice point a whole number of field samples (``oversample`` per pixel) from its
        lenslet's centre, so that one sampling of a depth's native field serves them all
        (without such a number, the fewest cells)."""
        if self.cells_per_lenslet is not None:
            return int(self.cells_per_lenslet)
        step = self.lateral_step_um or optics.wavelength_um / optics.na
        k_min = max(self.min_cells, math.ceil(optics.lenslet_object_um / step - 1e-9))
        ns = round(optics.px_per_lenslet) * int(oversample)
        for k in range(k_min, ns + 1):
            if ns % k == 0 and (ns // k - ns) % 2 == 0:
                return k
        return k_min

    def layers(self, optics, diameter_um: float) -> int:
        """Depth layers across a sphere of ``diameter_um`` (µm)."""
        na = min(optics.na, optics.medium_ior * math.sin(optics.emission_half_angle))
        step = self.axial_step_um or optics.wavelength_um * optics.medium_ior / (2 * na * na)
        return max(self.min_layers, math.ceil(diameter_um / step - 1e-9))


def wave_render_sampling(optics):
    """The :class:`lfsim.wave.WaveSampling` of a particle image: samples of at most
    ``λ / (3 (NA_image + NA_lenslet))`` (the field behind the lenslets, whose frequencies
    reach ``(NA_image + NA_lenslet) / λ``, at 1.5× its Nyquist rate), and no guard band: the
    windows of :func:`window_radius_lenslets` end a lenslet beyond the light already."""
    from .wave import WaveSampling

    na_img = optics.medium_ior * math.sin(optics.emission_half_angle) / optics.magnification
    step = optics.wavelength_um / (3.0 * (na_img + optics.lenslet_na))
    return WaveSampling(oversample=max(1, math.ceil(optics.pixel_um / step)), guard_lenslets=0.0)


def window_radius_lenslets(optics, z_um: float) -> int:
    """Half-width (lenslets) of the window that holds the light field of a point at true
    depth ``z_um`` (µm) lying within the central lenslet's footprint: the lenslets its
    geometric cone at the array reaches (radius ``d tan θ_image``, ``d`` the image distance,
    the apparent depth scaled over the cone's edge too), widened by the diffraction blur and
    half a lenslet for the light that spills past a lenslet's edge behind it, plus one
    lenslet for the diffraction rings of the objective (two with interfaces, for their
    aberrations too)."""
    d = abs(optics.magnification**2 * z_um) * optics.max_axial_scale  # image distance (µm)
    cone = d * math.tan(math.asin(min(optics.image_na, 1 - 1e-9)))
    blur = 4 * (optics.sigma_mla_um + optics.sigma_sensor_um)
    extra = 2 if optics.has_interfaces else 1
    return math.ceil((cone + blur) / optics.mla_pitch_um + 0.5) + extra


# -- the quadrature ---------------------------------------------------------------------------
def _disc_cells(cx: float, cy: float, rho: float, h: float, p: float):
    """Points and areas of a disc (centre ``(cx, cy)``, radius ``rho``) cut by the lattice of
    step ``h`` whose cell edges lie at ``−p/2 + i h``: ``(x, y, area)`` of each cell touched
    (its part's centroid, or the cell centre when wholly inside)."""
    if rho <= 0:
        return np.array([cx]), np.array([cy]), np.array([1.0])
    e0 = -p / 2
    ix = np.arange(math.floor((cx - rho - e0) / h), math.floor((cx + rho - e0) / h) + 1)
    iy = np.arange(math.floor((cy - rho - e0) / h), math.floor((cy + rho - e0) / h) + 1)
    sub = (np.arange(SUBCELL) + 0.5) / SUBCELL * h
    xs = (e0 + ix[:, None] * h + sub[None, :]).ravel()  # (nx·q,)
    ys = (e0 + iy[:, None] * h + sub[None, :]).ravel()
    inside = (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2 <= rho * rho
    q = SUBCELL
    cell = inside.reshape(len(iy), q, len(ix), q)
    count = cell.sum(axis=(1, 3)).astype(np.float64)  # (ny, nx)
    sx = (cell * xs.reshape(len(ix), q)[None, None, :, :]).sum(axis=(1, 3))
    sy = (cell * ys.reshape(len(iy), q)[:, :, None, None]).sum(axis=(1, 3))
    ok = count > 0
    x = np.where(ok, sx / np.maximum(count, 1), 0.0)
    y = np.where(ok, sy / np.maximum(count, 1), 0.0)
    # cells wholly inside, and every cell of a disc at least two cells wide, keep their centre
    full = (count == q * q) | (rho >= 2 * h)
    centre_x = e0 + (ix + 0.5) * h
    centre_y = e0 + (iy + 0.5) * h
    x = np.where(full, centre_x[None, :], x)
    y = np.where(full, centre_y[:, None], y)
    if not ok.any():  # a disc smaller than the sub-samples: its centre
        return np.array([cx]), np.array([cy]), np.array([1.0])
    return x[ok], y[ok], count[ok]


def sphere_points(
    optics, centers_um, diameters_um, sampling: SphereSampling | None = None, oversample: int = 1
):
    """Quadrature points of uniformly emitting spheres (module docstring).

    Parameters
    ----------
    optics : Optics
    centers_um : array_like, shape (n, 3)
        Sphere centres (µm, object space, x, y, z).
    diameters_um : array_like, shape (n,) or scalar
        Diameters (µm, ≥ 0).
    sampling : SphereSampling, optional
    oversample : int
        Field samples per pixel of the wave computation (:meth:`SphereSampling.cells`).

    Returns
    -------
    points : ndarray of float64, shape (m, 3)
        Point positions (µm, x, y, z).
    weights : ndarray of float64, shape (m,)
        Each point's share of its sphere (a sphere's weights sum to 1).
    owner : ndarray of int64, shape (m,)
        The sphere of each point.
    """
    sampling = sampling or SphereSampling()
    c = np.asarray(centers_um, dtype=np.float64).reshape(-1, 3)
    d = np.broadcast_to(np.asarray(diameters_um, dtype=np.float64), (len(c),))
    if not np.all(np.isfinite(c)) or not np.all(np.isfinite(d)) or np.any(d < 0):
        raise ConfigError("sphere centres must be finite (µm) and diameters finite and >= 0 (µm)")
    p = optics.lenslet_object_um
    h = p / sampling.cells(optics, oversample)
    pts, wts, own = [], [], []
    for i, (ctr, dia) in enumerate(zip(c, d, strict=True)):
        r = dia / 2
        if r <= 0:
            pts.append(ctr[None, :])
            wts.append(np.ones(1))
            own.append(np.full(1, i))
            continue
        t, wt = np.polynomial.legendre.leggauss(sampling.layers(optics, dia))
        layer_w = wt * (1.0 - t**2)  # ∝ node weight × cross-section area
        layer_w /= layer_w.sum()
        for tk, lw in zip(t, layer_w, strict=True):
            x, y, area = _disc_cells(ctr[0], ctr[1], r * math.sqrt(1.0 - tk * tk), h, p)
            pts.append(np.c_[x, y, np.full(len(x), ctr[2] + r * tk)])
            wts.append(lw * area / area.sum())
            own.append(np.full(len(x), i))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)
    return np.concatenate(pts), np.concatenate(wts), np.concatenate(own).astype(np.int64)


# -- the light fields ---------------------------------------------------------------------------
@dataclass
class _Window:
    """Sample grid, lenslet mask and transfer function of a window of radius ``h`` lenslets,
    and the offset (pixels) of its pixel (0, 0) from the sensor's when the source's lenslet
    is the on-axis one."""

    h: int
    size: int
    grid: tuple
    mla: np.ndarray
    tf: np.ndarray
    offset_xy: tuple[int, int]


def _window(optics, h: int, n: int, sampling) -> _Window:
    from .wave import lenslet_phase, sample_grid

    ax, ay = optics.axis_xy_px
    off = (math.floor(ax - n / 2) - h * n, math.floor(ay - n / 2) - h * n)
    size = (2 * h + 1) * n + 1
    wopt = replace(optics, sensor_xy_px=(size, size), axis_xy_px=(ax - off[0], ay - off[1]))
    grid = sample_grid(wopt, sampling)
    x, y, dx, _ = grid
    mla = lenslet_phase(optics, x[None, :], y[:, None], paraxial=sampling.paraxial_lenslets)
    from scipy import fft as sfft

    fy, fx = sfft.fftfreq(len(y), d=dx), sfft.fftfreq(len(x), d=dx)
    lam, dist = optics.wavelength_um, optics.sensor_distance_um
    arg = 1.0 / lam**2 - fy[:, None] ** 2 - fx[None, :] ** 2
    kz = 2.0 * np.pi * np.sqrt(np.clip(arg, 0.0, None))
    tf = np.where(arg > 0, np.exp(1j * dist * (kz - 2.0 * np.pi / lam)), 0.0)
    return _Window(h, size, grid, mla.astype(np.complex64), tf.astype(np.complex64), off)


def _native_fields(win: _Window, prof, dr: float, part, shared) -> np.ndarray:
    """Native fields (complex64) of sources at image-plane positions ``part`` (µm from the
    window's axis) on the window's grid, linearly interpolated from the radial profile
    ``prof`` (step ``dr``). ``shared``: ``(field, margin)`` of the profile on the grid widened
    by ``margin`` samples, read by the sources that lie a whole number of samples off the
    axis (``None``: none does)."""
    x, y, dx, _ = win.grid
    ny, nx = win.mla.shape
    fields = np.empty((len(part), ny, nx), np.complex64)
    x32, y32 = x.astype(np.float32), y.astype(np.float32)
    for j, (px, py) in enumerate(part):
        ia, ib = round(px / dx), round(py / dx)
        if shared is not None and abs(px / dx - ia) < 1e-6 and abs(py / dx - ib) < 1e-6:
            grid, mg = shared
            if abs(ia) <= mg and abs(ib) <= mg:
                fields[j] = grid[mg - ib : mg - ib + ny, mg - ia : mg - ia + nx]
                continue
        fields[j] = _sample_radial(prof, dr, x32 - np.float32(px), y32 - np.float32(py))
    return fields


def _sample_radial(prof, dr: float, x, y) -> np.ndarray:
    """``prof`` (complex, step ``dr``) at the distances of the grid ``x`` × ``y`` from the
    origin, linearly interpolated (complex64)."""
    rr = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2) * np.float32(1.0 / dr)
    idx = np.minimum(rr.astype(np.int32), len(prof) - 2)
    frac = rr - idx
    p64 = prof.astype(np.complex64)
    return p64[idx] + (p64[idx + 1] - p64[idx]) * frac


def _patterns(win: _Window, prof, dr: float, pos_xy_um, os_: int) -> np.ndarray:
    """Window images ``(k, size, size)`` (float64) of sources at image-plane positions
    ``pos_xy_um`` (µm from the window's axis) sharing the radial field ``prof`` (step ``dr``).
    """
    from scipy import fft as sfft

    x, y, dx, g = win.grid
    ny, nx = win.mla.shape
    batch = max(1, int(BATCH_BYTES // (ny * nx * 8 * 2)))
    lo_px, hi_px = g * os_, (g + win.size) * os_
    out = np.empty((len(pos_xy_um), win.size, win.size))
    steps = np.asarray(pos_xy_um) / dx
    on_grid = np.all(np.abs(steps - np.round(steps)) < 1e-6, axis=1)
    shared = None
    if on_grid.sum() > 1:
        mg = int(np.abs(np.round(steps[on_grid])).max())
        xe = (x[0] + (np.arange(nx + 2 * mg) - mg) * dx).astype(np.float32)
        ye = (y[0] + (np.arange(ny + 2 * mg) - mg) * dx).astype(np.float32)
        shared = (_sample_radial(prof, dr, xe, ye), mg)
    for lo in range(0, len(pos_xy_um), batch):
        part = pos_xy_um[lo : lo + batch]
        fields = _native_fields(win, prof, dr, part, shared)
        fields *= win.mla
        fields = sfft.fft2(fields, axes=(-2, -1), workers=-1, overwrite_x=True)
        fields *= win.tf
        fields = sfft.ifft2(fields, axes=(-2, -1), workers=-1, overwrite_x=True)
        sensor = fields[:, lo_px:hi_px, lo_px:hi_px]
        inten = sensor.real**2 + sensor.imag**2  # float32
        sums = inten.reshape(len(part), win.size, os_, win.size, os_).sum(
            axis=(2, 4), dtype=np.float64
        )
        out[lo : lo + len(part)] = sums * (dx * dx)
    return out


def _add(image: np.ndarray, pattern: np.ndarray, top: int, left: int, weight: float) -> None:
    """``image[top:, left:] += weight · pattern``, clipped to the image."""
    hgt, wid = image.shape
    ph, pw = pattern.shape
    r0, c0 = max(top, 0), max(left, 0)
    r1, c1 = min(top + ph, hgt), min(left + pw, wid)
    if r0 < r1 and c0 < c1:
        image[r0:r1, c0:c1] += weight * pattern[r0 - top : r1 - top, c0 - left : c1 - left]


def point_image(optics, points_xyz_um, weights, sampling=None, *, progress: bool = False):
    """Weighted incoherent sum of the wave-optics light fields of point sources.

    Parameters
    ----------
    optics : Optics
        Ideal lenslets, an integer number of pixels per lenslet.
    points_xyz_um : array_like, shape (m, 3)
        Source positions (µm, object space).
    weights : array_like, shape (m,)
        Each source's weight (its share of the light emitted into the collection cone).
    sampling : lfsim.wave.WaveSampling, optional
        Default :func:`wave_render_sampling`.
    progress : bool
        Show a progress bar over the distinct depths.

    Returns
    -------
    ndarray of float64, shape (height, width)
        ``Σ wᵢ · light_field(pointᵢ)`` (fraction of the cone's light per pixel, weighted).
    """
    from .wave import native_field

    _check_optics(optics)
    sampling = sampling or wave_render_sampling(optics)
    pts = np.asarray(points_xyz_um, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    n = round(optics.px_per_lenslet)
    wid, hgt = optics.sensor_xy_px
    image = np.zeros((hgt, wid))
    keep = w > 0
    pts, w = pts[keep], w[keep]
    if len(pts) == 0:
        return image
    p_obj, m = optics.lenslet_object_um, optics.magnification
    lens = np.round(pts[:, :2] / p_obj).astype(np.int64)  # lenslet of each point (x, y)
    phase = pts[:, :2] - lens * p_obj  # position within it (µm, object)
    key = np.round(np.c_[phase, pts[:, 2]], 9)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    depths, d_index = np.unique(uniq[:, 2], return_inverse=True)
    d_index = d_index.reshape(-1)
    radii = np.array([window_radius_lenslets(optics, z) for z in depths])
    windows = {h: _window(optics, int(h), n, sampling) for h in sorted(set(radii.tolist()))}
    far = max(math.hypot(abs(wn.grid[0]).max(), abs(wn.grid[1]).max()) for wn in windows.values())
    na_img = optics.medium_ior * math.sin(optics.emission_half_angle) / m
    dr = sampling.radial_step * optics.wavelength_um / na_img
    r = np.arange(0.0, far + optics.mla_pitch_um + 2 * dr, dr)
    radial = native_field(optics, r, depths, sampling)  # (nz, nr)
    order = np.argsort(inverse, kind="stable")
    starts = np.searchsorted(inverse[order], np.arange(len(uniq) + 1))
    it = range(len(depths))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="wave particles", unit="depth", leave=False)
    for k in it:
        win = windows[int(radii[k])]
        members = np.flatnonzero(d_index == k)
        pats = _patterns(win, radial[k], dr, uniq[members, :2] * m, int(sampling.oversample))
        for u, pat in zip(members, pats, strict=True):
            for i in order[starts[u] : starts[u + 1]]:
                top = win.offset_xy[1] + int(lens[i, 1]) * n
                left = win.offset_xy[0] + int(lens[i, 0]) * n
                _add(image, pat, top, left, w[i])
    log.debug("wave render: %d points, %d distinct light fields", len(pts), len(uniq))
    return image


def _check_optics(optics) -> None:
    if optics.mla_kind != "ideal":
        raise ConfigError(
            f"the wave-optics renderer models ideal lenslets only; got mla_kind="
            f"{optics.mla_kind!r} (render it with model 'ray')"
        )
    n = optics.px_per_lenslet
    if abs(n - round(n)) > 1e-6:
        raise ConfigError(
            f"the wave-optics renderer needs an integer number of pixels per lenslet, got {n:.4g}"
        )


def render_wave(optics, sources, settings, *, sphere=None, wave=None) -> np.ndarray:
    """Wave-optics image of sphere sources in the units of the ray tracers.

    Parameters
    ----------
    optics : Optics
        Ideal lenslets (``mla_kind="ideal"``), an integer number of pixels per lenslet.
    sources : lfsim.tracer.Sources
        ``kind="sphere"``: centres (µm), diameters (µm) and brightnesses.
    settings : lfsim.tracer.RenderSettings
        ``rays_per_particle`` sets the photons into the cone per unit brightness; ``mode``
        ``"expected"`` gives them as ``float32``, ``"photons"`` as Poisson counts (``uint32``)
        drawn from ``seed``; ``progress`` applies; the other fields are the ray tracers'.
    sphere : SphereSampling, optional
    wave : lfsim.wave.WaveSampling, optional
        Default :func:`wave_render_sampling`.

    Returns
    -------
    ndarray, shape (height, width)
        ``uint32`` photon counts or ``float32`` expected photons.
    """
    _check_optics(optics)
    if sources.kind != "sphere":
        raise ConfigError(f"the wave-optics renderer draws spheres, got {sources.kind!r} sources")
    from .tracer import _check_inside_specimen

    _check_inside_specimen(sources, optics)
    wave = wave or wave_render_sampling(optics)
    pts, w, own = sphere_points(
        optics, sources.centers_um, sources.sizes_um, sphere, int(wave.oversample)
    )
    w = w * sources.weights[own] * float(settings.rays_per_particle)
    expected = point_image(optics, pts, w, wave, progress=settings.progress)
    if settings.mode == "expected":
        return expected.astype(np.float32)
    rng = np.random.default_rng(int(settings.seed))
    return rng.poisson(np.clip(expected, 0.0, None)).astype(np.uint32)
