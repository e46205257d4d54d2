"""Particle PSF of a reconstructed volume, estimated automatically or loaded from a file.

The paper (§3.2) deconvolves every reconstructed volume a second time with a *particle PSF*:
the mean image of one or more particles selected (by hand, with bounding boxes) in the first
volume of a sequence; Table 1 uses boxes of 51 × 51 × ≈ 90 voxels at 1.64 µm × 1.64 µm × 5 µm.
:func:`estimate_psf` makes the same average without clicks:

1. background ``b`` = median of the volume, noise ``s`` = 1.4826 × MAD;
2. maxima = local maxima (3 × 3 × 3) of the volume smoothed with a 0.7-voxel Gaussian that
   stand 5 noise levels ``s_sm`` (robust noise of the smoothed volume) above its background;
   candidates are those whose raw value is at least ``min_snr · s`` and ``min_rel_height`` ×
   the brightest peak above ``b``;
3. a candidate is *isolated* when no other maximum inside its box is a separate particle,
   i.e. separated from the candidate by an intensity dip of at least ``5 s_sm`` along the
   straight line between them (noise bumps on the particle's own flanks have no such dip),
   and usable when the box (plus one voxel) lies inside the volume;
4. the ``n_particles`` brightest isolated candidates are cropped; each is aligned to
   sub-voxel precision by shifting (cubic spline, :func:`scipy.ndimage.shift`) the centroid
   of its upper half (voxels above half its peak height) onto the box centre, background
   subtracted and normalised to unit sum;
5. the mean box, minus the median of its outer shell (residual background), is cut to the
   connected region above twice the shell's robust noise level that holds the centre (so
   residual noise does not widen it), clipped at 0 and normalised to unit sum: the PSF.

Box: by default (:func:`auto_box_um`) three times the median full width at half maximum of
the brightest particles along each axis, measured on the volume itself, so that it follows the
microscope and the reconstruction settings (no built-in microscope). For the paper's optics
that is about 200 µm along z and 60 µm laterally, the box the paper's studies set explicitly
(:data:`PAPER_BOX_UM`). A 15 µm particle in a light-field
reconstruction is ≈ 15–20 µm wide laterally but elongated to ≈ 100–150 µm along z (the paper's
≈ 90 × 5 µm = 450 µm box also covers the far tails of its 0.2-NA reconstructions); 60 µm
laterally leaves ≈ 2 particle diameters for the tails and the background estimate, and
200 µm axially covers the bright core of the elongated image while keeping boxes small enough
for several isolated particles to fit in a seeded volume (37 × 37 × 41 voxels at
1.64 × 1.64 × 5 µm). Use a larger ``box_um`` for strongly elongated reconstructions.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import ndimage

from hrvbase.errors import raised_as
from hrvbase.validate import int_in_range

from ._threads import gaussian_filter, maximum_filter3
from .errors import InputError, TrackingError
from .localize import check_triple, check_volume, check_voxel_size_um

log = logging.getLogger(__name__)

#: The box the paper's studies use (``[track.detect] psf_box_um``), µm (z, y, x).
PAPER_BOX_UM = (200.0, 60.0, 60.0)
#: The automatic box is this many times the particles' median FWHM along each axis (±1.5
#: FWHM holds > 99 % of a Gaussian profile).
BOX_FWHM = 3.0
_SMOOTH_VOX = 0.7  # Gaussian smoothing (voxels) before the search for maxima
_FACE_VOX = 2  # outer voxels whose maxima are not particles (track.segment.FACE_VOX)


def box_shape_vox(box_um: Sequence[float], voxel_size_um: Sequence[float]) -> tuple[int, ...]:
    """Odd box shape (voxels) nearest to ``box_um`` (µm, (z, y, x)), at least 3 per axis."""
    box = check_triple(box_um, "box_um")
    spacing = check_voxel_size_um(voxel_size_um)
    return tuple(max(1, round(b / (2.0 * d))) * 2 + 1 for b, d in zip(box, spacing, strict=True))


def _noise(volume: np.ndarray) -> tuple[float, float]:
    b = float(np.median(volume))
    s = 1.4826 * float(np.median(np.abs(volume - b)))
    return b, s


def find_isolated_peaks(
    volume: np.ndarray,
    box_vox: Sequence[int],
    *,
    min_snr: float = 10.0,
    min_rel_height: float = 0.2,
) -> tuple[np.ndarray, np.ndarray]:
    """Bright local maxima with no other particle inside their box.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
    box_vox : sequence of 3 int
        Odd box shape ``(bz, by, bx)`` (voxels).
    min_snr : float
        Minimum peak height above the background, in units of the noise ``s`` (robust MAD).
    min_rel_height : float
        Minimum peak height as a fraction of the brightest peak's (both above background).

    Returns
    -------
    isolated : ndarray, shape (N, 3), int
        Peak voxels ``(z, y, x)`` of usable isolated particles, brightest first.
    crowded : ndarray, shape (M, 3), int
        Candidates rejected because another maximum lies inside their box.
    """
    vol = check_volume(volume)
    box = check_triple(box_vox, "box_vox", integer=True)
    if any(b % 2 == 0 for b in box):
        raise InputError(f"box_vox must be odd along every axis, got {box}")
    half = np.asarray(box) // 2
    b, s = _noise(vol)
    smooth = gaussian_filter(vol.astype(np.float64), _SMOOTH_VOX, mode="nearest")
    b_sm, s_sm = _noise(smooth)
    is_max = smooth == maximum_filter3(smooth, mode="nearest")
    peaks = np.argwhere(is_max & (smooth - b_sm > 5.0 * s_sm))
    height = vol[tuple(peaks.T)] - b
    # Only maxima whose box fits in the volume can be used, and only they set the reference
    # height: bright artefacts on the volume faces (reconstruction boundary effects) must not
    # make every real particle look faint.
    shape = np.asarray(vol.shape)
    inside = np.all((peaks - half - 1 >= 0) & (peaks + half + 1 < shape), axis=1)
    top = float(height[inside].max()) if inside.any() else 0.0
    if not top > 0:
        return np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3), dtype=np.int64)
    cand = inside & (height >= min_snr * s) & (height >= min_rel_height * top)
    order = np.argsort(-height, kind="stable")
    pts = peaks[order][cand[order]]
    h = 5.0 * s_sm  # prominence a maximum needs to count as a separate particle
    isolated, crowded = [], []
    for p in pts:
        d = np.abs(peaks - p)
        near = peaks[np.all(d <= half, axis=1) & np.any(d > 0, axis=1)]
        if any(_separate(smooth, p, q, h) for q in near):
            crowded.append(p)
        else:
            isolated.append(p)
    return (
        np.asarray(isolated, dtype=np.int64).reshape(-1, 3),
        np.asarray(crowded, dtype=np.int64).reshape(-1, 3),
    )


def _separate(smooth: np.ndarray, p: np.ndarray, q: np.ndarray, h: float) -> bool:
    """True when maximum ``q`` is separated from ``p`` by a dip of at least ``h``."""
    n = int(np.max(np.abs(q - p))) * 2 + 1
    t = np.linspace(0.0, 1.0, n)
    line = p[:, None] + (q - p)[:, None] * t[None, :]
    profile = ndimage.map_coordinates(smooth, line, order=1)
    return bool(smooth[tuple(q)] - profile.min() >= h)


def particle_fwhm_vox(volume: np.ndarray, n_peaks: int = 20) -> np.ndarray | None:
    """Median full width at half maximum ``(z, y, x)`` (voxels) of the particles of a volume.

    The ``n_peaks`` brightest local maxima of the volume smoothed with a 0.7-voxel Gaussian,
    away from its two outer voxels on every face (boundary artefacts), that stand at least 5
    robust noise levels and a quarter of the brightest of them above the median are measured
    along each axis, from the peak outwards to where the intensity falls below half its
    height above the background (the volume's median). The widths are measured on
    the volume itself, so they follow the microscope, the voxel size and the reconstruction
    settings (iterations, filter): nothing about the optics is assumed.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
    n_peaks : int
        Maxima measured (the brightest).

    Returns
    -------
    ndarray, shape (3,), float64, or None
        The median widths (≥ 1 voxel); None when the volume has no clear maximum.
    """
    vol = check_volume(volume)
    bg = float(np.median(vol))
    sm = gaussian_filter(vol.astype(np.float64), _SMOOTH_VOX)
    peaks = np.argwhere((sm == maximum_filter3(sm)) & (sm > bg))
    # reconstructions pile light from outside the field onto their outer voxels: maxima there
    # are artefacts (and cut), and must not set the reference height of the particles
    shape = np.asarray(vol.shape)
    face = np.where(shape > 4 * _FACE_VOX, _FACE_VOX, 0)
    peaks = peaks[np.all((peaks >= face) & (peaks < shape - face), axis=1)]
    if not peaks.size:
        return None
    heights = sm[tuple(peaks.T)] - bg
    noise = 1.4826 * float(np.median(np.abs(sm - np.median(sm))))
    real = heights >= max(5.0 * noise, 0.25 * float(heights.max()))  # particles, not noise
    peaks, heights = peaks[real], heights[real]
    order = np.argsort(heights)[::-1][:n_peaks]
    widths = []
    for p, h in zip(peaks[order], heights[order], strict=True):
        level = bg + 0.5 * h
        w = []
        for axis in range(3):
            line = np.moveaxis(sm, axis, 0)[(slice(None), *np.delete(p, axis))]
            i = p[axis]
            lo, hi = i, i
            while lo > 0 and line[lo - 1] > level:
                lo -= 1
            while hi < line.size - 1 and line[hi + 1] > level:
                hi += 1
            w.append(hi - lo + 1)
        widths.append(w)
    if not widths:
        return None
    return np.median(np.asarray(widths, dtype=float), axis=0)


def auto_box_um(
    volume: np.ndarray, voxel_size_um: Sequence[float], n_peaks: int = 20
) -> tuple[float, float, float]:
    """PSF box ``(z, y, x)`` in µm from the particles of ``volume``: :data:`BOX_FWHM` × the
    median full width at half maximum of its ``n_peaks`` brightest maxima along each axis
    (:func:`particle_fwhm_vox`).

    The box is at least 5 voxels and at most half the volume along each axis (so that
    isolated particles fit whole inside it); a volume without a clear maximum gets half its
    extent.
    """
    vol = check_volume(volume)
    spacing = np.asarray(check_voxel_size_um(voxel_size_um), dtype=float)
    shape = np.asarray(vol.shape)
    fwhm_vox = particle_fwhm_vox(vol, n_peaks)
    box_vox = shape / 2.0 if fwhm_vox is None else BOX_FWHM * fwhm_vox
    # at most half the volume, so that isolated particles fit whole inside it
    box_vox = np.clip(box_vox, 5.0, np.maximum(shape / 2.0, 5.0))
    return tuple(float(v) for v in box_vox * spacing)


def _shell(shape: tuple[int, ...]) -> np.ndarray:
    """Boolean mask of the outer one-voxel shell (the six faces) of a box."""
    shell = np.ones(shape, dtype=bool)
    shell[1:-1, 1:-1, 1:-1] = False
    return shell


def estimate_psf(
    volume: np.ndarray,
    voxel_size_um: Sequence[float],
    *,
    n_particles: int = 10,
    box_um: Sequence[float] | None = None,
    min_snr: float = 10.0,
) -> np.ndarray:
    """Average image of isolated bright particles, aligned to sub-voxel precision.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
        A reconstructed volume (the first of a sequence, as in the paper §3.2).
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` (µm).
    n_particles : int
        Number of particles averaged (the brightest isolated ones); fewer are used, with a
        warning, when fewer qualify.
    box_um : sequence of 3 float or None
        PSF box ``(z, y, x)`` in µm, rounded to an odd number of voxels per axis; ``None``:
        :func:`auto_box_um` of this volume (see the module docstring).
    min_snr : float
        Minimum particle peak height above background in units of the robust noise level.

    Returns
    -------
    ndarray, shape (bz, by, bx), float32
        Non-negative PSF with odd shape, its centre at the middle voxel, summing to 1.

    Raises
    ------
    InputError
        For a bad volume, voxel size, ``n_particles`` or a box larger than the volume.
    TrackingError
        If no isolated particle is found.
    """
    vol = check_volume(volume)
    spacing = check_voxel_size_um(voxel_size_um)
    with raised_as(InputError):
        n_particles = int_in_range(n_particles, "n_particles", 1)
    if box_um is None:
        box_um = auto_box_um(vol, spacing)
        log.info("estimate_psf: box %s µm from the particles' widths", [f"{b:.0f}" for b in box_um])
    box = box_shape_vox(box_um, spacing)
    if any(bx + 2 > n for bx, n in zip(box, vol.shape, strict=True)):
        raise InputError(
            f"box_um {tuple(box_um)} is {box} voxels, too large for a volume of shape "
            f"{vol.shape} (it needs one spare voxel on each side)"
        )
    isolated, crowded = find_isolated_peaks(vol, box, min_snr=min_snr)
    if isolated.shape[0] == 0:
        raise TrackingError(
            f"estimate_psf: no isolated particle found ({crowded.shape[0]} candidate(s) had a "
            f"neighbour inside the {box} voxel box); give a smaller box_um or a PSF file"
        )
    if isolated.shape[0] < n_particles:
        log.warning(
            "estimate_psf: only %d isolated particle(s) for n_particles=%d",
            isolated.shape[0],
            n_particles,
        )
    chosen = isolated[:n_particles]
    b, _ = _noise(vol)
    half = np.asarray(box) // 2
    pad = half + 1
    acc = np.zeros(box, dtype=np.float64)
    used = 0
    for p in chosen:
        lo, hi = p - pad, p + pad + 1
        crop = vol[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]].astype(np.float64) - b
        peak = crop[tuple(pad)]
        w = np.clip(crop - 0.5 * peak, 0.0, None)
        # the upper half of this particle only: the component of w > 0 holding the peak
        lab, _ = ndimage.label(w > 0)
        w = np.where(lab == lab[tuple(pad)], w, 0.0)
        centre = np.asarray(ndimage.center_of_mass(w))
        shifted = ndimage.shift(crop, pad - centre, order=3, mode="nearest")
        cut = shifted[1:-1, 1:-1, 1:-1]
        total = float(np.clip(cut, 0.0, None).sum())
        if not total > 0:
            continue
        acc += cut / total
        used += 1
    if used == 0:
        raise TrackingError("estimate_psf: every selected particle box was empty")
    psf = acc / used
    shell = _shell(psf.shape)
    level = float(np.median(psf[shell]))
    spread = 1.4826 * float(np.median(np.abs(psf[shell] - level)))
    psf = psf - level
    # residual noise: keep only the particle (the connected part above 2 σ holding the centre)
    lab, _ = ndimage.label(psf > 2.0 * spread)
    psf = np.where(lab == lab[tuple(half)], np.clip(psf, 0.0, None), 0.0)
    total = float(psf.sum())
    if not total > 0:
        raise TrackingError("estimate_psf: the averaged particle image is flat")
    log.info(
        "estimate_psf: averaged %d isolated particle(s) (%d crowded rejected), box %s voxels",
        used,
        crowded.shape[0],
        box,
    )
    return (psf / total).astype(np.float32)


def check_psf(psf: np.ndarray, name: str = "psf") -> np.ndarray:
    """Validate a PSF (3-D, odd shape, finite, non-negative sum > 0) and normalise it.

    Negative values (background subtraction residue) are clipped to 0.

    Returns
    -------
    ndarray, float32, summing to 1.

    Raises
    ------
    InputError
    """
    arr = check_volume(psf, name).astype(np.float64)
    if any(n % 2 == 0 for n in arr.shape):
        raise InputError(
            f"{name} must have an odd size along every axis (its centre must be a voxel), "
            f"got shape {arr.shape}"
        )
    arr = np.clip(arr, 0.0, None)
    total = float(arr.sum())
    if not total > 0:
        raise InputError(f"{name} has no positive value (it must sum to > 0)")
    return (arr / total).astype(np.float32)


def load_psf(path: str | Path) -> np.ndarray:
    """Read a user-given particle PSF from a TIFF stack ``(z, y, x)``.

    Parameters
    ----------
    path : str or Path
        TIFF file (read with tifffile) holding one 3-D stack with an odd size along every axis.

    Returns
    -------
    ndarray, float32, summing to 1 (negative values clipped to 0).

    Raises
    ------
    InputError
        If the file is missing or unreadable, or its content is not a valid PSF.
    """
    import tifffile

    p = Path(path)
    if not p.is_file():
        raise InputError(f"PSF file {str(p)!r} does not exist")
    try:
        arr = tifffile.imread(p)
    except Exception as exc:
        raise InputError(f"PSF file {str(p)!r} is not a readable TIFF: {exc}") from None
    arr = np.squeeze(arr)
    if arr.ndim != 3:
        raise InputError(f"PSF file {str(p)!r} must hold a 3-D stack (z, y, x), got {arr.shape}")
    return check_psf(arr, name=f"PSF file {str(p)!r}")
