"""CSV tables of :mod:`track`: particle positions, matches between two frames, tracks.

Thin wrappers over :mod:`hrvbase.tables`: every writer is **atomic** and refuses to replace
an existing file unless ``overwrite=True``; readers name the file and line of a bad value.

Formats (lengths in µm, docs/conventions.md §6.4):

- ``particles/NNNNNN.csv``: ``x_um,y_um,z_um[,intensity]``;
- ``matches_NNNNNN.csv``: ``row_ref,row_def,ux_um,uy_um,uz_um`` (0-based rows into the two
  frames' particle tables);
- ``tracks.csv``: ``frame,track_id,x_um,y_um,z_um``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hrvbase.tables import read_table, write_table

from .errors import InputError

POINT_COLUMNS = ("x_um", "y_um", "z_um")
MATCH_COLUMNS = ("row_ref", "row_def", "ux_um", "uy_um", "uz_um")
TRACK_COLUMNS = ("frame", "track_id", "x_um", "y_um", "z_um")


def _write_table(path, header: Sequence[str], columns: Sequence[np.ndarray], overwrite) -> Path:
    return write_table(path, dict(zip(header, columns, strict=True)), overwrite=overwrite)


def _read_table(path, required: Sequence[str], integer: Sequence[str] = ()) -> dict:
    """Columns ``required`` of a CSV file (others ignored); errors name the file and line."""
    return read_table(path, required=required, integer=integer)


def write_points_csv(
    path: str | os.PathLike,
    xyz_um: np.ndarray,
    intensity: np.ndarray | None = None,
    *,
    overwrite: bool = False,
) -> Path:
    """Write a particle table ``x_um,y_um,z_um[,intensity]``.

    Parameters
    ----------
    xyz_um : ndarray, shape (N, 3)
        Positions (µm), x, y, z.
    intensity : ndarray, shape (N,), optional
    """
    xyz = np.asarray(xyz_um, dtype=float).reshape(-1, 3)
    cols = [xyz[:, 0], xyz[:, 1], xyz[:, 2]]
    header = list(POINT_COLUMNS)
    if intensity is not None:
        inten = np.asarray(intensity, dtype=float).reshape(-1)
        if inten.shape[0] != xyz.shape[0]:
            raise InputError(f"{path}: {inten.shape[0]} intensities for {xyz.shape[0]} particles")
        cols.append(inten)
        header.append("intensity")
    return _write_table(path, header, cols, overwrite)


def read_points_csv(path: str | os.PathLike) -> np.ndarray:
    """Read a point cloud: columns ``x_um, y_um, z_um`` (others are ignored).

    Returns
    -------
    ndarray, shape (N, 3)
        Positions (µm); ``N`` may be 0 (header only).

    Raises
    ------
    InputError
        Missing/empty file, missing columns, or a non-numeric/NaN coordinate (names the file
        and line).
    """
    t = _read_table(path, POINT_COLUMNS)
    return np.stack([t[c] for c in POINT_COLUMNS], axis=1).reshape(-1, 3)


def write_matches_csv(
    path: str | os.PathLike,
    matches: np.ndarray,
    displacement_um: np.ndarray,
    *,
    overwrite: bool = False,
) -> Path:
    """Write matches ``row_ref,row_def,ux_um,uy_um,uz_um`` (0-based rows)."""
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    d = np.asarray(displacement_um, dtype=float).reshape(-1, 3)
    if m.shape[0] != d.shape[0]:
        raise InputError(f"{path}: {m.shape[0]} matches but {d.shape[0]} displacements")
    return _write_table(
        path, MATCH_COLUMNS, [m[:, 0], m[:, 1], d[:, 0], d[:, 1], d[:, 2]], overwrite
    )


def read_matches_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read matches: ``(matches (K, 2) int, displacement_um (K, 3))``."""
    t = _read_table(path, MATCH_COLUMNS, ("row_ref", "row_def"))
    m = np.stack([t["row_ref"], t["row_def"]], axis=1).reshape(-1, 2)
    d = np.stack([t["ux_um"], t["uy_um"], t["uz_um"]], axis=1).reshape(-1, 3)
    return m, d


def write_tracks_csv(path: str | os.PathLike, tracks, *, overwrite: bool = False) -> Path:
    """Write :class:`track.series.Tracks` as ``frame,track_id,x_um,y_um,z_um``."""
    xyz = np.asarray(tracks.xyz_um, dtype=float).reshape(-1, 3)
    order = np.lexsort((tracks.track_id, tracks.frame))
    cols = [tracks.frame[order], tracks.track_id[order], *(xyz[order, i] for i in range(3))]
    return _write_table(path, TRACK_COLUMNS, cols, overwrite)


def read_tracks_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read ``tracks.csv``: dict of columns ``frame, track_id`` (int) and ``x_um, y_um, z_um``."""
    return _read_table(path, TRACK_COLUMNS, ("frame", "track_id"))


__all__ = [
    "MATCH_COLUMNS",
    "POINT_COLUMNS",
    "TRACK_COLUMNS",
    "read_matches_csv",
    "read_points_csv",
    "read_tracks_csv",
    "write_matches_csv",
    "write_points_csv",
    "write_tracks_csv",
]
