"""Calibration step 2: pitch, rotation and offset of the lenslet grid from the power spectrum.

Pitch and rotation come from the two perpendicular fundamental peaks of the 2-D power spectrum
of the Hann-windowed white image, refined to a fraction of a frequency bin. A peak's
*prominence* (its power over the median power of the ring of the same spatial frequency) tells
a lenslet grid from noise or a natural image; among the prominent peaks the most powerful one
is the fundamental, a strong sub-harmonic takes over (small lenslet images). The grid's offset
comes from the Fourier phases at the two fundamental frequencies
(:func:`recon.calibration.calibrate_white` runs the steps).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .errors import CalibrationError

log = logging.getLogger(__name__)

#: Smallest lenslet pitch (pixels) the calibration looks for.
MIN_PITCH_PX = 3.0
#: The image must span at least this many lenslets in each direction.
MIN_LENSLETS = 4
#: Minimum whitened spectral power (peak power / median power at that spatial frequency) of
#: both fundamental peaks; white noise reaches about 20 on a megapixel image.
MIN_PROMINENCE = 100.0


@dataclass(frozen=True)
class SpectralLattice:
    """Pitch (px), rotation (rad) and the prominences of the two fundamental peaks."""

    pitch_px: float
    theta_rad: float
    prominence: tuple[float, float]


class Spectrum:
    """Whitened power spectrum of a Hann-windowed image (half plane, ``rfft2`` layout)."""

    def __init__(self, img: np.ndarray) -> None:
        h, w = img.shape
        self.shape = (h, w)
        win = np.hanning(h)[:, None] * np.hanning(w)[None, :]
        self.windowed = (img - img.mean()) * win
        power = np.abs(np.fft.rfft2(self.windowed)) ** 2
        ky = np.fft.fftfreq(h)[:, None]
        kx = np.fft.rfftfreq(w)[None, :]
        self.kr = np.hypot(kx, ky)
        ring = np.floor(self.kr * min(h, w)).astype(np.int64)
        # Median power of every ring of width one frequency bin (sort by ring, then power).
        flat_ring = ring.ravel()
        flat_p = power.ravel()
        order = np.lexsort((flat_p, flat_ring))
        counts = np.bincount(flat_ring)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        med = np.zeros(counts.size)
        has = counts > 0
        med[has] = flat_p[order][starts[has] + (counts[has] - 1) // 2]
        floor = max(float(power.max()) * 1e-12, 1e-300)
        self.power = power
        self.q = power / np.maximum(med[ring], floor)

    def q_at(self, iy: int, ix: int) -> float:
        """Whitened power at signed bin ``(iy, ix)`` (using the spectrum's symmetry)."""
        h = self.shape[0]
        if ix < 0:
            iy, ix = -iy, -ix
        if ix >= self.q.shape[1]:
            return 0.0
        return float(self.q[iy % h, ix])

    def logp_at(self, iy: int, ix: int) -> float:
        h, _ = self.shape
        if ix < 0:
            iy, ix = -iy, -ix
        if ix >= self.power.shape[1]:
            return -np.inf
        return float(np.log(max(self.power[iy % h, ix], 1e-300)))

    def bins(self, kx: float, ky: float) -> tuple[int, int]:
        h, w = self.shape
        return round(ky * h), round(kx * w)

    def p_at(self, iy: int, ix: int) -> float:
        """Power at signed bin ``(iy, ix)``."""
        if ix < 0:
            iy, ix = -iy, -ix
        if ix >= self.power.shape[1]:
            return 0.0
        return float(self.power[iy % self.shape[0], ix])

    def local_max(self, kx: float, ky: float, radius: int = 2) -> tuple[int, int, float, float]:
        """Most powerful bin within ``radius`` bins of frequency ``(kx, ky)``.

        Returns its signed bin ``(iy, ix)``, whitened power and power.
        """
        iy0, ix0 = self.bins(kx, ky)
        best = (iy0, ix0, 0.0, -1.0)
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                p = self.p_at(iy0 + dy, ix0 + dx)
                if p > best[3]:
                    best = (iy0 + dy, ix0 + dx, self.q_at(iy0 + dy, ix0 + dx), p)
        return best

    def refine(self, iy: int, ix: int) -> tuple[float, float]:
        """Sub-bin peak frequency ``(kx, ky)`` (cycles/pixel) by parabolas on log power."""
        h, w = self.shape

        def vertex(a: float, b: float, c: float) -> float:
            den = a - 2.0 * b + c
            if not np.isfinite(den) or den >= 0:
                return 0.0
            return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))

        l0 = self.logp_at(iy, ix)
        dx = vertex(self.logp_at(iy, ix - 1), l0, self.logp_at(iy, ix + 1))
        dy = vertex(self.logp_at(iy - 1, ix), l0, self.logp_at(iy + 1, ix))
        iys = iy - h if iy > h // 2 else iy
        return (ix + dx) / w, (iys + dy) / h

    def dft(self, kx: float, ky: float) -> complex:
        """Fourier transform of the windowed image at any frequency (pixel centres at +0.5)."""
        h, w = self.shape
        ex = np.exp(-2j * np.pi * kx * (np.arange(w) + 0.5))
        ey = np.exp(-2j * np.pi * ky * (np.arange(h) + 0.5))
        return complex(ey @ self.windowed @ ex)


def spectral_lattice(spec: Spectrum, expected_pitch_px: float | None) -> SpectralLattice:
    """Pitch and rotation of the lenslet grid from the two fundamental spectral peaks."""
    h, w = spec.shape
    k_lo = MIN_LENSLETS / min(h, w)
    k_hi = 1.0 / MIN_PITCH_PX
    if expected_pitch_px is not None:
        k_lo = max(k_lo, 1.0 / (1.25 * expected_pitch_px))
        k_hi = min(k_hi, 1.0 / (0.8 * expected_pitch_px))
    band = (spec.kr >= k_lo) & (spec.kr <= k_hi)
    if not band.any():
        raise CalibrationError("the image is too small to hold a lenslet grid of that pitch")
    q = np.where(band, spec.q, 0.0)
    iy, ix = np.unravel_index(int(np.argmax(q)), q.shape)
    q1 = float(q[iy, ix])
    if q1 >= MIN_PROMINENCE:
        # Among the prominent peaks, the fundamental is the most powerful (whitening favours
        # the harmonics, whose frequencies carry less background power).
        strong = np.where(q >= MIN_PROMINENCE, spec.power, -1.0)
        iy, ix = np.unravel_index(int(np.argmax(strong)), q.shape)
        q1 = float(q[iy, ix])
    kx, ky = spec.refine(int(iy), int(ix))
    # A strong peak may be a harmonic, (2, 0) or (1, 1), when the lenslet images are small:
    # prefer a prominent sub-harmonic that carries a good fraction of the peak's power.
    p1 = float(spec.power[iy, ix])
    k_min_all = MIN_LENSLETS / min(h, w)
    for _ in range(3):
        cands = [(kx / 2, ky / 2)]
        for sgn in (1.0, -1.0):
            c, s = math.cos(sgn * math.pi / 4), math.sin(sgn * math.pi / 4)
            cands.append(((c * kx - s * ky) / math.sqrt(2), (s * kx + c * ky) / math.sqrt(2)))
        found = False
        for cx, cy in cands:
            if math.hypot(cx, cy) < k_min_all:
                continue
            jy, jx, qc, pc = spec.local_max(cx, cy)
            if qc >= MIN_PROMINENCE and pc >= 0.1 * p1:
                log.debug("spectral peak at %.4g cycles/px is a harmonic", math.hypot(kx, ky))
                kx, ky = spec.refine(jy, jx)
                q1, p1 = qc, pc
                found = True
                break
        if not found:
            break
    k1 = math.hypot(kx, ky)
    if q1 < MIN_PROMINENCE:
        where = (
            f" near the expected pitch {expected_pitch_px:g} px"
            if expected_pitch_px is not None
            else ""
        )
        raise CalibrationError(
            f"no lenslet grid found{where}: the strongest periodic component "
            f"(period {1 / k1:.3g} px) has a spectral prominence of only {q1:.3g} "
            f"(a lenslet grid gives >= {MIN_PROMINENCE:g}); is this a white image?"
        )
    jy, jx, q2, _ = spec.local_max(-ky, kx)
    if q2 < MIN_PROMINENCE:
        raise CalibrationError(
            f"no square lenslet grid found: a periodic component of period {1 / k1:.3g} px "
            f"exists (prominence {q1:.3g}) but not the perpendicular one (prominence {q2:.3g})"
        )
    kx2, ky2 = spec.refine(jy, jx)
    k2 = math.hypot(kx2, ky2)
    if abs(k2 - k1) > 0.05 * k1:
        raise CalibrationError(
            f"the two periodic components of the image have periods {1 / k1:.4g} and "
            f"{1 / k2:.4g} px: not a square lenslet grid"
        )
    t1 = math.atan2(ky, kx)
    t2 = math.atan2(ky2, kx2) - math.pi / 2
    t2 = t1 + ((t2 - t1 + math.pi / 4) % (math.pi / 2) - math.pi / 4)
    theta = 0.5 * (t1 + t2)
    theta = (theta + math.pi / 4) % (math.pi / 2) - math.pi / 4
    pitch = 2.0 / (k1 + k2)
    if expected_pitch_px is not None and not (
        0.8 * expected_pitch_px <= pitch <= 1.25 * expected_pitch_px
    ):
        raise CalibrationError(
            f"the lenslet grid of the image has a pitch of about {pitch:.4g} px, far from "
            f"the expected {expected_pitch_px:g} px"
        )
    log.debug(
        "spectrum: pitch %.4f px, rotation %.4f deg, prominence %.3g / %.3g",
        pitch,
        math.degrees(theta),
        q1,
        q2,
    )
    return SpectralLattice(pitch, theta, (q1, q2))


def spectral_origin(spec: Spectrum, pitch: float, theta: float) -> np.ndarray:
    """Grid offset ``(x, y)`` from the Fourier phases at the two fundamental frequencies."""
    eu = np.array([math.cos(theta), math.sin(theta)])
    ev = np.array([-math.sin(theta), math.cos(theta)])
    tu = -np.angle(spec.dft(*(eu / pitch))) / (2 * np.pi)
    tv = -np.angle(spec.dft(*(ev / pitch))) / (2 * np.pi)
    return pitch * (tu * eu + tv * ev)
