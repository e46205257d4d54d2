"""Wave-optics light fields of point sources (scalar diffraction, numpy FFTs).

The optical train is :class:`~lfsim.optics.Optics`'s (docs/conventions.md §2), modelled with
scalar waves of vacuum wavelength ``wavelength_um``:

1. **Objective** — an aplanatic objective (Abbe sine condition) of numerical aperture ``na``
   designed for ``immersion_ior`` and, if set, a cover glass of ``coverslip_corrected_um``.
   The field of a point source at true depth ``z`` in the specimen, in the native image plane
   (the microlens array), is the scalar Debye integral over the invariant ``s = n sin θ``
   (conserved across the planar interfaces)::

       E(r) = 2π/(Mλ)² ∫ a(s) exp(i Φ(s, z)) J0(2π s r / (M λ)) s ds,     0 ≤ s ≤ s_max

   with ``r`` the distance from the source's geometric image, the apodisation of an isotropic
   emitter through an aplanatic lens ``a = 1/sqrt(cos θ_medium)`` (energy per solid angle in
   the specimen mapped onto the pupil), and the Gibson–Lanni phase of the layers between the
   source and the objective, relative to the objective's design::

       Φ = k0 [n_s d cos θ_s + n_g (t − t₀) cos θ_g − n_i (F + t − t₀) cos θ_i]

   where ``d = native_plane_depth_um + z`` is the source's depth below the specimen's surface,
   ``t``, ``t₀`` the actual and design cover-glass thicknesses and ``F = focus_depth_um``.
   Without interfaces it is the plain Debye defocus ``k0 n z cos θ``. ``s_max`` is
   ``n_s sin(emission_half_angle)``; the integral is evaluated by Gauss–Legendre quadrature
   over the specimen angle on a fine radial grid and interpolated onto the sampling grid, so
   any lateral source position is exact. The field is normalised so that its power is the
   power emitted into the collection cone (1).
2. **Microlens array** — a square array of ideal thin lenses of pitch ``mla_pitch_um`` and
   focal length ``mla_focal_um`` (100 % fill factor), as the phase mask of a perfect lens,
   ``exp(−i k0 (sqrt(ρ² + f_l²) − f_l))`` (a plane wave converges to a point, as the ray
   model's ideal lenslet), or its paraxial form ``exp(−i π ρ² / (λ f_l))``
   (``WaveSampling.paraxial_lenslets``, as oLaF / pyolaf), with ``ρ`` the distance from the
   nearest lenslet centre; the optical axis passes through a lenslet centre.
3. **Propagation** to the sensor, ``sensor_distance_um`` behind the array, in air by the
   angular spectrum (exact scalar transfer function ``exp(i 2π d sqrt(1/λ² − f²))``,
   evanescent waves dropped), on a grid padded by ``guard_lenslets`` so that nothing wraps.
4. **Sensor** — the intensity integrated over each pixel (``oversample²`` samples per pixel).

Coordinates are those of the sensor read-out (conventions §2): object ``+x`` runs along
increasing columns, a source at ``(x, y)`` images at ``(M x, M y)`` from the optical axis
``axis_xy_px``. A source at ``z > 0`` (away from the objective) images in front of the array.

A light field is sampled on the sensor's pixel grid with ``oversample`` samples per pixel
per axis; :func:`converged_light_field` doubles the sampling until the light field changes by
less than a tolerance. Patterns are in the units of the PSF bank (:mod:`recon.psf`): the
fraction of the light emitted into the collection cone that reaches each pixel.

The image side is taken as air and the objective as aplanatic, so the image-side numerical
aperture is ``na / M`` and the longitudinal magnification ``M² / n_immersion`` (paraxially).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import ConfigError

log = logging.getLogger(__name__)

__all__ = [
    "WaveSampling",
    "converged_light_field",
    "lenslet_phase",
    "light_field",
    "native_field",
    "pattern_stack",
    "propagate",
    "pupil_phase",
    "sample_grid",
]


@dataclass(frozen=True, kw_only=True)
class WaveSampling:
    """Sampling of the wave-optics computation.

    Parameters
    ----------
    oversample : int
        Field samples per sensor pixel along each axis (the grid step is
        ``pixel_um / oversample``).
    guard_lenslets : float
        Width (in lenslet pitches) of the band of array and empty space added around the sensor
        on each side, so that light crossing the sensor's edge and the FFT's periodicity do not
        fold back.
    radial_step : float
        Step of the radial grid on which the Debye integral is evaluated, in units of
        ``λ / NA_image``; the field is interpolated linearly from it.
    theta_factor : float
        Gauss–Legendre nodes (composite, 16 per panel) per radian of the integrand's largest
        phase excursion (Bessel argument plus defocus phase); 32 more are always added.
    obliquity : bool
        Multiply the pupil by the Kirchhoff obliquity factor ``(1 + cos θ) / 2`` (as in the
        Debye integral of oLaF / pyolaf); off by default (an aplanatic objective imaging an
        isotropic emitter has none).
    paraxial_lenslets : bool
        Use the paraxial (quadratic) lenslet phase instead of the perfect lens's; with the
        exact propagator it carries the spherical aberration ``ρ⁴ / (8 f_l³)``.
    batch : int
        Sources propagated together (memory: ``batch`` complex grids).
    """

    oversample: int = 3
    guard_lenslets: float = 2.0
    radial_step: float = 1.0 / 64.0
    theta_factor: float = 0.75
    obliquity: bool = False
    paraxial_lenslets: bool = False
    batch: int = 4

    def __post_init__(self) -> None:
        if int(self.oversample) != self.oversample or self.oversample < 1:
            raise ConfigError(
                f"WaveSampling.oversample must be a positive integer, got {self.oversample!r}"
            )
        for name in ("radial_step", "theta_factor"):
            v = getattr(self, name)
            if not math.isfinite(v) or v <= 0:
                raise ConfigError(f"WaveSampling.{name} must be positive, got {v!r}")
        if not math.isfinite(self.guard_lenslets) or self.guard_lenslets < 0:
            raise ConfigError(
                f"WaveSampling.guard_lenslets must be >= 0, got {self.guard_lenslets!r}"
            )
        if int(self.batch) != self.batch or self.batch < 1:
            raise ConfigError(f"WaveSampling.batch must be a positive integer, got {self.batch!r}")

    def doubled(self) -> WaveSampling:
        """The same sampling with every resolution parameter refined twofold."""
        return replace(
            self,
            oversample=2 * self.oversample,
            radial_step=self.radial_step / 2,
            theta_factor=self.theta_factor * 2,
        )


# -- the objective -------------------------------------------------------------------------
def _max_invariant(optics) -> float:
    """Largest ``s = n sin θ`` that reaches the sensor, ``n_s sin(emission_half_angle)``."""
    return optics.medium_ior * math.sin(optics.emission_half_angle)


def _image_na(optics) -> float:
    """Image-side numerical aperture of an aplanatic objective, ``s_max / M``."""
    return _max_invariant(optics) / optics.magnification


def pupil_phase(optics, s: np.ndarray, z_um: np.ndarray) -> np.ndarray:
    """Phase (rad) of the pupil at invariant ``s = n sin θ`` for sources at true depths ``z_um``.

    Gibson–Lanni optical path of the specimen, cover glass and immersion layers relative to the
    objective's design (module docstring); without interfaces ``k0 n z cos θ``. The phase at
    ``s = 0`` is subtracted (a piston per depth).

    Parameters
    ----------
    optics : Optics
    s : ndarray, shape (ns,)
        Invariants ``n sin θ`` (at most ``n_s sin(emission_half_angle)``).
    z_um : ndarray, shape (nz,)
        Depths from the native object plane (µm, positive away from the objective).

    Returns
    -------
    ndarray, shape (nz, ns)
    """
    s = np.asarray(s, dtype=np.float64)
    z = np.atleast_1d(np.asarray(z_um, dtype=np.float64))
    k0 = 2.0 * np.pi / optics.wavelength_um

    def cos_in(n):
        return np.sqrt(np.clip(1.0 - (s / n) ** 2, 0.0, None))

    n_s = optics.medium_ior
    c_s = cos_in(n_s)
    if not optics.has_interfaces:
        opd = n_s * z[:, None] * (c_s - 1.0)[None, :]
        return k0 * opd
    d = optics.native_plane_depth_um + z
    dt = optics.coverslip_thickness_um - optics.coverslip_corrected_um
    n_g, n_i = optics.coverslip_ior, optics.immersion_ior
    f = optics.focus_depth_um
    fixed = n_g * dt * (cos_in(n_g) - 1.0) - n_i * (f + dt) * (cos_in(n_i) - 1.0)
    opd = n_s * d[:, None] * (c_s - 1.0)[None, :] + fixed[None, :]
    return k0 * opd


def _quadrature(optics, z_um: np.ndarray, r_max_um: float, sampling: WaveSampling):
    """Gauss–Legendre nodes over the specimen angle: ``(s, weight·a·s ds/dθ, phase)``."""
    n_s = optics.medium_ior
    theta_max = optics.emission_half_angle
    k0 = 2.0 * np.pi / optics.wavelength_um
    s_max = _max_invariant(optics)
    bessel = k0 * s_max * r_max_um / optics.magnification
    zmax = float(np.max(np.abs(z_um))) if len(z_um) else 0.0
    probe = np.linspace(0.0, s_max, 257)
    defocus = 0.0
    if zmax > 0 or optics.has_interfaces:
        ph = pupil_phase(optics, probe, np.array([-zmax, zmax]))
        defocus = float(np.max(np.ptp(ph, axis=1)))
    n_theta = math.ceil(sampling.theta_factor * (bessel + defocus)) + 32
    # composite Gauss–Legendre: panels of 16 nodes
    panels = -(-n_theta // 16)
    x16, w16 = np.polynomial.legendre.leggauss(16)
    edges = np.linspace(0.0, theta_max, panels + 1)
    half = 0.5 * np.diff(edges)
    theta = ((edges[:-1] + half)[:, None] + half[:, None] * x16[None, :]).ravel()
    w = (half[:, None] * w16[None, :]).ravel()
    cos_t = np.cos(theta)
    s = n_s * np.sin(theta)
    # a(s) s ds = n_s² sqrt(cos θ) sin θ dθ with a = 1/sqrt(cos θ); power density n_s² sin θ dθ
    ob = 0.5 * (1.0 + cos_t) if sampling.obliquity else np.ones_like(cos_t)
    amp = w * n_s**2 * np.sqrt(cos_t) * np.sin(theta) * ob
    power_density = w * n_s**2 * np.sin(theta) * ob**2
    return s, amp, power_density, pupil_phase(optics, s, z_um)


def native_field(
    optics, r_um: np.ndarray, z_um: np.ndarray, sampling: WaveSampling | None = None
) -> np.ndarray:
    """Field of point sources in the native image plane, against distance from their image.

    Parameters
    ----------
    optics : Optics
    r_um : ndarray, shape (nr,)
        Distances (µm, image plane) from the source's geometric image ``M (x, y)``.
    z_um : ndarray, shape (nz,)
        Source depths from the native object plane (µm).
    sampling : WaveSampling, optional
        Its ``theta_factor`` and ``obliquity`` apply.

    Returns
    -------
    ndarray of complex128, shape (nz, nr)
        Field normalised so that ``∫ |E|² d²u = 1`` (µm⁻¹; the power emitted into the
        collection cone).
    """
    sampling = sampling or WaveSampling()
    r = np.asarray(r_um, dtype=np.float64)
    z = np.atleast_1d(np.asarray(z_um, dtype=np.float64))
    from scipy.special import j0

    lam, m = optics.wavelength_um, optics.magnification
    r_max = float(r.max()) if r.size else 0.0
    s, amp, pdens, phase = _quadrature(optics, z, r_max, sampling)
    scale = 2.0 * np.pi / (m * lam) ** 2
    power = scale * float(np.sum(pdens))  # 2π/(Mλ)² ∫ |a|² s ds
    pupil = (amp[None, :] * np.exp(1j * phase)) * (scale / math.sqrt(power))  # (nz, ns)
    out = np.empty((len(z), len(r)), np.complex128)
    chunk = max(1, int(4_000_000 // max(len(s), 1)))
    k = 2.0 * np.pi * s / (m * lam)
    for lo in range(0, len(r), chunk):
        bes = j0(np.outer(r[lo : lo + chunk], k)).T  # (ns, nr_chunk)
        out[:, lo : lo + chunk] = pupil.real @ bes + 1j * (pupil.imag @ bes)
    return out


# -- microlens array and propagation --------------------------------------------------------
def lenslet_phase(
    optics, x_um: np.ndarray, y_um: np.ndarray, *, paraxial: bool = False
) -> np.ndarray:
    """Transmission of the microlens array at points of its plane.

    ``exp(−i k0 (sqrt(ρ² + f_l²) − f_l))`` (a perfect lens), or ``exp(−i π ρ² / (λ f_l))`` with
    ``paraxial``; ``ρ`` is the distance from the nearest lenslet centre. Centres lie at integer
    multiples of the pitch from the optical axis (``x_um``, ``y_um`` measured from it, µm).
    Broadcasts.
    """
    p, f, lam = optics.mla_pitch_um, optics.mla_focal_um, optics.wavelength_um
    lx = x_um - p * np.round(x_um / p)
    ly = y_um - p * np.round(y_um / p)
    rho2 = lx**2 + ly**2
    if paraxial:
        return np.exp(-1j * np.pi * rho2 / (lam * f))
    return np.exp(-2j * np.pi / lam * (np.sqrt(rho2 + f * f) - f))


def propagate(field: np.ndarray, dx_um: float, distance_um: float, wavelength_um: float):
    """Angular-spectrum propagation of a sampled field by ``distance_um`` in air.

    Parameters
    ----------
    field : ndarray of complex, shape (..., ny, nx)
        Square samples of step ``dx_um``.
    distance_um, wavelength_um : float

    Returns
    -------
    ndarray of complex128, same shape
        The propagated field; periodic in the grid (pad beforehand to avoid wrap-around, and
        to ``N ≥ λ d / dx²`` samples so that the transfer function is not aliased).
        Evanescent components are dropped, so the power is conserved exactly otherwise.
    """
    from scipy import fft as sfft

    ny, nx = field.shape[-2:]
    fy = sfft.fftfreq(ny, d=dx_um)
    fx = sfft.fftfreq(nx, d=dx_um)
    arg = 1.0 / wavelength_um**2 - fy[:, None] ** 2 - fx[None, :] ** 2
    kz = 2.0 * np.pi * np.sqrt(np.clip(arg, 0.0, None))
    h = np.where(arg > 0, np.exp(1j * distance_um * (kz - 2.0 * np.pi / wavelength_um)), 0.0)
    spec = sfft.fft2(field, axes=(-2, -1), workers=-1)
    return sfft.ifft2(spec * h, axes=(-2, -1), workers=-1)


# -- light fields ---------------------------------------------------------------------------
def _grid(optics, sampling: WaveSampling):
    """Sample grid of the array plane: ``(x, y, dx, guard_px)``; ``x``, ``y`` are the sample
    centres (µm from the optical axis, read-out frame) along columns and rows."""
    from scipy import fft as sfft

    os_ = int(sampling.oversample)
    pix = optics.pixel_um
    w, h = optics.sensor_xy_px
    ax, ay = optics.axis_xy_px
    g = math.ceil(sampling.guard_lenslets * optics.px_per_lenslet)
    dx = pix / os_
    # the transfer function's chirp is sampled without aliasing for N ≥ λ d / dx²
    n_min = math.ceil(optics.wavelength_um * optics.sensor_distance_um / dx**2)
    nx = sfft.next_fast_len(max((w + 2 * g) * os_, n_min))
    ny = sfft.next_fast_len(max((h + 2 * g) * os_, n_min))
    x = (-g - ax) * pix + (np.arange(nx) + 0.5) * dx
    y = (-g - ay) * pix + (np.arange(ny) + 0.5) * dx
    return x, y, dx, g


def sample_grid(optics, sampling: WaveSampling | None = None):
    """The sample grid of the array plane on which :func:`light_field` computes the optics'
    sensor.

    Returns
    -------
    x, y : ndarray of float64, shapes (nx,), (ny,)
        Sample centres (µm from the optical axis, read-out frame) along columns and rows;
        the sensor's pixels are samples ``guard·oversample …`` of each.
    dx : float
        Sample step (µm).
    guard : int
        Guard band (pixels) around the sensor on each side.
    """
    return _grid(optics, sampling or WaveSampling())


def light_field(
    optics, sources_xyz_um, sampling: WaveSampling | None = None, *, progress: bool = False
) -> np.ndarray:
    """Wave-optics light field of each point source on the optics' sensor.

    Parameters
    ----------
    optics : Optics
        ``mla_kind`` must be ``"ideal"``.
    sources_xyz_um : array_like, shape (n, 3)
        Source positions (µm, object space, conventions §2).
    sampling : WaveSampling, optional
    progress : bool
        Show a progress bar over the batches of sources.

    Returns
    -------
    ndarray of float64, shape (n, height, width)
        Fraction of the light emitted into the collection cone that each pixel receives.
    """
    sampling = sampling or WaveSampling()
    if optics.mla_kind != "ideal":
        raise ConfigError(
            f"lfsim.wave models ideal thin lenslets; got mla_kind={optics.mla_kind!r}"
        )
    src = np.asarray(sources_xyz_um, dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(src)):
        raise ConfigError("sources_xyz_um must be finite positions (µm)")
    x, y, dx, g = _grid(optics, sampling)
    os_ = int(sampling.oversample)
    w, h = optics.sensor_xy_px
    lam, m = optics.wavelength_um, optics.magnification
    na_img = _image_na(optics)
    xs, ys = src[:, 0] * m, src[:, 1] * m
    # radial grid covering every distance from a source image to a sample
    far = np.hypot(
        np.maximum(np.abs(x[0] - xs), np.abs(x[-1] - xs)),
        np.maximum(np.abs(y[0] - ys), np.abs(y[-1] - ys)),
    ).max()
    dr = sampling.radial_step * lam / na_img
    r = np.arange(0.0, far + 2 * dr, dr)
    depths, inverse = np.unique(src[:, 2], return_inverse=True)
    radial = native_field(optics, r, depths, sampling)  # (nz, nr)
    mla = lenslet_phase(optics, x[None, :], y[:, None], paraxial=sampling.paraxial_lenslets)
    d_sensor = optics.sensor_distance_um
    out = np.empty((len(src), h, w), np.float64)
    g_os = g * os_
    batches = range(0, len(src), int(sampling.batch))
    if progress:
        from tqdm.auto import tqdm

        batches = tqdm(batches, desc="wave light field", unit="batch", leave=False)
    for lo in batches:
        idx = np.arange(lo, min(lo + int(sampling.batch), len(src)))
        fields = np.empty((len(idx), len(y), len(x)), np.complex128)
        for j, i in enumerate(idx):
            rr = np.hypot(x[None, :] - xs[i], y[:, None] - ys[i])
            prof = radial[inverse[i]]
            fields[j] = np.interp(rr, r, prof.real) + 1j * np.interp(rr, r, prof.imag)
        fields *= mla
        fields = propagate(fields, dx, d_sensor, lam)
        inten = np.abs(fields[:, g_os : g_os + h * os_, g_os : g_os + w * os_]) ** 2
        out[idx] = inten.reshape(len(idx), h, os_, w, os_).sum(axis=(2, 4)) * dx * dx
    return out


def converged_light_field(
    optics,
    sources_xyz_um,
    sampling: WaveSampling | None = None,
    *,
    tol: float = 1e-3,
    max_oversample: int = 24,
) -> tuple[np.ndarray, WaveSampling, list[tuple[int, float]]]:
    """:func:`light_field`, with the sampling doubled until it changes by less than ``tol``.

    The change between two samplings is ``‖I₂ − I₁‖ / ‖I₂‖`` (Frobenius norm over all
    sources and pixels).

    Returns
    -------
    images : ndarray, shape (n, height, width)
        The light field at the finest sampling computed.
    sampling : WaveSampling
        That sampling.
    history : list of (oversample, change)
        Each refinement's oversampling and its change from the previous one.

    Raises
    ------
    ConfigError
        If ``oversample`` would exceed ``max_oversample`` before converging.
    """
    sampling = sampling or WaveSampling()
    prev = light_field(optics, sources_xyz_um, sampling)
    history: list[tuple[int, float]] = []
    while True:
        nxt = sampling.doubled()
        if nxt.oversample > max_oversample:
            raise ConfigError(
                f"wave light field not converged to {tol:g} at oversample {sampling.oversample}"
                f" (changes {history}); raise max_oversample={max_oversample}"
            )
        cur = light_field(optics, sources_xyz_um, nxt)
        change = float(np.linalg.norm(cur - prev) / max(np.linalg.norm(cur), 1e-300))
        history.append((nxt.oversample, change))
        log.info("wave light field: oversample %d, change %.3g", nxt.oversample, change)
        sampling, prev = nxt, cur
        if change < tol:
            return cur, sampling, history


def pattern_stack(
    optics,
    depths_um,
    s: int,
    radius_lenslets: int,
    sampling: WaveSampling | None = None,
    *,
    progress: bool = False,
) -> np.ndarray:
    """Dense wave-optics patterns in the layout of the PSF bank (:mod:`recon.psf`).

    Pattern ``k·s² + b·s + a`` is the source at depth ``depths_um[k]`` and sub-lenslet position
    ``(a, b)`` along (x, y), ``((a + 0.5)/s − 0.5) p/M`` from the centre of the on-axis lenslet,
    imaged on a window of ``2·radius_lenslets + 1`` lenslets whose pixel
    ``(radius_lenslets·n, radius_lenslets·n)`` is the top-left pixel of the source's lenslet.

    Parameters
    ----------
    optics : Optics
        Must have an integer number ``n`` of pixels per lenslet.
    depths_um : array_like, shape (nz,)
    s : int
    radius_lenslets : int
    sampling : WaveSampling, optional

    Returns
    -------
    ndarray of float64, shape (nz·s², win, win)
        ``win = (2·radius_lenslets + 1)·n``; same normalisation as :func:`light_field`.
    """
    n = optics.px_per_lenslet
    if abs(n - round(n)) > 1e-6:
        raise ConfigError(f"pattern_stack needs an integer number of pixels per lenslet, got {n}")
    n = round(n)
    if int(s) != s or s < 1:
        raise ConfigError(f"s must be a positive integer, got {s!r}")
    hwin = int(radius_lenslets)
    win = (2 * hwin + 1) * n
    wopt = replace(optics, sensor_xy_px=(win, win), axis_xy_px=(hwin * n + n / 2, hwin * n + n / 2))
    p_obj = optics.lenslet_object_um
    sub = ((np.arange(s) + 0.5) / s - 0.5) * p_obj
    gx, gy = np.meshgrid(sub, sub, indexing="xy")
    depths = np.atleast_1d(np.asarray(depths_um, dtype=np.float64))
    src = np.concatenate([np.c_[gx.ravel(), gy.ravel(), np.full(s * s, z)] for z in depths], axis=0)
    return light_field(wopt, src, sampling, progress=progress)
