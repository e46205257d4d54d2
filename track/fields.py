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

The grids and their settings are in :mod:`track.grid` (re-exported here); the thin-plate
spline's basis and GCV in :mod:`track.thin_plate`, its evaluation and uncertainties in
:mod:`track.thin_plate_fit`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .grid import GridAxes, GridField, GridSettings, grid_axes, grid_spacing_um
from .strain import green_lagrange, infinitesimal
from .thin_plate import (
    GCV_AFFINE_RTOL,
    GCV_MIN_POINTS,
    _gcv_choose,
    _points,
    _ThinPlateBasis,
    gcv_smoothing,
)
from .thin_plate import _tps_kernel as _tps_kernel  # re-exported (tests)
from .thin_plate_fit import (
    STD_GRID_MODE_CUTOFF,
    STD_GRID_SUB_SPACING,
    STD_MODE_CUTOFF,
    _ThinPlateFit,
)
from .thin_plate_fit import _sub_indices as _sub_indices  # re-exported (tests)

log = logging.getLogger(__name__)


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
        (``sigma_xyz_um`` of :func:`fit_displacement`, else the noise level GCV's residuals
        imply, ``RSS / tr((I − A)²)``, per axis); the same through ``∂/∂x_j`` for the gradient.
        Axes and particles are taken as independent.

        Returns
        -------
        u_std : ndarray, shape (P, 3)
            µm. NaN for an axis whose noise is unknown (``smoothing=0`` without
            ``sigma_xyz_um``).
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
    sigma_xyz_um: np.ndarray | None = None,
) -> DisplacementInterpolant:
    """Fit a continuous displacement field to scattered particle displacements.

    Parameters
    ----------
    positions_um : ndarray, shape (N, 3)
        Particle positions in the configuration the field is defined on (µm).
    displacement_um : ndarray, shape (N, 3)
        Their displacements (µm).
    settings : GridSettings, optional
    sigma_xyz_um : ndarray, shape (N, 3), optional
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
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    settings = settings or GridSettings()
    X, U, sig = _fit_inputs(positions_um, displacement_um, sigma_xyz_um)
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
        lam, tps, fn = _fit_rbf(X, U, sig, settings)
    else:
        fn = _linear_interpolant(X, U, hull)
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


def _fit_inputs(positions_um, displacement_um, sigma_xyz_um):
    """:func:`fit_displacement`'s positions (N, 3), displacements (N, 3) and σ ((N, 3) or
    None), checked."""
    X = _points(positions_um, "positions_um")
    U = _points(displacement_um, "displacement_um")
    if U.shape != X.shape:
        raise InputError(f"displacement_um has shape {U.shape}, positions_um has {X.shape}")
    if X.shape[0] < 4:
        raise InputError(f"a displacement field needs at least 4 particles, got {X.shape[0]}")
    sig = None
    if sigma_xyz_um is not None:
        sig = np.asarray(sigma_xyz_um, dtype=float)
        if sig.shape != X.shape or not np.all(np.isfinite(sig)) or np.any(sig < 0):
            raise InputError(
                f"sigma_xyz_um must be finite, >= 0 and of shape {X.shape} (x, y, z µm per "
                f"particle), got shape {sig.shape}"
            )
    return X, U, sig


def _fit_rbf(X, U, sig, settings: GridSettings):
    """λ (3,) and the global thin-plate spline (:class:`_ThinPlateFit`, up to
    ``rbf_max_points`` particles) or the local RBF's function: ``(lam, tps, fn)``, one of
    ``tps`` and ``fn`` None."""
    lam = np.zeros(3)
    tps = fn = None
    n = X.shape[0]
    basis = None
    if n <= settings.rbf_max_points:
        try:
            basis = _ThinPlateBasis(X)
        except np.linalg.LinAlgError as exc:
            raise InputError(f"cannot fit a displacement field to {n} particles: {exc}") from exc
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
    return lam, tps, fn


def _linear_interpolant(X, U, hull):
    """``method="linear"``: piecewise linear on the Delaunay triangulation inside the hull,
    the nearest particle's value outside it."""
    from scipy.spatial import Delaunay, QhullError, cKDTree

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

    return fn


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
    sigma_xyz_um: np.ndarray | None = None,
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
    sigma_xyz_um : ndarray, shape (N, 3), optional
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
    interp = fit_displacement(positions_um, displacement_um, settings, sigma_xyz_um=sigma_xyz_um)
    return field_on_grid(interp, axes)


__all__ = [
    "GCV_AFFINE_RTOL",
    "GCV_MIN_POINTS",
    "STD_GRID_MODE_CUTOFF",
    "STD_GRID_SUB_SPACING",
    "STD_MODE_CUTOFF",
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
