"""The lenslet sums of a stage micrometer's light-field image and the model of a ruling averaged
over each lenslet (:mod:`recon.pixel_size`, method steps 1 and 3)."""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy import special

from .pixel_size_defaults import SUM_RADIUS

log = logging.getLogger(__name__)


def lenslet_sums(
    image: np.ndarray, grid, radius_fraction: float | None = SUM_RADIUS
) -> tuple[np.ndarray, int, int]:
    """Sum the pixels behind every lenslet that lies wholly inside the image.

    Parameters
    ----------
    image : ndarray, shape (height, width)
        Light-field image (any units).
    grid : recon.calibration.LensletGrid
        Lenslet grid of the image (pixels).
    radius_fraction : float, optional
        Sum only the pixels whose centres lie within ``radius_fraction · pitch`` of the
        lenslet centre (default :data:`~recon.pixel_size_defaults.SUM_RADIUS`): the rim of a lenslet
        image overlaps its neighbours' (diffraction, f-number mismatch), and that cross-talk would
        look like light from the neighbouring footprints. ``None`` sums the whole cell.

    Returns
    -------
    sums : ndarray, shape (n_v, n_u)
        Sum over each lenslet ``(u, v)``; NaN for lenslets whose cell (one pitch square about
        the centre) leaves the image.
    u0, v0 : int
        Lenslet indices of ``sums[0, 0]``.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = grid.lenslet_index(np.stack([xx + 0.5, yy + 0.5], axis=-1))
    near = np.rint(uv)
    iu = near[..., 0].astype(np.int64)
    iv = near[..., 1].astype(np.int64)
    weight = img
    if radius_fraction is not None:
        off = np.hypot(uv[..., 0] - near[..., 0], uv[..., 1] - near[..., 1])
        weight = np.where(off <= radius_fraction, img, 0.0)
    u0, v0 = int(iu.min()), int(iv.min())
    nu, nv = int(iu.max()) - u0 + 1, int(iv.max()) - v0 + 1
    flat = (iv - v0) * nu + (iu - u0)
    sums = np.bincount(flat.ravel(), weights=weight.ravel(), minlength=nu * nv).reshape(nv, nu)
    # A lenslet is whole when the four corners of its cell lie inside the image.
    vv, uu = np.mgrid[v0 : v0 + nv, u0 : u0 + nu]
    ok = np.ones((nv, nu), dtype=bool)
    for du in (-0.5, 0.5):
        for dv in (-0.5, 0.5):
            xy = grid.centers(np.c_[(uu + du).ravel(), (vv + dv).ravel()]).reshape(nv, nu, 2)
            ok &= (xy[..., 0] >= 0) & (xy[..., 0] <= w) & (xy[..., 1] >= 0) & (xy[..., 1] <= h)
    sums[~ok] = np.nan
    return sums, u0, v0


class _Profile:
    """Antiderivatives of a periodic ruling (period 1) of lines ``box(ρ) ⊛ N(0, σ²)``.

    ``P(x) = H(x) − ρ x`` and ``Q(x) = ∫₀ˣ P − P̄ x`` are periodic, where ``H`` is the
    antiderivative of the profile (``H' = h``, the line coverage) and ``P̄`` the mean of ``P``.
    Only the lines within ``ρ/2 + 7σ`` of ``[0, 1)`` contribute (``m`` below).
    """

    def __init__(self, rho: float, sigma: float) -> None:
        self.rho, self.sigma = rho, sigma
        # For f in [0, 1) only lines m with |f + m| < ρ/2 + 7σ differ from 0 or ρ.
        k = max(math.ceil(rho / 2 + 7 * sigma), 1)
        self.m = np.arange(-k, k, dtype=float)
        self.pos = (self.m >= 0).astype(float)
        self.jm = self._j(self.m)
        self.pbar = float(self._int_p(np.array([1.0]))[0])

    def _phi(self, x):
        return np.exp(-0.5 * (x / self.sigma) ** 2) * (1.0 / math.sqrt(2 * math.pi))

    def _g(self, t):
        """Cumulative of one line (0 before it, ``ρ`` after it)."""
        s, r = self.sigma, self.rho / 2
        hi, lo = t + r, t - r
        return (
            hi * special.ndtr(hi / s)
            - lo * special.ndtr(lo / s)
            + s * (self._phi(hi) - self._phi(lo))
        )

    def _j(self, t):
        """Antiderivative of :meth:`_g`."""
        s, r = self.sigma, self.rho / 2
        hi, lo = t + r, t - r
        return 0.5 * (
            (hi * hi + s * s) * special.ndtr(hi / s)
            - (lo * lo + s * s) * special.ndtr(lo / s)
            + s * (hi * self._phi(hi) - lo * self._phi(lo))
        )

    def p(self, x: np.ndarray) -> np.ndarray:
        f = x - np.floor(x)
        t = f[..., None] + self.m
        return (self._g(t) - self.rho * self.pos).sum(axis=-1) - self.rho * f

    def _int_p(self, f: np.ndarray) -> np.ndarray:
        t = f[..., None] + self.m
        s = (self._j(t) - self.jm - self.rho * self.pos * f[..., None]).sum(axis=-1)
        return s - 0.5 * self.rho * f * f

    def q(self, x: np.ndarray) -> np.ndarray:
        f = x - np.floor(x)
        return self._int_p(f) - self.pbar * f


def ruling_coverage(
    c: np.ndarray, r: np.ndarray, q: float, theta: float, phi: float, rho: float, sigma: float
) -> np.ndarray:
    """Mean line coverage of the lenslet cells ``[c ± ½] × [r ± ½]`` (lenslet units).

    The ruling has phase ``Ψ(ξ, η) = q (ξ cos θ + η sin θ) + φ`` (cycles; lines at integer
    ``Ψ``), lines of relative width ``ρ`` blurred by a Gaussian of ``σ`` (both in periods).
    The cell average is exact: the second difference of the profile's double antiderivative
    over the cell's corners, divided by the cell's area in ``Ψ`` units.

    Returns
    -------
    ndarray
        Coverage in ``[0, 1]`` (``ρ`` on average), same shape as ``c``.
    """
    prof = _Profile(rho, sigma)
    span = q * math.cos(theta)  # Ψ change across a cell along ξ
    delta = q * math.sin(theta)  # ... along η
    a = q * ((c - 0.5) * math.cos(theta) + (r - 0.5) * math.sin(theta)) + phi
    b = a + span
    if abs(delta) < 1e-5:
        pb, pa = np.split(prof.p(np.concatenate([b, a]) + delta / 2), 2)
        return rho + (pb - pa) / span
    q4 = np.split(prof.q(np.concatenate([b + delta, b, a + delta, a])), 4)
    return rho + (q4[0] - q4[1] - q4[2] + q4[3]) / (span * delta)
