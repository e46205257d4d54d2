"""Regular grids of the displacement and strain fields: how they are chosen
(:class:`GridSettings`, :func:`grid_axes`, :func:`grid_spacing_um`) and what a gridded field
holds (:class:`GridAxes`, :class:`GridField`).

Default grid: the particles' bounding box sampled with one isotropic spacing chosen so that
the grid has about ``target_nodes`` = 50 000 nodes (the paper's value).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .thin_plate import GCV_MIN_POINTS, _points

_METHODS = ("rbf", "linear")


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
        rescaled to the full particle density).
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


__all__ = ["GridAxes", "GridField", "GridSettings", "grid_axes", "grid_spacing_um"]
