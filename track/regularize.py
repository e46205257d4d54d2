"""Global, kinematically admissible displacement fields fitted to scattered particle matches.

Two solvers of one variational problem on a regular grid with trilinear interpolation:

.. math::

    \\min_g \\; \\frac{1}{2P}\\lVert B g - d \\rVert^2
        + \\frac{\\alpha}{2R}\\lVert L g \\rVert^2

where ``B`` (P × G) interpolates grid values trilinearly at the P particles, ``d`` are the
measured displacements, ``L`` (R × G) stacks the second differences of the grid along x, y and
z (its null space holds every affine field, so the penalty never biases a homogeneous
deformation) and ``α`` is a dimensionless smoothness weight.

* ``method="gridded"`` solves the normal equations directly (sparse LU), as the scattered-data
  to grid step of SerialTrack (Yang et al., SoftwareX 19, 101204, 2022) does.
* ``method="admm"`` splits the data term (on particles) from the smoothness term (on the grid)
  with an augmented Lagrangian / ADMM iteration (Boyd et al., Found. Trends Mach. Learn. 3,
  2011) and converges to the same minimiser.

A robust affine map (:func:`fit_affine`) serves as the stiffest global fit when tracking
starts from large deformations.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import cg, splu
from scipy.spatial import cKDTree

from track.errors import InputError
from track.grid import GridAxes

logger = logging.getLogger(__name__)

METHODS = ("gridded", "admm")
EXTRAPOLATIONS = ("linear", "nearest")


def _as_points(name: str, arr, allow_empty: bool = False) -> np.ndarray:
    """Validate an ``(n, 3)`` finite float array named ``name``."""
    a = np.asarray(arr, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{name} must have shape (n, 3) in µm, got {a.shape}")
    if not allow_empty and a.shape[0] == 0:
        raise InputError(f"{name} is empty; need at least one point")
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(a), axis=1)))
        raise InputError(f"{name} holds {bad} row(s) with NaN or infinite coordinates")
    return a


def _paired_points(
    points_um,
    values_um,
    values_name: str = "displacements_um",
    *,
    min_points: int = 1,
    who: str = "",
    what: str = "points",
) -> tuple[np.ndarray, np.ndarray]:
    """Validate points and the vectors at them: two finite ``(n, 3)`` arrays of one shape with
    at least ``min_points`` rows (else "``who`` needs at least ``min_points`` ``what``")."""
    x = _as_points("points_um", points_um)
    v = _as_points(values_name, values_um)
    if x.shape != v.shape:
        raise InputError(f"points_um {x.shape} and {values_name} {v.shape} differ in shape")
    if x.shape[0] < min_points:
        raise InputError(f"{who} needs at least {min_points} {what}, got {x.shape[0]}")
    return x, v


@dataclass(frozen=True)
class AffineDisplacement:
    """Affine displacement field ``u(X) = (A - I) (X - centre) + t``.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Deformation gradient ``A`` (dimensionless), mapping reference to deformed vectors.
    center_xyz_um : ndarray, shape (3,)
        Reference point ``X0`` in µm.
    translation_um : ndarray, shape (3,)
        Displacement at ``center_xyz_um`` in µm.
    """

    matrix: np.ndarray
    center_xyz_um: np.ndarray
    translation_um: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=float)
        c = np.asarray(self.center_xyz_um, dtype=float)
        t = np.asarray(self.translation_um, dtype=float)
        if m.shape != (3, 3) or c.shape != (3,) or t.shape != (3,):
            raise InputError(
                "AffineDisplacement needs matrix (3, 3), center_xyz_um and translation_um (3,)"
            )
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(c)) and np.all(np.isfinite(t))):
            raise InputError("AffineDisplacement parameters must be finite")
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "center_xyz_um", c)
        object.__setattr__(self, "translation_um", t)

    def __call__(self, xyz_um) -> np.ndarray:
        """Displacement (P, 3) in µm at reference points ``xyz_um`` (P, 3) in µm."""
        x = _as_points("xyz_um", xyz_um, allow_empty=True)
        return (x - self.center_xyz_um) @ (self.matrix - np.eye(3)).T + self.translation_um


def fit_affine(points_um, displacements_um, weights=None) -> AffineDisplacement:
    """Least-squares affine displacement field through matched particles.

    Parameters
    ----------
    points_um : array_like, shape (P, 3)
        Reference positions in µm (P ≥ 4, not coplanar).
    displacements_um : array_like, shape (P, 3)
        Displacements in µm.
    weights : array_like, shape (P,), optional
        Non-negative weights of the points.

    Returns
    -------
    AffineDisplacement

    Raises
    ------
    InputError
        Fewer than 4 points, mismatched shapes, or coplanar points.
    """
    x, u = _paired_points(points_um, displacements_um, min_points=4, who="fit_affine")
    c = x.mean(axis=0)
    design = np.hstack([x - c, np.ones((x.shape[0], 1))])
    rhs = u
    if weights is not None:
        w = np.sqrt(np.clip(np.asarray(weights, dtype=float), 0.0, None))[:, None]
        design, rhs = design * w, rhs * w
    coef, _, rank, _ = np.linalg.lstsq(design, rhs, rcond=None)
    if rank < 4:
        raise InputError("fit_affine: points_um are coplanar or collinear (rank-deficient)")
    return AffineDisplacement(
        matrix=np.eye(3) + coef[:3].T, center_xyz_um=c, translation_um=coef[3]
    )


@dataclass(frozen=True)
class GridDisplacement:
    """Displacement sampled on a regular grid, evaluated by trilinear interpolation.

    The same grid and array order as :class:`track.fields.GridField`: node ``(k, j, i)``
    lies at ``origin_xyz_um + (i, j, k) * spacing_xyz_um``. :attr:`axes` gives the grid as
    :class:`track.fields.GridAxes`, :meth:`from_axes` builds a field from one.

    Attributes
    ----------
    origin_xyz_um : ndarray, shape (3,)
        Position of the first node ``(x0, y0, z0)`` in µm.
    spacing_xyz_um : ndarray, shape (3,)
        Node spacing ``(dx, dy, dz)`` in µm (> 0).
    values_um : ndarray, shape (nz, ny, nx, 3)
        Displacement (ux, uy, uz) in µm at the nodes, in array order (z, y, x).
    extrapolation : {"linear", "nearest"}
        Outside the grid, continue the boundary cell linearly or hold the boundary value.
    info : dict
        How the field was fitted (see :func:`fit_field`).
    """

    origin_xyz_um: np.ndarray
    spacing_xyz_um: np.ndarray
    values_um: np.ndarray
    extrapolation: str = "linear"
    info: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        o = np.asarray(self.origin_xyz_um, dtype=float)
        h = np.asarray(self.spacing_xyz_um, dtype=float)
        v = np.asarray(self.values_um, dtype=float)
        if o.shape != (3,) or h.shape != (3,):
            raise InputError("origin_xyz_um and spacing_xyz_um must have shape (3,)")
        if not np.all(np.isfinite(o)):
            raise InputError(f"origin_xyz_um must be finite, got {o}")
        if not np.all(h > 0) or not np.all(np.isfinite(h)):
            raise InputError(f"spacing_xyz_um must be finite and > 0, got {h}")
        if v.ndim != 4 or v.shape[3] != 3 or min(v.shape[:3]) < 2:
            raise InputError(f"values_um must have shape (nz, ny, nx, 3) with n ≥ 2, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise InputError("values_um holds NaN or infinite displacements")
        if self.extrapolation not in EXTRAPOLATIONS:
            raise InputError(
                f"extrapolation must be one of {EXTRAPOLATIONS}, got {self.extrapolation!r}"
            )
        object.__setattr__(self, "origin_xyz_um", o)
        object.__setattr__(self, "spacing_xyz_um", h)
        object.__setattr__(self, "values_um", v)

    @classmethod
    def from_axes(
        cls, axes: GridAxes, values_um, extrapolation: str = "linear"
    ) -> GridDisplacement:
        """Field on the nodes of ``axes`` (evenly spaced), ``values_um`` (nz, ny, nx, 3) µm.

        Raises
        ------
        InputError
            An axis of ``axes`` is not evenly spaced (relative tolerance 1e-9), or
            ``values_um`` does not match its shape.
        """
        for name in ("x_um", "y_um", "z_um"):
            step = np.diff(getattr(axes, name))
            if not np.allclose(step, step.mean(), rtol=1e-9, atol=0.0):
                raise InputError(f"GridDisplacement needs evenly spaced nodes; axes.{name} is not")
        v = np.asarray(values_um, dtype=float)
        if v.shape != (*axes.shape, 3):
            raise InputError(
                f"values_um must have shape {(*axes.shape, 3)} (nz, ny, nx, 3) of the axes, "
                f"got {v.shape}"
            )
        return cls(axes.origin_xyz_um, axes.spacing_xyz_um, v, extrapolation)

    @property
    def shape(self) -> tuple[int, int, int]:
        """Number of nodes ``(nz, ny, nx)``."""
        return tuple(int(n) for n in self.values_um.shape[:3])

    def _axis_um(self, a: int) -> np.ndarray:
        """Node coordinates along x (``a = 0``), y (1) or z (2), µm."""
        return self.origin_xyz_um[a] + self.spacing_xyz_um[a] * np.arange(self.shape[2 - a])

    @property
    def axes(self) -> GridAxes:
        """The grid as :class:`track.fields.GridAxes`."""
        return GridAxes(self._axis_um(0), self._axis_um(1), self._axis_um(2))

    def node_xyz_um(self) -> np.ndarray:
        """Node positions, shape (nz, ny, nx, 3), columns x, y, z in µm."""
        z, y, x = np.meshgrid(self._axis_um(2), self._axis_um(1), self._axis_um(0), indexing="ij")
        return np.stack([x, y, z], axis=-1)

    def __call__(self, xyz_um) -> np.ndarray:
        """Displacement (P, 3) in µm at points ``xyz_um`` (P, 3) in µm."""
        x = _as_points("xyz_um", xyz_um, allow_empty=True)
        mat = interpolation_matrix(
            x, self.origin_xyz_um, self.spacing_xyz_um, self.shape, self.extrapolation
        )
        return np.asarray(mat @ self.values_um.reshape(-1, 3))


def interpolation_matrix(
    xyz_um: np.ndarray,
    origin_xyz_um: np.ndarray,
    spacing_xyz_um: np.ndarray,
    shape: tuple[int, int, int],
    extrapolation: str = "linear",
) -> sp.csr_matrix:
    """Sparse trilinear interpolation matrix ``B`` (P × nz·ny·nx) of a regular grid.

    Parameters
    ----------
    xyz_um : ndarray, shape (P, 3)
        Points (x, y, z) in µm.
    origin_xyz_um, spacing_xyz_um : ndarray, shape (3,)
        First node and node spacing, (x, y, z) in µm.
    shape : tuple of int
        Node counts ``(nz, ny, nx)``; columns of ``B`` are nodes in C order over (z, y, x),
        so ``B @ values.reshape(-1, 3)`` interpolates ``values`` of shape (nz, ny, nx, 3).
    extrapolation : {"linear", "nearest"}
        Points outside the grid use the nearest boundary cell; ``"linear"`` continues its
        trilinear polynomial, ``"nearest"`` clips the local coordinates (boundary values are
        held).
    """
    p = xyz_um.shape[0]
    n = np.asarray(shape)[::-1]  # (nx, ny, nz), the order of the columns of xyz_um
    f = (xyz_um - origin_xyz_um) / spacing_xyz_um
    i0 = np.clip(np.floor(f).astype(np.int64), 0, n - 2)
    t = f - i0
    if extrapolation == "nearest":
        t = np.clip(t, 0.0, 1.0)
    rows, cols, vals = [], [], []
    for dx in (0, 1):
        wx = t[:, 0] if dx else 1.0 - t[:, 0]
        for dy in (0, 1):
            wy = t[:, 1] if dy else 1.0 - t[:, 1]
            for dz in (0, 1):
                wz = t[:, 2] if dz else 1.0 - t[:, 2]
                idx = ((i0[:, 2] + dz) * n[1] + (i0[:, 1] + dy)) * n[0] + (i0[:, 0] + dx)
                rows.append(np.arange(p))
                cols.append(idx)
                vals.append(wx * wy * wz)
    return sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(p, int(np.prod(n))),
    )


def second_difference_operator(shape: tuple[int, int, int]) -> sp.csr_matrix:
    """Stacked second differences along each axis of a C-ordered grid (R × G, dimensionless).

    ``shape`` is the grid's array shape, ``(nz, ny, nx)`` for :class:`GridDisplacement`.
    """
    eyes = [sp.identity(int(n), format="csr") for n in shape]
    blocks = []
    for axis, n in enumerate(shape):
        if n < 3:
            continue
        d2 = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n), format="csr")
        mats = [eyes[0], eyes[1], eyes[2]]
        mats[axis] = d2
        blocks.append(sp.kron(sp.kron(mats[0], mats[1]), mats[2], format="csr"))
    g = int(np.prod(shape))
    if not blocks:
        return sp.csr_matrix((0, g))
    return sp.vstack(blocks, format="csr")


def make_grid(bounds_xyz_um, spacing_xyz_um) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Regular grid covering ``bounds_xyz_um`` ((3, 2): min, max µm per axis x, y, z).

    The node spacing is the largest value ≤ ``spacing_xyz_um`` that divides each extent into a
    whole number of cells (at least one cell per axis).

    Returns
    -------
    origin_xyz_um, spacing_xyz_um : ndarray, shape (3,)
        First node and node spacing, (x, y, z) in µm.
    shape : tuple of int
        Node counts ``(nz, ny, nx)`` (array order, as :attr:`GridDisplacement.shape`).
    """
    b = np.asarray(bounds_xyz_um, dtype=float)
    if b.shape != (3, 2) or not np.all(np.isfinite(b)) or np.any(b[:, 1] < b[:, 0]):
        raise InputError(
            f"bounds_xyz_um must be finite (3, 2) [min, max] per axis, got {b.tolist()}"
        )
    h = np.broadcast_to(np.asarray(spacing_xyz_um, dtype=float), (3,))
    if not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise InputError(f"spacing_xyz_um must be finite and > 0, got {spacing_xyz_um}")
    extent = b[:, 1] - b[:, 0]
    cells = np.maximum(1, np.ceil(extent / h - 1e-9)).astype(int)
    step = np.where(extent > 0, extent / cells, h)
    origin = np.where(extent > 0, b[:, 0], b[:, 0] - 0.5 * h)
    return origin, step, tuple(int(c) + 1 for c in cells[::-1])


def _factorize_spd(mat: sp.spmatrix):
    """Sparse LU of a symmetric positive definite matrix with a symmetric ordering."""
    lu = splu(sp.csc_matrix(mat), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    return lu.solve


def _solve_spd(mat: sp.csr_matrix, rhs: np.ndarray, info: dict, rtol: float = 1e-10) -> np.ndarray:
    """Solve ``mat x = rhs`` (G × G SPD, rhs (G, 3)) by Jacobi-preconditioned CG.

    Falls back to a sparse LU when CG does not converge.
    """
    precond = sp.diags(1.0 / mat.diagonal())
    out = np.empty_like(rhs)
    iters = [0]

    def count(_):
        iters[0] += 1

    for k in range(rhs.shape[1]):
        sol, status = cg(
            mat, rhs[:, k], M=precond, rtol=rtol, maxiter=20 * mat.shape[0], callback=count
        )
        if status != 0:
            logger.debug("CG did not converge (status %d); using sparse LU", status)
            return _factorize_spd(mat)(rhs)
        out[:, k] = sol
    info["cg_iterations"] = iters[0]
    return out


def fit_field(
    points_um,
    displacements_um,
    bounds_xyz_um,
    spacing_xyz_um,
    method: str = "gridded",
    weight: float = 1.0,
    *,
    extrapolation: str = "linear",
    admm_rho: float | None = None,
    admm_max_iter: int = 2000,
    admm_tol: float = 1e-7,
) -> GridDisplacement:
    """Fit a smooth gridded displacement field to scattered matches.

    Parameters
    ----------
    points_um : array_like, shape (P, 3)
        Reference positions of matched particles in µm.
    displacements_um : array_like, shape (P, 3)
        Their displacements in µm.
    bounds_xyz_um : array_like, shape (3, 2)
        Region [min, max] (µm) the grid must cover; rows x, y, z.
    spacing_xyz_um : float or array_like, shape (3,)
        Largest allowed node spacing in µm (per axis: x, y, z, as the rows of ``bounds_xyz_um``).
    method : {"gridded", "admm"}
        Direct sparse solve of the normal equations, or ADMM splitting (same minimiser).
    weight : float
        Dimensionless smoothness weight ``α`` ≥ 0 (see module docstring).
    extrapolation : {"linear", "nearest"}
        Behaviour of the returned field outside the grid.
    admm_rho, admm_max_iter, admm_tol
        ADMM penalty (default: geometric mean of the mean diagonals of the data and
        smoothness Hessians, which balances the two sub-problems), iteration cap and relative
        tolerance on the primal and dual residuals.

    Returns
    -------
    GridDisplacement
        ``info`` holds ``method`` and, for ADMM, ``iterations`` and ``converged``.

    Raises
    ------
    InputError
        Bad shapes, non-finite values, unknown method, negative weight, or fewer than 4 points.
    """
    x, u = _paired_points(
        points_um, displacements_um, min_points=4, who="fit_field", what="matched points"
    )
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}, got {method!r}")
    if not np.isfinite(weight) or weight < 0:
        raise InputError(f"weight must be finite and ≥ 0, got {weight}")
    origin, step, shape = make_grid(bounds_xyz_um, spacing_xyz_um)
    b = interpolation_matrix(x, origin, step, shape, "linear")
    lap = second_difference_operator(shape)
    p, g = b.shape
    r = max(lap.shape[0], 1)
    btb = (b.T @ b) / p
    btd = np.asarray(b.T @ u) / p
    ltl = (lap.T @ lap) * (weight / r)
    ridge = 1e-10 * max(float(btb.diagonal().mean()), 1e-30)
    eye = sp.identity(g, format="csc")
    info: dict = {"method": method, "nodes": g}
    if method == "gridded":
        vals = _solve_spd((btb + ltl + ridge * eye).tocsr(), btd, info)
    else:
        if admm_rho is None:
            d_data = float(btb.diagonal().mean())
            d_smooth = float(ltl.diagonal().mean()) if ltl.nnz else 0.0
            rho = np.sqrt(d_data * d_smooth) if d_smooth > 0 else d_data
        else:
            rho = float(admm_rho)
        if not rho > 0:
            raise InputError(f"admm_rho must be > 0, got {admm_rho}")
        solve_g = _factorize_spd(btb + rho * eye)
        solve_z = _factorize_spd(ltl + (rho + ridge) * eye)
        zv = np.zeros((g, 3))
        wv = np.zeros((g, 3))
        converged = False
        it = 0
        for it in range(1, admm_max_iter + 1):
            info["iterations"] = it
            gv = solve_g(btd + rho * (zv - wv))
            z_old = zv
            zv = solve_z(rho * (gv + wv))
            wv = wv + gv - zv
            scale = max(np.linalg.norm(zv), np.linalg.norm(gv), 1e-30)
            primal = np.linalg.norm(gv - zv) / scale
            dual = np.linalg.norm(zv - z_old) / scale
            if primal < admm_tol and dual < admm_tol:
                converged = True
                break
        if not converged:
            logger.warning("ADMM stopped after %d iterations without converging", it)
        info["converged"] = converged
        vals = zv
    return GridDisplacement(
        origin_xyz_um=origin,
        spacing_xyz_um=step,
        values_um=vals.reshape(*shape, 3),
        extrapolation=extrapolation,
        info=info,
    )


@dataclass(frozen=True)
class LocalPrediction:
    """Local polynomial regression of scattered values at query points.

    Attributes
    ----------
    values_um : ndarray, shape (Q, 3)
        Predicted value (e.g. displacement) at each query point, µm.
    misfit_um : ndarray, shape (Q, 3)
        Weighted RMS per component of the neighbours' values about the local fit, corrected
        for the degrees of freedom, µm (how well the local polynomial describes the
        neighbourhood); inf where too few neighbours were found to tell.
    n_neighbors : ndarray of int, shape (Q,)
        Neighbours used (within the radius, the excluded point left out).
    degree : ndarray of int, shape (Q,)
        Degree of the polynomial fitted at each query point (0 where no neighbour).
    """

    values_um: np.ndarray
    misfit_um: np.ndarray
    n_neighbors: np.ndarray
    degree: np.ndarray


def _monomials(dx: np.ndarray, degree: int) -> np.ndarray:
    """Columns 1, x, y, z (and x², y², z², xy, xz, yz) of offsets ``dx`` (..., 3)."""
    cols = [np.ones(dx.shape[:-1]), dx[..., 0], dx[..., 1], dx[..., 2]]
    if degree == 2:
        cols += [dx[..., 0] ** 2, dx[..., 1] ** 2, dx[..., 2] ** 2]
        cols += [dx[..., 0] * dx[..., 1], dx[..., 0] * dx[..., 2], dx[..., 1] * dx[..., 2]]
    return np.stack(cols, axis=-1)


def _weighted_poly_fit(w, dx, vals, degree, ridge):
    """Batched weighted least squares; returns (value at 0 (Q, 3), misfit (Q, 3))."""
    design = _monomials(dx, degree)  # (Q, k, p)
    p = design.shape[-1]
    wdt = (design * w[:, :, None]).transpose(0, 2, 1)  # (Q, p, k)
    normal = wdt @ design  # (Q, p, p)
    rhs = wdt @ vals  # (Q, p, 3)
    sw = normal[:, 0, 0].copy()
    none = sw <= 0
    idx = np.arange(1, p)
    normal[:, idx, idx] += (ridge * sw)[:, None]
    normal[:, 0, 0] += 1e-12 * sw
    normal[none] = np.eye(p)
    rhs[none] = 0.0
    coef = np.linalg.solve(normal, rhs)  # (Q, p, 3)
    res = vals - design @ coef
    res2 = np.einsum("qk,qkc->qc", w, res * res)
    # Effective neighbour count (Kish) and a degrees-of-freedom correction: p or fewer
    # neighbours fit the polynomial exactly, so their misfit says nothing (inf).
    k_eff = sw**2 / np.maximum(np.einsum("qk,qk->q", w, w), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(k_eff > p + 0.5, k_eff / (k_eff - p), np.inf)
        misfit = np.sqrt(res2 / np.where(none, 1.0, sw)[:, None] * dof[:, None])
    misfit[none] = np.inf
    return coef[:, 0, :], misfit


def local_polynomial_predict(
    points_um,
    values_um,
    query_um,
    n_neighbors: int = 12,
    radius_um: float = np.inf,
    *,
    scale_um: float | None = None,
    exclude=None,
    ridge: float = 0.01,
    degree: int = 1,
    min_quadratic: int = 16,
) -> LocalPrediction:
    """Moving-least-squares polynomial fit of scattered values around each query point.

    For query point ``q`` the ``n_neighbors`` nearest ``points_um`` within ``radius_um``
    (minus ``exclude[q]``, e.g. ``q`` itself for a leave-one-out prediction) are weighted by
    ``exp(−d² / (2 h²))`` with ``h = scale_um`` and fitted by an affine (``degree=1``) or
    quadratic (``degree=2``) polynomial in ``x − q``; the prediction is its constant term. A
    ridge ``ridge · Σw`` on the other coefficients (offsets in units of ``h``) keeps the fit
    defined for few or coplanar neighbours (it then tends to their weighted mean). With
    ``degree=2``, query points with fewer than ``min_quadratic`` neighbours get the affine
    fit.

    Parameters
    ----------
    points_um : array_like, shape (P, 3)
        Positions of the known values (µm).
    values_um : array_like, shape (P, 3)
        Values at those positions.
    query_um : array_like, shape (Q, 3)
        Where to predict.
    n_neighbors : int
        Neighbours per fit (≥ 1).
    radius_um : float
        Largest neighbour distance (µm, > 0).
    scale_um : float, optional
        Weight length ``h``; default the median distance to the ``n_neighbors``-th neighbour.
    exclude : array_like of int, shape (Q,), optional
        Row of ``points_um`` not to use for each query point (−1: none).
    ridge : float
        Dimensionless ridge on the non-constant coefficients (≥ 0).
    degree : {1, 2}
        Polynomial degree.
    min_quadratic : int
        Fewest neighbours of a quadratic fit (≥ 11).

    Returns
    -------
    LocalPrediction
        Query points without any neighbour get value 0 and misfit inf.

    Raises
    ------
    InputError
        Bad shapes or parameters.
    """
    x, v = _paired_points(points_um, values_um, "values_um")
    q = _as_points("query_um", query_um, allow_empty=True)
    if int(n_neighbors) < 1:
        raise InputError(f"n_neighbors must be ≥ 1, got {n_neighbors}")
    if not radius_um > 0:
        raise InputError(f"radius_um must be > 0, got {radius_um}")
    if not ridge >= 0:
        raise InputError(f"ridge must be ≥ 0, got {ridge}")
    if degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree}")
    if int(min_quadratic) < 11:
        raise InputError(f"min_quadratic must be ≥ 11, got {min_quadratic}")
    nq = q.shape[0]
    k = min(int(n_neighbors) + (exclude is not None), x.shape[0])
    d, idx = cKDTree(x).query(q, k, distance_upper_bound=radius_um)
    d, idx = d.reshape(nq, k), idx.reshape(nq, k)
    valid = np.isfinite(d)
    if exclude is not None:
        ex = np.asarray(exclude, dtype=np.int64).reshape(nq)
        valid &= idx != ex[:, None]
    valid &= np.cumsum(valid, axis=1) <= int(n_neighbors)  # the n_neighbors nearest
    safe = np.where(valid, idx, 0)
    if scale_um is None:
        far = np.max(np.where(valid, d, -np.inf), axis=1)
        far = far[np.isfinite(far) & (far > 0)]
        h = float(np.median(far)) if far.size else 1.0
    else:
        h = float(scale_um)
        if not h > 0:
            raise InputError(f"scale_um must be > 0, got {scale_um}")
    w = np.exp(-0.5 * (np.where(valid, d, 0.0) / h) ** 2)
    w[~valid] = 0.0  # (Q, k)
    dx = (x[safe] - q[:, None, :]) / h  # dimensionless offsets
    vals = v[safe]  # (Q, k, 3)
    count = valid.sum(axis=1)
    value = np.zeros((nq, 3))
    misfit = np.full((nq, 3), np.inf)
    deg = np.where(count > 0, 1, 0)
    if degree == 2:
        deg[count >= int(min_quadratic)] = 2
    for dg in (1, 2):
        sel = np.flatnonzero(deg == dg)
        if sel.size:
            value[sel], misfit[sel] = _weighted_poly_fit(w[sel], dx[sel], vals[sel], dg, ridge)
    return LocalPrediction(values_um=value, misfit_um=misfit, n_neighbors=count, degree=deg)


#: Candidate local corrections of :func:`fit_field_refined`: (scale in units of the given
#: length, polynomial degree, neighbours).
REFINE_CANDIDATES = ((1.0, 2, 20), (1.5, 2, 20), (1.0, 1, 12), (2.0, 1, 12))


@dataclass(frozen=True)
class RefinedDisplacement:
    """A global field plus, per component, a local polynomial correction of its residuals.

    ``u_c(x) = coarse_c(x) + MLS_c(x)`` where ``MLS_c`` is the moving-least-squares fit
    (:func:`local_polynomial_predict`) of the residuals ``residual_um[:, c]`` at
    ``points_um`` with the scale, degree and neighbour count chosen for component ``c``
    (no correction where ``scale_um[c]`` is nan).

    Attributes
    ----------
    coarse : callable
        ``(P, 3) µm -> (P, 3) µm`` global field (e.g. :class:`GridDisplacement`).
    points_um : ndarray, shape (K, 3)
        Where the residuals are known.
    residual_um : ndarray, shape (K, 3)
        ``displacement − coarse`` at those points.
    scale_um : ndarray, shape (3,)
        Weight length of each component's correction (nan: none).
    degree, n_neighbors : ndarray of int, shape (3,)
        Degree and neighbour count of each component's correction.
    info : dict
        How the corrections were chosen (cross-validated errors).
    """

    coarse: object
    points_um: np.ndarray
    residual_um: np.ndarray
    scale_um: np.ndarray
    degree: np.ndarray
    n_neighbors: np.ndarray
    info: dict = field(default_factory=dict, compare=False)

    def __call__(self, xyz_um) -> np.ndarray:
        """Displacement (P, 3) in µm at points ``xyz_um`` (P, 3) in µm."""
        x = _as_points("xyz_um", xyz_um, allow_empty=True)
        out = np.array(self.coarse(x), dtype=float)
        if x.shape[0] == 0:
            return out
        done = np.zeros(3, dtype=bool)
        for c in range(3):
            if done[c] or not np.isfinite(self.scale_um[c]):
                continue
            same = (
                (self.scale_um == self.scale_um[c])
                & (self.degree == self.degree[c])
                & (self.n_neighbors == self.n_neighbors[c])
            )
            lp = local_polynomial_predict(
                self.points_um,
                self.residual_um,
                x,
                int(self.n_neighbors[c]),
                3.0 * float(self.scale_um[c]),
                scale_um=float(self.scale_um[c]),
                degree=int(self.degree[c]),
            )
            out[:, same] += lp.values_um[:, same]
            done |= same
        return out


def fit_field_refined(
    coarse: GridDisplacement,
    points_um,
    displacements_um,
    *,
    length_um: float,
    candidates=REFINE_CANDIDATES,
    max_cv_points: int = 2000,
    seed: int = 0,
) -> RefinedDisplacement:
    """The smooth gridded field ``coarse`` refined locally where the data show more detail.

    ``coarse`` is the global, stiff field; for each component, the local polynomial corrections
    of its residuals in ``candidates`` are compared by leave-one-out prediction error (on at
    most ``max_cv_points`` particles) with no correction, and the best is kept. A homogeneous
    field keeps the global fit (its residuals are noise, which no correction predicts); a field
    with features finer than the grid (fronts, vortices, inclusions) gets a correction in the
    components that carry them, with the resolution that predicts best, while a noisy component
    (the axial one of light-field data) stays smooth.

    Parameters
    ----------
    coarse : GridDisplacement
        :func:`fit_field` of these matches.
    points_um, displacements_um
        As :func:`fit_field`.
    length_um : float
        Unit of the candidates' scales (µm, > 0), e.g. the mean particle spacing.
    candidates : sequence of (scale, degree, n_neighbors)
        Local corrections to try; scale in units of ``length_um``.
    max_cv_points : int
        Particles on which the leave-one-out errors are computed (a random subset).
    seed : int
        Seed of that subset.

    Returns
    -------
    RefinedDisplacement
        ``info`` holds ``cv_rms_um`` (component → {candidate: rms}) and the grid's ``info``.
    """
    x = _as_points("points_um", points_um)
    u = _as_points("displacements_um", displacements_um)
    if not (np.isfinite(length_um) and length_um > 0):
        raise InputError(f"length_um must be finite and > 0, got {length_um}")
    r = u - coarse(x)
    p = x.shape[0]
    sub = np.arange(p)
    if p > max_cv_points:
        sub = np.sort(np.random.default_rng(seed).choice(p, int(max_cv_points), replace=False))
    best_err = np.mean(r[sub] ** 2, axis=0)
    cv: dict = {c: {"none": float(np.sqrt(best_err[c]))} for c in range(3)}
    scale = np.full(3, np.nan)
    degree = np.zeros(3, dtype=np.int64)
    nnb = np.zeros(3, dtype=np.int64)
    if p >= 20:
        for sc, dg, k in candidates:
            h = float(sc) * float(length_um)
            lp = local_polynomial_predict(
                x, r, x[sub], int(k), 3.0 * h, scale_um=h, exclude=sub, degree=int(dg)
            )
            err = np.mean((r[sub] - lp.values_um) ** 2, axis=0)
            for c in range(3):
                cv[c][f"{sc}/{dg}/{k}"] = float(np.sqrt(err[c]))
                if err[c] < best_err[c]:
                    best_err[c], scale[c], degree[c], nnb[c] = err[c], h, dg, k
    info = {"coarse": coarse.info, "cv_rms_um": cv}
    logger.debug("refined field: scales %s µm, degrees %s", scale, degree)
    return RefinedDisplacement(coarse, x, r, scale, degree, nnb, info)
