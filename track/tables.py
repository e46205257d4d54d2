"""CSV tables of :mod:`track`: particle positions, matches between two frames, tracks.

Thin wrappers over :mod:`hrvbase.tables`: every writer is **atomic** and refuses to replace
an existing file unless ``overwrite=True``; readers name the file and line of a bad value.

Formats (lengths in µm, docs/conventions.md §6.4):

- ``particles/NNNNNN.csv``: ``x_um,y_um,z_um[,intensity][,sigma_x_um,sigma_y_um,sigma_z_um]``;
- ``matches_NNNNNN.csv``: ``row_ref,row_def,ux_um,uy_um,uz_um[,sigma_dx_um,sigma_dy_um,
  sigma_dz_um]`` (0-based rows into the two frames' particle tables);
- ``tracks.csv``: ``frame,track_id,x_um,y_um,z_um[,sigma_x_um,sigma_y_um,sigma_z_um]
  [,time_s]``.

``frame`` is the frame number (the camera frame a volume was reconstructed from, when
recorded) and ``time_s`` its time in seconds, when the frame times are known; a match table
then also holds each displacement over the time between its two frames,
``vx_um_per_s,vy_um_per_s,vz_um_per_s`` (µm/s).

The ``sigma_*`` columns are standard uncertainties (µm, one standard deviation per axis);
tables written before they existed read as NaN uncertainties (:func:`read_point_sigmas`,
:func:`read_match_sigmas`); a ``nan`` uncertainty means unknown.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from hrvbase.tables import read_table, write_table

from .errors import InputError

POINT_COLUMNS = ("x_um", "y_um", "z_um")
MATCH_COLUMNS = ("row_ref", "row_def", "ux_um", "uy_um", "uz_um")
TRACK_COLUMNS = ("frame", "track_id", "x_um", "y_um", "z_um")
SIGMA_COLUMNS = ("sigma_x_um", "sigma_y_um", "sigma_z_um")
MATCH_SIGMA_COLUMNS = ("sigma_dx_um", "sigma_dy_um", "sigma_dz_um")
VELOCITY_COLUMNS = ("vx_um_per_s", "vy_um_per_s", "vz_um_per_s")
TIME_COLUMN = "time_s"


def _sigma_columns(path, sigma, n: int, what: str) -> list[np.ndarray]:
    s = np.asarray(sigma, dtype=float).reshape(-1, 3) if np.size(sigma) else np.zeros((0, 3))
    if s.shape[0] != n:
        raise InputError(f"{path}: {s.shape[0]} uncertainties for {n} {what}")
    if np.any(s < 0):
        raise InputError(f"{path}: negative uncertainties")
    return [s[:, 0], s[:, 1], s[:, 2]]


def _read_sigmas(path, names: Sequence[str], n: int) -> np.ndarray:
    t = read_table(path, required=(), optional=names, allow_nan=True)
    if not all(c in t for c in names):
        return np.full((n, 3), np.nan)
    s = np.stack([t[c] for c in names], axis=1).reshape(-1, 3)
    if s.shape[0] != n:  # pragma: no cover - the same rows were read twice
        raise InputError(f"{path}: {s.shape[0]} uncertainties for {n} rows")
    if np.any(s < 0) or np.any(np.isinf(s)):
        raise InputError(f"{path}: uncertainties must be >= 0 (or nan for unknown)")
    return s


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
    sigma_xyz_um: np.ndarray | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a particle table ``x_um,y_um,z_um[,intensity][,sigma_x_um,sigma_y_um,sigma_z_um]``.

    Parameters
    ----------
    xyz_um : ndarray, shape (N, 3)
        Positions (µm), x, y, z.
    intensity : ndarray, shape (N,), optional
    sigma_xyz_um : ndarray, shape (N, 3), optional
        Standard uncertainty of each position (µm, x, y, z; ≥ 0, NaN = unknown).
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
    if sigma_xyz_um is not None:
        cols += _sigma_columns(path, sigma_xyz_um, xyz.shape[0], "particles")
        header += SIGMA_COLUMNS
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


def read_point_sigmas(path: str | os.PathLike) -> np.ndarray:
    """Standard uncertainties ``sigma_x_um, sigma_y_um, sigma_z_um`` of a particle table.

    Returns
    -------
    ndarray, shape (N, 3)
        µm; all NaN when the table has no uncertainty columns (written before they existed,
        or from another source).

    Raises
    ------
    InputError
        As :func:`read_points_csv`, or a negative uncertainty.
    """
    n = read_points_csv(path).shape[0]
    return _read_sigmas(path, SIGMA_COLUMNS, n)


def write_matches_csv(
    path: str | os.PathLike,
    matches: np.ndarray,
    displacement_um: np.ndarray,
    *,
    sigma_xyz_um: np.ndarray | None = None,
    dt_s: float | None = None,
    overwrite: bool = False,
) -> Path:
    """Write matches ``row_ref,row_def,ux_um,uy_um,uz_um`` (0-based rows), with
    ``sigma_dx_um,sigma_dy_um,sigma_dz_um`` when ``sigma_xyz_um`` (K, 3) µm is given and the
    velocities ``vx_um_per_s,vy_um_per_s,vz_um_per_s`` (displacement / ``dt_s``, µm/s) when
    the time ``dt_s`` (s, > 0) between the two frames is."""
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    d = np.asarray(displacement_um, dtype=float).reshape(-1, 3)
    if m.shape[0] != d.shape[0]:
        raise InputError(f"{path}: {m.shape[0]} matches but {d.shape[0]} displacements")
    cols = [m[:, 0], m[:, 1], d[:, 0], d[:, 1], d[:, 2]]
    header = list(MATCH_COLUMNS)
    if sigma_xyz_um is not None:
        cols += _sigma_columns(path, sigma_xyz_um, m.shape[0], "matches")
        header += MATCH_SIGMA_COLUMNS
    if dt_s is not None:
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise InputError(f"{path}: the time between the frames must be > 0 s, got {dt_s!r}")
        cols += [d[:, 0] / dt_s, d[:, 1] / dt_s, d[:, 2] / dt_s]
        header += VELOCITY_COLUMNS
    return _write_table(path, header, cols, overwrite)


def read_matches_csv(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read matches: ``(matches (K, 2) int, displacement_um (K, 3))``."""
    t = _read_table(path, MATCH_COLUMNS, ("row_ref", "row_def"))
    m = np.stack([t["row_ref"], t["row_def"]], axis=1).reshape(-1, 2)
    d = np.stack([t["ux_um"], t["uy_um"], t["uz_um"]], axis=1).reshape(-1, 3)
    return m, d


def read_match_sigmas(path: str | os.PathLike) -> np.ndarray:
    """Displacement uncertainties ``sigma_dx_um, sigma_dy_um, sigma_dz_um`` of a match
    table: (K, 3) µm, all NaN when the table has none."""
    n = read_matches_csv(path)[0].shape[0]
    return _read_sigmas(path, MATCH_SIGMA_COLUMNS, n)


def write_tracks_csv(
    path: str | os.PathLike,
    tracks,
    *,
    times_s: Mapping[int, float] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write :class:`track.series.Tracks` as ``frame,track_id,x_um,y_um,z_um``, with
    ``sigma_x_um,sigma_y_um,sigma_z_um`` when the tracks carry uncertainties and ``time_s``
    when ``times_s`` (``{frame: time in s}``, every frame of the tracks) is given."""
    xyz = np.asarray(tracks.xyz_um, dtype=float).reshape(-1, 3)
    order = np.lexsort((tracks.track_id, tracks.frame))
    cols = [tracks.frame[order], tracks.track_id[order], *(xyz[order, i] for i in range(3))]
    header = list(TRACK_COLUMNS)
    sig = getattr(tracks, "sigma_xyz_um", None)
    if sig is not None:
        cols += _sigma_columns(path, np.asarray(sig)[order], xyz.shape[0], "track points")
        header += SIGMA_COLUMNS
    if times_s is not None:
        frames = np.asarray(tracks.frame)[order]
        missing = sorted(set(frames.tolist()) - set(times_s))
        if missing:
            raise InputError(f"{path}: no time for frame {missing[0]}")
        cols.append(np.array([times_s[int(f)] for f in frames], dtype=float))
        header.append(TIME_COLUMN)
    return _write_table(path, header, cols, overwrite)


def read_tracks_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read ``tracks.csv``: dict of columns ``frame, track_id`` (int) and ``x_um, y_um, z_um``,
    ``sigma_x_um, sigma_y_um, sigma_z_um`` (NaN when the table has none) and ``time_s``
    (s; only when the table has it)."""
    t = _read_table(path, TRACK_COLUMNS, ("frame", "track_id"))
    sig = _read_sigmas(path, SIGMA_COLUMNS, t["frame"].shape[0])
    for j, c in enumerate(SIGMA_COLUMNS):
        t[c] = sig[:, j]
    times = read_table(path, required=(), optional=(TIME_COLUMN,))
    if TIME_COLUMN in times:
        t[TIME_COLUMN] = times[TIME_COLUMN]
    return t


__all__ = [
    "MATCH_COLUMNS",
    "MATCH_SIGMA_COLUMNS",
    "POINT_COLUMNS",
    "SIGMA_COLUMNS",
    "TIME_COLUMN",
    "TRACK_COLUMNS",
    "VELOCITY_COLUMNS",
    "read_match_sigmas",
    "read_matches_csv",
    "read_point_sigmas",
    "read_points_csv",
    "read_tracks_csv",
    "write_matches_csv",
    "write_points_csv",
    "write_tracks_csv",
]
