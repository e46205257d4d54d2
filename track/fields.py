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

Gradients are taken on the grid with :func:`numpy.gradient` and the physical spacings
(second-order central differences inside, first-order one-sided at the borders), giving
``F = I + ∂u/∂X`` (``F[..., i, j] = δ_ij + ∂u_i/∂X_j``), Green–Lagrange ``E`` and
infinitesimal ``e`` (see :mod:`track.strain`).

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
    """

    spacing_um: float | None = None
    target_nodes: int = 50_000
    method: str = "rbf"
    smoothing: float | str = "gcv"
    rbf_max_points: int = 2000
    rbf_neighbours: int = 64
    gcv_max_points: int = 1000
    support_radius_um: float | None = None

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
    """

    x_um: np.ndarray
    y_um: np.ndarray
    z_um: np.ndarray
    u: np.ndarray
    F: np.ndarray
    E: np.ndarray
    e: np.ndarray
    mask: np.ndarray

    def __post_init__(self) -> None:
        axes = GridAxes(self.x_um, self.y_um, self.z_um)
        for name in ("x_um", "y_um", "z_um"):
            object.__setattr__(self, name, getattr(axes, name))
        shape = axes.shape
        checks = {"u": (*shape, 3), "F": (*shape, 3, 3), "E": (*shape, 3, 3), "e": (*shape, 3, 3)}
        for name, want in checks.items():
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


def _tps_kernel(r: np.ndarray) -> np.ndarray:
    """``r² log r`` (0 at ``r = 0``): the kernel and sign scipy's ``thin_plate_spline`` uses."""
    from scipy.special import xlogy

    return xlogy(r * r, r)


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
    decade). A column of exactly affine data (no residual) gets the smallest λ of the scan.

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
    from scipy.spatial.distance import cdist

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
    m = X.shape[0]
    P = np.c_[np.ones(m), X - X.mean(axis=0)]
    Q, _ = np.linalg.qr(P, mode="complete")
    Q2 = Q[:, P.shape[1] :]
    K = _tps_kernel(cdist(X, X))
    gam, V = np.linalg.eigh(Q2.T @ K @ Q2)
    gam = np.maximum(gam, 0.0)
    z2 = (V.T @ (Q2.T @ Y)) ** 2  # (m - 4, C)
    top = max(float(gam.max()), np.finfo(float).tiny)
    lams = top * np.logspace(-12.0, 4.0, 161)
    f = lams[None, :] / (gam[:, None] + lams[None, :])  # (m - 4, L)
    rss = (f * f).T @ z2  # (L, C)
    tr = f.sum(axis=0)  # (L,)
    score = m * rss / (tr * tr)[:, None]
    best = np.argmin(score, axis=0)
    return lams[best] * scale


@dataclass(frozen=True)
class DisplacementInterpolant:
    """Continuous displacement field fitted to scattered particle displacements.

    Call it with positions ``(P, 3)`` (µm) to get displacements ``(P, 3)`` (µm);
    :meth:`gradient` gives ``∂u_i/∂x_j`` by central differences and :meth:`supported` tells
    which positions are backed by data. Build it with :func:`fit_displacement`.
    ``smoothing`` holds the λ used for ``u_x``, ``u_y``, ``u_z`` (chosen by GCV or given).
    """

    positions_um: np.ndarray
    displacement_um: np.ndarray
    settings: GridSettings
    support_radius_um: float
    smoothing: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _fn: object = field(repr=False, default=None)
    _hull: object = field(repr=False, default=None)
    _tree: object = field(repr=False, default=None)

    def __call__(self, xyz_um: np.ndarray) -> np.ndarray:
        q = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
        out = np.empty((q.shape[0], 3))
        chunk = 20_000
        for s in range(0, q.shape[0], chunk):
            out[s : s + chunk] = self._fn(q[s : s + chunk])
        return out

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
        inside = np.zeros(q.shape[0], dtype=bool)
        if self._hull is not None:
            eq = self._hull.equations  # outward facet normals n and offsets c: n·x + c <= 0
            tol = 1e-9 * max(1.0, float(np.max(np.abs(self.positions_um))))
            for s in range(0, q.shape[0], 20_000):
                block = q[s : s + 20_000] @ eq[:, :3].T + eq[:, 3]
                inside[s : s + 20_000] = np.all(block <= tol, axis=1)
        d, _ = self._tree.query(q, k=1)
        return inside | (d <= self.support_radius_um)


def fit_displacement(
    positions_um: np.ndarray,
    displacement_um: np.ndarray,
    settings: GridSettings | None = None,
) -> DisplacementInterpolant:
    """Fit a continuous displacement field to scattered particle displacements.

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Particle positions in the configuration the field is defined on (µm).
    displacement_um : ndarray, shape (N, 3)
        Their displacements (µm).
    settings : GridSettings, optional

    Returns
    -------
    DisplacementInterpolant

    Raises
    ------
    InputError
        Bad shapes, non-finite values, or fewer than 4 particles.
    """
    from scipy.interpolate import RBFInterpolator
    from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

    settings = settings or GridSettings()
    X = _points(positions_um, "positions_um")
    U = _points(displacement_um, "displacement_um")
    if U.shape != X.shape:
        raise InputError(f"displacement_um has shape {U.shape}, positions_um has {X.shape}")
    if X.shape[0] < 4:
        raise InputError(f"a displacement field needs at least 4 particles, got {X.shape[0]}")
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
    if settings.method == "rbf":
        kw = {}
        if X.shape[0] > settings.rbf_max_points:
            kw["neighbors"] = settings.rbf_neighbours
        if settings.smoothing != "gcv":
            lam[:] = float(settings.smoothing)
        elif X.shape[0] >= GCV_MIN_POINTS:
            lam = gcv_smoothing(X, U, max_points=settings.gcv_max_points)
            log.debug("GCV smoothing of u_x, u_y, u_z: %.3g, %.3g, %.3g", *lam)
        else:
            log.info("only %d particles: too few to choose the smoothing; interpolating", len(X))
        try:
            if np.all(lam == lam[0]):
                fn = RBFInterpolator(
                    X, U, kernel="thin_plate_spline", degree=1, smoothing=lam[0], **kw
                )
            else:
                parts = [
                    RBFInterpolator(
                        X, U[:, c], kernel="thin_plate_spline", degree=1, smoothing=lam[c], **kw
                    )
                    for c in range(3)
                ]

                def fn(q):
                    return np.stack([p(q) for p in parts], axis=1)

        except (np.linalg.LinAlgError, ValueError) as exc:
            raise InputError(
                f"cannot fit a displacement field to {X.shape[0]} particles: {exc}"
            ) from exc
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
    )


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


def field_on_grid(
    interpolant: DisplacementInterpolant,
    axes: GridAxes,
) -> GridField:
    """Evaluate an interpolant on a grid and differentiate it (see module docstring)."""
    pts = axes.points()
    u = interpolant(pts).reshape(*axes.shape, 3)
    F, E, e = strain_from_displacement(axes, u)
    mask = interpolant.supported(pts).reshape(axes.shape)
    return GridField(axes.x_um, axes.y_um, axes.z_um, u, F, E, e, mask)


def gridded_field(
    positions_um: np.ndarray,
    displacement_um: np.ndarray,
    settings: GridSettings | None = None,
    *,
    axes: GridAxes | None = None,
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
        ``settings.spacing_um`` / ``settings.target_nodes``.

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
        axes = grid_axes(positions_um, settings.spacing_um, target_nodes=settings.target_nodes)
    interp = fit_displacement(positions_um, displacement_um, settings)
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
    "gridded_field",
    "strain_from_displacement",
]
