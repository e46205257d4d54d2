"""Comparison with the known truth: association, error statistics, imposed strain.

Metrics follow the paper (§4): the RMSD between measured and imposed values,
``RMSD = sqrt(Σ (x_i − x_0)² / n)`` over the measurement points of a frame, the mean error
(bias) and the largest absolute error; the standard error ``σ / √n`` where a spread of a
measured quantity is reported (Fig. 7).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from track.strain import green_lagrange  # E = (FᵀF − I)/2, the one definition (re-exported)

#: Components of a symmetric 3 × 3 tensor, in report order, with their (row, column).
TENSOR_COMPONENTS = {
    "xx": (0, 0),
    "yy": (1, 1),
    "zz": (2, 2),
    "xy": (0, 1),
    "xz": (0, 2),
    "yz": (1, 2),
}
AXES = ("x", "y", "z")

__all__ = [
    "AXES",
    "TENSOR_COMPONENTS",
    "associate",
    "green_lagrange",
    "numerical_deformation_gradient",
    "tensor_stats",
    "vector_stats",
]


def associate(detected_um, truth_um, radius_um: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one association of detected particles with true ones.

    Minimises the total distance (Hungarian assignment, :func:`scipy.optimize.
    linear_sum_assignment`) among pairs closer than ``radius_um``.

    Parameters
    ----------
    detected_um : array_like, shape (N, 3)
    truth_um : array_like, shape (M, 3)
    radius_um : float
        Largest accepted distance (µm).

    Returns
    -------
    i_det, i_truth : ndarray of int, shape (K,)
        Rows of associated pairs, sorted by ``i_det``.
    """
    d = np.asarray(detected_um, dtype=float).reshape(-1, 3)
    t = np.asarray(truth_um, dtype=float).reshape(-1, 3)
    if len(d) == 0 or len(t) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    pairs = cKDTree(d).sparse_distance_matrix(cKDTree(t), radius_um, output_type="coo_matrix")
    if pairs.nnz == 0:
        return np.zeros(0, int), np.zeros(0, int)
    # Dense assignment on the rows/columns that have a candidate; far pairs cost "infinity".
    rows = np.unique(pairs.row)
    cols = np.unique(pairs.col)
    big = 1e6 * radius_um
    cost = np.full((len(rows), len(cols)), big)
    cost[np.searchsorted(rows, pairs.row), np.searchsorted(cols, pairs.col)] = pairs.data
    r, c = linear_sum_assignment(cost)
    keep = cost[r, c] < big
    i_det, i_truth = rows[r[keep]], cols[c[keep]]
    order = np.argsort(i_det)
    return i_det[order], i_truth[order]


def vector_stats(err, prefix: str = "") -> dict[str, float]:
    """Mean error, RMSD and largest absolute error of each component of ``err`` (K, 3).

    Returns keys ``{prefix}mean_x``, ``{prefix}rmsd_x``, ``{prefix}maxabs_x`` … (NaN when
    ``K = 0``), and ``{prefix}n``.
    """
    e = np.asarray(err, dtype=float).reshape(-1, 3)
    out: dict[str, float] = {f"{prefix}n": len(e)}
    for j, ax in enumerate(AXES):
        col = e[:, j]
        if len(col):
            out[f"{prefix}mean_{ax}"] = float(col.mean())
            out[f"{prefix}rmsd_{ax}"] = float(np.sqrt(np.mean(col**2)))
            out[f"{prefix}maxabs_{ax}"] = float(np.abs(col).max())
        else:
            out[f"{prefix}mean_{ax}"] = math.nan
            out[f"{prefix}rmsd_{ax}"] = math.nan
            out[f"{prefix}maxabs_{ax}"] = math.nan
    return out


def numerical_deformation_gradient(displacement, X_um, h_um: float = 0.5) -> np.ndarray:
    """``F = I + ∂u/∂X`` (K, 3, 3) of a displacement function by central differences.

    Parameters
    ----------
    displacement : callable
        ``u(X (K, 3) µm) -> (K, 3) µm``.
    X_um : array_like, shape (K, 3)
    h_um : float
        Difference step (µm).
    """
    X = np.asarray(X_um, dtype=float).reshape(-1, 3)
    F = np.repeat(np.eye(3)[None], len(X), axis=0)
    for j in range(3):
        d = np.zeros(3)
        d[j] = h_um
        F[:, :, j] += (displacement(X + d) - displacement(X - d)) / (2 * h_um)
    return F


def tensor_stats(
    measured, truth, prefix: str = "", n_independent: int | None = None
) -> dict[str, float]:
    """Per-component statistics of a measured strain field against the imposed one.

    Parameters
    ----------
    measured : array_like, shape (K, 3, 3)
        Measured tensors at K measurement points.
    truth : array_like, shape (3, 3) or (K, 3, 3)
        Imposed tensor (homogeneous) or tensors at the same points.
    prefix : str
    n_independent : int, optional
        Number of independent measurements behind the K points, for the standard error
        (gridded nodes interpolate the particles: pass the particle count). Default K.

    Returns
    -------
    dict
        For each component ``c`` of :data:`TENSOR_COMPONENTS`: ``{prefix}true_c`` (mean imposed
        value), ``{prefix}meas_c`` (mean measured), ``{prefix}se_c`` (standard deviation of
        the measured values over the points / √n_independent), ``{prefix}err_c`` (mean error) and
        ``{prefix}rmsd_c``; ``{prefix}n`` = K. Strains are dimensionless (0.01 = 1 %).
    """
    m = np.asarray(measured, dtype=float).reshape(-1, 3, 3)
    t = np.broadcast_to(np.asarray(truth, dtype=float), m.shape) if len(m) else m
    out: dict[str, float] = {f"{prefix}n": len(m)}
    for name, (i, j) in TENSOR_COMPONENTS.items():
        if len(m) == 0:
            for key in ("true", "meas", "se", "err", "rmsd"):
                out[f"{prefix}{key}_{name}"] = math.nan
            continue
        mv, tv = m[:, i, j], t[:, i, j]
        d = mv - tv
        out[f"{prefix}true_{name}"] = float(tv.mean())
        out[f"{prefix}meas_{name}"] = float(mv.mean())
        n_se = len(mv) if n_independent is None else max(int(n_independent), 1)
        out[f"{prefix}se_{name}"] = float(mv.std() / math.sqrt(n_se))
        out[f"{prefix}err_{name}"] = float(d.mean())
        out[f"{prefix}rmsd_{name}"] = float(np.sqrt(np.mean(d**2)))
    return out
