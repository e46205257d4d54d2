"""Depth-adaptive anti-aliasing filter for light-field deconvolution (Stefanoiu et al. 2019).

A light field samples each depth of the object at a different rate, so a volume estimate on a
uniform voxel grid develops aliasing artefacts (grid patterns) wherever the grid is finer
than what the light field can resolve at that depth. Stefanoiu, Page, Symvoulidis, Westmeyer
& Lasser (Opt. Express 27, 2019) low-pass filter every depth of the estimate after each
Richardson–Lucy update with a Lanczos-windowed sinc whose width follows the depth; the
paper's "Lanczos filter width" (2) is the window parameter ``a``.

The cut-off used here, in cycles per lateral voxel, is derived from the optics:

- **geometric sampling** — a point at depth ``z`` images ``D = M² |z|`` from the array and is
  seen by about ``D / f_l`` lenslets per axis, whose views interleave: the light field samples
  that plane every ``p · f_l / D`` (intermediate-image units), never coarser than one lenslet
  ``p``. In voxels (``s`` per lenslet) the resolvable period is ``T = s · min(1, f_l / D)``
  and the cut-off ``1 / T``.
- **diffraction** — the band limit of Broxton et al. (2013), the paper's Eq. 2,
  ``ν(z) = p / (0.94 λ M |z|)`` cycles per µm in object space, i.e. ``ν · p / (M s)`` cycles
  per voxel.

The filter passes everything up to the lower of the two, and nothing is done where that is at
or above the grid's Nyquist frequency (0.5 cycles per voxel).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .errors import InputError


def cutoff_cycles_per_voxel(optics, depths_um, s: int) -> np.ndarray:
    """Lateral cut-off frequency (cycles / voxel) of every depth, capped at 0.5.

    Parameters
    ----------
    optics : lfsim.optics.Optics
    depths_um : array_like, shape (nz,)
    s : int
        Voxels per lenslet.

    Returns
    -------
    ndarray, shape (nz,)
    """
    z = np.abs(np.asarray(depths_um, dtype=np.float64))
    d = optics.magnification**2 * z  # image distance from the array (µm)
    with np.errstate(divide="ignore"):
        period = s * np.minimum(1.0, optics.mla_focal_um / np.where(d > 0, d, 1e-30))
        geometric = 1.0 / period
        voxel_um = optics.lenslet_object_um / s
        nu = optics.mla_pitch_um / (0.94 * optics.wavelength_um * optics.magnification * z)
        diffraction = np.where(z > 0, nu * voxel_um, np.inf)
    return np.minimum(0.5, np.minimum(geometric, diffraction))


def lanczos_kernel(cutoff: float, a: float = 2.0) -> np.ndarray:
    """1-D Lanczos-windowed sinc low-pass with cut-off ``cutoff`` cycles/sample, sum 1.

    ``h(x) ∝ sinc(2 f_c x) · sinc(2 f_c x / a)`` for ``|x| < a / (2 f_c)``.
    """
    if not (0 < cutoff <= 0.5):
        raise InputError(f"cutoff must lie in (0, 0.5] cycles per voxel, got {cutoff!r}")
    if a <= 0:
        raise InputError(f"Lanczos window a must be > 0, got {a!r}")
    half = int(np.floor(a / (2 * cutoff)))
    x = np.arange(-half, half + 1, dtype=np.float64)
    h = np.sinc(2 * cutoff * x) * np.sinc(2 * cutoff * x / a)
    return h / h.sum()


class DepthFilter:
    """Per-depth separable Lanczos low-pass of volumes ``(nz, ny, nx)``.

    Parameters
    ----------
    cutoffs : array_like, shape (nz,)
        Cut-off per depth in cycles per voxel (0.5 or more: that depth is left unchanged).
    a : float
        Lanczos window parameter (the paper's "Lanczos filter width", 2).
    """

    def __init__(self, cutoffs, a: float = 2.0):
        self.cutoffs = np.asarray(cutoffs, dtype=np.float64)
        self.a = float(a)
        self.kernels = [
            None if c >= 0.5 else lanczos_kernel(float(c), self.a) for c in self.cutoffs
        ]

    @classmethod
    def for_optics(cls, optics, depths_um, s: int, a: float = 2.0) -> DepthFilter:
        return cls(cutoff_cycles_per_voxel(optics, depths_um, s), a)

    @property
    def active(self) -> bool:
        return any(k is not None for k in self.kernels)

    def __call__(self, volume: np.ndarray) -> np.ndarray:
        """Filter in place-safe fashion; negative ringing is clipped to keep the volume ≥ 0."""
        vol = np.asarray(volume, dtype=np.float32)
        if vol.ndim != 3 or vol.shape[0] != len(self.kernels):
            raise InputError(
                f"volume shape {vol.shape} does not match the filter's {len(self.kernels)} depths"
            )
        out = vol.copy()
        for k, h in enumerate(self.kernels):
            if h is None:
                continue
            sl = ndimage.correlate1d(vol[k], h, axis=0, mode="nearest")
            sl = ndimage.correlate1d(sl, h, axis=1, mode="nearest")
            out[k] = np.maximum(sl, 0.0)
        return out
