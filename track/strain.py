"""Strain measures and per-particle deformation gradients.

Conventions (docs/conventions.md): lengths in µm, vectors and tensors in x, y, z order, tensors as
``(..., 3, 3)`` arrays. With the displacement ``u`` defined on the reference configuration
``X``,

- deformation gradient ``F = I + ∂u/∂X``  (``F[..., i, j] = δ_ij + ∂u_i/∂X_j``);
- Green–Lagrange strain ``E = (FᵀF − I) / 2`` (exact for finite deformation, zero for any
  rigid rotation);
- infinitesimal strain ``e = sym(F − I) = (∂u/∂X + ∂u/∂Xᵀ) / 2`` (not zero for a finite
  rotation: a rotation by θ gives ``e_xx = e_yy = cos θ − 1``);
- engineering shear strain ``γ_ij = 2 e_ij`` (the paper's ``γ_zx``).

:func:`particle_deformation_gradient` fits, for every particle, the affine model
``u(X) ≈ u0 + G (X − X0)`` to the displacements of its ``k`` nearest neighbours by (optionally
weighted) linear least squares, and returns ``F = I + G``. The fit uses the reference
positions; neighbourhoods whose positions do not span 3-D space well (collinear or coplanar
neighbours, measured by the condition number of the scaled design matrix) are flagged and
their tensors set to NaN rather than silently reported.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.validate import finite_float, int_in_range, points_xyz

from .errors import InputError

log = logging.getLogger(__name__)

#: Index pairs of the strain components, by name.
_COMPONENTS = {
    "xx": (0, 0),
    "yy": (1, 1),
    "zz": (2, 2),
    "xy": (0, 1),
    "yx": (1, 0),
    "xz": (0, 2),
    "zx": (2, 0),
    "yz": (1, 2),
    "zy": (2, 1),
}


def _as_tensor(F: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(F, dtype=float)
    if arr.ndim < 2 or arr.shape[-2:] != (3, 3):
        raise InputError(f"{name} must have shape (..., 3, 3), got {arr.shape}")
    return arr


def green_lagrange(F: np.ndarray) -> np.ndarray:
    """Green–Lagrange strain ``E = (FᵀF − I) / 2``.

    Parameters
    ----------
    F : ndarray, shape (..., 3, 3)
        Deformation gradient (dimensionless), x, y, z order.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Symmetric strain tensor; NaN where ``F`` is NaN.
    """
    F = _as_tensor(F, "F")
    # the six distinct entries, each a dot product of two columns of F (a third of the time
    # of a batched matmul or einsum over many small tensors)
    E = np.empty(F.shape)
    col = [F[..., :, i] for i in range(3)]
    for i in range(3):
        for j in range(i, 3):
            s = np.einsum("...k,...k->...", col[i], col[j])
            if i == j:
                s -= 1.0
            s *= 0.5
            E[..., i, j] = s
            E[..., j, i] = s
    return E


def infinitesimal(F: np.ndarray) -> np.ndarray:
    """Infinitesimal (small-strain) tensor ``e = sym(F − I)``.

    Parameters
    ----------
    F : ndarray, shape (..., 3, 3)
        Deformation gradient.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        ``(H + Hᵀ) / 2`` with ``H = F − I``.
    """
    F = _as_tensor(F, "F")
    H = F - np.eye(3)
    e = H + np.swapaxes(H, -1, -2)
    e *= 0.5
    return e


def engineering_shear(strain: np.ndarray, component: str = "xz") -> np.ndarray:
    """Engineering shear strain ``γ_ij = 2 ε_ij`` of a symmetric strain tensor.

    Parameters
    ----------
    strain : ndarray, shape (..., 3, 3)
        Infinitesimal strain ``e`` (the paper's γ) or Green–Lagrange ``E``.
    component : str
        Two different axes among ``x, y, z`` (``"xz"`` and ``"zx"`` are the same).

    Returns
    -------
    ndarray, shape (...)
    """
    strain = _as_tensor(strain, "strain")
    key = str(component).lower()
    if key not in _COMPONENTS or key[0] == key[1]:
        raise InputError(
            f"component must name two different axes such as 'xz', 'xy' or 'yz', got {component!r}"
        )
    i, j = _COMPONENTS[key]
    return 2.0 * strain[..., i, j]


def component(tensor: np.ndarray, name: str) -> np.ndarray:
    """One component of a ``(..., 3, 3)`` tensor by name (``"xx"``, ``"xz"``...)."""
    tensor = _as_tensor(tensor, "tensor")
    key = str(name).lower()
    if key not in _COMPONENTS:
        raise InputError(
            f"unknown tensor component {name!r}; expected one of {sorted(_COMPONENTS)}"
        )
    i, j = _COMPONENTS[key]
    return tensor[..., i, j]


@dataclass(frozen=True)
class LocalFitSettings:
    """Settings of the per-particle least-squares deformation-gradient fit.

    Attributes
    ----------
    n_neighbours : int
        Particles in each fit, the particle itself included (≥ 4: an affine 3-D fit has 4
        unknowns per displacement component). Default 12.
    max_condition : float
        Neighbourhoods whose scaled design matrix has a larger condition number are flagged
        ill-conditioned and get NaN tensors. Default 100.
    """

    n_neighbours: int = 12
    max_condition: float = 100.0

    def __post_init__(self) -> None:
        if not isinstance(self.n_neighbours, int | np.integer):
            raise InputError(f"n_neighbours must be an integer, got {self.n_neighbours!r}")
        with raised_as(InputError):
            int_in_range(self.n_neighbours, "n_neighbours", 4)
            if not finite_float(self.max_condition, "max_condition") > 1:
                raise InputError(
                    f"max_condition must be finite and > 1, got {self.max_condition!r}"
                )


@dataclass(frozen=True)
class ParticleStrain:
    """Per-particle deformation gradients and strains.

    Attributes
    ----------
    F, E, e : ndarray, shape (N, 3, 3)
        Deformation gradient, Green–Lagrange and infinitesimal strain (NaN where flagged).
    condition : ndarray, shape (N,)
        Condition number of each neighbourhood's scaled design matrix.
    ill_conditioned : ndarray of bool, shape (N,)
        ``True`` where the neighbourhood does not span 3-D space well.
    residual_um : ndarray, shape (N,)
        RMS misfit of the affine model over the neighbourhood (µm).
    neighbours : ndarray of int, shape (N, k)
        Rows of the particles used in each fit (the particle itself first).
    """

    F: np.ndarray
    E: np.ndarray
    e: np.ndarray
    condition: np.ndarray
    ill_conditioned: np.ndarray
    residual_um: np.ndarray
    neighbours: np.ndarray


def _points(arr, name: str) -> np.ndarray:
    return points_xyz(arr, name, error=InputError)


def particle_deformation_gradient(
    reference_um: np.ndarray,
    displacement_um: np.ndarray,
    settings: LocalFitSettings | None = None,
    *,
    weights: np.ndarray | None = None,
) -> ParticleStrain:
    """Deformation gradient of every particle by a local affine least-squares fit.

    For particle ``p`` with reference position ``X_p`` and its ``k`` nearest neighbours
    ``q`` (in the reference configuration), solve

    ``min Σ_q w_q |u_q − u0 − G (X_q − X_p)|²``

    for ``u0`` (3) and ``G`` (3 × 3), and report ``F = I + G``.

    Parameters
    ----------
    reference_um : ndarray, shape (N, 3)
        Reference positions ``X`` (µm), x, y, z.
    displacement_um : ndarray, shape (N, 3)
        Displacements ``u`` of the same particles (µm).
    settings : LocalFitSettings, optional
    weights : ndarray, shape (N,), optional
        Non-negative confidence of each particle's displacement (e.g. intensities); each
        neighbour's residual is weighted by its weight. Default: equal weights.

    Returns
    -------
    ParticleStrain

    Raises
    ------
    InputError
        Bad shapes, non-finite values, negative weights, or fewer than 4 particles.
    """
    from scipy.spatial import cKDTree

    settings = settings or LocalFitSettings()
    X = _points(reference_um, "reference_um")
    U = _points(displacement_um, "displacement_um")
    if U.shape != X.shape:
        raise InputError(
            f"displacement_um has shape {U.shape} but reference_um has shape {X.shape}"
        )
    n = X.shape[0]
    if n < 4:
        raise InputError(f"a deformation gradient needs at least 4 particles, got {n}")
    if weights is None:
        w = np.ones(n)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError(
                f"weights must be {n} non-negative finite numbers, got shape {w.shape}"
            )
    k = min(settings.n_neighbours, n)
    _, nb = cKDTree(X).query(X, k=k)
    nb = np.asarray(nb).reshape(n, k)
    dX = X[nb] - X[:, None, :]  # (N, k, 3)
    scale = np.sqrt(np.mean(np.sum(dX**2, axis=2), axis=1))  # (N,) rms neighbour distance
    scale = np.where(scale > 0, scale, 1.0)
    sw = np.sqrt(w[nb])  # (N, k)
    A = np.concatenate([np.ones((n, k, 1)), dX / scale[:, None, None]], axis=2) * sw[..., None]
    b = U[nb] * sw[..., None]  # (N, k, 3)
    Umat, s, Vt = np.linalg.svd(A, full_matrices=False)  # (N,k,4), (N,4), (N,4,4)
    smax = s[:, 0]
    smin = s[:, -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.where(smin > 0, smax / smin, np.inf)
    bad = ~(cond <= settings.max_condition)
    inv_s = np.where(s > smax[:, None] * 1e-12, 1.0 / np.where(s > 0, s, 1.0), 0.0)
    coef = np.einsum("nji,nj,nkj,nkc->nic", Vt, inv_s, Umat, b)  # (N, 4, 3)
    G = np.swapaxes(coef[:, 1:, :], 1, 2) / scale[:, None, None]  # G[i, j] = du_i/dX_j
    pred = coef[:, :1, :] + np.einsum("nij,nkj->nki", G, dX)
    resid = np.sqrt(np.mean(np.sum((U[nb] - pred) ** 2, axis=2), axis=1))
    F = np.eye(3) + G
    F[bad] = np.nan
    if np.any(bad):
        log.warning(
            "%d of %d particles have ill-conditioned neighbourhoods (condition > %g); "
            "their strains are NaN",
            int(np.sum(bad)),
            n,
            settings.max_condition,
        )
    return ParticleStrain(
        F=F,
        E=green_lagrange(F),
        e=infinitesimal(F),
        condition=cond,
        ill_conditioned=bad,
        residual_um=np.where(bad, np.nan, resid),
        neighbours=nb,
    )


__all__ = [
    "LocalFitSettings",
    "ParticleStrain",
    "component",
    "engineering_shear",
    "green_lagrange",
    "infinitesimal",
    "particle_deformation_gradient",
]
