"""Calibration step 4: the lenslet grid fitted to measured centres, robust to outliers.

The grid is a similarity transform of the integer lattice (:mod:`recon.lenslet_grid`),
linear in ``(x0, y0, a, b) = (x0, y0, p cos θ, p sin θ)``: a linear least-squares fit,
repeated with the centres farther than 4.5 robust σ (σ from the median absolute residual)
left out until the set of inliers no longer changes.
"""

from __future__ import annotations

import numpy as np


def fit_similarity(uv: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Least-squares ``(x0, y0, a, b)`` with ``x = x0 + a u − b v``, ``y = y0 + b u + a v``."""
    u = uv[:, 0].astype(float)
    v = uv[:, 1].astype(float)
    one = np.ones_like(u)
    zero = np.zeros_like(u)
    design = np.concatenate([np.c_[one, zero, u, -v], np.c_[zero, one, v, u]])
    rhs = np.concatenate([xy[:, 0], xy[:, 1]])
    sol, *_ = np.linalg.lstsq(design, rhs, rcond=None)
    return sol


def predict(params: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Centres ``(x, y)`` (K, 2) of lenslets ``uv`` under the similarity ``params``."""
    x0, y0, a, b = params
    u = uv[:, 0].astype(float)
    v = uv[:, 1].astype(float)
    return np.c_[x0 + a * u - b * v, y0 + b * u + a * v]


def robust_fit(uv: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Similarity fit with iterative rejection of outliers (MAD-based robust σ).

    Returns the parameters, the inlier mask and the residual distances (pixels).
    """
    inlier = np.ones(len(uv), bool)
    params = fit_similarity(uv, xy)
    for _ in range(30):
        res = xy - predict(params, uv)
        dist = np.hypot(res[:, 0], res[:, 1])
        sigma = 1.4826 * float(np.median(np.abs(res[inlier])))
        new = dist <= max(4.5 * sigma, 0.02)
        if new.sum() < 4 or np.array_equal(new, inlier):
            break
        inlier = new
        params = fit_similarity(uv[inlier], xy[inlier])
    res = xy - predict(params, uv)
    return params, inlier, np.hypot(res[:, 0], res[:, 1])
