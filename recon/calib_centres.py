"""Calibration step 3: the sub-pixel centre of every lenslet of a white image.

Each lenslet's centre is the fixed point ``c = centroid(c)`` of the intensity-weighted
centroid over the lenslet's square cell (side one pitch, aligned with the grid, edges softened
over ``max(2, 0.2 p)`` px) centred on ``c`` itself, solved by Newton's method with the
analytic Jacobian. A point-symmetric lenslet image has its centre as fixed point; the cell
edges run through the dark corners, so the centroid hardly follows the window (low noise
gain), and the soft edges keep the pixel sampling from locking the estimate to the pixel grid
(< 0.02 px with integer pitch and zero rotation, where every lenslet has the same sub-pixel
phase). Before that the dark level of the cell corners is subtracted and the local vignetting
divided out (a plane fitted to the log-brightness of the 5 × 5 neighbouring lenslets).
Lenslets less than half as bright as their neighbours (dead, dust) are skipped, as are
lenslets cut by the image border.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .lenslet_grid import LensletGrid

log = logging.getLogger(__name__)

#: A lenslet whose brightness is below this fraction of its neighbours' is dark (skipped).
DARK_LENSLET_FRACTION = 0.5


@dataclass
class Measurement:
    """What :func:`measure_centres` found for ``K`` lenslets."""

    uv: np.ndarray  # (K, 2) int, lenslet indices
    xy: np.ndarray  # (K, 2) measured centres
    valid: np.ndarray  # (K,) bool: bright and converged
    dark: np.ndarray  # (K,) bool: much darker than the neighbours


def sample_nearest(img: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Values of the pixels holding the points ``xy`` (K, 2), clamped to the image."""
    h, w = img.shape
    j = np.clip(np.floor(xy[:, 0]).astype(int), 0, w - 1)
    i = np.clip(np.floor(xy[:, 1]).astype(int), 0, h - 1)
    return img[i, j]


def _dark_level(img: np.ndarray, grid: LensletGrid, uv: np.ndarray) -> float:
    """Median intensity at the cell corners (where lenslet images do not reach)."""
    h, w = img.shape
    pts = np.concatenate(
        [grid.centers(uv + np.array(d)) for d in ((0.5, 0.5), (-0.5, 0.5), (0.5, -0.5))]
    )
    inside = (pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)
    return float(np.median(sample_nearest(img, pts[inside])))


def _local_log_planes(
    uv: np.ndarray, basis: np.ndarray, brightness: np.ndarray, use: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``log B ≈ a + g · (x − x_k)`` over each lenslet's 5 × 5 neighbours (itself excluded).

    Returns the level ``a`` (K,) and the gradient ``g`` (K, 2) in 1/pixel; NaN level where no
    neighbour is usable.
    """
    lo = uv.min(axis=0)
    n = uv.max(axis=0) - lo + 1
    pad = 2
    table = np.full((n[1] + 2 * pad, n[0] + 2 * pad), np.nan)
    ok = use & (brightness > 0)
    logb = np.full(brightness.shape, np.nan)
    logb[ok] = np.log(brightness[ok])
    table[uv[:, 1] - lo[1] + pad, uv[:, 0] - lo[0] + pad] = logb
    d = np.arange(-pad, pad + 1)
    dv, du = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))
    vals = table[(uv[:, 1] - lo[1] + pad)[:, None] + dv, (uv[:, 0] - lo[0] + pad)[:, None] + du]
    wts = np.exp(-(du**2 + dv**2) / (2 * 1.5**2))
    wts = np.where((du == 0) & (dv == 0), 0.0, wts)
    wk = np.where(np.isfinite(vals), wts, 0.0)
    vals = np.nan_to_num(vals)
    off = np.c_[du, dv] @ basis  # (25, 2) pixel offsets of the neighbours
    a = np.c_[np.ones(len(du)), off]  # (25, 3)
    m = np.einsum("kn,ni,nj->kij", wk, a, a)
    rhs = np.einsum("kn,ni,kn->ki", wk, a, vals)
    m += np.diag([1e-12, 1e-6, 1e-6])  # keeps lenslets without neighbours solvable (g = 0)
    sol = np.linalg.solve(m, rhs[..., None])[..., 0]
    level = np.where(wk.sum(axis=1) > 0, sol[:, 0], np.nan)
    return level, sol[:, 1:]


def _taper(t: np.ndarray, half: float, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Smooth step (cubic, C¹): 1 for ``t <= half − width/2``, 0 for ``t >= half + width/2``.

    Returns the value and its derivative with respect to ``t``.
    """
    z = np.clip((t - (half - 0.5 * width)) * (1.0 / width), 0.0, 1.0)
    zz = z * (1.0 - z)
    val = 1.0 - z * z * (3.0 - 2.0 * z)
    der = zz * (-6.0 / width)
    return val, der


def _cell_window(
    dx: np.ndarray, dy: np.ndarray, basis: np.ndarray, taper_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid window: the lenslet's square cell with softened edges.

    ``(dx, dy)`` are pixel-centre offsets from the window centre; ``basis`` the grid steps
    (rows ``p e_u``, ``p e_v``). The weight is ``s(|a|) s(|b|)`` with ``a, b`` the offsets along
    ``e_u, e_v`` and ``s`` a smooth step ``taper_px`` wide centred on the cell edge
    ``p/2``. Along the cell edges the lenslet images of a white image are dark or nearly so,
    which makes the centroid almost insensitive to where the window sits (low gain), and the
    smooth edge keeps the pixel sampling accurate. Returns the weight and its derivatives with
    respect to the window centre's x and y.
    """
    p = float(np.hypot(*basis[0]))
    eu = basis[0] / p
    ev = basis[1] / p
    a = dx * eu[0] + dy * eu[1]
    b = dx * ev[0] + dy * ev[1]
    sa, dsa = _taper(np.abs(a), 0.5 * p, taper_px)
    sb, dsb = _taper(np.abs(b), 0.5 * p, taper_px)
    # d|a|/dc = -sign(a) e_u
    ga = -dsa * np.sign(a) * sb
    gb = -dsb * np.sign(b) * sa
    return sa * sb, ga * eu[0] + gb * ev[0], ga * eu[1] + gb * ev[1]


def measure_centres(
    img: np.ndarray, grid: LensletGrid, uv: np.ndarray, *, max_drift_px: float
) -> Measurement:
    """Sub-pixel centre of every lenslet ``uv``, starting from the centres ``grid`` predicts.

    Lenslets whose window could leave the image (cut by the border) are dropped. Each centre
    is the fixed point of the cell-window centroid (:func:`_cell_window`), found by Newton's
    method with the analytic Jacobian; it may move at most ``max_drift_px`` from the
    prediction (else the lenslet is flagged invalid).
    """
    h, w = img.shape
    p = grid.pitch_px
    basis = grid.basis_px
    taper = max(2.0, 0.2 * p)
    t = math.radians(grid.rotation_deg)
    half = math.ceil((0.5 * p + 0.5 * taper) * (abs(math.cos(t)) + abs(math.sin(t)))) + 1
    pred = grid.centers(uv)
    lo = np.floor(pred - max_drift_px).astype(int) - half
    hi = np.floor(pred + max_drift_px).astype(int) + half
    fits = (lo[:, 0] >= 0) & (lo[:, 1] >= 0) & (hi[:, 0] < w) & (hi[:, 1] < h)
    uv, pred = uv[fits], pred[fits]
    k = len(uv)
    if k == 0:
        return Measurement(uv, pred, np.zeros(0, bool), np.zeros(0, bool))
    # float32 halves the cost of the patch arithmetic; offsets are local, so precision holds.
    img = (img - _dark_level(img, grid, uv)).astype(np.float32)
    d = np.arange(-half, half + 1)
    di, dj = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))

    def patches(c: np.ndarray, grad: np.ndarray | None = None, ref: np.ndarray | None = None):
        """Pixels around ``c``: offsets from ``c`` and values, divided by the vignetting plane
        of gradient ``grad`` through ``ref`` when given."""
        base = np.floor(c).astype(int)
        rows = base[:, 1:2] + di
        cols = base[:, 0:1] + dj
        dx = (cols + 0.5 - c[:, 0:1]).astype(np.float32)
        dy = (rows + 0.5 - c[:, 1:2]).astype(np.float32)
        vals = img[rows, cols]
        if grad is not None and ref is not None:
            ox = (c[:, 0:1] - ref[:, 0:1]).astype(np.float32)
            oy = (c[:, 1:2] - ref[:, 1:2]).astype(np.float32)
            grad = grad.astype(np.float32)
            # First order of exp(-g·d): the neglected term is even about c (no bias).
            vals = vals * (1.0 - ((dx + ox) * grad[:, 0:1] + (dy + oy) * grad[:, 1:2]))
        return vals, dx, dy

    # Brightness at the predicted centres -> local vignetting planes and dark lenslets.
    vals, dx, dy = patches(pred)
    bright = np.sum(_cell_window(dx, dy, basis, taper)[0] * vals, axis=1)
    use = np.ones(k, bool)
    for _ in range(3):
        level, grad = _local_log_planes(uv, basis, bright, use)
        ref = np.exp(np.nan_to_num(level, nan=-np.inf))
        dark = ~(bright > DARK_LENSLET_FRACTION * ref)
        dark &= np.isfinite(level)
        dark |= bright <= 0
        if np.array_equal(~dark, use):
            break
        use = ~dark
    # Newton iteration on the fixed point c = centroid(c), with the analytic Jacobian of the
    # centroid with respect to the window position; dark lenslets are left out.
    live = np.flatnonzero(~dark)
    c = pred[live].copy()
    p_live = pred[live]
    g_live = grad[live]
    eye = np.eye(2)[None]
    converged = np.zeros(len(live), bool)
    n_iter = 0
    while n_iter < 20:
        n_iter += 1
        vals, dx, dy = patches(c, g_live, p_live)
        wc, gx, gy = _cell_window(dx, dy, basis, taper)
        wt = wc * vals
        m = np.sum(wt, axis=1, dtype=np.float64)
        ok = m > 0
        safe = np.where(ok, m, 1.0)[:, None]
        mx = np.sum(wt * dx, axis=1, keepdims=True, dtype=np.float64) / safe  # centroid - c
        my = np.sum(wt * dy, axis=1, keepdims=True, dtype=np.float64) / safe
        ex = (dx - mx.astype(np.float32)) * (vals / safe.astype(np.float32))
        ey = (dy - my.astype(np.float32)) * (vals / safe.astype(np.float32))
        jac = np.stack(
            [
                np.stack([np.sum(gx * ex, 1), np.sum(gy * ex, 1)], axis=-1),
                np.stack([np.sum(gx * ey, 1), np.sum(gy * ey, 1)], axis=-1),
            ],
            axis=1,
        )
        a = eye - jac
        det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        a = np.where((ok & (np.abs(det) > 0.05))[:, None, None], a, eye)
        step = np.linalg.solve(a, np.c_[mx, my][..., None])[..., 0]
        step = np.where(ok[:, None], np.clip(step, -0.05 * p, 0.05 * p), 0.0)
        c = p_live + np.clip(c + step - p_live, -max_drift_px, max_drift_px)
        converged = ok & np.all(np.abs(step) < 2e-4, axis=1)
        if converged.all():
            break
    log.debug("centroids of %d lenslets: %d Newton iteration(s)", len(live), n_iter)
    xy = pred.copy()
    xy[live] = c
    valid = np.zeros(k, bool)
    valid[live] = converged & np.all(np.abs(c - p_live) < max_drift_px, axis=1)
    return Measurement(uv, xy, valid, dark)
