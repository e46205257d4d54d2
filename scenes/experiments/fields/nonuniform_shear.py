"""Displacement fields of the heterogeneous validation study (``shear_nonuniform*.toml``).

Used through lfsim's ``user_field`` motion: ``f(X_um, frame, **params) -> u_um``, with
``X_um`` of shape (N, 3) (x, y, z in µm, reference configuration) and ``u_um`` the same shape.
"""

from __future__ import annotations

import numpy as np


def nonuniform_shear(
    X_um: np.ndarray,
    frame: int,
    gamma_step: float = 0.025,
    width_um: float = 1100.0,
    z0_um: float = 250.0,
) -> np.ndarray:
    """Simple shear of the z-faces along x whose amount varies across y.

    ``u_x = γ(y) (Z − z0)`` with ``γ(y) = frame · gamma_step · cos(π Y / width_um)``: the full
    shear at ``Y = 0``, none at ``Y = ±width_um / 2``. Besides ``E_xz ≈ γ(y) / 2`` the field has
    a shear ``E_xy = −(π / 2 width_um) frame · gamma_step · (Z − z0) sin(π Y / width_um)``
    that changes sign across the volume — a field no affine fit reproduces.
    """
    X = np.asarray(X_um, dtype=float)
    gamma = frame * gamma_step * np.cos(np.pi * X[:, 1] / width_um)
    u = np.zeros_like(X)
    u[:, 0] = gamma * (X[:, 2] - z0_um)
    return u
