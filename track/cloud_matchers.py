"""Matchers of two particle clouds: by descriptor, by nearest neighbour and by prediction
(the building blocks of :func:`track.matching.link_pair`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def match_descriptors_global(
    desc_ref: np.ndarray, desc_def: np.ndarray, ratio: float
) -> np.ndarray:
    """Mutual nearest descriptors passing a ratio test, over the whole clouds.

    Parameters
    ----------
    desc_ref, desc_def : ndarray, shape (N, D), (M, D)
        Descriptors (:func:`track.features.topology_descriptors`).
    ratio : float
        Best descriptor distance must be < ``ratio`` × the second best.

    Returns
    -------
    ndarray of int, shape (K, 2)
        ``[row_ref, row_def]`` candidates.
    """
    d, i = cKDTree(desc_def).query(desc_ref, 2, workers=-1)
    _, back = cKDTree(desc_ref).query(desc_def, 1, workers=-1)
    rows = np.arange(desc_ref.shape[0])
    ok = (d[:, 0] < ratio * d[:, 1]) & (back[i[:, 0]] == rows)
    return np.column_stack([rows[ok], i[ok, 0]])


def match_nearest(
    warped_ref: np.ndarray, def_xyz: np.ndarray, max_distance_um: float, ratio: float
) -> np.ndarray:
    """Mutual nearest neighbours within ``max_distance_um`` passing a distance-ratio test.

    Returns ``[row_ref, row_def]`` pairs, shape (K, 2).
    """
    k = 2 if def_xyz.shape[0] > 1 else 1
    d, i = cKDTree(def_xyz).query(warped_ref, k)
    d, i = d.reshape(len(d), -1), i.reshape(len(i), -1)
    _, back = cKDTree(warped_ref).query(def_xyz, 1)
    rows = np.arange(warped_ref.shape[0])
    ok = (d[:, 0] <= max_distance_um) & (back[i[:, 0]] == rows)
    if k == 2:
        ok &= d[:, 0] < ratio * d[:, 1]
    return np.column_stack([rows[ok], i[ok, 0]])


def match_predicted(
    warped_ref: np.ndarray, def_xyz: np.ndarray, tolerance_xyz_um: np.ndarray, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """Unambiguous deformed particle inside each predicted position's tolerance ellipsoid.

    The distance of deformed particle ``j`` from warped reference particle ``i`` is
    ``q_ij = |(def_j − warped_i) / tolerance_i|`` (per-axis tolerances, so anisotropic noise
    gets an ellipsoid). A pair is kept when ``q ≤ 1`` and it beats every other candidate of
    both ``i`` and ``j`` by the ratio: ``q < ratio × q_second``.

    Parameters
    ----------
    warped_ref : ndarray, shape (N, 3)
        Predicted deformed positions of the reference particles (µm).
    def_xyz : ndarray, shape (M, 3)
        Deformed particles (µm).
    tolerance_xyz_um : ndarray, shape (N, 3)
        Semi-axes (x, y, z) of each particle's tolerance ellipsoid (µm, > 0).
    ratio : float
        Ratio test, 0 < ratio ≤ 1.

    Returns
    -------
    pairs : ndarray of int, shape (K, 2)
        ``[row_ref, row_def]``.
    q : ndarray, shape (K,)
        Normalised distance of each pair.
    """
    n = warped_ref.shape[0]
    tol = np.asarray(tolerance_xyz_um, dtype=float)
    k = min(4, def_xyz.shape[0])
    reach = float(np.max(tol)) / ratio
    d, j = cKDTree(def_xyz).query(warped_ref, k, distance_upper_bound=reach)
    d, j = d.reshape(n, k), j.reshape(n, k)
    valid = np.isfinite(d)
    safe = np.where(valid, j, 0)
    q = np.sqrt(np.sum(((def_xyz[safe] - warped_ref[:, None, :]) / tol[:, None, :]) ** 2, axis=2))
    q[~valid] = np.inf
    order = np.argsort(q, axis=1)
    q1 = np.take_along_axis(q, order[:, :1], axis=1)[:, 0]
    q2 = np.take_along_axis(q, order[:, 1:2], axis=1)[:, 0] if k > 1 else np.full(n, np.inf)
    best_j = np.take_along_axis(safe, order[:, :1], axis=1)[:, 0]
    ok = (q1 <= 1.0) & (q1 < ratio * q2)
    # deformed side: j's best claimant must be i and beat j's other claimants by the ratio
    rows = np.repeat(np.arange(n), k)[valid.ravel()]
    cols = safe.ravel()[valid.ravel()]
    qq = q.ravel()[valid.ravel()]
    srt = np.lexsort((qq, cols))
    rows, cols, qq = rows[srt], cols[srt], qq[srt]
    first = np.ones(cols.size, dtype=bool)
    first[1:] = cols[1:] != cols[:-1]
    nxt = np.full(cols.size, np.inf)
    same_next = np.zeros(cols.size, dtype=bool)
    same_next[:-1] = cols[1:] == cols[:-1]
    nxt[:-1] = np.where(same_next[:-1], qq[1:], np.inf)
    owner = np.full(def_xyz.shape[0], -1)
    owner_ok = np.zeros(def_xyz.shape[0], dtype=bool)
    owner[cols[first]] = rows[first]
    owner_ok[cols[first]] = qq[first] < ratio * nxt[first]
    ok &= (owner[best_j] == np.arange(n)) & owner_ok[best_j]
    sel = np.flatnonzero(ok)
    return np.column_stack([sel, best_j[sel]]).astype(np.int64), q1[sel]
