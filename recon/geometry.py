"""The reconstruction grid: depths, lateral voxels and their relation to the lenslet array.

Volumes live on a grid tied to the (rectified) lenslet array: every lenslet's object-space
footprint ``p / M`` (25 µm for the paper's optics) is split into ``s × s`` voxels
(super-resolution factor ``s``), and the depth planes are ``depths_um``. Voxel ``(k, j, i)`` of
a volume ``(z, y, x)`` sits at depth ``depths_um[k]`` under lenslet ``(i // s, j // s)`` at
sub-position ``(i % s, j % s)``. Its object-space centre is

``x = x0 + (i + 0.5) · p / (M s)``, ``y = y0 + (j + 0.5) · p / (M s)``

where ``(x0, y0)`` is the object-space corner of lenslet ``(0, 0)``; for lfsim scenes, whose
optical axis passes through a lenslet centre, this puts the central voxel of that lenslet
(odd ``s``) exactly on the axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class ReconGrid:
    """Geometry of a reconstructed volume.

    Parameters
    ----------
    lenslet_object_um : float
        Lenslet pitch referred to object space, ``p / M`` (µm).
    depths_um : tuple of float
        Depth of every plane (µm, z away from the objective), increasing.
    s : int
        Voxels per lenslet along x and y (super-resolution factor).
    n_lenslets_xy : tuple of int
        ``(nx, ny)`` lenslets of the rectified image.
    origin_xy_um : tuple of float
        Object-space ``(x, y)`` of the corner of lenslet ``(0, 0)`` (µm).
    """

    lenslet_object_um: float
    depths_um: tuple
    s: int
    n_lenslets_xy: tuple
    origin_xy_um: tuple = (0.0, 0.0)

    def __post_init__(self) -> None:
        if not (self.lenslet_object_um > 0 and math.isfinite(self.lenslet_object_um)):
            raise InputError(f"lenslet_object_um must be > 0, got {self.lenslet_object_um!r}")
        d = np.asarray(self.depths_um, dtype=np.float64)
        if d.ndim != 1 or d.size < 1 or not np.all(np.isfinite(d)):
            raise InputError("depths_um must be a non-empty list of finite depths (µm)")
        if d.size > 1 and np.any(np.diff(d) <= 0):
            raise InputError("depths_um must be strictly increasing")
        object.__setattr__(self, "depths_um", tuple(float(v) for v in d))
        if int(self.s) != self.s or self.s < 1:
            raise InputError(
                f"super-resolution factor s must be a positive integer, got {self.s!r}"
            )
        object.__setattr__(self, "s", int(self.s))
        nl = tuple(int(v) for v in self.n_lenslets_xy)
        if len(nl) != 2 or min(nl) < 1:
            raise InputError(
                f"n_lenslets_xy must be two positive integers, got {self.n_lenslets_xy!r}"
            )
        object.__setattr__(self, "n_lenslets_xy", nl)
        object.__setattr__(self, "origin_xy_um", tuple(float(v) for v in self.origin_xy_um))

    @property
    def voxel_um(self) -> float:
        """Lateral voxel size ``p / (M s)`` (µm)."""
        return self.lenslet_object_um / self.s

    @property
    def z_step_um(self) -> float:
        """Depth spacing (µm); the mean spacing if the planes are not uniform."""
        d = self.depths_um
        return float((d[-1] - d[0]) / (len(d) - 1)) if len(d) > 1 else 0.0

    @property
    def shape(self) -> tuple[int, int, int]:
        """Volume shape ``(nz, ny, nx)``."""
        nx, ny = self.n_lenslets_xy
        return (len(self.depths_um), ny * self.s, nx * self.s)

    @property
    def voxel_size_um(self) -> tuple[float, float, float]:
        """``(dz, dy, dx)`` in µm."""
        return (self.z_step_um, self.voxel_um, self.voxel_um)

    def x_um(self) -> np.ndarray:
        """Object-space x of every voxel column, shape ``(nx·s,)``."""
        return self.origin_xy_um[0] + (np.arange(self.shape[2]) + 0.5) * self.voxel_um

    def y_um(self) -> np.ndarray:
        """Object-space y of every voxel row, shape ``(ny·s,)``."""
        return self.origin_xy_um[1] + (np.arange(self.shape[1]) + 0.5) * self.voxel_um

    def to_um(self, zyx_index: np.ndarray) -> np.ndarray:
        """Fractional voxel indices ``(N, 3)`` (z, y, x) → positions ``(N, 3)`` (x, y, z) in µm."""
        idx = np.asarray(zyx_index, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(self.depths_um)
        z = np.interp(idx[:, 0], np.arange(len(d)), d) if len(d) > 1 else np.full(len(idx), d[0])
        x = self.origin_xy_um[0] + (idx[:, 2] + 0.5) * self.voxel_um
        y = self.origin_xy_um[1] + (idx[:, 1] + 0.5) * self.voxel_um
        return np.c_[x, y, z]

    def to_dict(self) -> dict:
        return {
            "lenslet_object_um": self.lenslet_object_um,
            "depths_um": list(self.depths_um),
            "s": self.s,
            "n_lenslets_xy": list(self.n_lenslets_xy),
            "origin_xy_um": list(self.origin_xy_um),
        }


def depth_range(z_min_um: float, z_max_um: float, z_step_um: float) -> np.ndarray:
    """Depths ``z_min, z_min + step, ..., z_max`` (µm), inclusive of ``z_max`` when on the grid."""
    if not z_step_um > 0:
        raise InputError(f"z step must be > 0 µm, got {z_step_um!r}")
    if not z_max_um >= z_min_um:
        raise InputError(f"z range must satisfy z_min <= z_max, got {z_min_um}:{z_max_um}")
    n = math.floor((z_max_um - z_min_um) / z_step_um + 1e-9) + 1
    return z_min_um + z_step_um * np.arange(n)
