"""Geometry of a real glass microlens array: one spherical-cap lenslet as a triangle mesh.

The array in a scene is one mesh of such caps (:func:`lenslet_array_mesh`), in front of a flat
glass back. It is generated from pitch, focal length and index when a scene is written or
loaded (:func:`lfsim.scene.ensure_mesh`), never committed. One mesh rather than Mitsuba
instances: a scene with thousands of instances makes every BSDF call a virtual call over
thousands of shapes, which LLVM cannot compile in reasonable time.

A lenslet is the spherical cap ``z(x, y) = R − sqrt(R² − x² − y²)`` (vertex at ``z = 0``,
surface bending away from the incoming light towards +z) over the square ``|x|, |y| ≤ p/2``.
Neighbouring caps meet at the square's edges at equal height, so the array surface is
continuous. Vertex normals are the analytic sphere normals (pointing to −z, into the air), so
Mitsuba's ``dielectric`` BSDF refracts with the exact surface orientation whatever the facet
size. The sphere normal's x and y components are linear in x and y, so the linear interpolation
of vertex normals is exact in them; with 8 facets per side the chord (sag) error is below
0.05 µm for the paper's lenslets, far below the wavelength.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from hrvbase.io import atomic_write_bytes

from .errors import ConfigError


def lenslet_cap_mesh(
    pitch: float, radius: float, n_facets: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate one square spherical-cap lenslet.

    Parameters
    ----------
    pitch : float
        Lenslet pitch (side of the square aperture), in the scene's length unit.
    radius : float
        Radius of curvature, same unit; must exceed ``pitch / sqrt(2)``.
    n_facets : int
        Quads per side.

    Returns
    -------
    vertices : ndarray, shape (V, 3), float32
    normals : ndarray, shape (V, 3), float32
        Unit normals pointing to −z (out of the glass, towards the incoming light).
    faces : ndarray, shape (F, 3), uint32
        Counter-clockwise seen from −z, so geometric normals also point to −z.
    """
    if radius <= pitch / np.sqrt(2.0):
        raise ConfigError(f"lenslet radius {radius} too small for pitch {pitch}")
    if n_facets < 2:
        raise ConfigError(f"n_facets must be >= 2, got {n_facets}")
    t = np.linspace(-pitch / 2, pitch / 2, n_facets + 1)
    x, y = np.meshgrid(t, t, indexing="xy")
    rr = x * x + y * y
    z = radius - np.sqrt(radius * radius - rr)
    # Outward normal of the sphere centred at (0, 0, R): (x, y, z - R) / R, pointing to -z.
    n = np.stack([x, y, z - radius], axis=-1) / radius
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    norms = n.reshape(-1, 3)
    m = n_facets + 1
    i, j = np.meshgrid(np.arange(n_facets), np.arange(n_facets), indexing="xy")
    v00 = (j * m + i).ravel()
    v10 = v00 + 1
    v01 = v00 + m
    v11 = v01 + 1
    # (v00, v01, v10): edge a = +y, edge b = +x, a × b = -z -> normal to -z.
    faces = np.concatenate(
        [np.stack([v00, v01, v10], 1), np.stack([v10, v01, v11], 1)], axis=0
    ).astype(np.uint32)
    return verts.astype(np.float32), norms.astype(np.float32), faces


def lenslet_array_mesh(
    centers: np.ndarray, pitch: float, radius: float, n_facets: int = 8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh of many caps: :func:`lenslet_cap_mesh` translated to each of ``centers`` (K, 2).

    Vertices are not shared between lenslets (normals differ at the seams).
    """
    v, n, f = lenslet_cap_mesh(pitch, radius, n_facets)
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 2)
    k = len(centers)
    shift = np.zeros((k, 1, 3))
    shift[:, 0, :2] = centers
    verts = (v[None].astype(np.float64) + shift).reshape(-1, 3).astype(np.float32)
    norms = np.broadcast_to(n[None], (k, *n.shape)).reshape(-1, 3)
    faces = (f[None].astype(np.int64) + (np.arange(k) * len(v))[:, None, None]).reshape(-1, 3)
    if faces.max(initial=0) >= 2**32:
        raise ConfigError("lenslet array mesh too large")
    return verts, norms.astype(np.float32), faces.astype(np.uint32)


def write_ply(path: str | os.PathLike, vertices: np.ndarray, normals: np.ndarray, faces) -> None:
    """Write a binary little-endian PLY with positions, normals and triangles (atomically)."""
    path = Path(path)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(vertices)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        f"element face {len(faces)}\n"
        "property list uchar uint vertex_indices\nend_header\n"
    ).encode("ascii")
    vdata = np.concatenate([vertices, normals], axis=1).astype("<f4").tobytes()
    fdt = np.dtype([("n", "u1"), ("idx", "<u4", (3,))])
    frec = np.empty(len(faces), dtype=fdt)
    frec["n"] = 3
    frec["idx"] = faces
    atomic_write_bytes(path, header + vdata + frec.tobytes(), overwrite=True)
