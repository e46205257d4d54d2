"""The wave-optics PSF bank: the patterns of :mod:`recon.psf` from scalar diffraction.

The same :class:`~recon.psf.PSFBank` (channels, sparse format, units, cache folder) as the
ray-traced bank, with each pattern computed by the wave-optics model of :mod:`lfsim.wave`
(Debye / Gibson–Lanni field of the objective in the native image plane, the microlens array
as a phase mask, angular-spectrum propagation to the sensor, intensity integrated over each
pixel). The projector does not change, so its forward and backward projections stay exact
adjoints.

The computation is shared wherever the physics allows:

- the Debye integral is evaluated once for all depths (one matrix product over the
  quadrature nodes, :func:`lfsim.wave.native_field`) on one radial grid; every source of a
  depth samples the same radial profile at its own lateral shift;
- the lenslet mask and the propagation's transfer function depend only on the window, so
  they are computed once per window size (depths are grouped by window);
- the patterns of a depth are mirror images of one another: the optics are symmetric under
  ``x → −x``, ``y → −y`` and ``x ↔ y`` about the axis of the source's lenslet, so only the
  sub-lenslet positions ``0 ≤ a' ≤ b' ≤ (s − 1)/2`` (folded) are propagated (6 of 25 for
  ``s = 5``) and the others are flipped or transposed copies;
- the sources are propagated in batches of single-precision (``complex64``) FFTs.

The window of a depth is the ray bank's (:func:`recon.psf.pattern_radius_lenslets`: the
geometric cone at the array plus a lenslet and the diffraction blur), and pixels below
``threshold × max`` of their pattern are dropped, as in the ray bank. The sampling defaults to
:func:`default_wave_sampling`. Banks are cached under a key hashing the optics, depths,
``s``, the sampling, the threshold and the model (``"wave"``).

:func:`choose_psf_model` decides which model ``ReconSettings.psf_model = "auto"`` uses.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from dataclasses import asdict, dataclass, replace

import numpy as np

from .errors import InputError
from .psf import (
    BANK_FORMAT,
    PSFBank,
    bank_from_patterns,
    bank_key,
    cached_bank,
    pattern_radius_lenslets,
)

log = logging.getLogger(__name__)

#: PSF models of :class:`recon.settings.ReconSettings` (``"auto"``: :func:`choose_psf_model`).
PSF_MODELS = ("auto", "ray", "wave")

#: ``auto`` chooses the wave-optics bank where a lenslet's diffraction spot ``λ f_l / p`` is
#: wider than this many sensor pixels (:func:`lenslet_spot_px`): between the paper's 4×/0.2
#: (0.91 px), where the ray bank localises point sources as well as the wave bank, and the
#: 10×/0.4 (1.13 px), where it does worse by more than the noise spread (benchmarks/README.md,
#: "ray_bank_error.py — where the ray PSF bank stops being enough").
WAVE_SPOT_PX = 1.0
#: ... or where the aperture angle in the specimen has ``sin θ`` above this
#: (:func:`aperture_sin`): between 0.6, where the ray bank's axial error is 1.2–1.6× the wave
#: bank's, and 0.9, where it is 2–5× (same measurement).
WAVE_SIN_THETA = 0.75

#: Bytes of complex fields one batch of propagated sources may hold.
BATCH_BYTES = 256 << 20


def lenslet_spot_px(optics) -> float:
    """Diffraction spot of one lenslet on the sensor, in pixels: ``λ f_l / (p · pixel)``
    (``λ N`` with ``N = f_l / p`` the lenslet's f-number; 0.91 px for the paper's optics)."""
    return optics.wavelength_um * optics.mla_focal_um / (optics.mla_pitch_um * optics.pixel_um)


def aperture_sin(optics) -> float:
    """``sin θ`` of the aperture angle in the specimen, ``min(NA, n) / n`` (0.2 for the paper's
    optics, 0.9 for a 1.2 NA water objective into water)."""
    return math.sin(optics.emission_half_angle)


def choose_psf_model(optics, model: str = "auto") -> str:
    """The PSF model (``"ray"`` or ``"wave"``) a reconstruction with ``psf_model=model`` uses.

    ``"auto"`` is ``"wave"`` where :func:`lenslet_spot_px` exceeds :data:`WAVE_SPOT_PX` (a
    lenslet's diffraction spot spans more than about a pixel: the ray bank's Gaussian blur no
    longer stands in for it) or :func:`aperture_sin` exceeds :data:`WAVE_SIN_THETA` (the
    high-angle rays, whose diffraction the ray bank blurs with the paraxial width); ``"ray"``
    otherwise.
    """
    from hrvbase import validate

    from .errors import recon_input_errors

    with recon_input_errors():
        validate.one_of(model, "psf_model", PSF_MODELS)
    if model != "auto":
        return model
    wave = lenslet_spot_px(optics) > WAVE_SPOT_PX or aperture_sin(optics) > WAVE_SIN_THETA
    return "wave" if wave else "ray"


def default_wave_sampling(optics):
    """The :class:`lfsim.wave.WaveSampling` of a wave bank for these optics.

    ``oversample``: the fewest samples per pixel with a step of at most
    ``λ / (5 (NA_image + NA_lenslet))``: the intensity behind the lenslets, whose spatial
    frequencies reach ``2 (NA_image + NA_lenslet) / λ``, sampled at 1.25× its Nyquist rate
    (benchmarks/README.md measures the patterns' convergence). ``guard_lenslets`` 1: the light
    crossing the window's edge between the array and the sensor spreads less than a lenslet
    (``(NA_image + NA_lenslet) f_l < p`` for matched lenslets).
    """
    from lfsim.wave import WaveSampling

    na_img = optics.medium_ior * math.sin(optics.emission_half_angle) / optics.magnification
    step = optics.wavelength_um / (5.0 * (na_img + optics.lenslet_na))
    os_min = max(1, math.ceil(optics.pixel_um / step))
    return WaveSampling(oversample=os_min, guard_lenslets=1.0)


def wave_bank_key(optics, depths_um, s: int, sampling, threshold: float) -> str:
    """Cache key of a wave bank (the ray bank's scheme, :func:`recon.psf.bank_key`, with the
    model and the sampling in place of the rays)."""
    payload = json.dumps(
        {
            "model": "wave",
            "optics": optics.fingerprint_dict(),
            "depths": [round(float(d), 9) for d in depths_um],
            "s": int(s),
            "sampling": asdict(sampling),
            "threshold": float(threshold),
            "precision": "complex64",
            "format": BANK_FORMAT,
        },
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


def model_bank_key(optics, depths_um, s: int, model: str, rays_per_pattern: int) -> str:
    """Cache key of the default bank of ``model`` (``"ray"``: :func:`recon.psf.compute_psf_bank`
    with ``rays_per_pattern``; ``"wave"``: :func:`compute_wave_psf_bank`), as
    :func:`choose_psf_model` gives it."""
    if model == "wave":
        return wave_bank_key(optics, depths_um, s, default_wave_sampling(optics), 1e-3)
    return bank_key(optics, depths_um, s, rays_per_pattern, 0, 1e-3)


def _check_inputs(optics, depths_um, s) -> tuple[int, np.ndarray]:
    n = optics.px_per_lenslet
    if abs(n - round(n)) > 1e-6:
        raise InputError(
            f"the PSF bank needs an integer number of pixels per lenslet, got {n:.4g}; "
            "rectify the images first"
        )
    if isinstance(s, bool) or int(s) != s or s < 1:
        raise InputError(f"super-resolution factor s must be a positive integer, got {s!r}")
    if optics.mla_kind != "ideal":
        raise InputError(
            f"the wave-optics PSF bank models ideal lenslets; got mla_kind={optics.mla_kind!r}"
        )
    depths = np.atleast_1d(np.asarray(depths_um, dtype=np.float64))
    if depths.ndim != 1 or not np.all(np.isfinite(depths)):
        raise InputError("depths_um must be a 1-D array of finite depths (µm)")
    return round(n), depths


def compute_wave_psf_bank(
    optics,
    depths_um,
    s: int,
    *,
    sampling=None,
    threshold: float = 1e-3,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
) -> PSFBank:
    """Compute (or load from the cache) the wave-optics PSF bank.

    The wave-optics counterpart of :func:`recon.psf.compute_psf_bank`: a bank of the same
    layout, cached in the same folder.

    Parameters
    ----------
    optics : lfsim.optics.Optics
        With ideal lenslets and an integer number ``n`` of pixels per lenslet.
    depths_um, s, threshold, cache_dir, progress
        As :func:`recon.psf.compute_psf_bank`.
    sampling : lfsim.wave.WaveSampling, optional
        Default :func:`default_wave_sampling`. Its ``batch`` is not used (batches are sized by
        :data:`BATCH_BYTES`).

    Returns
    -------
    PSFBank
        Channel ``k·s² + b·s + a``: depth ``k``, sub-lenslet position ``(a, b)`` along (x, y);
        weights are the fraction of the light emitted into the collection cone reaching each
        pixel (float32).
    """
    n, depths = _check_inputs(optics, depths_um, s)
    s = int(s)
    sampling = sampling or default_wave_sampling(optics)
    key = wave_bank_key(optics, depths, s, sampling, threshold)
    path, cached = cached_bank(cache_dir, key)
    if cached is not None:
        return cached
    radii = np.array([pattern_radius_lenslets(optics, z) for z in depths])
    images = _dense_patterns(optics, depths, s, n, radii, sampling, progress)
    bank = bank_from_patterns(images, depths, s, n, threshold, optics)
    log.info(
        "wave PSF bank: %d depths × %d² patterns, oversample %d, %d non-zeros (%.0f per pattern)",
        len(depths),
        s,
        sampling.oversample,
        bank.nnz,
        bank.nnz / bank.n_channels,
    )
    if path is not None:
        bank.save(path)
    return bank


def _folded(s: int) -> list[tuple[int, int]]:
    """The sub-lenslet positions ``(a, b)`` computed: ``a ≤ b ≤ (s − 1)/2`` after folding."""
    half = (s - 1) // 2
    return [(a, b) for b in range(half + 1) for a in range(b + 1)]


def _unfold(computed: dict, s: int) -> np.ndarray:
    """Every position's pattern ``(s², win, win)`` from those of :func:`_folded` by mirror
    images (``a → s − 1 − a`` flips the columns, ``b → s − 1 − b`` the rows) and the
    transpose (``a ↔ b``)."""
    out = []
    for b in range(s):
        for a in range(s):
            fa, fb = min(a, s - 1 - a), min(b, s - 1 - b)
            img = computed[(fa, fb)] if fa <= fb else computed[(fb, fa)].T
            if a != fa:
                img = img[:, ::-1]
            if b != fb:
                img = img[::-1, :]
            out.append(img)
    return np.stack(out)


def _window_optics(optics, h: int, n: int):
    """The optics on a window of ``2h + 1`` lenslets whose centre lenslet holds the axis."""
    win = (2 * h + 1) * n
    return replace(optics, sensor_xy_px=(win, win), axis_xy_px=(h * n + n / 2, h * n + n / 2))


def _transfer(ny: int, nx: int, dx: float, distance: float, lam: float) -> np.ndarray:
    """Angular-spectrum transfer function (complex64), as :func:`lfsim.wave.propagate`."""
    from scipy import fft as sfft

    fy = sfft.fftfreq(ny, d=dx)
    fx = sfft.fftfreq(nx, d=dx)
    arg = 1.0 / lam**2 - fy[:, None] ** 2 - fx[None, :] ** 2
    kz = 2.0 * np.pi * np.sqrt(np.clip(arg, 0.0, None))
    h = np.where(arg > 0, np.exp(1j * distance * (kz - 2.0 * np.pi / lam)), 0.0)
    return h.astype(np.complex64)


@dataclass
class _Window:
    """What every depth of one window size shares: the sample grid, the lenslet mask and the
    transfer function, and where the sources' native fields are read from one shared grid."""

    h: int
    grid: tuple
    mla: np.ndarray
    tf: np.ndarray
    margin: int = 0  # samples added on each side of the shared grid (0: no shared grid)
    index: np.ndarray | None = None  # radial-grid index of each shared sample
    frac: np.ndarray | None = None  # its fraction of a radial step beyond that index


def _window(optics, h: int, n: int, sampling, dr: float, shifts_um) -> _Window:
    """The :class:`_Window` of radius ``h`` lenslets. Where every sub-lenslet shift is a whole
    number of samples, the native field of a depth is sampled once, on the grid widened by
    the largest shift, and each source reads its own part of it."""
    from lfsim.wave import lenslet_phase, sample_grid

    grid = sample_grid(_window_optics(optics, h, n), sampling)
    x, y, dx, _ = grid
    mla = lenslet_phase(optics, x[None, :], y[:, None], paraxial=sampling.paraxial_lenslets)
    tf = _transfer(len(y), len(x), dx, optics.sensor_distance_um, optics.wavelength_um)
    win = _Window(h, grid, mla.astype(np.complex64), tf)
    steps = np.asarray(shifts_um) / dx
    if np.allclose(steps, np.round(steps), rtol=0, atol=1e-6):
        m = int(np.abs(np.round(steps)).max())
        xe = x[0] + (np.arange(len(x) + 2 * m) - m) * dx
        ye = y[0] + (np.arange(len(y) + 2 * m) - m) * dx
        rr = np.hypot(xe[None, :], ye[:, None]) / dr
        win.index = np.floor(rr).astype(np.int32)
        win.frac = (rr - win.index).astype(np.float32)
        win.margin = m
    return win


def _dense_patterns(optics, depths, s, n, radii, sampling, progress):
    """Yield ``(k, h, patterns)`` for every depth ``k`` (in order of window radius ``h``):
    its dense patterns, shape ``(s², (2h + 1) n, (2h + 1) n)``, float64."""
    from lfsim.wave import native_field, sample_grid

    lam = optics.wavelength_um
    na_img = optics.medium_ior * math.sin(optics.emission_half_angle) / optics.magnification
    # one radial grid for every depth: out to the farthest corner of the windows' grids (a
    # small window's grid may reach further: padded to the propagation's sampling), plus the
    # farthest sub-lenslet shift
    far = optics.mla_pitch_um
    for h in set(radii.tolist()):
        x, y, _, _ = sample_grid(_window_optics(optics, int(h), n), sampling)
        far = max(far, math.hypot(abs(x).max(), abs(y).max()) + optics.mla_pitch_um)
    dr = sampling.radial_step * lam / na_img
    r = np.arange(0.0, far + 2 * dr, dr)
    radial = native_field(optics, r, depths, sampling)  # (nz, nr) complex128
    shifts = ((np.arange(s) + 0.5) / s - 0.5) * optics.mla_pitch_um  # image plane, µm
    todo = _folded(s)
    positions = [(shifts[a], shifts[b]) for a, b in todo]
    order = np.argsort(radii, kind="stable")
    it = order
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(order, desc="wave PSF bank", unit="depth", leave=False)
    win = None
    for k in it:
        h = int(radii[k])
        if win is None or win.h != h:
            win = _window(optics, h, n, sampling, dr, shifts)
        computed = _propagate_sources(
            radial[k], r, positions, win, int(sampling.oversample), (2 * h + 1) * n
        )
        yield int(k), h, _unfold(dict(zip(todo, computed, strict=True)), s)


def _native_fields(prof, r, positions, win: _Window) -> np.ndarray:
    """The native field (complex64) of each source at its ``positions`` (image plane, µm)
    on the window's grid, from the radial profile ``prof`` sampled at ``r``."""
    x, y, dx, _ = win.grid
    fields = np.empty((len(positions), len(y), len(x)), np.complex64)
    if win.index is not None:
        p64 = np.asarray(prof, np.complex64)
        shared = p64[win.index] * (1 - win.frac) + p64[win.index + 1] * win.frac
        m = win.margin
        for j, (px, py) in enumerate(positions):
            ia, ib = round(px / dx), round(py / dx)
            fields[j] = shared[m - ib : m - ib + len(y), m - ia : m - ia + len(x)]
        return fields
    for j, (px, py) in enumerate(positions):
        rr = np.hypot(x[None, :] - px, y[:, None] - py)
        fields[j].real = np.interp(rr, r, prof.real)
        fields[j].imag = np.interp(rr, r, prof.imag)
    return fields


def _propagate_sources(prof, r, positions, win: _Window, os_: int, n_win: int) -> list:
    """Sensor images ``(n_win, n_win)`` (float64) of sources at image-plane ``positions`` (µm
    from the axis) sharing the radial field ``prof`` (sampled at ``r``), in batches of
    complex64 fields: field × lenslet mask → FFT × transfer function → inverse FFT → pixel
    sums."""
    from scipy import fft as sfft

    _, _, dx, g = win.grid
    ny, nx = win.mla.shape
    batch = max(1, int(BATCH_BYTES // (ny * nx * 8 * 2)))
    lo_px, hi_px = g * os_, (g + n_win) * os_
    out = []
    for lo in range(0, len(positions), batch):
        part = positions[lo : lo + batch]
        fields = _native_fields(prof, r, part, win)
        fields *= win.mla
        fields = sfft.fft2(fields, axes=(-2, -1), workers=-1, overwrite_x=True)
        fields *= win.tf
        fields = sfft.ifft2(fields, axes=(-2, -1), workers=-1, overwrite_x=True)
        sensor = fields[:, lo_px:hi_px, lo_px:hi_px]
        inten = sensor.real.astype(np.float64) ** 2 + sensor.imag.astype(np.float64) ** 2
        sums = inten.reshape(len(part), n_win, os_, n_win, os_).sum(axis=(2, 4)) * (dx * dx)
        out.extend(sums)
    return out


__all__ = [
    "BATCH_BYTES",
    "PSF_MODELS",
    "WAVE_SIN_THETA",
    "WAVE_SPOT_PX",
    "aperture_sin",
    "choose_psf_model",
    "compute_wave_psf_bank",
    "default_wave_sampling",
    "lenslet_spot_px",
    "model_bank_key",
    "wave_bank_key",
]
