"""Gridded displacement and strain fields from scattered particle displacements.

Interpolation choice
--------------------
Particle displacements are scattered, sparse (tens to thousands of particles) and noisy. The
default interpolant is a **thin-plate-spline radial basis function with a degree-1
polynomial** (:class:`scipy.interpolate.RBFInterpolator`, ``kernel="thin_plate_spline"``):

- it reproduces any affine displacement field exactly (homogeneous stretch, shear and
  rotation give exact ``F`` on the grid, see the tests);
- it is smooth (C¹), so finite-difference gradients are meaningful everywhere;
- it extends linearly outside the particles' convex hull instead of inventing structure; the
  grid's :attr:`GridField.mask` marks which nodes are actually supported by data;
- ``smoothing > 0`` turns it into a regularised (smoothing-spline) fit for noisy
  displacements, and the default ``smoothing="gcv"`` chooses the amount **from the data**, for
  each displacement component separately, by generalised cross-validation (see
  :func:`gcv_smoothing`). The smoothing penalty vanishes on affine fields, so smoothing never
  biases a homogeneous deformation; it only removes the part of the noise that is not affine;
- above ``rbf_max_points`` particles it uses the nearest ``rbf_neighbours`` particles only
  (local RBF), keeping the cost linear.

``method="linear"`` instead uses piecewise-linear interpolation on the Delaunay
triangulation inside the hull and the nearest particle outside it (faster, but its gradient
is piecewise constant and discontinuous).

Gradients: the global thin-plate spline (up to ``rbf_max_points`` particles) is
differentiated exactly at the nodes; the local RBF and ``method="linear"`` on the grid with
:func:`numpy.gradient` and the physical spacings (second-order central differences inside,
first-order one-sided at the borders). Both give ``F = I + ∂u/∂X``
(``F[..., i, j] = δ_ij + ∂u_i/∂X_j``), Green–Lagrange ``E`` and infinitesimal ``e`` (see
:mod:`track.strain`).

Uncertainty: for a fixed λ the fit is linear in the particle displacements, node values
``u = W d``, so ``var u_i = Σ_j W_ij² σ_ij²`` (per axis, particles and axes independent), and
the same through the gradient; ``σ`` is the link table's per-match uncertainty when given,
else the noise level the smoothing residuals imply (:meth:`DisplacementInterpolant.std`).
On a grid they are computed on a sub-grid of about one particle spacing and interpolated
(:data:`STD_GRID_SUB_SPACING`).

Default grid: the particles' bounding box sampled with one isotropic spacing chosen so that
the grid has about ``target_nodes`` = 50 000 nodes (the paper's value).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from hrvbase.validate import points_xyz

from .errors import InputError
from .strain import green_lagrange, infinitesimal

log = logging.getLogger(__name__)

_METHODS = ("rbf", "linear")

#: Fewest particles for which :func:`gcv_smoothing` chooses λ (below it: exact interpolation).
GCV_MIN_POINTS = 10


@dataclass(frozen=True)
class GridSettings:
    """How scattered displacements are gridded.

    Attributes
    ----------
    spacing_um : float, optional
        Node spacing (µm, all three axes). Default: the spacing giving about
        ``target_nodes`` nodes over the particles' bounding box.
    target_nodes : int
        Approximate node count of the default grid (50 000).
    method : {"rbf", "linear"}
        Interpolant (see the module docstring).
    smoothing : float or "gcv"
        RBF smoothing parameter λ of ``min Σ|u_i - f(x_i)|² + λ J(f)`` (µm⁻¹ for the
        thin-plate kernel; 0 = interpolate exactly, larger = smoother), or ``"gcv"`` (default)
        to choose λ for each displacement component by generalised cross-validation
        (:func:`gcv_smoothing`).
    rbf_max_points : int
        Above this many particles the RBF uses only the nearest ``rbf_neighbours``.
    gcv_max_points : int
        Above this many particles ``"gcv"`` chooses λ on a random subset of this many (λ
        rescaled to the full particle density; about 0.5 s for 1000 on one core).
    rbf_neighbours : int
        Neighbours of the local RBF.
    support_radius_um : float, optional
        With ``method="rbf"``, nodes outside the convex hull but within this distance of a
        particle still count as supported. Default: the median nearest-neighbour distance
        between particles. With ``method="linear"`` only nodes inside the hull are
        supported (outside it the nearest particle's value is used, with zero gradient).
    nodes_per_spacing : float, optional
        Make the grid follow the particle density: node spacing = the particles' median
        nearest-neighbour distance / ``nodes_per_spacing`` (at most
        ``10 × target_nodes`` nodes), instead of the ``target_nodes`` grid. 2 resolves
        everything the particles sample (a field's features are at least a particle spacing
        wide) with far fewer nodes than 50 000 for a few hundred particles. Ignored when
        ``spacing_um`` is given.
    uncertainty : bool
        Give the fields standard uncertainties (:attr:`GridField.u_std`, ``F_std``,
        ``e_std``; global thin-plate spline only, see :meth:`DisplacementInterpolant.std`).
    """

    spacing_um: float | None = None
    target_nodes: int = 50_000
    method: str = "rbf"
    smoothing: float | str = "gcv"
    rbf_max_points: int = 2000
    rbf_neighbours: int = 64
    gcv_max_points: int = 1000
    support_radius_um: float | None = None
    nodes_per_spacing: float | None = None
    uncertainty: bool = True

    def __post_init__(self) -> None:
        if self.spacing_um is not None and not (
            math.isfinite(self.spacing_um) and self.spacing_um > 0
        ):
            raise InputError(f"spacing_um must be positive and finite, got {self.spacing_um!r}")
        if int(self.target_nodes) < 8:
            raise InputError(f"target_nodes must be at least 8, got {self.target_nodes!r}")
        if self.method not in _METHODS:
            raise InputError(f"method must be one of {_METHODS}, got {self.method!r}")
        if isinstance(self.smoothing, str):
            if self.smoothing != "gcv":
                raise InputError(
                    f"smoothing must be a number >= 0 or 'gcv', got {self.smoothing!r}"
                )
        elif not (
            isinstance(self.smoothing, (int, float))
            and not isinstance(self.smoothing, bool)
            and math.isfinite(self.smoothing)
            and self.smoothing >= 0
        ):
            raise InputError(f"smoothing must be a number >= 0 or 'gcv', got {self.smoothing!r}")
        if self.rbf_neighbours < 5 or self.rbf_max_points < 5:
            raise InputError("rbf_neighbours and rbf_max_points must be at least 5")
        if int(self.gcv_max_points) < GCV_MIN_POINTS:
            raise InputError(
                f"gcv_max_points must be at least {GCV_MIN_POINTS}, got {self.gcv_max_points!r}"
            )
        if self.support_radius_um is not None and not (
            math.isfinite(self.support_radius_um) and self.support_radius_um >= 0
        ):
            raise InputError(
                f"support_radius_um must be finite and >= 0, got {self.support_radius_um!r}"
            )
        if self.nodes_per_spacing is not None and not (
            isinstance(self.nodes_per_spacing, (int, float))
            and not isinstance(self.nodes_per_spacing, bool)
            and math.isfinite(self.nodes_per_spacing)
            and self.nodes_per_spacing > 0
        ):
            raise InputError(
                f"nodes_per_spacing must be positive and finite, got {self.nodes_per_spacing!r}"
            )


@dataclass(frozen=True)
class GridAxes:
    """A regular grid: node coordinates along each axis (µm), increasing."""

    x_um: np.ndarray
    y_um: np.ndarray
    z_um: np.ndarray

    def __post_init__(self) -> None:
        for name in ("x_um", "y_um", "z_um"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 1 or a.size < 2 or not np.all(np.isfinite(a)) or np.any(np.diff(a) <= 0):
                raise InputError(f"grid axis {name} must hold >= 2 increasing finite values")
            object.__setattr__(self, name, a)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Grid shape ``(nz, ny, nx)``."""
        return (self.z_um.size, self.y_um.size, self.x_um.size)

    @property
    def spacing_xyz_um(self) -> tuple[float, float, float]:
        """Node spacing ``(dx, dy, dz)`` (µm; mean step along each axis)."""
        return tuple(float(np.mean(np.diff(a))) for a in (self.x_um, self.y_um, self.z_um))

    @property
    def origin_xyz_um(self) -> tuple[float, float, float]:
        """First node ``(x0, y0, z0)`` (µm)."""
        return (float(self.x_um[0]), float(self.y_um[0]), float(self.z_um[0]))

    def points(self) -> np.ndarray:
        """Node positions, shape ``(nz*ny*nx, 3)`` in x, y, z order, C order over (z, y, x)."""
        Z, Y, X = np.meshgrid(self.z_um, self.y_um, self.x_um, indexing="ij")
        return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


@dataclass(frozen=True)
class GridField:
    """Displacement and strain on a regular grid.

    Attributes
    ----------
    x_um, y_um, z_um : ndarray, shapes (nx,), (ny,), (nz,)
        Node coordinates (µm).
    u : ndarray, shape (nz, ny, nx, 3)
        Displacement (µm), components x, y, z.
    F, E, e : ndarray, shape (nz, ny, nx, 3, 3)
        Deformation gradient, Green–Lagrange and infinitesimal strain.
    mask : ndarray of bool, shape (nz, ny, nx)
        Nodes supported by data (inside the particles' convex hull or within the support
        radius of a particle); values elsewhere are extrapolated.
    u_std : ndarray, shape (nz, ny, nx, 3), optional
        Standard uncertainty of ``u`` (µm) from the particles' noise (see
        :meth:`DisplacementInterpolant.std`); None when not computed.
    F_std : ndarray, shape (nz, ny, nx, 3, 3), optional
        Standard uncertainty of each ``F_ij = δ_ij + ∂u_i/∂X_j``.
    e_std : ndarray, shape (nz, ny, nx, 3, 3), optional
        Standard uncertainty of each infinitesimal strain component ``e_ij`` (for small
        strains also that of ``E_ij``); components of ``u`` taken as independent.
    """

    x_um: np.ndarray
    y_um: np.ndarray
    z_um: np.ndarray
    u: np.ndarray
    F: np.ndarray
    E: np.ndarray
    e: np.ndarray
    mask: np.ndarray
    u_std: np.ndarray | None = None
    F_std: np.ndarray | None = None
    e_std: np.ndarray | None = None

    def __post_init__(self) -> None:
        axes = GridAxes(self.x_um, self.y_um, self.z_um)
        for name in ("x_um", "y_um", "z_um"):
            object.__setattr__(self, name, getattr(axes, name))
        shape = axes.shape
        checks = {"u": (*shape, 3), "F": (*shape, 3, 3), "E": (*shape, 3, 3), "e": (*shape, 3, 3)}
        checks.update({"u_std": (*shape, 3), "F_std": (*shape, 3, 3), "e_std": (*shape, 3, 3)})
        for name, want in checks.items():
            if name.endswith("_std") and getattr(self, name) is None:
                continue
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != want:
                raise InputError(f"GridField.{name} must have shape {want}, got {arr.shape}")
            object.__setattr__(self, name, arr)
        mask = np.asarray(self.mask, dtype=bool)
        if mask.shape != shape:
            raise InputError(f"GridField.mask must have shape {shape}, got {mask.shape}")
        object.__setattr__(self, "mask", mask)

    @property
    def axes(self) -> GridAxes:
        """The grid as :class:`GridAxes`."""
        return GridAxes(self.x_um, self.y_um, self.z_um)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(nz, ny, nx)``."""
        return self.axes.shape

    @property
    def spacing_xyz_um(self) -> tuple[float, float, float]:
        """``(dx, dy, dz)`` (µm)."""
        return self.axes.spacing_xyz_um

    @property
    def origin_xyz_um(self) -> tuple[float, float, float]:
        """``(x0, y0, z0)`` (µm)."""
        return self.axes.origin_xyz_um


def _points(arr, name: str) -> np.ndarray:
    return points_xyz(arr, name, error=InputError)


def grid_axes(
    points_um: np.ndarray,
    spacing_um: float | None = None,
    *,
    target_nodes: int = GridSettings.target_nodes,
) -> GridAxes:
    """Regular grid over the bounding box of ``points_um``.

    Parameters
    ----------
    points_um : ndarray, shape (N, 3)
        Positions (µm), x, y, z.
    spacing_um : float, optional
        Node spacing; default ``(volume / target_nodes)^(1/3)`` of the bounding box.
    target_nodes : int
        Approximate node count of the default grid.

    Returns
    -------
    GridAxes
        Nodes start at the box's lower corner; the box is extended by less than one spacing
        at the upper end so that it is covered. Each axis has at least 2 nodes.

    Raises
    ------
    InputError
        Fewer than 2 points, or all points in one plane perpendicular to an axis.
    """
    p = _points(points_um, "points_um")
    if p.shape[0] < 2:
        raise InputError(f"a grid needs at least 2 particles, got {p.shape[0]}")
    lo, hi = p.min(axis=0), p.max(axis=0)
    ext = hi - lo
    if np.any(ext <= 0):
        axis = "xyz"[int(np.argmin(ext))]
        raise InputError(
            f"the particles have no extent along {axis}; a 3-D grid cannot be fitted to them"
        )
    if spacing_um is None:
        spacing_um = float(np.prod(ext) / float(target_nodes)) ** (1.0 / 3.0)
    h = float(spacing_um)
    if not (math.isfinite(h) and h > 0):
        raise InputError(f"spacing_um must be positive and finite, got {spacing_um!r}")
    n = np.maximum(2, np.ceil(ext / h - 1e-9).astype(int) + 1)
    if int(np.prod(n)) > 50_000_000:
        raise InputError(
            f"grid spacing {h:g} µm gives {int(np.prod(n))} nodes (> 5e7); choose a larger spacing"
        )
    axes = [lo[i] + h * np.arange(n[i]) for i in range(3)]
    return GridAxes(*axes)


def grid_spacing_um(points_um: np.ndarray, settings: GridSettings) -> float | None:
    """Node spacing (µm) the settings ask for over ``points_um`` (N, 3), None: the default.

    ``settings.spacing_um`` when given; else, with ``settings.nodes_per_spacing``, the
    particles' median nearest-neighbour distance divided by it, but no finer than the
    spacing giving ``10 × target_nodes`` nodes over their bounding box; else None (the
    ``target_nodes`` grid of :func:`grid_axes`).
    """
    if settings.spacing_um is not None:
        return float(settings.spacing_um)
    if settings.nodes_per_spacing is None:
        return None
    from scipy.spatial import cKDTree

    p = _points(points_um, "points_um")
    if p.shape[0] < 2:
        raise InputError(f"a grid needs at least 2 particles, got {p.shape[0]}")
    d, _ = cKDTree(p).query(p, k=2)
    h = float(np.median(d[:, 1])) / float(settings.nodes_per_spacing)
    ext = np.ptp(p, axis=0)
    if np.all(ext > 0):
        h = max(h, float(np.prod(ext) / (10.0 * settings.target_nodes)) ** (1.0 / 3.0))
    return h if h > 0 else None


def _tps_kernel(r: np.ndarray) -> np.ndarray:
    """``r² log r`` (0 at ``r = 0``): the kernel and sign scipy's ``thin_plate_spline`` uses."""
    from scipy.special import xlogy

    return xlogy(r * r, r)


def _tps_kernel_sq(r2: np.ndarray) -> np.ndarray:
    """:func:`_tps_kernel` from ``r²``, as ``r² log(r²) / 2`` (no square root, no ``xlogy``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.log(r2)
        k *= r2
    k *= 0.5
    k[r2 <= 0] = 0.0
    return k


def gcv_smoothing(
    positions_um: np.ndarray,
    values: np.ndarray,
    *,
    max_points: int = 1000,
    seed: int = 0,
) -> np.ndarray:
    """Smoothing parameter of a thin-plate-spline fit chosen by generalised cross-validation.

    For each column ``y`` of ``values`` the smoothing thin-plate spline with a degree-1
    polynomial, ``f_λ = argmin Σ (y_i − f(x_i))² + λ J(f)`` (exactly what
    :class:`scipy.interpolate.RBFInterpolator` fits with ``kernel="thin_plate_spline"``,
    ``degree=1``, ``smoothing=λ``), has the influence matrix ``A(λ)`` with ``f_λ(x) = A y``.
    GCV (Craven & Wahba 1979, *Numer. Math.* 31:377) picks the λ minimising

    ``V(λ) = n ‖(I − A(λ)) y‖² / tr(I − A(λ))²``,

    an estimate of the prediction error that needs neither the truth nor the noise level.
    With ``Q₂`` an orthonormal basis of the null space of the polynomial block ``Pᵀ`` and
    ``Q₂ᵀ K Q₂ = U diag(γ) Uᵀ`` (Wahba 1990, *Spline Models for Observational Data*, §4.3),

    ``(I − A) y = Q₂ U diag(λ / (γ + λ)) Uᵀ Q₂ᵀ y``,  ``tr(I − A) = Σ λ / (γ_k + λ)``,

    so one eigen-decomposition gives ``V`` for every λ of a log-spaced scan (16 decades, 10 per
    decade). A column of exactly affine data (its non-affine part ``Bᵀ y`` at round-off,
    :data:`GCV_AFFINE_RTOL`) gets the largest λ of the scan: its fit is that affine function
    for every λ, its uncertainties those of the affine least-squares fit (round-off alone
    would otherwise choose λ, differently with each BLAS and thread count).

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Particle positions (µm).
    values : ndarray, shape (N,) or (N, C)
        Data at the particles, e.g. the three displacement components (µm).
    max_points : int
        Above this many particles λ is chosen on a random subset of ``max_points`` particles
        and multiplied by ``N / max_points`` (the data term of the criterion grows with the
        particle density, the penalty does not).
    seed : int
        Seed of that subset.

    Returns
    -------
    ndarray, shape (C,)
        λ for each column (µm⁻¹ for data in µm: the units of ``J`` are µm² / µm³).

    Raises
    ------
    InputError
        Bad shapes, non-finite values or fewer than :data:`GCV_MIN_POINTS` particles.
    """
    X = _points(positions_um, "positions_um")
    Y = np.asarray(values, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    if Y.ndim != 2 or Y.shape[0] != X.shape[0]:
        raise InputError(
            f"values must have shape (N,) or (N, C) with N = {X.shape[0]}, got {Y.shape}"
        )
    if not np.all(np.isfinite(Y)):
        raise InputError("values holds NaN or infinite values")
    n = X.shape[0]
    if n < GCV_MIN_POINTS:
        raise InputError(f"GCV needs at least {GCV_MIN_POINTS} particles, got {n}")
    scale = 1.0
    if n > max_points:
        keep = np.random.default_rng(seed).choice(n, size=int(max_points), replace=False)
        X, Y = X[keep], Y[keep]
        scale = n / float(max_points)
    basis = _ThinPlateBasis(X)
    return _gcv_choose(basis.gam, basis.to_modes(Y), np.linalg.norm(Y, axis=0)) * scale


#: A column whose non-affine part ``‖Bᵀ y‖`` is at most this fraction of ``‖y‖`` is exactly
#: affine (round-off): :func:`_gcv_choose` gives it the largest λ of the scan.
GCV_AFFINE_RTOL = 1e-11


def _gcv_choose(gam: np.ndarray, z: np.ndarray, y_norm: np.ndarray | None = None) -> np.ndarray:
    """GCV's λ for each column of ``z = Bᵀ y`` (shape (m − 4, C)), eigenvalues ``gam``;
    ``y_norm``: ``‖y‖`` of each column (exactly affine columns, see :func:`gcv_smoothing`)."""
    m = gam.size + 4
    z2 = z * z
    top = max(float(gam.max(initial=0.0)), np.finfo(float).tiny)
    lams = top * np.logspace(-12.0, 4.0, 161)
    f = lams[None, :] / (gam[:, None] + lams[None, :])  # (m - 4, L)
    rss = (f * f).T @ z2  # (L, C)
    tr = f.sum(axis=0)  # (L,)
    score = m * rss / (tr * tr)[:, None]
    best = np.argmin(score, axis=0)
    if y_norm is not None:
        affine = np.sqrt(z2.sum(axis=0)) <= GCV_AFFINE_RTOL * np.asarray(y_norm)
        best[affine] = lams.size - 1
    return lams[best]


class _ThinPlateBasis:
    """The eigen-basis of a thin-plate spline with a degree-1 polynomial on ``N`` centres.

    ``P = [1, X − X̄] = Q R`` (Householder QR, ``Q = H₀ H₁ H₂ H₃``, ``Q₁ R₁`` its thin part),
    ``Q₂`` the other ``N − 4`` columns of ``Q`` (an orthonormal basis of the null space of
    ``Pᵀ``), ``Q₂ᵀ K Q₂ = V diag(γ) Vᵀ`` and ``B = Q₂ V`` (N × (N − 4), orthonormal columns,
    orthogonal to ``Q₁``). Every smoothing parameter λ reuses it (:func:`gcv_smoothing`,
    :class:`_ThinPlateFit`).

    ``Qᵀ K Q`` is formed with the four reflectors (compact WY form ``Q = I − V T Vᵀ``: one
    rank-8 update, O(N²)) and ``B`` is applied through them (:meth:`to_modes`,
    :meth:`from_modes`) instead of as dense N × N products: the eigen-decomposition is then
    most of the cost.

    The eigen-decomposition is LAPACK's ``dsyevd`` (what :func:`numpy.linalg.eigh` calls)
    without its last step: ``Q₂ᵀ K Q₂ = Z T Zᵀ`` (``dsytrd``, ``T`` tridiagonal, ``Z`` kept as
    its Householder reflectors), ``T = S diag(γ) Sᵀ`` (``dstevd``, divide and conquer), and
    ``V = Z S`` is never formed: ``Z`` is applied to the few vectors that need it (``dormqr``,
    :meth:`_z`). The same γ and ``V`` as ``eigh`` (bit for bit on bench_fields' series) for
    about 60 % of its time (the N × N back-transformation was 40 % of it).
    """

    def __init__(self, X: np.ndarray) -> None:
        from scipy.linalg import qr
        from scipy.spatial.distance import cdist

        self.centre = X.mean(axis=0)
        self.Xc = X - self.centre
        m = X.shape[0]
        P = np.c_[np.ones(m), self.Xc]
        (h, tau), R = qr(P, mode="raw", check_finite=False)
        vs = np.zeros((4, m))
        for j in range(4):
            vs[j, j] = 1.0
            vs[j, j + 1 :] = h[j + 1 :, j]
        tau = np.asarray(tau, dtype=float)
        # Q = H₀ H₁ H₂ H₃ = I − V T Vᵀ (compact WY form, T upper triangular 4 × 4)
        V = np.ascontiguousarray(vs.T)
        T = np.zeros((4, 4))
        for j in range(4):
            T[j, j] = tau[j]
            T[:j, j] = -tau[j] * (T[:j, :j] @ (V[:, :j].T @ V[:, j]))
        self._V4, self._T4 = V, T
        self.R1 = np.triu(R[:4, :4])
        self.K = _tps_kernel_sq(cdist(self.Xc, self.Xc, "sqeuclidean"))
        # Qᵀ K Q = K − Z Vᵀ − V Zᵀ, Z = K V T − V Tᵀ (Vᵀ K V T) / 2: one rank-8 product, of
        # the rows and columns 4: only
        Y = (self.K @ V) @ T
        Z = Y - 0.5 * V @ (T.T @ (V.T @ Y))
        M2 = (
            self.K[4:, 4:]
            - np.concatenate([Z[4:], V[4:]], axis=1) @ np.concatenate([V[4:], Z[4:]], axis=1).T
        )
        e = np.zeros((m, 4))
        e[:4, :4] = np.eye(4)
        self.Q1 = self._apply_q(e)
        gam, self._S, self._zr, self._ztau = _eigh_reflected(0.5 * (M2 + M2.T))
        self.gam = np.maximum(gam, 0.0)

    def _z(self, Y: np.ndarray, transpose: bool = False) -> np.ndarray:
        """``Z Y`` (``Zᵀ Y`` with ``transpose``) for ``Y`` (N − 4, C): ``dsytrd``'s reflectors,
        as ``dormtr`` applies them (``dormqr`` on all rows but the first)."""
        Y = np.array(Y, dtype=float, order="F")
        if self._ztau.size == 0 or Y.shape[1] == 0:
            return Y
        from scipy.linalg import lapack

        # up to ~30 columns LAPACK's unblocked code (a workspace of one row) is the faster:
        # the blocked one builds a 64 × 64 triangular factor per block of reflectors
        k = Y.shape[1]
        lwork = k if k <= 32 else 64 * k + 65 * 64
        out, _, info = lapack.dormqr(
            "L", "T" if transpose else "N", self._zr, self._ztau, Y[1:], lwork, overwrite_c=1
        )
        if info != 0:
            raise np.linalg.LinAlgError(f"dormqr failed (info {info})")
        Y[1:] = out
        return Y

    @property
    def V(self) -> np.ndarray:
        """The eigenvectors ``V`` (N − 4, N − 4), formed (for tests and checks)."""
        return self._z(self._S)

    def _apply_q(self, Y: np.ndarray) -> np.ndarray:
        """``Q Y = Y − V (T (Vᵀ Y))`` (N, C) for ``Y`` (N, C)."""
        Y = np.asarray(Y, dtype=float)
        return Y - self._V4 @ (self._T4 @ (self._V4.T @ Y))

    def _apply_qt(self, Y: np.ndarray) -> np.ndarray:
        """``Qᵀ Y = Y − V (Tᵀ (Vᵀ Y))`` (N, C) for ``Y`` (N, C)."""
        Y = np.asarray(Y, dtype=float)
        return Y - self._V4 @ (self._T4.T @ (self._V4.T @ Y))

    def to_modes(self, Y: np.ndarray) -> np.ndarray:
        """``Bᵀ Y`` (N − 4, C) for ``Y`` (N, C)."""
        return self._S.T @ self._z(self._apply_qt(Y)[4:], transpose=True)

    def from_modes(self, Z: np.ndarray) -> np.ndarray:
        """``B Z`` (N, C) for ``Z`` (N − 4, C)."""
        W = np.zeros((Z.shape[0] + 4, Z.shape[1]))
        W[4:] = self._z(self._S @ Z)
        return self._apply_q(W)

    def columns(self, keep: np.ndarray) -> np.ndarray:
        """The columns ``B[:, keep]`` (N, r)."""
        W = np.zeros((self._S.shape[0] + 4, keep.size))
        W[4:] = self._z(self._S[:, keep])
        return self._apply_q(W)

    @property
    def B(self) -> np.ndarray:
        """``B`` (N, N − 4), formed (for tests and checks; the fits use :meth:`to_modes`)."""
        return self.columns(np.arange(self._S.shape[1]))


def _eigh_reflected(A: np.ndarray):
    """``A = Z S diag(γ) Sᵀ Zᵀ`` for a symmetric ``A`` (n, n): ``γ`` ascending (n,), ``S``
    (n, n) and ``dsytrd``'s reflectors of ``Z`` (``(n − 1, n − 1)`` and ``τ`` (n − 1,), empty
    for n < 2), see :class:`_ThinPlateBasis`. Raises :class:`numpy.linalg.LinAlgError`."""
    n = A.shape[0]
    if n < 2:
        gam, S = np.linalg.eigh(A)
        return gam, S, np.zeros((0, 0), order="F"), np.zeros(0)
    from scipy.linalg import lapack

    lwork, info = lapack.dsytrd_lwork(n, lower=1)
    c, d, e, tau, info = lapack.dsytrd(A, lower=1, lwork=int(lwork), overwrite_a=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"dsytrd failed (info {info})")
    gam, S, info = lapack.dstevd(d, e, compute_v=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"the eigenvalues did not converge (dstevd info {info})")
    return gam, S, np.asfortranarray(c[1:, :-1]), tau


#: Modes of the spline whose filter factor γ/(γ + λ) is below this are left out of the
#: standard uncertainties at arbitrary points (their share of a node's variance is of the
#: order of its square times σ²): :meth:`DisplacementInterpolant.std`.
STD_MODE_CUTOFF = 1e-4
#: The same for the uncertainties of gridded fields (:func:`field_on_grid`), where the cost
#: matters (measured on bench_fields' series: 36 of 480 modes, u σ within 0.3 % and gradient
#: σ within 2.5 % of the value with every mode).
STD_GRID_MODE_CUTOFF = 3e-2
#: The gridded fields' uncertainties are computed on a sub-grid (every ``k``-th node along each
#: axis, and the last) whose spacing is at most this many median nearest-neighbour distances
#: of the particles, and interpolated (trilinear) in between: they vary over a particle
#: spacing, not a node spacing. Measured on bench_fields' series (``nodes_per_spacing=2``,
#: ``k = 2``): ``u_std`` and ``F_std`` within 3.6 % of every node's own (median 0.4 % / 0.1 %);
#: on a clustered cloud with σ varying 5× between particles (tests) median 1 %, 99th
#: percentile 6 % / 11 %, up to 17 % / 37 % next to isolated particles. 0: every node.
STD_GRID_SUB_SPACING = 1.0
#: Rows of query points evaluated at once (a block of ``rows × N`` kernel values).
_BLOCK_ROWS = 256
#: Smallest squared distance in the kernel (µm²): keeps ``log`` finite (in single precision)
#: at a centre.
_R2_FLOOR = 1e-30


class _ThinPlateFit:
    """Smoothing thin-plate splines (degree-1 polynomial) of the columns of ``Y``, each with
    its λ, from one :class:`_ThinPlateBasis`; values, analytic gradients and the standard
    uncertainties of both, with ``u(q) = k(q)ᵀ c + p(q)ᵀ d`` and ``p(q) = [1, q − X̄]``.

    For data ``y`` the fit is linear, ``u(q) = w(q)ᵀ y``, with
    ``w(q) = B diag(1/(γ + λ)) a(q) + Q₁ R₁⁻ᵀ p(q)`` and
    ``a(q) = Bᵀ k(q) − Bᵀ K Q₁ R₁⁻ᵀ p(q)``. ``[B, Q₁]`` is orthogonal, so with independent
    data errors of standard deviation ``σ_j``,
    ``var u(q) = Σ_j w_j(q)² σ_j² = fᵀ [B, Q₁]ᵀ diag(σ²) [B, Q₁] f`` with
    ``f = [a / (γ + λ), R₁⁻ᵀ p]``, and the same with ``∂/∂q`` for the gradient.
    """

    def __init__(
        self,
        basis: _ThinPlateBasis,
        Y: np.ndarray,
        lam: np.ndarray,
        sigma: np.ndarray | None = None,
    ) -> None:
        b = basis
        self.basis = b
        self.lam = np.asarray(lam, dtype=float)
        scale = max(float(b.gam.max(initial=0.0)), 1.0)
        den = b.gam[:, None] + self.lam[None, :]  # (N - 4, C)
        rdiag = np.abs(np.diag(b.R1))
        # four particles fix the affine part exactly: no spline mode (den is empty)
        if rdiag.min() <= 1e-10 * rdiag.max() or den.min(initial=np.inf) <= 1e-14 * scale:
            raise InputError(
                f"cannot fit a displacement field to {Y.shape[0]} particles: they are coplanar "
                "or repeated"
            )
        self.den = den
        self.z = b.to_modes(Y)  # (N - 4, C)
        C = b.from_modes(self.z / den)
        D = np.linalg.solve(b.R1, b.Q1.T @ (Y - b.K @ C - C * self.lam[None, :]))
        self.C, self.D = C, D
        nc = Y.shape[1]
        Xc = b.Xc
        # M @ [C, C_i X_j]: the gradient of Σ_k c_k φ(|q − x_k|) with φ'(r)/r = 2 log r + 1
        self._Cg = np.concatenate(
            [C] + [C[:, [i]] * Xc[:, [j]] for i in range(nc) for j in range(3)], axis=1
        )
        self._xsq = np.einsum("ij,ij->i", Xc, Xc)
        self._m2Xt = np.ascontiguousarray(-2.0 * Xc.T)
        # log r @ W gives values and gradients at once (:meth:`_value_gradient`)
        self._W = np.concatenate(
            [C, self._xsq[:, None] * C] + [Xc[:, [j]] * C for j in range(3)], axis=1
        )
        self._s0 = C.sum(axis=0)
        self._s1 = np.stack([(Xc[:, [j]] * C).sum(axis=0) for j in range(3)])  # (3, C)
        self._r2_scale = max(float(np.sum(np.ptp(Xc, axis=0) ** 2)), 1e-12)
        # r² / s = [q̃, 1, |q̃|²] @ _Xaug (one product, :meth:`_logs`)
        self._Xaug = np.vstack([self._m2Xt, self._xsq[None, :], np.ones((1, Xc.shape[0]))])
        self._Xaug /= self._r2_scale
        self._log_s = math.log(self._r2_scale)
        self._floor32 = np.float32(max(_R2_FLOOR / self._r2_scale, 1e-37))
        self._W_sum = self._W.sum(axis=0)
        self.sigma = self._noise(sigma)

    # -- noise -------------------------------------------------------------------------------
    def _noise(self, sigma):
        """Per-datum, per-column σ (N, C): given, or ``RSS / tr((I − A)²)`` from the residuals
        (unbiased for noise on a field the spline reproduces; ``RSS / tr(I − A)`` would be
        biased low by up to 20 % for lightly smoothed fits, see the tests)."""
        n, nc = self.C.shape
        if sigma is not None:
            return np.broadcast_to(np.asarray(sigma, dtype=float), (n, nc))
        f = self.lam[None, :] / self.den  # (N - 4, C): filter of the residuals
        rss = np.sum((f * self.z) ** 2, axis=0)
        tr = np.sum(f * f, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(tr > 1e-9, rss / tr, np.nan)
        return np.broadcast_to(np.sqrt(var)[None, :], (n, nc))

    # -- evaluation --------------------------------------------------------------------------
    def _kernels(self, q: np.ndarray, single: bool = False, kernel: bool = True):
        """``q − X̄`` (P, 3), the kernel block ``r² log r`` (P, N; None unless ``kernel``) and
        ``log r`` (P, N).

        With ``single``, ``log`` is taken in single precision (a third of the time of
        double's; the rest stays double, and the log is of ``r²`` over the centres' squared
        extent, near 1): values and exact gradients then carry a relative error of about
        1e-7 of the field's magnitude (measured on bench_fields' series: 6e-6 of ``u_std``,
        3e-6 of ``F_std``), far below any noise, but too rough for finite
        differences with tiny steps, so only the gridded fields and the Eulerian composition
        (exact gradients) use it. ``r`` is clamped at ``sqrt(_R2_FLOOR)``: at a centre
        ``r² log r`` → 0 and its gradient term ``(q − x) φ'(r)/r`` → 0 with any finite log.
        """
        b = self.basis
        dq = q - b.centre
        r2 = dq @ self._m2Xt
        r2 += self._xsq[None, :]
        r2 += np.einsum("ij,ij->i", dq, dq)[:, None]
        np.maximum(r2, _R2_FLOOR, out=r2)
        if single:
            # log of r² over the centres' squared extent (near 1: smaller absolute error)
            l32 = np.empty(r2.shape, dtype=np.float32)
            np.multiply(r2, 1.0 / self._r2_scale, out=l32, casting="unsafe")
            np.log(l32, out=l32)
            logr = l32.astype(np.float64)
            logr += math.log(self._r2_scale)
        else:
            logr = np.log(r2)
        logr *= 0.5
        return dq, (np.multiply(r2, logr, out=r2) if kernel else None), logr

    def _logs(self, q: np.ndarray):
        """``q − X̄`` (P, 3) and ``log(r² / s)`` (P, N) in single precision, ``s`` the centres'
        squared extent (:meth:`_kernels`' ``single``; ``log r = (L + log s) / 2``): ``r²`` from
        one product in double precision, then scaled, floored and logged in float32."""
        dq = q - self.basis.centre
        A = np.empty((dq.shape[0], 5))
        A[:, :3] = dq
        A[:, 3] = 1.0
        A[:, 4] = np.einsum("ij,ij->i", dq, dq)
        L = np.empty((dq.shape[0], self._Xaug.shape[1]), dtype=np.float32)
        # floored in double and cast in one pass (the floor is a float32 value: the same L)
        np.maximum(A @ self._Xaug, float(self._floor32), out=L, casting="same_kind")
        np.log(L, out=L)
        return dq, L

    def _log_r_product(self, L: np.ndarray, W: np.ndarray, W_sum: np.ndarray) -> np.ndarray:
        """``log r @ W`` (P, K) from :meth:`_logs`' ``L`` and ``W_sum = W.sum(axis=0)`` (in
        double precision; the product in single precision when ``W`` is float32)."""
        M = np.asarray(L @ W, dtype=np.float64)
        M += self._log_s * W_sum
        M *= 0.5
        return M

    def _value_gradient(self, q: np.ndarray, logs=None):
        """Values (P, C) and ``∂u_i/∂x_j`` (P, C, 3) at ``q`` (P, 3) from one product
        ``log r @ W`` (single-precision log, :meth:`_logs`): with
        ``r² = |q̃|² + |x̃|² − 2 q̃·x̃`` (``~``: minus the centre),
        ``Σ c r² log r = |q̃|² (L c) + L (|x̃|² c) − 2 Σ_j q̃_j L (x̃_j c)`` and
        ``∂/∂q_j Σ c r² log r = q̃_j (2 L c + Σ c) − (2 L (x̃_j c) + Σ x̃_j c)``."""
        dq, L = self._logs(q) if logs is None else logs
        return self._from_products(dq, self._log_r_product(L, self._W, self._W_sum))

    def _from_products(self, dq: np.ndarray, M: np.ndarray):
        """:meth:`_value_gradient` from ``q̃`` (P, 3) and the products ``M = log r @ W``
        (P, 5 C)."""
        nc = self.C.shape[1]
        M0, M1 = M[:, :nc], M[:, nc : 2 * nc]
        Mx = M[:, 2 * nc :].reshape(-1, 3, nc)  # (P, j, c)
        u = np.einsum("ij,ij->i", dq, dq)[:, None] * M0 + M1
        u -= 2.0 * np.einsum("pj,pjc->pc", dq, Mx)
        u += self.D[0] + dq @ self.D[1:]
        G = dq[:, None, :] * (2.0 * M0 + self._s0)[:, :, None]  # (P, c, j)
        G -= np.swapaxes(2.0 * Mx + self._s1[None], 1, 2)
        G += self.D[1:].T[None, :, :]
        return u, G

    def evaluate(self, q: np.ndarray, gradient: bool = False, single: bool = False):
        """Values (P, C) and, with ``gradient``, ``∂u_i/∂x_j`` (P, C, 3) at ``q`` (P, 3);
        ``single``: see :meth:`_kernels`."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        nc = self.C.shape[1]
        u = np.empty((q.shape[0], nc))
        G = np.empty((q.shape[0], nc, 3)) if gradient else None
        for s in range(0, q.shape[0], _BLOCK_ROWS):
            if gradient and single:
                u[s : s + _BLOCK_ROWS], G[s : s + _BLOCK_ROWS] = self._value_gradient(
                    q[s : s + _BLOCK_ROWS]
                )
                continue
            dq, Kq, logr = self._kernels(q[s : s + _BLOCK_ROWS], single)
            u[s : s + _BLOCK_ROWS] = Kq @ self.C + self.D[0] + dq @ self.D[1:]
            if gradient:
                logr *= 2.0
                logr += 1.0  # φ'(r)/r
                MC = logr @ self._Cg
                g = dq[:, None, :] * MC[:, :nc, None] - MC[:, nc:].reshape(-1, nc, 3)
                G[s : s + _BLOCK_ROWS] = g + self.D[1:].T[None, :, :]
        return u, G

    def _modes(self, cutoff: float = 0.0) -> np.ndarray:
        """Indices of the modes whose filter factor γ/(γ + λ) reaches ``cutoff`` for the
        least smoothed column."""
        lam = float(self.lam.min())
        g = self.basis.gam
        return np.flatnonzero(g >= cutoff * (g + lam))

    def _std_setup(self, cutoff: float):
        """Mode indices, ``Bₖ``, ``H``, ``R₁⁻¹`` and the quadratic form of each column."""
        b = self.basis
        keep = self._modes(cutoff)
        Bk = b.columns(keep)
        R1inv = np.linalg.inv(b.R1)  # (4, 4)
        H = (Bk.T @ (b.K @ b.Q1)) @ R1inv.T  # (r, 4): a(q) = Bₖᵀ k(q) − H p(q)
        Ob = None  # [Bₖ, Q₁] (N, r + 4), orthonormal columns (formed when needed)
        quads = []  # None: one σ for the column ([B, Q₁] orthogonal: fᵀ Obᵀ σ² Ob f = σ² |f|²)
        for c in range(self.C.shape[1]):
            sc = self.sigma[:, c]
            if np.all(sc == sc[0]):
                quads.append(None)
            else:
                if Ob is None:
                    Ob = np.concatenate([Bk, b.Q1], axis=1)
                S = Ob.T @ (Ob * (sc**2)[:, None])
                quads.append(lambda f, S=S: np.einsum("ij,ij->i", f @ S, f))
        return keep, Bk, H, R1inv, quads

    def _var(self, a, pt, keep, quads) -> np.ndarray:
        """``var`` (P, C) of ``w = [B, Q₁] [a / (γ + λ_c), pt]`` for features ``a`` (P, r) and
        ``pt`` (P, 4)."""
        nc = self.C.shape[1]
        out = np.empty((a.shape[0], nc))
        den = self.den[keep]  # (r, C)
        homo = [c for c in range(nc) if quads[c] is None]
        if homo:
            s2 = self.sigma[0, homo] ** 2
            out[:, homo] = (
                (a * a) @ (den[:, homo] ** -2.0) + np.sum(pt * pt, axis=1)[:, None]
            ) * s2
        for c in range(nc):
            if quads[c] is not None:
                out[:, c] = quads[c](np.concatenate([a / den[:, c], pt], axis=1))
        return out

    def std(
        self,
        q: np.ndarray,
        gradient: bool = False,
        cutoff: float = STD_MODE_CUTOFF,
        single: bool = False,
    ):
        """Standard uncertainties of :meth:`evaluate`: (P, C) and (P, C, 3) or None, from the
        modes above ``cutoff`` (:meth:`_modes`); ``single``: see :meth:`_kernels`."""
        q = np.asarray(q, dtype=float).reshape(-1, 3)
        nc = self.C.shape[1]
        setup = self._std_features(cutoff) if single else self._std_setup(cutoff)
        u_sd = np.empty((q.shape[0], nc))
        G_sd = np.empty((q.shape[0], nc, 3)) if gradient else None
        for s in range(0, q.shape[0], _BLOCK_ROWS):
            blk = slice(s, s + _BLOCK_ROWS)
            if single:
                u_sd[blk], g = self._std_from_logs(self._logs(q[blk]), setup, gradient)
            else:
                u_sd[blk], g = self._std_block(q[blk], setup, gradient)
            if gradient:
                G_sd[blk] = g
        return u_sd, G_sd

    def _std_features(self, cutoff: float):
        """:meth:`_std_setup` and the weights of ``log r`` giving ``a`` and ``∂a/∂q`` at once
        (:meth:`_std_from_logs`): ``[Bₖ, |x̃|² Bₖ, x̃_x Bₖ, x̃_y Bₖ, x̃_z Bₖ]`` (N, 5 r)."""
        keep, Bk, H, R1inv, quads = self._std_setup(cutoff)
        Xc = self.basis.Xc
        r = keep.size
        # float32 weights: the product is the largest of the grid (P × N × 5 r) and variances
        # need no more (measured on bench_fields' series: 2e-6 of u_std and F_std); each
        # block computed in double and rounded once
        scales = np.vstack([np.ones(Xc.shape[0]), self._xsq, Xc.T])  # (5, N)
        Wb = np.empty((Xc.shape[0], 5 * r), dtype=np.float32)
        Wb[:, :r] = Bk
        for s in range(1, 5):
            np.multiply(scales[s][:, None], Bk, out=Wb[:, s * r : (s + 1) * r], casting="same_kind")
        return keep, Bk, H, R1inv, quads, Wb, (scales @ Bk).ravel()

    def _std_block(self, q, setup, gradient):
        """:meth:`std` in double precision for one block of points."""
        keep, Bk, H, R1inv, quad = setup[:5]
        Xc = self.basis.Xc
        r = keep.size
        dq, Kq, logr = self._kernels(q)
        p = np.c_[np.ones(dq.shape[0]), dq]
        a = Kq @ Bk - p @ H.T  # (P, r)
        pt = p @ R1inv  # R₁⁻ᵀ p, as rows
        u_sd = np.sqrt(self._var(a, pt, keep, quad))
        if not gradient:
            return u_sd, None
        G_sd = np.empty((q.shape[0], self.C.shape[1], 3))
        logr *= 2.0
        logr += 1.0
        cols = np.concatenate([Bk] + [Xc[:, [j]] * Bk for j in range(3)], axis=1)
        MB = logr @ cols  # (P, 4r)
        for j in range(3):
            da = dq[:, [j]] * MB[:, :r] - MB[:, (j + 1) * r : (j + 2) * r] - H[:, 1 + j]
            dpt = np.broadcast_to(R1inv[1 + j], (dq.shape[0], 4))
            G_sd[:, :, j] = np.sqrt(self._var(da, dpt, keep, quad))
        return u_sd, G_sd

    def _std_from_logs(self, logs, setup, gradient: bool = True):
        """:meth:`std` at the points of :meth:`_logs`' ``(q̃, L)``, from one product
        ``log r @ [Bₖ, |x̃|² Bₖ, x̃_j Bₖ]`` (``setup``: :meth:`_std_features`): with
        ``M_b = log r @ Bₖ``, ``M_s = log r @ (|x̃|² Bₖ)``, ``M_j = log r @ (x̃_j Bₖ)``,
        ``Bₖᵀ k(q) = |q̃|² M_b + M_s − 2 Σ_j q̃_j M_j`` and, with ``φ'(r)/r = 2 log r + 1``,
        ``∂(Bₖᵀ k)/∂q_j = q̃_j (2 M_b + Σ Bₖ) − (2 M_j + Σ x̃_j Bₖ)``."""
        keep, _, H, R1inv, quad, Wb, Wb_sum = setup
        dq, L = logs
        n, r = dq.shape[0], keep.size
        M = self._log_r_product(L, Wb, Wb_sum).reshape(n, 5, r)  # M_b, M_s, M_x, M_y, M_z
        p = np.c_[np.ones(n), dq]
        # features of u and of its three derivatives, stacked: one variance product for all
        a = np.empty((4 if gradient else 1, n, r))
        pt = np.empty((a.shape[0], n, 4))
        coef = np.empty((n, 5))  # a = Σ_t coef_t M_t − p Hᵀ
        coef[:, 0] = np.einsum("ij,ij->i", dq, dq)
        coef[:, 1] = 1.0
        np.multiply(dq, -2.0, out=coef[:, 2:])
        np.einsum("pt,ptk->pk", coef, M, out=a[0])
        a[0] -= p @ H.T
        pt[0] = p @ R1inv
        if gradient:
            phi_b = 2.0 * M[:, 0]
            phi_b += Wb_sum[:r]
            for j in range(3):
                np.multiply(dq[:, [j]], phi_b, out=a[1 + j])
                a[1 + j] -= 2.0 * M[:, 2 + j]
                a[1 + j] -= Wb_sum[(2 + j) * r : (3 + j) * r] + H[:, 1 + j]
                pt[1 + j] = R1inv[1 + j]
        m = a.shape[0] * n
        sd = np.sqrt(self._var(a.reshape(m, r), pt.reshape(m, 4), keep, quad))
        sd = sd.reshape(a.shape[0], n, sd.shape[1])
        if not gradient:
            return sd[0], None
        return sd[0], np.moveaxis(sd[1:], 0, -1)

    def on_grid(self, axes: GridAxes, with_std: bool, stride: int | None = None):
        """Values, exact gradients and (``with_std``) standard uncertainties on a grid.

        One single-precision ``log r`` block per chunk of nodes (:meth:`_logs`) gives values
        and gradients and, on the nodes of the sub-grid, the uncertainties: they keep the modes
        above :data:`STD_GRID_MODE_CUTOFF`, are computed on every ``stride``-th node along each
        axis (the last node always; default :meth:`_std_stride`) and interpolated (trilinear)
        at the other nodes.

        Returns
        -------
        u : (nz, ny, nx, C), G : (nz, ny, nx, C, 3), u_std, G_std : the same or None
        """
        pts = axes.points()
        shape = axes.shape
        nc = self.C.shape[1]
        M = np.empty((pts.shape[0], self._W.shape[1]))  # log r @ W of every node
        rest = np.arange(pts.shape[0])
        if with_std:  # the sub-grid's nodes first: their log r blocks serve both
            if stride is None:
                stride = self._std_stride(axes)
            sub = [_sub_indices(n, max(1, int(stride))) for n in shape]
            on_sub = np.zeros(shape, dtype=bool)
            on_sub[np.ix_(*sub)] = True
            first, rest = np.flatnonzero(on_sub), np.flatnonzero(~on_sub)
            setup = self._std_features(STD_GRID_MODE_CUTOFF)
            u_sd, G_sd = np.empty((first.size, nc)), np.empty((first.size, nc, 3))
            for s in range(0, first.size, _BLOCK_ROWS):
                idx = first[s : s + _BLOCK_ROWS]
                logs = self._logs(pts[idx])
                M[idx] = self._log_r_product(logs[1], self._W, self._W_sum)
                u_sd[s : s + _BLOCK_ROWS], G_sd[s : s + _BLOCK_ROWS] = self._std_from_logs(
                    logs, setup
                )
        for s in range(0, rest.size, _BLOCK_ROWS):
            idx = rest[s : s + _BLOCK_ROWS] if with_std else slice(s, s + _BLOCK_ROWS)
            M[idx] = self._log_r_product(self._logs(pts[idx])[1], self._W, self._W_sum)
        # values and gradients of all nodes at once (:meth:`_value_gradient`)
        u, G = self._from_products(pts - self.basis.centre, M)
        u, G = u.reshape(*shape, nc), G.reshape(*shape, nc, 3)
        if not with_std:
            return u, G, None, None
        sub_shape = tuple(ix.size for ix in sub)
        u_sd = _upsample(u_sd.reshape(*sub_shape, nc), sub, shape)
        G_sd = _upsample(G_sd.reshape(*sub_shape, nc, 3), sub, shape)
        return u, G, u_sd, G_sd

    def _std_stride(self, axes: GridAxes) -> int:
        """Node stride of the uncertainties' sub-grid: its spacing at most about (+20 %)
        :data:`STD_GRID_SUB_SPACING` median nearest-neighbour distances of the centres."""
        from scipy.spatial import cKDTree

        Xc = self.basis.Xc
        if STD_GRID_SUB_SPACING <= 0 or Xc.shape[0] < 2:
            return 1
        d, _ = cKDTree(Xc).query(Xc, k=2)
        h = max(axes.spacing_xyz_um)
        # 20 % leeway: an increment's matched particles are spaced a little unlike frame 0's,
        # whose spacing set the grid (nodes_per_spacing = 2 must give 2, not 1)
        return max(1, int(STD_GRID_SUB_SPACING * float(np.median(d[:, 1])) / h + 0.2))


def _sub_indices(n: int, stride: int) -> np.ndarray:
    """Every ``stride``-th index of ``range(n)`` and the last."""
    ix = np.arange(0, n, stride)
    return ix if ix[-1] == n - 1 else np.r_[ix, n - 1]


def _upsample(a: np.ndarray, sub: list, shape: tuple) -> np.ndarray:
    """Linear interpolation along the first three axes of ``a`` (values at the indices
    ``sub[k]`` of axis ``k``) onto ``shape``; ``sub[k]`` increasing, from 0 to ``shape[k] − 1``."""
    for ax, (ix, n) in enumerate(zip(sub, shape, strict=True)):
        if ix.size == n:
            continue
        k = np.clip(np.searchsorted(ix, np.arange(n), side="right") - 1, 0, ix.size - 2)
        w = (np.arange(n) - ix[k]) / (ix[k + 1] - ix[k])
        w = w.reshape((-1,) + (1,) * (a.ndim - ax - 1))
        lo, hi = np.take(a, k, axis=ax), np.take(a, k + 1, axis=ax)
        a = lo + w * (hi - lo)
    return a


@dataclass(frozen=True)
class DisplacementInterpolant:
    """Continuous displacement field fitted to scattered particle displacements.

    Call it with positions ``(P, 3)`` (µm) to get displacements ``(P, 3)`` (µm);
    :meth:`gradient` gives ``∂u_i/∂x_j`` by central differences, :meth:`value_and_gradient`
    both at once (analytic for the global thin-plate spline), :meth:`std` their standard
    uncertainties and :meth:`supported` tells which positions are backed by data. Build it with
    :func:`fit_displacement`. ``smoothing`` holds the λ used for ``u_x``, ``u_y``, ``u_z``
    (chosen by GCV or given).
    """

    positions_um: np.ndarray
    displacement_um: np.ndarray
    settings: GridSettings
    support_radius_um: float
    smoothing: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _fn: object = field(repr=False, default=None)
    _hull: object = field(repr=False, default=None)
    _tree: object = field(repr=False, default=None)
    _tps: object = field(repr=False, default=None)

    def __call__(self, xyz_um: np.ndarray) -> np.ndarray:
        q = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
        if self._tps is not None:
            return self._tps.evaluate(q)[0]
        out = np.empty((q.shape[0], 3))
        chunk = 20_000
        for s in range(0, q.shape[0], chunk):
            out[s : s + chunk] = self._fn(q[s : s + chunk])
        return out

    @property
    def has_uncertainty(self) -> bool:
        """Whether the fields get standard uncertainties: the global thin-plate spline,
        ``settings.uncertainty``, and a known noise level (given, or estimated from the
        residuals: not with ``smoothing=0``)."""
        return (
            self._tps is not None
            and bool(self.settings.uncertainty)
            and bool(np.all(np.isfinite(self._tps.sigma)))
        )

    def value_and_gradient(
        self, xyz_um: np.ndarray, step_um: float | tuple = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Displacement (P, 3) and ``∂u_i/∂x_j`` (P, 3, 3) at ``xyz_um`` (P, 3).

        Exact derivatives of the global thin-plate spline (one kernel evaluation for both,
        its ``log`` in single precision: relative error about 1e-7 of the field's magnitude);
        for the local RBF and ``method="linear"``, central differences with half-width
        ``step_um`` (as :meth:`gradient`).
        """
        q = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
        if self._tps is not None:
            return self._tps.evaluate(q, gradient=True, single=True)
        return self(q), self.gradient(q, step_um)

    def std(self, xyz_um: np.ndarray, gradient: bool = True):
        """Standard uncertainties of the displacement and its gradient at ``xyz_um`` (P, 3).

        The fit is linear in the particle displacements ``d`` for its λ, ``u(q) = W(q) d``
        per axis, so ``var u_i(q) = Σ_j W_ij(q)² σ_ij²`` with the particles' σ
        (``sigma_um`` of :func:`fit_displacement`, else the noise level GCV's residuals
        imply, ``RSS / tr((I − A)²)``, per axis); the same through ``∂/∂x_j`` for the gradient.
        Axes and particles are taken as independent.

        Returns
        -------
        u_std : ndarray, shape (P, 3)
            µm. NaN for an axis whose noise is unknown (``smoothing=0`` without
            ``sigma_um``).
        G_std : ndarray, shape (P, 3, 3) or None
            Of ``∂u_i/∂x_j``; None unless ``gradient``.

        Raises
        ------
        InputError
            The interpolant has no uncertainty model (local RBF or ``method="linear"``).
        """
        if self._tps is None:
            raise InputError(
                "standard uncertainties need the global thin-plate spline (method='rbf' with "
                "at most rbf_max_points particles)"
            )
        return self._tps.std(np.asarray(xyz_um, dtype=float).reshape(-1, 3), gradient=gradient)

    def gradient(self, xyz_um: np.ndarray, step_um: float | tuple) -> np.ndarray:
        """Displacement gradient ``G[..., i, j] = ∂u_i/∂x_j`` by central differences.

        Parameters
        ----------
        xyz_um : ndarray, shape (P, 3)
        step_um : float or (hx, hy, hz)
            Half-width of the difference along each axis (µm); use the grid spacing to
            match :func:`numpy.gradient` on the grid.

        Returns
        -------
        ndarray, shape (P, 3, 3)
        """
        q = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
        h = np.broadcast_to(np.asarray(step_um, dtype=float), (3,))
        G = np.empty((q.shape[0], 3, 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = h[j]
            G[:, :, j] = (self(q + d) - self(q - d)) / (2 * h[j])
        return G

    def supported(self, xyz_um: np.ndarray) -> np.ndarray:
        """``True`` for positions inside the particles' hull or near a particle, shape (P,)."""
        q = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
        out = np.zeros(q.shape[0], dtype=bool)
        if self._hull is not None:
            # inside a ball about the particles' centroid that the hull contains (every
            # facet's plane farther than its radius): inside the hull, no test needed
            eq = self._hull.equations  # unit outward normals n, offsets c: n·x + c <= 0
            centre = self.positions_um.mean(axis=0)
            r_in = float(np.min(-(eq[:, :3] @ centre + eq[:, 3]))) * (1.0 - 1e-9)
            if r_in > 0:
                dc = q - centre
                out = np.einsum("ij,ij->i", dc, dc) < r_in * r_in
        # near a particle (the search stops at the radius), else inside the hull
        bound = np.nextafter(float(self.support_radius_um), np.inf)
        rest = np.flatnonzero(~out)
        d, _ = self._tree.query(q[rest], k=1, distance_upper_bound=bound)
        out[rest] = d <= self.support_radius_um
        rest = rest[~out[rest]]
        if self._hull is not None and rest.size:
            eq = self._hull.equations  # outward facet normals n and offsets c: n·x + c <= 0
            tol = 1e-9 * max(1.0, float(np.max(np.abs(self.positions_um))))
            for s in range(0, rest.size, 20_000):
                idx = rest[s : s + 20_000]
                block = q[idx] @ eq[:, :3].T + eq[:, 3]
                out[idx] = np.all(block <= tol, axis=1)
        return out

    def supported_on_grid(self, axes: GridAxes) -> np.ndarray:
        """:meth:`supported` at the nodes of ``axes`` (in :meth:`GridAxes.points` order, shape
        (P,)): the hull is convex, so along each line of nodes in x it holds an interval,
        found from the facets once per line instead of testing every node against every
        facet."""
        pts = axes.points()
        bound = np.nextafter(float(self.support_radius_um), np.inf)
        if self._hull is None:
            d, _ = self._tree.query(pts, k=1, distance_upper_bound=bound)
            return d <= self.support_radius_um
        eq = self._hull.equations  # n·x + c <= 0 inside
        tol = 1e-9 * max(1.0, float(np.max(np.abs(self.positions_um))))
        Z, Y = np.meshgrid(axes.z_um, axes.y_um, indexing="ij")
        # n_x x <= b on each line (z, y), for each facet
        b = tol - eq[:, 3] - Y[..., None] * eq[:, 1] - Z[..., None] * eq[:, 2]  # (nz, ny, F)
        nx = eq[:, 0]
        pos, neg = nx > 0, nx < 0
        hi = np.min(b[..., pos] / nx[pos], axis=-1, initial=np.inf)
        lo = np.max(b[..., neg] / nx[neg], axis=-1, initial=-np.inf)
        ok = np.all(b[..., ~(pos | neg)] >= 0, axis=-1)
        x = axes.x_um
        out = (ok[..., None] & (x >= lo[..., None]) & (x <= hi[..., None])).ravel()
        # near a particle: searched only outside the hull (most nodes are inside)
        rest = np.flatnonzero(~out)
        d, _ = self._tree.query(pts[rest], k=1, distance_upper_bound=bound)
        out[rest] = d <= self.support_radius_um
        return out


def fit_displacement(
    positions_um: np.ndarray,
    displacement_um: np.ndarray,
    settings: GridSettings | None = None,
    *,
    sigma_um: np.ndarray | None = None,
) -> DisplacementInterpolant:
    """Fit a continuous displacement field to scattered particle displacements.

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Particle positions in the configuration the field is defined on (µm).
    displacement_um : ndarray, shape (N, 3)
        Their displacements (µm).
    settings : GridSettings, optional
    sigma_um : ndarray, shape (N, 3), optional
        Standard uncertainty of each displacement (µm, x, y, z), e.g. a link table's
        per-match uncertainty; default: estimated per axis from the smoothing residuals
        (:meth:`DisplacementInterpolant.std`). Only the uncertainties use it.

    Returns
    -------
    DisplacementInterpolant

    Raises
    ------
    InputError
        Bad shapes, non-finite values, or fewer than 4 particles.

    Notes
    -----
    Up to ``rbf_max_points`` particles the global thin-plate spline is solved from one
    eigen-decomposition (:class:`_ThinPlateBasis`) that also gives GCV's λ when there are at
    most ``gcv_max_points`` particles; it equals :class:`scipy.interpolate.RBFInterpolator`
    (``kernel="thin_plate_spline"``, ``degree=1``, ``smoothing=λ``) to round-off and is
    evaluated with one kernel block for all three components and their gradients.
    """
    from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

    settings = settings or GridSettings()
    X = _points(positions_um, "positions_um")
    U = _points(displacement_um, "displacement_um")
    if U.shape != X.shape:
        raise InputError(f"displacement_um has shape {U.shape}, positions_um has {X.shape}")
    if X.shape[0] < 4:
        raise InputError(f"a displacement field needs at least 4 particles, got {X.shape[0]}")
    sig = None
    if sigma_um is not None:
        sig = np.asarray(sigma_um, dtype=float)
        if sig.shape != X.shape or not np.all(np.isfinite(sig)) or np.any(sig < 0):
            raise InputError(
                f"sigma_um must be finite, >= 0 and of shape {X.shape} (x, y, z µm per "
                f"particle), got shape {sig.shape}"
            )
    tree = cKDTree(X)
    if settings.method == "linear":
        radius = 0.0
    elif settings.support_radius_um is None:
        d, _ = tree.query(X, k=2)
        radius = float(np.median(d[:, 1]))
    else:
        radius = float(settings.support_radius_um)
    try:
        hull = ConvexHull(X)
    except QhullError:
        hull = None
        log.warning("particles are (nearly) coplanar; no convex hull for the support mask")
    lam = np.zeros(3)
    tps = None
    fn = None
    if settings.method == "rbf":
        n = X.shape[0]
        basis = None
        if n <= settings.rbf_max_points:
            try:
                basis = _ThinPlateBasis(X)
            except np.linalg.LinAlgError as exc:
                raise InputError(
                    f"cannot fit a displacement field to {n} particles: {exc}"
                ) from exc
        if settings.smoothing != "gcv":
            lam[:] = float(settings.smoothing)
        elif n >= GCV_MIN_POINTS:
            if basis is not None and n <= settings.gcv_max_points:
                lam = _gcv_choose(basis.gam, basis.to_modes(U), np.linalg.norm(U, axis=0))
            else:
                lam = gcv_smoothing(X, U, max_points=settings.gcv_max_points)
            log.debug("GCV smoothing of u_x, u_y, u_z: %.3g, %.3g, %.3g", *lam)
        else:
            log.info("only %d particles: too few to choose the smoothing; interpolating", n)
        if basis is not None:
            tps = _ThinPlateFit(basis, U, lam, sig)
        else:
            # (imported here: scipy.interpolate takes 0.4 s to import, and the global spline
            # above does not need it)
            from scipy.interpolate import RBFInterpolator

            fn = _local_rbf(X, U, lam, settings, RBFInterpolator)
    else:
        if hull is None:
            raise InputError("method='linear' needs particles that span 3-D space")
        try:
            tri = Delaunay(X)
        except QhullError as exc:
            raise InputError(f"cannot triangulate {X.shape[0]} particles: {exc}") from exc
        near = cKDTree(X)

        def fn(q):
            # Locate simplices by brute force: scipy's directed walk can be very slow for
            # points outside the hull.
            simplex = tri.find_simplex(q, bruteforce=True)
            v = np.empty((q.shape[0], 3))
            inside = simplex >= 0
            if np.any(inside):
                s_in = simplex[inside]
                T = tri.transform[s_in]  # (P, 4, 3): barycentric transform
                b = np.einsum("pij,pj->pi", T[:, :3], q[inside] - T[:, 3])
                bary = np.c_[b, 1.0 - b.sum(axis=1)]
                v[inside] = np.einsum("pk,pkc->pc", bary, U[tri.simplices[s_in]])
            if np.any(~inside):
                v[~inside] = U[near.query(q[~inside], k=1)[1]]
            return v

    return DisplacementInterpolant(
        positions_um=X,
        displacement_um=U,
        settings=settings,
        support_radius_um=radius,
        smoothing=tuple(float(v) for v in lam),
        _fn=fn,
        _hull=hull,
        _tree=tree,
        _tps=tps,
    )


def _local_rbf(X, U, lam, settings, rbf_class):
    """scipy's RBF on the ``rbf_neighbours`` nearest particles (above ``rbf_max_points``)."""
    kw = {"neighbors": settings.rbf_neighbours}
    try:
        if np.all(lam == lam[0]):
            return rbf_class(X, U, kernel="thin_plate_spline", degree=1, smoothing=lam[0], **kw)
        parts = [
            rbf_class(X, U[:, c], kernel="thin_plate_spline", degree=1, smoothing=lam[c], **kw)
            for c in range(3)
        ]
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise InputError(
            f"cannot fit a displacement field to {X.shape[0]} particles: {exc}"
        ) from exc

    def fn(q):
        return np.stack([p(q) for p in parts], axis=1)

    return fn


def strain_from_displacement(axes: GridAxes, u: np.ndarray) -> tuple[np.ndarray, ...]:
    """``F``, ``E`` and ``e`` of a gridded displacement by :func:`numpy.gradient`.

    Parameters
    ----------
    axes : GridAxes
    u : ndarray, shape (nz, ny, nx, 3)
        Displacement on the grid (µm).

    Returns
    -------
    F, E, e : ndarray, shape (nz, ny, nx, 3, 3)
    """
    u = np.asarray(u, dtype=float)
    if u.shape != (*axes.shape, 3):
        raise InputError(f"u must have shape {(*axes.shape, 3)}, got {u.shape}")
    G = np.empty((*axes.shape, 3, 3))
    coords = (axes.z_um, axes.y_um, axes.x_um)
    for i in range(3):
        dz, dy, dx = np.gradient(u[..., i], *coords, edge_order=1)
        G[..., i, 0], G[..., i, 1], G[..., i, 2] = dx, dy, dz
    F = np.eye(3) + G
    return F, green_lagrange(F), infinitesimal(F)


def strain_std(G_std: np.ndarray) -> np.ndarray:
    """Standard uncertainty of ``e = (G + Gᵀ)/2`` from that of ``G = ∂u/∂X`` (..., 3, 3).

    ``G_ij`` and ``G_ji`` (i ≠ j) come from different displacement components, taken as
    independent: ``var e_ij = (var G_ij + var G_ji) / 4``, ``var e_ii = var G_ii``.
    """
    v = np.square(np.asarray(G_std, dtype=float))
    out = v + np.swapaxes(v, -1, -2)
    out *= 0.25
    i = np.arange(3)
    out[..., i, i] = v[..., i, i]
    return np.sqrt(out, out=out)


def field_on_grid(
    interpolant: DisplacementInterpolant,
    axes: GridAxes,
) -> GridField:
    """Evaluate an interpolant on a grid and differentiate it (see module docstring).

    The global thin-plate spline gives its exact gradient at the nodes (and, when
    :attr:`DisplacementInterpolant.has_uncertainty`, the standard uncertainties ``u_std``,
    ``F_std``, ``e_std``; otherwise they are None);
    the other interpolants are differentiated on the grid by :func:`numpy.gradient`.
    """
    pts = axes.points()
    shape = axes.shape
    stds = {}
    if interpolant._tps is not None:
        with_std = interpolant.has_uncertainty
        u, G, u_sd, G_sd = interpolant._tps.on_grid(axes, with_std)
        F = np.eye(3) + G
        E, e = green_lagrange(F), infinitesimal(F)
        if with_std:
            stds = {"u_std": u_sd, "F_std": G_sd, "e_std": strain_std(G_sd)}
    else:
        u = interpolant(pts).reshape(*shape, 3)
        F, E, e = strain_from_displacement(axes, u)
    mask = interpolant.supported_on_grid(axes).reshape(shape)
    return GridField(axes.x_um, axes.y_um, axes.z_um, u, F, E, e, mask, **stds)


def gridded_field(
    positions_um: np.ndarray,
    displacement_um: np.ndarray,
    settings: GridSettings | None = None,
    *,
    axes: GridAxes | None = None,
    sigma_um: np.ndarray | None = None,
) -> GridField:
    """Grid scattered particle displacements and compute ``F``, ``E``, ``e`` on the grid.

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Reference positions of the particles (µm), x, y, z.
    displacement_um : ndarray, shape (N, 3)
        Their displacements (µm).
    settings : GridSettings, optional
    axes : GridAxes, optional
        Grid to use; default :func:`grid_axes` over the particles' bounding box with
        :func:`grid_spacing_um` / ``settings.target_nodes``.
    sigma_um : ndarray, shape (N, 3), optional
        Standard uncertainty of each displacement (µm), see :func:`fit_displacement`.

    Returns
    -------
    GridField

    Raises
    ------
    InputError
        Bad shapes or values, fewer than 4 particles, or flat particle sets.
    """
    settings = settings or GridSettings()
    if axes is None:
        h = grid_spacing_um(positions_um, settings)
        axes = grid_axes(positions_um, h, target_nodes=settings.target_nodes)
    interp = fit_displacement(positions_um, displacement_um, settings, sigma_um=sigma_um)
    return field_on_grid(interp, axes)


__all__ = [
    "DisplacementInterpolant",
    "GridAxes",
    "GridField",
    "GridSettings",
    "field_on_grid",
    "fit_displacement",
    "gcv_smoothing",
    "grid_axes",
    "grid_spacing_um",
    "gridded_field",
    "strain_from_displacement",
    "strain_std",
]
