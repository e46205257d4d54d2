"""Analytic heterogeneous displacement fields, defined once for the simulator and the tests.

Pure numpy. ``lfsim.motion`` prescribes them to particles (a study's known truth) and
``track.synthetic`` builds its linker test pairs with them; neither imports the other, so
the field definitions live here in the shared base. Each field is linear in its amplitude
(the indentation depth, the far-field strain), so a per-frame schedule scales it.

Reference positions ``X_um`` have shape (N, 3), columns x, y, z in µm; displacements have
the same shape (µm); gradients are ``∂u_i/∂X_j`` of shape (N, 3, 3) with ``i`` the row
(component) and ``j`` the column (docs/conventions.md).

Fields
------
Gaussian indentation
    A punch pressed into a face ``z = surface_z_um`` at ``(x, y) = center_xy_um``:
    ``u_z = −A exp(−ρ²/(2 w²)) exp(−(surface − Z)/D)``, ``u_x = u_y = 0``, with ``ρ`` the
    lateral distance from the centre, ``w`` the width and ``D`` the decay depth. ``A > 0``
    pushes towards −z (into a volume below the face, ``Z ≤ surface``).
Stiff inclusion
    A nearly rigid sphere (centre ``c``, radius ``a``) in an incompressible matrix stretched
    along one axis: ``u = (1 − φ(r)) ε M (X − c)`` with ``M = ê êᵀ − ½ (I − ê êᵀ)`` (``ê`` the
    stretch axis, trace 0), ``φ = 1 − δ`` inside (strain ``δ ε`` in the sphere) and
    ``(1 − δ)(a/r)³`` outside: continuous, the far-field stretch ``ε`` far away and a strain
    concentration of about ``3 ε`` at the interface (an Eshelby-like ``(a/r)³`` perturbation,
    a kinematic field, not an elastic solution).
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = [
    "inclusion_displacement",
    "inclusion_gradient",
    "indentation_displacement",
    "indentation_gradient",
]

_AXES = {"x": 0, "y": 1, "z": 2}


def _points(X_um) -> np.ndarray:
    X = np.asarray(X_um, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"X_um must have shape (N, 3) (x, y, z in µm), got {X.shape}")
    return X


def _axis_index(axis) -> int:
    if isinstance(axis, str) and axis in _AXES:
        return _AXES[axis]
    if isinstance(axis, int | np.integer) and not isinstance(axis, bool) and 0 <= axis < 3:
        return int(axis)
    raise InputError(f"axis must be 'x', 'y', 'z' or 0, 1, 2, got {axis!r}")


# -- Gaussian indentation ----------------------------------------------------------------------
def _indentation_uz(X, depth_um, center_xy_um, surface_z_um, width_um, decay_um) -> np.ndarray:
    c = np.asarray(center_xy_um, dtype=np.float64).reshape(2)
    rho2 = np.sum((X[:, :2] - c) ** 2, axis=1)
    return -depth_um * np.exp(-rho2 / (2.0 * width_um**2) - (surface_z_um - X[:, 2]) / decay_um)


def indentation_displacement(
    X_um, depth_um: float, center_xy_um, surface_z_um: float, width_um: float, decay_um: float
) -> np.ndarray:
    """Displacement of the Gaussian indentation (module docstring).

    Parameters
    ----------
    X_um : array_like, shape (N, 3)
        Reference positions (x, y, z), µm.
    depth_um : float
        Indentation depth ``A`` at the punch centre on the face, µm (> 0: towards −z).
    center_xy_um : array_like, shape (2,)
        Punch centre (x, y), µm.
    surface_z_um : float
        z of the indented face, µm.
    width_um, decay_um : float
        Lateral width ``w`` (standard deviation) and decay depth ``D`` into the volume, µm.

    Returns
    -------
    numpy.ndarray, shape (N, 3)
        ``u`` in µm (only ``u_z`` is non-zero).
    """
    X = _points(X_um)
    u = np.zeros_like(X)
    u[:, 2] = _indentation_uz(X, depth_um, center_xy_um, surface_z_um, width_um, decay_um)
    return u


def indentation_gradient(
    X_um, depth_um: float, center_xy_um, surface_z_um: float, width_um: float, decay_um: float
) -> np.ndarray:
    """``∂u_i/∂X_j`` (N, 3, 3) of :func:`indentation_displacement` (same parameters)."""
    X = _points(X_um)
    c = np.asarray(center_xy_um, dtype=np.float64).reshape(2)
    uz = _indentation_uz(X, depth_um, c, surface_z_um, width_um, decay_um)
    out = np.zeros((X.shape[0], 3, 3))
    out[:, 2, 0] = -uz * (X[:, 0] - c[0]) / width_um**2
    out[:, 2, 1] = -uz * (X[:, 1] - c[1]) / width_um**2
    out[:, 2, 2] = uz / decay_um
    return out


# -- stiff inclusion ---------------------------------------------------------------------------
def _inclusion_parts(X, strain, center_xyz_um, radius_um, inner_fraction, axis):
    d = X - np.asarray(center_xyz_um, dtype=np.float64).reshape(3)
    r = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    m = np.full(3, -0.5)
    m[_axis_index(axis)] = 1.0
    e = strain * m  # the far-field strain's diagonal
    ed = d * e
    k = 1.0 - inner_fraction
    outside = r >= radius_um
    ro = np.maximum(r, radius_um)
    phi = np.where(outside, k * (radius_um / ro) ** 3, k)
    dphi = np.where(outside, -3.0 * k * radius_um**3 / ro**4, 0.0)
    return d, r, e, ed, phi, dphi


def inclusion_displacement(
    X_um,
    strain: float,
    center_xyz_um,
    radius_um: float,
    inner_fraction: float = 0.05,
    axis="x",
) -> np.ndarray:
    """Displacement of the stiff inclusion in a stretched matrix (module docstring).

    Parameters
    ----------
    X_um : array_like, shape (N, 3)
        Reference positions (x, y, z), µm.
    strain : float
        Far-field engineering strain ``ε`` along ``axis`` (``−ε/2`` across).
    center_xyz_um : array_like, shape (3,)
        Centre of the sphere (x, y, z), µm.
    radius_um : float
        Radius ``a`` of the sphere, µm.
    inner_fraction : float
        ``δ``: the strain inside the sphere as a fraction of the far field (0: rigid).
    axis : {"x", "y", "z"} or {0, 1, 2}
        Stretch axis.

    Returns
    -------
    numpy.ndarray, shape (N, 3)
        ``u`` in µm.
    """
    X = _points(X_um)
    _, _, _, ed, phi, _ = _inclusion_parts(
        X, strain, center_xyz_um, radius_um, inner_fraction, axis
    )
    return (1.0 - phi)[:, None] * ed


def inclusion_gradient(
    X_um,
    strain: float,
    center_xyz_um,
    radius_um: float,
    inner_fraction: float = 0.05,
    axis="x",
) -> np.ndarray:
    """``∂u_i/∂X_j`` (N, 3, 3) of :func:`inclusion_displacement` (same parameters)."""
    X = _points(X_um)
    d, r, e, ed, phi, dphi = _inclusion_parts(
        X, strain, center_xyz_um, radius_um, inner_fraction, axis
    )
    out = (1.0 - phi)[:, None, None] * np.diag(e)[None]
    out -= (dphi / r)[:, None, None] * ed[:, :, None] * d[:, None, :]
    return out
