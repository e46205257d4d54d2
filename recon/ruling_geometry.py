"""Where the ruling of a stage micrometer lies in its lenslet sums: the direction of its band,
its ruled region and the micrometer's defocus (:mod:`recon.pixel_size`, method step 2)."""

from __future__ import annotations

import logging
import math

import numpy as np

from .pixel_size_defaults import DIRECTION_KERNEL, MIN_COLUMNS, ROW_FRACTION, SUM_RADIUS
from .ruling_model import lenslet_sums

log = logging.getLogger(__name__)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of ``True`` in a 1-D mask."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def _ruled_region(
    sums: np.ndarray, q0: float, theta_strips: float = 0.0
) -> tuple[np.ndarray, np.ndarray, int, int] | None:
    """The ruled region of ``sums`` (lenslet sums, scale near the columns' direction).

    The lenslets are grouped in strips one lenslet wide along the scale: the rows when
    ``theta_strips`` (radians, the scale's direction from the columns) is 0, else strips
    tilted by it (lenslet ``(u, v)`` is in strip ``round(v cos θ − u sin θ)``).
    Strips: the contiguous block, around the brightest strip, of strips whose mean over the
    background reaches :data:`~recon.pixel_size_defaults.ROW_FRACTION` of the brightest's — a ruling
    crosses a block of strips. Along the scale: the longest run lit in those strips after smoothing
    over one division.

    Returns
    -------
    keep : ndarray of bool, shape of ``sums``
        The lenslets of the region (whole lenslets of strips with enough of them).
    strip : ndarray of int, shape of ``sums``
        Strip number of every lenslet.
    n_strips, n_along : int
        Strips of the region and its length along the scale (lenslets).
    """
    fin = np.isfinite(sums)
    if fin.sum() < MIN_COLUMNS:
        return None
    vv, uu = np.mgrid[0 : sums.shape[0], 0 : sums.shape[1]]
    ct, st = math.cos(theta_strips), math.sin(theta_strips)
    t = np.rint(vv * ct - uu * st).astype(int)
    a = np.rint(uu * ct + vv * st).astype(int)
    t -= t.min()
    a -= a.min()
    bg = float(np.nanpercentile(sums, 5))
    n_t = np.bincount(t[fin], minlength=t.max() + 1)
    s_t = np.bincount(t[fin], sums[fin], minlength=t.max() + 1)
    strip_mean = np.where(n_t >= MIN_COLUMNS, s_t / np.maximum(n_t, 1) - bg, -np.inf)
    top = int(np.argmax(strip_mean))
    if not np.isfinite(strip_mean[top]) or strip_mean[top] <= 0:
        return None
    run = next(r for r in _runs(strip_mean >= ROW_FRACTION * strip_mean[top]) if r[0] <= top < r[1])
    in_strips = fin & (t >= run[0]) & (t < run[1])
    n_a = np.bincount(a[in_strips], minlength=a.max() + 1)
    s_a = np.bincount(a[in_strips], sums[in_strips], minlength=a.max() + 1)
    prof = np.where(n_a > 0, s_a / np.maximum(n_a, 1) - bg, 0.0)
    win = max(1, math.ceil(1.0 / q0)) + 1
    smooth = np.convolve(prof, np.ones(win) / win, mode="same")
    runs = _runs(smooth > 0.2 * smooth.max())
    first, stop = max(runs, key=lambda r: r[1] - r[0])
    keep = in_strips & (a >= first) & (a < stop)
    counts = np.bincount(t[keep], minlength=t.max() + 1)
    keep &= counts[t] >= MIN_COLUMNS
    return keep, t, int(run[1] - run[0]), int(stop - first)


def ruling_direction(sums: np.ndarray) -> tuple[float, float]:
    """Direction of the ruled band in lenslet sums: the direction of the scale, unaliased.

    A micrometer's lines are all cut to lengths that start together, so the ruled region is a
    band along the scale; the lenslet sums alias the lines' period but not the band. Its
    direction is the one along which the sums, projected onto the perpendicular direction,
    have the sharpest profile: the largest ``wᵀ K w`` with ``w = sums − mean`` and ``K`` a
    Gaussian of :data:`~recon.pixel_size_defaults.DIRECTION_KERNEL` lenslets in the projected
    distance between two lenslets (a smooth projection, free of the lattice's preference for its own
    axes), searched every degree and refined every 0.05° within ±1.5° (its accuracy:
    docs/validation_notes.md, "Pixel size").

    Parameters
    ----------
    sums : ndarray, shape (n_v, n_u)
        Lenslet sums (NaN: missing lenslets).

    Returns
    -------
    direction_deg : float
        Direction of the scale from the lenslet ``u`` axis towards ``v``, in [0, 180).
    contrast : float
        Largest over smallest ``wᵀ K w`` over the directions (1: no direction stands out).
    """
    fin = np.isfinite(sums)
    vv, uu = np.nonzero(fin)
    w = sums[fin] - float(np.mean(sums[fin]))
    c, r = uu - uu.mean(), vv - vv.mean()

    def score(deg: float) -> float:
        a = math.radians(deg)
        t = r * math.cos(a) - c * math.sin(a)
        return float(w @ np.exp(-0.5 * ((t[:, None] - t[None, :]) / DIRECTION_KERNEL) ** 2) @ w)

    coarse = np.arange(0.0, 180.0, 1.0)
    sc = np.array([score(a) for a in coarse])
    k = int(np.argmax(sc))
    fine = coarse[k] + np.arange(-1.5, 1.5001, 0.05)
    sf = np.array([score(a) for a in fine])
    direction = float(fine[int(np.argmax(sf))] % 180.0)
    contrast = float(sc[k] / max(sc.min(), 1e-300 * max(sc[k], 1.0)))
    return direction, contrast


def defocus_um(image: np.ndarray, grid, optics) -> tuple[float, float]:
    """Defocus of the object from the parallax between the lenslets' views.

    In the native object plane every point fills its lenslet's pupil image alike, so the
    centroid of the light behind a lenslet does not depend on the object. Out of focus by
    ``z`` each pixel behind a lenslet sees the object shifted by ``z tan α`` (``α`` the
    pixel's direction), and the centroid moves with the gradient of the lenslet sums: by
    ``κ z ∇ln S`` lenslets, ``κ = NA / (8 P)`` for a uniformly filled pupil image (``P`` the
    object-space lenslet pitch, µm; the sign is the optics' inversion). The slope of the
    centroids over ``∇ln S`` (central differences, lenslets brighter than 1/5 of the
    brightest) gives ``z``.

    Returns
    -------
    z_um, z_std_um : float
        Estimated defocus (µm; positive away from the objective, the sign of lfsim's
        ``z_um``) and its standard uncertainty; ``(0, inf)`` when the image has no gradients
        to measure it on.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = grid.lenslet_index(np.stack([xx + 0.5, yy + 0.5], axis=-1))
    near = np.rint(uv)
    off = uv - near
    inside = np.hypot(off[..., 0], off[..., 1]) <= SUM_RADIUS
    iu = near[..., 0].astype(np.int64)
    iv = near[..., 1].astype(np.int64)
    u0, v0 = int(iu.min()), int(iv.min())
    nu, nv = int(iu.max()) - u0 + 1, int(iv.max()) - v0 + 1
    flat = ((iv - v0) * nu + (iu - u0)).ravel()
    wimg = np.where(inside, img, 0.0)

    def per_lenslet(values: np.ndarray) -> np.ndarray:
        return np.bincount(flat, values.ravel(), nu * nv).reshape(nv, nu)

    total = per_lenslet(wimg)
    whole, _, _ = lenslet_sums(img, grid)
    ok = np.isfinite(whole) & (total > 0)
    den = np.where(ok, total, 1.0)
    cx = np.where(ok, per_lenslet(wimg * off[..., 0]) / den, np.nan)
    cy = np.where(ok, per_lenslet(wimg * off[..., 1]) / den, np.nan)
    level = np.where(ok, total, np.nan)
    mid = level[1:-1, 1:-1]
    gx = 0.5 * (level[1:-1, 2:] - level[1:-1, :-2]) / mid
    gy = 0.5 * (level[2:, 1:-1] - level[:-2, 1:-1]) / mid
    dx, dy = cx[1:-1, 1:-1], cy[1:-1, 1:-1]
    with np.errstate(invalid="ignore"):
        m = np.isfinite(gx + gy + dx + dy) & (mid > 0.2 * np.nanmax(level))
    if m.sum() < 8:
        return 0.0, math.inf
    dx, dy, gx, gy = dx[m] - np.median(dx[m]), dy[m] - np.median(dy[m]), gx[m], gy[m]
    gg = float(gx @ gx + gy @ gy)
    if not gg > 0:
        return 0.0, math.inf
    k = float(dx @ gx + dy @ gy) / gg
    res = np.r_[dx - k * gx, dy - k * gy]
    se = math.sqrt(float(res @ res) / max(len(res) - 1, 1) / gg)
    kappa = optics.na / (8.0 * optics.lenslet_object_um)
    return -k / kappa, se / kappa
