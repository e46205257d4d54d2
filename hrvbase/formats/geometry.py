"""Where the voxels of a volume lie: the one volume-geometry type of the toolkit."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class VolumeGeometry:
    """Where the voxels of a volume (or of every volume of a series) lie.

    ``recon`` writes its volumes with one geometry (:mod:`recon.volume_store`); the volume
    readers give every volume they find its geometry (:class:`hrvbase.formats.VolumeInfo`
    derives from this class).

    Attributes
    ----------
    shape : tuple of int
        ``(nz, ny, nx)``.
    voxel_size_um : tuple of float
        ``(dz, dy, dx)`` (µm).
    origin_xyz_um : tuple of float
        Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm).
    """

    shape: tuple
    voxel_size_um: tuple
    origin_xyz_um: tuple


__all__ = ["VolumeGeometry"]
