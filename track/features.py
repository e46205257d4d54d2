"""Rotation-invariant neighbourhood-topology descriptors of 3-D point clouds.

Each particle is described by the geometry of itself and its ``n_core`` nearest neighbours:
the sorted distances to those neighbours followed by the sorted pairwise distances among
them. Distances are invariant to rotations and translations, and a set of ``n_core + 1``
points is (generically) fixed up to a reflection by its pairwise distances, so the vector is
a compact rotation-invariant fingerprint of the local topology, in the spirit of the
neighbourhood-topology features of SerialTrack (Yang et al., SoftwareX 19, 101204, 2022) and
of Patel & Franck's topology-based tracking (T-PT, Exp. Mech. 2018). Sorting makes the vector
a continuous function of the coordinates (no dependence on a fragile local frame).

Large stretch or shear changes distances. :func:`moment_normalization` removes the
homogeneous part of a deformation before descriptors are built: it maps a cloud to zero mean
and identity covariance (times a shared scale), so two clouds related by any affine map become
related by an orthogonal one, to which the descriptors are blind.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from track.errors import InputError

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class MomentNormalization:
    """Affine map ``y = (x - center_xyz_um) @ matrix.T`` that whitens a point cloud.

    Attributes
    ----------
    center_xyz_um : ndarray, shape (3,)
        Centroid of the cloud in µm.
    matrix : ndarray, shape (3, 3)
        ``scale_um · C^{-1/2}`` with ``C`` the covariance of the cloud (µm²), so the output
        has covariance ``scale_um² · I`` and keeps µm-like magnitudes.
    """

    center_xyz_um: np.ndarray
    matrix: np.ndarray

    def __post_init__(self) -> None:
        c = np.asarray(self.center_xyz_um, dtype=float)
        m = np.asarray(self.matrix, dtype=float)
        if c.shape != (3,) or m.shape != (3, 3):
            raise InputError("MomentNormalization needs center_xyz_um (3,) and matrix (3, 3)")
        object.__setattr__(self, "center_xyz_um", c)
        object.__setattr__(self, "matrix", m)

    def apply(self, xyz_um: np.ndarray) -> np.ndarray:
        """Normalised coordinates (N, 3) of points ``xyz_um`` (N, 3)."""
        return (np.asarray(xyz_um, dtype=float) - self.center_xyz_um) @ self.matrix.T


def moment_normalization(xyz_um: np.ndarray, scale_um: float) -> MomentNormalization:
    """Whitening map of a cloud with a prescribed output scale.

    Parameters
    ----------
    xyz_um : ndarray, shape (N, 3)
        Points in µm, N ≥ 4, not coplanar.
    scale_um : float
        Standard deviation (µm) of the normalised cloud along every direction. Use the same
        value for both clouds of a pair.

    Returns
    -------
    MomentNormalization

    Raises
    ------
    InputError
        Degenerate (coplanar) cloud or bad ``scale_um``.
    """
    x = np.asarray(xyz_um, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 4:
        raise InputError(f"xyz_um must have shape (N ≥ 4, 3), got {x.shape}")
    if not (np.isfinite(scale_um) and scale_um > 0):
        raise InputError(f"scale_um must be finite and > 0, got {scale_um}")
    c = x.mean(axis=0)
    cov = np.cov((x - c).T)
    w, v = np.linalg.eigh(cov)
    if w[0] <= 1e-12 * max(w[-1], 1e-300):
        raise InputError("xyz_um is coplanar: its covariance is singular")
    return MomentNormalization(center_xyz_um=c, matrix=scale_um * (v / np.sqrt(w)) @ v.T)


def cloud_scale_um(xyz_um: np.ndarray) -> float:
    """Root-mean eigenvalue of the covariance of a cloud (µm), a rotation-invariant size."""
    x = np.asarray(xyz_um, dtype=float)
    return float(np.sqrt(np.mean(np.linalg.eigvalsh(np.cov(x.T)))))


def topology_descriptors(xyz_um: np.ndarray, n_core: int = 5) -> np.ndarray:
    """Rotation-invariant descriptor of each particle's ``n_core`` nearest neighbours.

    Parameters
    ----------
    xyz_um : ndarray, shape (N, 3)
        Particle positions in µm, N > ``n_core``.
    n_core : int
        Neighbours per descriptor (≥ 2).

    Returns
    -------
    ndarray, shape (N, n_core + n_core (n_core - 1) / 2)
        Sorted centre–neighbour distances, then sorted neighbour–neighbour distances (µm).

    Raises
    ------
    InputError
        ``n_core`` < 2 or not fewer than the number of particles.
    """
    x = np.asarray(xyz_um, dtype=float)
    if n_core < 2:
        raise InputError(f"n_core must be ≥ 2, got {n_core}")
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] <= n_core:
        raise InputError(
            f"topology_descriptors needs more than n_core={n_core} points, got {x.shape}"
        )
    dist, idx = cKDTree(x).query(x, n_core + 1)
    nb = x[idx[:, 1:]] - x[:, None, :]
    iu, ju = np.triu_indices(n_core, 1)
    mutual = np.linalg.norm(nb[:, iu] - nb[:, ju], axis=-1)
    return np.hstack([dist[:, 1:], np.sort(mutual, axis=1)])
