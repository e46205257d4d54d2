"""Regular grids of the displacement and strain fields: how they are chosen
(:class:`GridSettings`, :func:`grid_axes`, :func:`grid_spacing_um`) and what a gridded field
holds (:class:`GridAxes`, :class:`GridField`).

Default grid: the particles' bounding box sampled with one isotropic spacing that follows the
particle density, the particles' median nearest-neighbour distance over
``nodes_per_spacing`` = 2 (:func:`grid_spacing_um`). Giving ``target_nodes`` (e.g. the paper's
50 000) instead samples the box with about that many nodes, whatever the particles; giving
``spacing_um`` fixes the spacing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .thin_plate import GCV_MIN_POINTS, _points

_METHODS = ("rbf", "linear")

#: Nodes of the bounding-box grid (:func:`grid_axes` without a spacing) when
#: ``GridSettings.target_nodes`` is not given (the paper's value); the limits of the other
#: grids are multiples of it.
BOX_GRID_NODES = 50_000
#: Most nodes of the particle-density grid: its spacing is made no finer than the one giving
#: this many over the particles' bounding box.
PARTICLE_GRID_MAX_NODES = 10 * BOX_GRID_NODES


@dataclass(frozen=True)
class GridSettings:
    """How scattered displacements are gridded.

    Attributes
    ----------
    spacing_um : float, optional
        Node spacing (µm, all three axes). Default: the particle-density spacing
        (``nodes_per_spacing``), or the ``target_nodes`` grid when that is given.
    target_nodes : int, optional
        Sample the particles' bounding box with about this many nodes (the paper: 50 000)
        instead of following the particle density. Ignored when ``spacing_um`` is given.
        Also scales the limit of an explicit ``spacing_um``
        (:func:`track.series.check_grid`: at most 10 × this, default
        :data:`BOX_GRID_NODES`).
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
    nodes_per_spacing : float
        The default grid follows the particle density: node spacing = the particles' median
        nearest-neighbour distance / ``nodes_per_spacing`` (default 2; at most
        :data:`PARTICLE_GRID_MAX_NODES` nodes). 2 resolves everything the particles sample
        (a field's features are at least a particle spacing wide): the strains at the nodes
        are those of a finer grid (the spline does not depend on the nodes; its accuracy on
        both grids: benchmarks/README.md, ``bench_fields.py``), with far fewer nodes than
        50 000 for a few hundred particles and more for tens of thousands. Ignored when
        ``spacing_um`` or ``target_nodes`` is given.
    uncertainty : bool
        Give the fields standard uncertainties (:attr:`GridField.u_std`, ``F_std``,
        ``e_std``; global thin-plate spline only, see :meth:`DisplacementInterpolant.std`).
    """

    spacing_um: float | None = None
    target_nodes: int | None = None
    method: str = "rbf"
    smoothing: float | str = "gcv"
    rbf_max_points: int = 2000
    rbf_neighbours: int = 64
    gcv_max_points: int = 1000
    support_radius_um: float | None = None
    nodes_per_spacing: float = 2.0
    uncertainty: bool = True

    def __post_init__(self) -> None:
        if self.spacing_um is not None and not (
            math.isfinite(self.spacing_um) and self.spacing_um > 0
        ):
            raise InputError(f"spacing_um must be positive and finite, got {self.spacing_um!r}")
        if self.target_nodes is not None and int(self.target_nodes) < 8:
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
        if not (
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
    target_nodes: int | None = None,
) -> GridAxes:
    """Regular grid over the bounding box of ``points_um``.

    Parameters
    ----------
    points_um : ndarray, shape (N, 3)
        Positions (µm), x, y, z.
    spacing_um : float, optional
        Node spacing; default ``(volume / target_nodes)^(1/3)`` of the bounding box.
    target_nodes : int, optional
        Approximate node count when ``spacing_um`` is None (default :data:`BOX_GRID_NODES`).

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
        nodes = BOX_GRID_NODES if target_nodes is None else int(target_nodes)
        spacing_um = float(np.prod(ext) / float(nodes)) ** (1.0 / 3.0)
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
    """Node spacing (µm) the settings ask for over ``points_um`` (N, 3); None: the
    ``target_nodes`` grid of :func:`grid_axes`.

    ``settings.spacing_um`` when given; else None when ``settings.target_nodes`` is given;
    else (the default) the particles' median nearest-neighbour distance divided by
    ``settings.nodes_per_spacing``, but no finer than the spacing giving
    :data:`PARTICLE_GRID_MAX_NODES` nodes over their bounding box.
    """
    if settings.spacing_um is not None:
        return float(settings.spacing_um)
    if settings.target_nodes is not None:
        return None
    from scipy.spatial import cKDTree

    p = _points(points_um, "points_um")
    if p.shape[0] < 2:
        raise InputError(f"a grid needs at least 2 particles, got {p.shape[0]}")
    d, _ = cKDTree(p).query(p, k=2)
    h = float(np.median(d[:, 1])) / float(settings.nodes_per_spacing)
    ext = np.ptp(p, axis=0)
    if np.all(ext > 0):
        h = max(h, float(np.prod(ext) / float(PARTICLE_GRID_MAX_NODES)) ** (1.0 / 3.0))
    return h if h > 0 else None


__all__ = [
    "BOX_GRID_NODES",
    "PARTICLE_GRID_MAX_NODES",
    "GridAxes",
    "GridField",
    "GridSettings",
    "grid_axes",
    "grid_spacing_um",
]
