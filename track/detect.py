"""Particle detection in one reconstructed volume: deconvolve → segment → localise.

The pipeline of the paper's §3.2 (settings of Table 1):

1. **secondary deconvolution** (:mod:`track.deconvolve`): ``deconvolution_iterations``
   Richardson–Lucy updates (paper: 5) with a particle PSF, given or estimated from this volume
   (:mod:`track.psf_estimate`; skipped with a note in the report when no isolated particle is
   found, or when the particles are narrower than :data:`PSF_MIN_FWHM_VOX` voxels along some
   axis, as many reconstruction iterations make them; discarded, with a note, when an
   estimated PSF deconvolves the maxima it was measured on to images narrower than that: it
   was made of noise, as in a volume without particles, and sharpened the noise into blobs);
2. **segmentation** (:mod:`track.segment`) of a band-passed copy of the volume at the scale
   of its particles (the FWHM measured on it, :func:`track.psf_estimate.particle_fwhm_vox`,
   see ``smooth_fwhm``/``background_fwhm``): threshold, connected components, edge, size,
   shape and clump filters, each blob's rejection counted by filter in ``report
   ["rejections"]``. Every scale follows the volume (reconstruction iterations,
   super-resolution, depth step, depth filter, noise, optics): nothing is tuned to one
   reconstruction setting (``benchmarks/detect_sweep.py`` measures it over a grid of them);
3. **sub-voxel localisation** (:mod:`track.localize`): 3-D radial symmetry (Liu et al. 2013)
   or weighted centroid in a box around every accepted blob's centroid, on the input volume
   (``localize_on="input"``, default) or the deconvolved one. Deconvolution serves the
   segmentation; the localisation defaults to the input because it is linear in the data and
   does not inherit a centring error of an estimated PSF (which would shift every particle);
   for very noisy data choose ``"deconvolved"`` (measurements: docs/validation_notes.md,
   "Detection").

Given the lenslet period of a light-field reconstruction (``lenslet_period_vox``: its
super-resolution factor, which ``recon run`` records in ``recon.json``), the noise of every
sub-lenslet phase is first brought to its depth's typical level
(:func:`track.lenslet_phases.equalize_lenslet_phases`): the reconstruction concentrates noise
into single voxels and lines at a few phases, which would otherwise pass for particles or set
their width. The light piled up on its outer lenslets and planes is kept out of the band-pass,
and the significance test follows the depth-dependent noise (see :func:`detect_particles`).

Positions are returned in µm, columns ``x, y, z``: voxel ``(k, j, i)`` (z, y, x indices) has its
centre at ``origin_xyz_um + (i dx, j dy, k dz)``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.validate import finite_float, int_in_range, nonnegative_float, per_axis

from ._threads import gaussian_filter
from .deconvolve import DeconvolveSettings, deconvolve
from .errors import InputError, TrackingError
from .lenslet_phases import (  # noqa: F401 (re-exported)
    PHASE_MIN_VOX,
    PHASE_SIGMA_TOL,
    check_lenslet,
    equalize_lenslet_phases,
)
from .localize import METHODS, check_triple, check_volume, check_voxel_size_um, localize
from .psf_estimate import check_psf, estimate_psf, particle_fwhm_vox
from .segment import (
    FACE_VOX,
    MIN_AUTO_VOX,
    SegmentSettings,
    interior,
    median_and_sigma,
    segment,
)
from .surface import beyond_surface

log = logging.getLogger(__name__)


#: Smallest particle FWHM (voxels, every axis) for an automatic PSF: a narrower image is not
#: resolved on the voxel grid (Nyquist: two samples per width).
PSF_MIN_FWHM_VOX = 2.0
#: Smallest smoothing σ (voxels) of the band-pass: a Gaussian of this σ has a FWHM of
#: :data:`PSF_MIN_FWHM_VOX`, so that segmented particles are resolved along every axis
#: (a narrower image's shape is sampling noise, which the shape test would read as shape).
SMOOTH_MIN_VOX = PSF_MIN_FWHM_VOX / (2.0 * math.sqrt(2.0 * math.log(2.0)))

#: :class:`DetectSettings` fields that are the :class:`track.segment.SegmentSettings` of
#: :func:`track.segment.segment` (their defaults are defined there).
SEGMENT_SETTINGS = tuple(f.name for f in dataclasses.fields(SegmentSettings))
_SEGMENT = SegmentSettings()


@dataclass(frozen=True)
class DetectSettings:
    """Settings of :func:`detect_particles` (defaults follow the paper's Table 1 where it has one).

    The segmentation fields (:data:`SEGMENT_SETTINGS`) are a
    :class:`track.segment.SegmentSettings` (:meth:`segment_settings`) and
    ``deconvolution_iterations`` a :class:`track.deconvolve.DeconvolveSettings`
    (:meth:`deconvolve_settings`): their defaults are defined there, once.

    Parameters
    ----------
    deconvolution_iterations : int
        Richardson–Lucy iterations of the secondary deconvolution (paper: 5; 0 = off).
    psf_box_um : tuple of 3 float or None
        Box ``(z, y, x)`` (µm) of the automatic PSF estimate; ``None`` (default): from the
        particles' widths in the volume (:func:`track.psf_estimate.auto_box_um`); the paper's
        studies set 200 × 60 × 60 µm.
    psf_particles : int
        Particles averaged into the automatic PSF.
    threshold : float or "auto"
        Binarisation threshold: a fraction of the intensity range in (0, 1) (default and
        paper: 0.25) or ``"auto"`` (robust ``median + k σ``, see :mod:`track.segment`). On
        light-field volumes 0.25 separates the axially elongated particles best: on a
        paper-size synthetic frame (75 particles, SNR 17) it finds 70, "auto" 53, whose lower
        threshold merges neighbours (``hrvptm`` validation, docs/validation.md).
    auto_k_sigma : float
        ``k`` of the automatic threshold.
    blob_min_vox, blob_max_vox : int or None
        Blob size limits in voxels (paper: 1000–5000 at 1.64 × 1.64 × 5 µm); None = automatic
        (``auto_size_factors`` × the voxel-weighted median blob size).
    auto_size_factors : tuple of 2 float
        Factors of the automatic size limits. The low one is small (0.1) because the size of
        a blob at a fixed threshold follows its brightness (∝ ``ln(peak / threshold)^1.5``
        for a Gaussian image: a particle at 1.3 × the threshold fills 0.08 × the volume of one
        at 4 ×), while the band-pass (``smooth_fwhm``) already leaves no noise specks.
    max_rel_aspect : float
        Largest aspect ratio relative to the median blob's second-moment tensor (≥ 1).
    clump_prominence : float
        Relative prominence of a second maximum that marks a clump (0 = test off).
    edge_margin_um : float
        Distance (µm) a blob's bounding box must keep from the volume faces (0 = reject only
        blobs touching a face).
    method : {"radial", "centroid"}
        Sub-voxel localisation method.
    half_box_vox : tuple of 3 int or None
        Localisation patch half-size ``(hz, hy, hx)`` (voxels); None = automatic: 1.5 × the
        median blob half-extent per axis, at least 2.
    localize_on : {"deconvolved", "input"}
        Volume the localisation runs on (the input with its lenslet phases equalised when
        :func:`detect_particles` is given the lenslet period).
    smooth_fwhm : float
        Segmentation runs on a band-passed copy of the (deconvolved) volume: Gaussian
        smoothing of σ = ``smooth_fwhm`` × the particles' FWHM measured along each axis on the
        volume itself (:func:`track.psf_estimate.particle_fwhm_vox`), minus a local background
        (below). The scale follows the reconstruction (iterations, s, z step, filter) and the
        optics: it joins the fragments and axial ripples that many Richardson–Lucy iterations
        break a particle image into, and averages noise. 0 = no smoothing.
    background_fwhm : float
        σ of the subtracted local background, in measured FWHM along each axis: removes the
        out-of-focus cone that few iterations leave around every particle (it would join the
        particles with each other and with the volume's faces). 0 = none.
    min_peak_snr : float
        A blob is a particle only if its peak in the segmented (band-passed) volume stands
        ``min_peak_snr`` noise σ above the background, σ the robust spread (1.4826 × the
        median absolute deviation) of that volume before its negative part is cut: a
        threshold set as a fraction of the range (``threshold``) finds blobs in any volume,
        even one of pure noise. Rejections are counted as ``"insignificant"``. 0 = off.
    sigma_noise_factor : float or tuple of 3 float
        Factor (> 0; one for all axes or one per axis ``(z, y, x)``) on the voxel-noise σ
        of :func:`track.localize.localize`, which assumes independent voxel noise: a
        reconstruction's noise is correlated over several voxels, so the σ it gives is too
        small by a factor set by the reconstruction (and differently along z, where the
        light field samples depth by parallax). This is the
        *random* part of a particle's uncertainty, independent between frames. Default 1.
    sigma_systematic_um : tuple of 3 float
        Per-particle error ``(z, y, x)`` (µm, ≥ 0) that does not change between frames of a
        particle that barely moves (the reconstruction's bias at the particle's place),
        added in quadrature to every particle's σ; it cancels in displacements
        (:func:`track.series.match_sigma`). Default 0.
    sigma_snr_um : tuple of 3 float
        Random error ``(z, y, x)`` (µm, ≥ 0) at a camera SNR of 1, falling as ``1 / SNR``
        with the SNR of the volume's camera frame (``recon run`` measures it,
        :func:`recon.preprocess.frame_snr`), added in quadrature to the random part: the
        localiser's own σ hardly follows the camera noise, which a few RL iterations turn into
        structure shaped like the particles (Fig. 4c: from 100 to 25 000 fps the lateral error
        grows 11-fold, the localiser's σ 2-fold). Default 0 (off); when set, every volume
        needs its SNR (a volume of ``recon run``).

    Calibrate them on simulated data of the same setup, with other seeds than the data
    they are then checked on (``hrvptm`` studies report the coverage of the σ).
    """

    deconvolution_iterations: int = DeconvolveSettings.iterations
    psf_box_um: tuple[float, float, float] | None = None
    psf_particles: int = 10
    threshold: float | str = _SEGMENT.threshold
    auto_k_sigma: float = _SEGMENT.auto_k_sigma
    blob_min_vox: int | None = _SEGMENT.blob_min_vox
    blob_max_vox: int | None = _SEGMENT.blob_max_vox
    auto_size_factors: tuple[float, float] = _SEGMENT.auto_size_factors
    max_rel_aspect: float = _SEGMENT.max_rel_aspect
    clump_prominence: float = _SEGMENT.clump_prominence
    edge_margin_um: float = 0.0
    method: str = "radial"
    half_box_vox: tuple[int, int, int] | None = None
    localize_on: str = "input"
    sigma_noise_factor: float | tuple[float, float, float] = 1.0
    sigma_systematic_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_snr_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    smooth_fwhm: float = 0.25
    background_fwhm: float = 1.5
    min_peak_snr: float = 5.0

    def __post_init__(self) -> None:
        with raised_as(InputError):
            int_in_range(self.deconvolution_iterations, "deconvolution_iterations", 0)
            int_in_range(self.psf_particles, "psf_particles", 1)
            for name in ("edge_margin_um", "smooth_fwhm", "background_fwhm", "min_peak_snr"):
                nonnegative_float(getattr(self, name), name)
            sys_um = per_axis(self.sigma_systematic_um, "sigma_systematic_um", positive=False)
            snr_um = per_axis(self.sigma_snr_um, "sigma_snr_um", positive=False)
            for name, v in (("sigma_systematic_um", sys_um), ("sigma_snr_um", snr_um)):
                if min(v) < 0:
                    raise InputError(f"{name} must be >= 0, got {getattr(self, name)!r}")
            f = self.sigma_noise_factor
            if isinstance(f, list | tuple | np.ndarray):
                f = per_axis(f, "sigma_noise_factor")
            elif not finite_float(f, "sigma_noise_factor") > 0:
                raise InputError(f"sigma_noise_factor must be finite and > 0, got {f!r}")
        if not isinstance(self.deconvolution_iterations, int | np.integer):
            raise InputError(
                "deconvolution_iterations must be an integer >= 0, got "
                f"{self.deconvolution_iterations!r}"
            )
        if not isinstance(self.psf_particles, int | np.integer):
            raise InputError(
                f"psf_particles must be a positive integer, got {self.psf_particles!r}"
            )
        if 0 < self.background_fwhm <= self.smooth_fwhm:
            raise InputError(
                f"background_fwhm ({self.background_fwhm!r}) must exceed smooth_fwhm "
                f"({self.smooth_fwhm!r}) (or be 0)"
            )
        seg = self.segment_settings()  # validates the segmentation fields
        for name in SEGMENT_SETTINGS:
            object.__setattr__(self, name, getattr(seg, name))
        if self.psf_box_um is not None:
            object.__setattr__(self, "psf_box_um", check_triple(self.psf_box_um, "psf_box_um"))
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.half_box_vox is not None:
            object.__setattr__(
                self, "half_box_vox", check_triple(self.half_box_vox, "half_box_vox", integer=True)
            )
        object.__setattr__(self, "sigma_systematic_um", sys_um)
        object.__setattr__(self, "sigma_snr_um", snr_um)
        if isinstance(f, tuple):
            object.__setattr__(self, "sigma_noise_factor", f)
        if self.localize_on not in ("deconvolved", "input"):
            raise InputError(
                f"localize_on must be 'deconvolved' or 'input', got {self.localize_on!r}"
            )

    def segment_settings(self) -> SegmentSettings:
        """The :class:`track.segment.SegmentSettings` these settings hold."""
        return SegmentSettings(**{name: getattr(self, name) for name in SEGMENT_SETTINGS})

    def deconvolve_settings(self) -> DeconvolveSettings:
        """The :class:`track.deconvolve.DeconvolveSettings` of the secondary deconvolution."""
        return DeconvolveSettings(self.deconvolution_iterations)


@dataclass(frozen=True)
class Detection:
    """Particles found in one volume by :func:`detect_particles`.

    Attributes
    ----------
    positions_um : ndarray, shape (N, 3), float64
        Particle centres, columns ``x, y, z`` (µm).
    positions_vox : ndarray, shape (N, 3), float64
        The same in voxel indices ``(z, y, x)`` of the volume.
    intensities : ndarray, shape (N,), float64
        Peak intensity of every particle's blob (in the segmented volume).
    sigma_xyz_um : ndarray, shape (N, 3), float64
        Standard uncertainty of each centre, columns ``x, y, z`` (µm): :attr:`sigma_random_xyz_um`
        with ``DetectSettings.sigma_systematic_um`` added in quadrature.
    sigma_random_xyz_um : ndarray, shape (N, 3), float64
        Its random part (independent between frames): the localiser's voxel-noise σ times
        ``DetectSettings.sigma_noise_factor``, with ``sigma_snr_um / snr`` in quadrature.
    sizes_vox : ndarray, shape (N,), int64
        Blob voxel counts.
    report : dict
        Counts after each stage, threshold, size limits, PSF/deconvolution notes, the particle
        FWHM of the band-pass (``particle_fwhm_vox``), localisation fallbacks, timings,
        ``empty``, ``rejections`` (rejected blobs counted by filter: ``edge``, ``too_small``,
        ``specks``, ``too_large``, ``elongated``, ``clump``, ``localization``) and the
        rejected blobs with their reasons
        (JSON-serialisable; blobs under ``segment.MIN_AUTO_VOX`` voxels, noise specks, are only
        counted, in ``rejected_specks``).
    voxel_size_um : tuple of 3 float
        ``(dz, dy, dx)``.
    origin_xyz_um : tuple of 3 float
        ``(x0, y0, z0)``: centre of voxel ``(0, 0, 0)``.
    """

    positions_um: np.ndarray
    positions_vox: np.ndarray
    intensities: np.ndarray
    sizes_vox: np.ndarray
    report: dict = field(default_factory=dict)
    voxel_size_um: tuple[float, float, float] = (1.0, 1.0, 1.0)
    origin_xyz_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    sigma_xyz_um: np.ndarray | None = None
    sigma_random_xyz_um: np.ndarray | None = None

    @property
    def n(self) -> int:
        """Number of particles."""
        return int(self.positions_um.shape[0])

    @property
    def empty(self) -> bool:
        """True when no particle was found."""
        return self.n == 0


def voxel_to_um(
    positions_vox: np.ndarray,
    voxel_size_um: Sequence[float],
    origin_xyz_um: Sequence[float] = (0.0, 0.0, 0.0),
) -> np.ndarray:
    """Map ``(z, y, x)`` voxel positions ``(N, 3)`` to ``(x, y, z)`` µm (see module docstring)."""
    p = np.asarray(positions_vox, dtype=np.float64).reshape(-1, 3)
    dz, dy, dx = check_voxel_size_um(voxel_size_um)
    x0, y0, z0 = check_triple(origin_xyz_um, "origin_xyz_um", positive=False)
    return np.stack([x0 + p[:, 2] * dx, y0 + p[:, 1] * dy, z0 + p[:, 0] * dz], axis=1)


def _robust_sigma(vol: np.ndarray) -> float:
    """Noise σ of a sparse volume: the robust σ of its interior (:func:`track.segment.interior`;
    particles fill too few voxels to move it)."""
    return median_and_sigma(interior(vol))[1]


def _fill_faces(img: np.ndarray, band_vox: Sequence[int]) -> None:
    """Replace the ``band_vox`` outer voxels of every face (z, y, x) of ``img`` by the median
    of the voxels inside them (axes shorter than 4 bands keep theirs), in place."""
    inner = tuple(
        slice(b, n - b) if n > 4 * b else slice(None)
        for b, n in zip(band_vox, img.shape, strict=True)
    )
    med = float(np.median(img[inner]))
    for axis, (b, n) in enumerate(zip(band_vox, img.shape, strict=True)):
        if b > 0 and n > 4 * b:
            sl = [slice(None)] * 3
            sl[axis] = slice(0, b)
            img[tuple(sl)] = med
            sl[axis] = slice(n - b, n)
            img[tuple(sl)] = med


def _plane_sigmas(vol: np.ndarray) -> np.ndarray:
    """Robust σ of every depth plane of ``vol`` (its lateral interior), shape (nz,)."""
    lat = tuple(
        slice(FACE_VOX, n - FACE_VOX) if n > 4 * FACE_VOX else slice(None) for n in vol.shape[1:]
    )
    v = vol[(slice(None), *lat)].reshape(vol.shape[0], -1)
    med = np.median(v, axis=1, keepdims=True)
    return 1.4826 * np.median(np.abs(v - med), axis=1)


def _bandpass(
    work: np.ndarray,
    settings: DetectSettings,
    report: dict,
    face_fill_vox: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The volume segmentation runs on: smoothed and background-subtracted at the scale of
    the particles measured on ``work`` (see :class:`DetectSettings`); notes in ``report``.

    With ``face_fill_vox`` (a light-field reconstruction, :func:`detect_particles`), the
    outer voxels that hold the light piled up from outside the field are replaced by the
    volume's median before filtering (:func:`_fill_faces`), and the robust σ of every depth
    plane of the band-passed volume is returned with it (else None): the noise of a
    reconstruction changes with depth."""
    if settings.smooth_fwhm == 0 and settings.background_fwhm == 0:
        report["particle_fwhm_vox"] = None
        report["noise_sigma_segmented"] = _robust_sigma(work)
        return work, None
    fwhm = particle_fwhm_vox(work)
    if fwhm is None:
        log.warning("detect_particles: no particle maximum to measure; no band-pass")
        report["particle_fwhm_vox"] = None
        report["noise_sigma_segmented"] = _robust_sigma(work)
        return work, None
    report["particle_fwhm_vox"] = [float(v) for v in fwhm]
    img = work.astype(np.float32)
    if face_fill_vox is not None:
        # the background Gaussian would carry the face light far inwards (one iteration:
        # σ of 60 depth planes), a negative background that the noise σ then measures
        _fill_faces(img, face_fill_vox)
        report["face_fill_vox"] = [int(v) for v in face_fill_vox]
    sigma = settings.smooth_fwhm * fwhm
    if settings.smooth_fwhm > 0:
        sigma = np.maximum(sigma, SMOOTH_MIN_VOX)
    out = gaussian_filter(img, sigma, mode="nearest")
    if settings.background_fwhm > 0:
        out -= gaussian_filter(img, settings.background_fwhm * fwhm, mode="nearest")
    report["noise_sigma_segmented"] = _robust_sigma(out)
    planes = _plane_sigmas(out) if face_fill_vox is not None else None
    if settings.background_fwhm > 0:
        # below the local background is background: the threshold fraction is of [0, max]
        out = np.clip(out, 0.0, None)
    # reconstructions pile light from outside the field onto their outer voxels
    # (segment.FACE_VOX); smoothing spreads it 2 σ further in: that band is background, so
    # that it neither sets the threshold nor forms blobs
    band = [FACE_VOX + math.ceil(2.0 * s) for s in sigma]
    for axis, (b, n) in enumerate(zip(band, out.shape, strict=True)):
        if n > 4 * b:
            sl = [slice(None)] * 3
            sl[axis] = slice(0, b)
            out[tuple(sl)] = 0.0
            sl[axis] = slice(n - b, n)
            out[tuple(sl)] = 0.0
    report["face_band_vox"] = [
        int(b) if n > 4 * b else 0 for b, n in zip(band, out.shape, strict=True)
    ]
    log.info(
        "detect_particles: band-pass at %s × particle FWHM %s voxels",
        (settings.smooth_fwhm, settings.background_fwhm),
        [f"{v:.1f}" for v in fwhm],
    )
    return out, planes


def _snr_term(sigma_snr_um: tuple, snr: float | None) -> np.ndarray:
    """``sigma_snr_um / snr`` (z, y, x) µm; zero when the term is off."""
    c = np.asarray(sigma_snr_um, dtype=float)
    if not c.any():
        return np.zeros(3)
    if snr is None:
        raise InputError(
            "sigma_snr_um is set but the volume has no camera SNR (recon run records it in "
            "recon.json); set sigma_snr_um to 0 for volumes from elsewhere"
        )
    if isinstance(snr, bool) or not isinstance(snr, int | float) or not 0 < snr < math.inf:
        raise InputError(f"snr must be a finite number > 0, got {snr!r}")
    return c / float(snr)


def detect_particles(
    volume: np.ndarray,
    voxel_size_um: Sequence[float],
    settings: DetectSettings | None = None,
    psf: np.ndarray | None = None,
    *,
    origin_xyz_um: Sequence[float] = (0.0, 0.0, 0.0),
    lenslet_period_vox: int | None = None,
    lenslet_phase_vox: Sequence[int] = (0, 0),
    snr: float | None = None,
    surface_z_um: float | None = None,
) -> Detection:
    """Find and localise particles in a reconstructed volume.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
        Reconstructed intensities (float; finite).
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` (µm), each > 0.
    settings : DetectSettings, optional
        Defaults: ``DetectSettings()``.
    psf : ndarray, optional
        Particle PSF (odd shape, same voxel grid) for the secondary deconvolution; estimated
        from ``volume`` when None and deconvolution is on. Pass the PSF of the first volume
        to treat a sequence consistently, as the paper does.
    origin_xyz_um : sequence of 3 float
        ``(x0, y0, z0)``: position (µm) of the centre of voxel ``(0, 0, 0)``.
    lenslet_period_vox : int, optional
        Lateral lenslet period of a light-field reconstruction (voxels: its super-resolution
        factor ``s``; ``recon.json`` ``grid.s``, :attr:`track.volumes.VolumeInfo.
        lenslet_period_vox`). When given, the volume is treated as a light-field
        reconstruction: (1) the noise of every sub-lenslet phase is brought to its depth's
        level (:func:`~track.lenslet_phases.equalize_lenslet_phases`) in the volume the particles
        are found, measured (PSF, width) and localised in (the input, ``localize_on="input"``); (2)
        before the band-pass its outer lenslet (``s`` voxels) on the lateral faces and its 2 outer
        depth planes, where the light from outside the field piles up, are set to the volume's
        median; (3) each blob's significance is measured against the larger of the volume's noise σ
        and that of its own depth plane; (4) particles longer than half the volume along some axis
        (one RL iteration) are localised on the band-passed volume, as their box around them is cut
        by the faces. None (default): none of this, the behaviour without a period.
    lenslet_phase_vox : sequence of 2 int
        ``(phase_y, phase_x)``: sub-lenslet position of voxel row and column 0 (0 for the
        volumes of ``recon run``); used only with ``lenslet_period_vox``.
    snr : float, optional
        SNR of the camera frame the volume was reconstructed from
        (:attr:`track.volumes.VolumeInfo.snr`), for ``DetectSettings.sigma_snr_um``; needed
        when that is set.
    surface_z_um : float, optional
        Object ``z`` (µm) of the specimen's near surface
        (:attr:`track.volumes.VolumeInfo.surface_z_um`): the planes in front of it are the
        reconstruction's guard planes, where nothing emits. A particle found more than one
        depth step in front of it (the reconstruction of a particle at the surface lies
        within that) is rejected (``report["rejections"]["in_front_of_surface"]``). None
        (default): no surface.

    Returns
    -------
    Detection
        Empty (``detection.empty``, ``report["empty"]``) when no particle is found.

    Raises
    ------
    InputError
        For a non-3-D, empty or non-finite volume, bad voxel size, origin, PSF or settings,
        or ``sigma_snr_um`` set without an ``snr``.
    """
    t0 = time.perf_counter()
    vol, spacing, origin, settings, psf, snr_term_um = _check_inputs(
        volume, voxel_size_um, settings, psf, origin_xyz_um, snr
    )
    with raised_as(InputError):
        surface_z_um = None if surface_z_um is None else finite_float(surface_z_um, "surface_z_um")
    report: dict = {"volume_shape": list(vol.shape), "voxel_size_um": list(spacing)}
    if snr is not None:
        report["snr"] = float(snr)
    timings: dict = {}

    # the volume particles are found in (``vol`` itself without a lenslet period)
    found_in, period = vol, None
    if lenslet_period_vox is not None:
        period, phase = check_lenslet(lenslet_period_vox, lenslet_phase_vox)
        t = time.perf_counter()
        found_in, report["lenslet_phases"] = equalize_lenslet_phases(vol, period, phase)
        timings["lenslet_phases_s"] = time.perf_counter() - t
    t = time.perf_counter()
    work = _secondary_deconvolution(found_in, psf, spacing, settings, report)
    if settings.deconvolution_iterations > 0:
        timings["deconvolve_s"] = time.perf_counter() - t

    t = time.perf_counter()
    # a light-field reconstruction piles the light from outside its field onto its outer
    # lenslets (s voxels laterally) and depth planes
    face_fill = None
    if period is not None:
        face_fill = (FACE_VOX, max(FACE_VOX, period), max(FACE_VOX, period))
    seg_vol, plane_sigma = _bandpass(work, settings, report, face_fill)
    timings["bandpass_s"] = time.perf_counter() - t
    t = time.perf_counter()
    seg = _segment(seg_vol, spacing, settings, report)
    timings["segment_s"] = time.perf_counter() - t
    accepted = _significant_blobs(seg, seg_vol, plane_sigma, settings, report)

    t = time.perf_counter()
    loc_vol = work if settings.localize_on == "deconvolved" else found_in
    if accepted and _localize_on_bandpassed(period, report.get("particle_fwhm_vox"), vol.shape):
        loc_vol = seg_vol
        report["localized_on"] = "band-passed"
    located = _localize_blobs(loc_vol, accepted, spacing, settings, snr_term_um, report)
    located = beyond_surface(located, spacing, origin, surface_z_um, report)
    timings["localize_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t0
    return _detection(located, spacing, origin, settings, seg.threshold, report, timings)


def _check_inputs(volume, voxel_size_um, settings, psf, origin_xyz_um, snr) -> tuple:
    """The validated inputs of :func:`detect_particles`: volume, voxel size, origin, settings,
    PSF and the camera-SNR term of the σ (``sigma_snr_um / snr``, z, y, x µm)."""
    vol = check_volume(volume)
    spacing = check_voxel_size_um(voxel_size_um)
    origin = check_triple(origin_xyz_um, "origin_xyz_um", positive=False)
    if settings is None:
        settings = DetectSettings()
    elif not isinstance(settings, DetectSettings):
        raise InputError(f"settings must be a DetectSettings, got {type(settings).__name__}")
    if psf is not None:
        psf = check_psf(psf)
    return vol, spacing, origin, settings, psf, _snr_term(settings.sigma_snr_um, snr)


def _secondary_deconvolution(
    found_in: np.ndarray,
    psf: np.ndarray | None,
    spacing: tuple[float, float, float],
    settings: DetectSettings,
    report: dict,
) -> np.ndarray:
    """The volume segmentation starts from (float32): ``found_in`` deconvolved with ``psf``
    (given, or estimated from ``found_in``), or ``found_in`` itself when the deconvolution is
    off, has no PSF or would only sharpen noise (module docstring); ``report["psf"]`` and
    ``report["deconvolution_iterations"]`` say which."""
    if settings.deconvolution_iterations == 0:
        report["psf"] = "not used (deconvolution off)"
        report["deconvolution_iterations"] = 0
        return found_in.astype(np.float32)
    fwhm_in = particle_fwhm_vox(found_in) if psf is None else None
    if fwhm_in is not None and fwhm_in.min() < PSF_MIN_FWHM_VOX:
        # an image this sharp (many RL iterations) is not resolved on the voxel grid: a PSF
        # made of it is sampling noise, and deconvolving with it only sharpens noise
        report["psf"] = (
            f"not estimated: the particles are {[float(v) for v in fwhm_in]} voxels wide "
            f"(FWHM), under {PSF_MIN_FWHM_VOX} along some axis (unresolved)"
        )
        log.info("detect_particles: no deconvolution: %s", report["psf"])
    elif psf is None:
        try:
            psf = estimate_psf(
                found_in, spacing, n_particles=settings.psf_particles, box_um=settings.psf_box_um
            )
            report["psf"] = f"estimated from this volume, shape {list(psf.shape)}"
        except (TrackingError, InputError) as exc:
            log.warning("detect_particles: no deconvolution: %s", exc)
            report["psf"] = f"not available: {exc}"
    else:
        report["psf"] = f"given, shape {list(psf.shape)}"
    if psf is None:
        report["deconvolution_iterations"] = 0
        return found_in.astype(np.float32)
    work = deconvolve(found_in, psf, settings.deconvolve_settings())
    report["deconvolution_iterations"] = settings.deconvolution_iterations
    fwhm_out = particle_fwhm_vox(work) if fwhm_in is not None else None
    if fwhm_out is not None and fwhm_out.min() < PSF_MIN_FWHM_VOX:
        # a PSF estimated from resolved maxima that deconvolves them to unresolved images was
        # made of noise, not particles (a particle-free light-field volume: face light and
        # noise spikes, the PSF of one "isolated particle"), and the deconvolution sharpened
        # noise into blobs: the input is used
        report["deconvolution_iterations"] = 0
        report["psf"] += (
            f"; deconvolution discarded: it left the maxima "
            f"{[float(v) for v in fwhm_out]} voxels wide (FWHM, from "
            f"{[float(v) for v in fwhm_in]}), under {PSF_MIN_FWHM_VOX} along some "
            "axis (unresolved)"
        )
        log.info("detect_particles: %s", report["psf"])
        return found_in.astype(np.float32)
    return work


def _segment(seg_vol: np.ndarray, spacing, settings: DetectSettings, report: dict):
    """:func:`track.segment.segment` of the band-passed volume with the edge margin of
    ``settings``; resolved particles (one measured FWHM apart) are split, not rejected."""
    margin_vox = tuple(math.ceil(settings.edge_margin_um / d) for d in spacing)
    return segment(
        seg_vol,
        spacing,
        settings.segment_settings(),
        edge_margin_vox=margin_vox,
        split_min_sep_vox=report.get("particle_fwhm_vox"),
    )


def _significant_blobs(
    seg, seg_vol: np.ndarray, plane_sigma: np.ndarray | None, settings: DetectSettings, report
) -> list:
    """The accepted blobs of ``seg`` whose peak stands ``min_peak_snr`` noise σ above the
    background (the volume's σ, or that of the blob's depth plane where larger); the
    segmentation's counts and rejections, these included, go to ``report``."""
    accepted = seg.accepted
    noise = report.get("noise_sigma_segmented")
    floor = settings.min_peak_snr * noise if noise is not None else 0.0
    # a pure-noise volume has a median of its own: significance is above it
    base = float(np.median(interior(seg_vol)))
    if plane_sigma is None:
        floors = [floor] * len(accepted)
    else:
        # a light-field reconstruction's noise changes with depth: each blob is tested
        # against the σ of its own depth plane where that exceeds the volume's
        nz = len(plane_sigma)
        floors = [
            settings.min_peak_snr
            * max(noise, float(plane_sigma[min(max(round(b.centroid_vox[0]), 0), nz - 1)]))
            for b in accepted
        ]
    significant = [b for b, f in zip(accepted, floors, strict=True) if b.peak - base >= f]
    insignificant = [
        dataclasses.replace(
            b,
            reason=f"insignificant (peak {(b.peak - base) / noise:.2g} σ above the background "
            f"< min_peak_snr {settings.min_peak_snr:g} × the σ of its depth or the volume)",
        )
        for b, f in zip(accepted, floors, strict=True)
        if b.peak - base < f
    ]
    report.update(
        {
            "threshold": seg.threshold,
            "threshold_setting": settings.threshold,
            "size_bounds_vox": list(seg.size_bounds_vox),
            "split_components": seg.n_split,
            "counts": dict(seg.counts),
            # noise specks (fewer voxels than the automatic-size floor) are only counted
            "rejected": [
                b.as_dict() for b in [*seg.rejected, *insignificant] if b.n_vox >= MIN_AUTO_VOX
            ],
            "rejected_specks": sum(1 for b in seg.rejected if b.n_vox < MIN_AUTO_VOX),
            "rejections": {**seg.rejections, "insignificant": len(insignificant)},
            "min_peak": base + floor,
        }
    )
    return significant


def _localize_on_bandpassed(period: int | None, fwhm, shape) -> bool:
    """Whether a light-field volume's particles are longer than half the volume along some
    axis (one iteration: the out-of-focus cone spans the depth): the box around each is cut
    by the faces and the pedestal it holds pulls the centre towards the middle (1 iteration,
    SNR 5: 2-3 of 6 localised 70-100 µm off in z); the band-passed volume has no pedestal."""
    return (
        period is not None
        and fwhm is not None
        and any(w > 0.5 * n for w, n in zip(fwhm, shape, strict=True))
    )


@dataclass(frozen=True)
class _Located:
    """Localised particles (rows of the accepted blobs that were localised)."""

    pos_vox: np.ndarray  # (N, 3) z, y, x voxels
    sig_zyx_um: np.ndarray  # (N, 3) total σ, µm
    rand_zyx_um: np.ndarray  # (N, 3) random part of the σ, µm
    intensities: np.ndarray  # (N,)
    sizes: np.ndarray  # (N,) int64


def _half_box(accepted, settings: DetectSettings) -> tuple[int, int, int]:
    """The localisation half box: the setting, or 1.5 × the median blob half-extent per axis
    (at least 2 voxels)."""
    if settings.half_box_vox is not None:
        return settings.half_box_vox
    ext = np.array(
        [[b.bbox[1] - b.bbox[0], b.bbox[3] - b.bbox[2], b.bbox[5] - b.bbox[4]] for b in accepted],
        dtype=float,
    )
    return tuple(int(v) for v in np.maximum(np.ceil(0.75 * np.median(ext, axis=0)), 2))


def _localize_blobs(
    loc_vol: np.ndarray, accepted, spacing, settings: DetectSettings, snr_term_um, report: dict
) -> _Located:
    """Sub-voxel positions and σ of the ``accepted`` blobs in ``loc_vol`` (the phase-equalised
    input when a lenslet period is given: the noise spikes of a few phases pull the
    radial-symmetry centre off); the localiser's counts go to ``report``."""
    if not accepted:
        report["localization_fallbacks"] = 0
        report["localization_failures"] = 0
        empty = np.zeros((0, 3))
        return _Located(np.zeros((0, 3)), empty, empty, np.zeros(0), np.zeros(0, dtype=np.int64))
    half = _half_box(accepted, settings)
    seeds = np.array([b.centroid_vox for b in accepted])
    loc = localize(loc_vol, seeds, spacing, half_box_vox=half, method=settings.method)
    keep = loc.ok
    n_ok = int(keep.sum())
    factor = np.asarray(settings.sigma_noise_factor, dtype=float)  # scalar or (z, y, x)
    rand_zyx_um = np.hypot(factor * loc.sigma_vox[keep] * np.asarray(spacing), snr_term_um)
    sig_zyx_um = np.hypot(rand_zyx_um, np.asarray(settings.sigma_systematic_um))
    report["noise_sigma_median"] = float(np.nanmedian(loc.noise_sigma)) if n_ok else None
    report["half_box_vox"] = list(half)
    report["localization_fallbacks"] = int(loc.fallback.sum())
    report["localization_failures"] = int((~keep).sum())
    return _Located(
        loc.positions_vox[keep],
        sig_zyx_um,
        rand_zyx_um,
        np.array([b.peak for b in accepted], dtype=float)[keep],
        np.array([b.n_vox for b in accepted], dtype=np.int64)[keep],
    )


def _detection(
    located: _Located, spacing, origin, settings: DetectSettings, threshold, report, timings
) -> Detection:
    """The :class:`Detection` of the localised particles, with the report's final counts."""
    pos_vox = located.pos_vox
    report["counts"]["localized"] = int(pos_vox.shape[0])
    report["rejections"]["localization"] = report["localization_failures"]
    log.info(
        "detect_particles: %d accepted; rejected: %s",
        pos_vox.shape[0],
        ", ".join(f"{k} {v}" for k, v in report["rejections"].items()),
    )
    report["method"] = settings.method
    report["empty"] = bool(pos_vox.shape[0] == 0)
    report["timings"] = timings
    if report["empty"]:
        log.warning("detect_particles: no particle found (threshold %.4g)", threshold)
    else:
        log.info("detect_particles: %d particles in %.2f s", pos_vox.shape[0], timings["total_s"])
    return Detection(
        positions_um=voxel_to_um(pos_vox, spacing, origin),
        positions_vox=pos_vox,
        intensities=located.intensities,
        sizes_vox=located.sizes,
        report=report,
        voxel_size_um=spacing,
        origin_xyz_um=origin,
        sigma_xyz_um=located.sig_zyx_um[:, ::-1].copy(),
        sigma_random_xyz_um=located.rand_zyx_um[:, ::-1].copy(),
    )
