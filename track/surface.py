"""Particles in front of a specimen's near surface.

Where a specimen's near surface (``lfsim.optics.Optics.surface_z_um``, recorded by ``recon
run`` as ``surface_z_um``) cuts the reconstructed depth range, the planes in front of it are
guard planes (``recon.settings``, docs/conventions.md §2): they give the reconstruction of a
particle at the surface room, but nothing emits there. A particle found there is an artefact,
unless it lies at the surface and the reconstruction put it a little in front: within one
depth step it is kept.
"""

from __future__ import annotations

import dataclasses

import numpy as np


def beyond_surface(located, spacing, origin, surface_z_um: float | None, report: dict):
    """The localised particles no more than one depth step in front of the surface.

    Parameters
    ----------
    located : dataclass
        Localised particles: ``pos_vox`` ``(N, 3)`` voxel positions ``(z, y, x)`` and other
        per-particle arrays of ``N`` rows (all are selected alike).
    spacing : sequence of 3 float
        ``(dz, dy, dx)`` (µm).
    origin : sequence of 3 float
        ``(x0, y0, z0)``: position (µm) of the centre of voxel ``(0, 0, 0)``.
    surface_z_um : float or None
        Object ``z`` (µm) of the specimen's near surface; None: no surface, all kept.
    report : dict
        Receives ``surface_z_um`` and ``rejections["in_front_of_surface"]`` (the count).

    Returns
    -------
    The particles with ``z >= surface_z_um - dz``, of the type of ``located``.
    """
    if surface_z_um is None:
        return located
    report["surface_z_um"] = surface_z_um
    z_um = origin[2] + located.pos_vox[:, 0] * spacing[0]
    keep = z_um >= surface_z_um - spacing[0]
    report["rejections"]["in_front_of_surface"] = int(np.count_nonzero(~keep))
    n = len(keep)
    return dataclasses.replace(
        located,
        **{
            f.name: getattr(located, f.name)[keep]
            for f in dataclasses.fields(located)
            if isinstance(getattr(located, f.name), np.ndarray)
            and len(getattr(located, f.name)) == n
        },
    )
