"""Outlier rejection for particle matches.

* :func:`normalized_median_test` — the normalised median test of Westerweel & Scarano
  (Exp. Fluids 39, 1096–1100, 2005), applied to scattered particle displacements with each
  particle's k nearest matched neighbours as its neighbourhood.
* :func:`ransac_affine` — RANSAC (Fischler & Bolles, Commun. ACM 24, 1981) consensus of an
  affine map over candidate matches, the bootstrap for large deformations where most
  candidate matches may be wrong.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import cKDTree

from track.errors import InputError
from track.regularize import AffineDisplacement, fit_affine

logger = logging.getLogger(__name__)

#: Threshold of the normalised median test (the paper's 3; 2 in Westerweel & Scarano), the
#: default of :func:`normalized_median_test` and of ``LinkSettings.outlier_threshold``.
MEDIAN_TEST_THRESHOLD = 3.0


def normalized_median_test(
    points_um,
    displacements_um,
    n_neighbors: int = 8,
    threshold: float = MEDIAN_TEST_THRESHOLD,
    eps_um: float = 0.1,
) -> np.ndarray:
    """Flag displacements that deviate from their neighbours' median.

    For particle ``i`` with neighbours ``j`` (its ``n_neighbors`` nearest matched particles),
    per component: ``u_m = median(u_j)``, ``r_m = median(|u_j - u_m|)`` and
    ``r_i = |u_i - u_m| / (r_m + eps_um)``. The particle is an outlier when any component
    has ``r_i > threshold`` (Westerweel & Scarano 2005, their eq. 2).

    Parameters
    ----------
    points_um : array_like, shape (P, 3)
        Reference positions of matched particles in µm.
    displacements_um : array_like, shape (P, 3)
        Displacements in µm.
    n_neighbors : int
        Neighbours per test (≥ 3; reduced to P − 1 for small sets).
    threshold : float
        Normalised residual above which a match is rejected (> 0; 2 in W&S, 3 in the paper).
    eps_um : float or array_like, shape (3,) or (P, 3)
        Acceptable fluctuation level in µm (≥ 0), of the order of the displacement noise:
        one value, one per component (x, y, z) when the noise is anisotropic (light-field
        localisation: axial ≈ 10 × lateral), or one per particle and component.

    Returns
    -------
    ndarray of bool, shape (P,)
        True for matches that pass (inliers). With fewer than 4 points all pass.

    Raises
    ------
    InputError
        Bad shapes, non-finite values or parameters out of range.
    """
    x = np.asarray(points_um, dtype=float)
    u = np.asarray(displacements_um, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or u.shape != x.shape:
        raise InputError(f"points_um {x.shape} and displacements_um {u.shape} must both be (P, 3)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(u))):
        raise InputError("points_um / displacements_um hold NaN or infinite values")
    if n_neighbors < 3:
        raise InputError(f"n_neighbors must be ≥ 3, got {n_neighbors}")
    if not threshold > 0:
        raise InputError(f"threshold must be > 0, got {threshold}")
    eps = np.asarray(eps_um, dtype=float)
    if eps.shape not in ((), (3,), x.shape) or not np.all(eps >= 0):
        raise InputError(
            f"eps_um must be one value, 3 (x, y, z) or one row per point, ≥ 0, got shape "
            f"{eps.shape}"
        )
    if not np.all(np.isfinite(eps)):
        raise InputError("eps_um holds NaN or infinite values")
    p = x.shape[0]
    if p < 4:
        return np.ones(p, dtype=bool)
    k = min(n_neighbors, p - 1)
    _, idx = cKDTree(x).query(x, k + 1)
    nb = u[idx[:, 1:]]  # (P, k, 3)
    med = np.median(nb, axis=1)
    spread = np.median(np.abs(nb - med[:, None, :]), axis=1)
    resid = np.abs(u - med) / (spread + eps)
    return np.all(resid <= threshold, axis=1)


def ransac_affine(
    ref_um,
    def_um,
    threshold_um: float,
    *,
    n_trials: int = 500,
    seed: int = 0,
    min_inliers: int = 8,
) -> tuple[AffineDisplacement, np.ndarray] | None:
    """Affine map ``def ≈ ref + u(ref)`` supported by the most candidate matches.

    Parameters
    ----------
    ref_um, def_um : array_like, shape (C, 3)
        Candidate matched positions (reference, deformed) in µm.
    threshold_um : float
        Residual distance (µm) below which a candidate supports a hypothesis.
    n_trials : int
        Random 4-point hypotheses to test.
    seed : int
        Seed of the sampler.
    min_inliers : int
        Fewest supporters of an acceptable map.

    Returns
    -------
    (AffineDisplacement, ndarray of bool (C,)) or None
        The least-squares refit on the consensus set and the inlier mask, or None when no
        hypothesis reaches ``min_inliers``.
    """
    a = np.asarray(ref_um, dtype=float)
    b = np.asarray(def_um, dtype=float)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"ref_um {a.shape} and def_um {b.shape} must both be (C, 3)")
    if not threshold_um > 0:
        raise InputError(f"threshold_um must be > 0, got {threshold_um}")
    c = a.shape[0]
    if c < max(4, min_inliers):
        return None
    rng = np.random.default_rng(seed)
    samples = np.array([rng.choice(c, 4, replace=False) for _ in range(n_trials)])
    ca = a[samples] - a[samples][:, :1]  # (T, 4, 3)
    cb = b[samples] - b[samples][:, :1]
    da = ca[:, 1:]  # (T, 3, 3) rows = edge vectors
    db = cb[:, 1:]
    det = np.linalg.det(da)
    scale = np.maximum(np.abs(da).max(axis=(1, 2)) ** 3, 1e-300)
    good = np.abs(det) > 1e-3 * scale
    if not np.any(good):
        return None
    da, db, samples = da[good], db[good], samples[good]
    # F maps reference edges to deformed edges: db = da @ F.T  ->  F.T = inv(da) @ db
    ft = np.linalg.solve(da, db)  # (T, 3, 3)
    a0 = a[samples[:, 0]]
    b0 = b[samples[:, 0]]
    best_count, best_mask = -1, None
    thr2 = threshold_um**2
    for t in range(ft.shape[0]):
        pred = (a - a0[t]) @ ft[t] + b0[t]
        mask = np.sum((pred - b) ** 2, axis=1) < thr2
        cnt = int(mask.sum())
        if cnt > best_count:
            best_count, best_mask = cnt, mask
    if best_count < min_inliers:
        return None
    mask = best_mask
    for _ in range(3):  # refit on the consensus set, re-select with the refined map
        aff = fit_affine(a[mask], b[mask] - a[mask])
        new = np.sum((a + aff(a) - b) ** 2, axis=1) < thr2
        if new.sum() < min_inliers or np.array_equal(new, mask):
            break
        mask = new
    aff = fit_affine(a[mask], b[mask] - a[mask])
    logger.debug("RANSAC affine: %d / %d candidates agree", int(mask.sum()), c)
    return aff, mask
