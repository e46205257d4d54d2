"""The tables and fields of :mod:`track` as pandas DataFrames, and trackpy's column names.

Readers return one row per item of the files ``track run | detect | link`` write (built on
the CSV readers of :mod:`track.tables` and the field readers of :mod:`track.field_files`:
a bad file raises the same one-line :class:`~track.errors.InputError`). The CSV files stay
as they are; the DataFrames keep their column names, which carry the units (lengths in µm,
times in s), and add only what the file's name or folder tells:

``read_particles``
    ``frame`` (from ``NNNNNN.csv``; absent for a file not named so), ``row`` (0-based row in
    its table, what a match table's ``row_ref``/``row_def`` refer to), ``x_um, y_um, z_um``
    and, when the table has them, ``intensity`` and ``sigma_x_um, sigma_y_um, sigma_z_um``.
``read_matches``
    ``ref_frame`` (when the folder's ``summary.json`` names it), ``def_frame`` (from
    ``matches_NNNNNN.csv``), ``row_ref, row_def, ux_um, uy_um, uz_um`` and, when present,
    ``sigma_dx_um, sigma_dy_um, sigma_dz_um`` and ``vx_um_per_s, vy_um_per_s, vz_um_per_s``.
``read_tracks``
    ``frame, track_id, x_um, y_um, z_um`` and, when present, ``sigma_x_um, sigma_y_um,
    sigma_z_um`` and ``time_s``.
``read_fields``
    One row per grid node, in VTK point order (x fastest, then y, then z): ``x_um, y_um,
    z_um`` (the node), ``ux_um, uy_um, uz_um``, ``F_xx … F_zz`` (9, row-major),
    ``E_xx, E_yy, E_zz, E_xy, E_xz, E_yz`` and the same for ``e``, ``mask`` (bool: the node
    is supported by particles; values elsewhere are extrapolated in ``.npz`` files, NaN in
    ``.vti`` files), and with uncertainties ``sigma_ux_um, sigma_uy_um, sigma_uz_um``,
    ``sigma_F_xx … sigma_F_zz`` and ``sigma_e_xx … sigma_e_yz``; ``frame`` and ``time_s``
    when the file records them.

trackpy: our ``x_um, y_um, z_um`` are trackpy's ``x, y, z`` in µm, our ``frame`` is its
``frame`` and our ``track_id`` its ``particle``. :func:`to_trackpy` renames those columns
(values unchanged, lengths stay in µm) and :func:`from_trackpy` renames them back, so that
``trackpy.link(to_trackpy(read_particles(folder)), search_range_um)`` links the particles
``track detect`` found and :func:`write_tracks` writes trackpy's trajectories as our
``tracks.csv``.

pandas is imported when this module is (``import track`` does not import it).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pandas as pd

from hrvbase.io import read_json
from hrvbase.tables import read_table

from . import field_files, tables
from .errors import InputError
from .fields import GridField

#: Our column → trackpy's (values unchanged: positions stay in µm).
TRACKPY_COLUMNS = {"x_um": "x", "y_um": "y", "z_um": "z", "track_id": "particle"}

_FRAME_CSV = re.compile(r"^(\d{6})\.csv$")
_MATCHES_CSV = re.compile(r"^matches_(\d{6})\.csv$")
_FIELD_FILE = re.compile(r"^(\d{6})\.(npz|vti)$")
_SUMMARY = "summary.json"
_COMPONENTS = ("x", "y", "z")
_SYM = ("xx", "yy", "zz", "xy", "xz", "yz")
_IJ = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def _present(path: Path, names) -> dict[str, np.ndarray]:
    """The columns ``names`` the table has (values read as float, NaN allowed); the table
    itself was validated by the :mod:`track.tables` reader before."""
    return read_table(path, required=(), optional=tuple(names), allow_nan=True)


def _has_all(found: dict, names) -> bool:
    return all(c in found for c in names)


def _particle_table(path: Path) -> pd.DataFrame:
    xyz = tables.read_points_csv(path)
    cols: dict[str, Any] = {"row": np.arange(xyz.shape[0], dtype=np.int64)}
    cols.update({c: xyz[:, j] for j, c in enumerate(tables.POINT_COLUMNS)})
    extra = _present(path, ("intensity", *tables.SIGMA_COLUMNS))
    if "intensity" in extra:
        cols["intensity"] = extra["intensity"]
    if _has_all(extra, tables.SIGMA_COLUMNS):
        sig = tables.read_point_sigmas(path)
        cols.update({c: sig[:, j] for j, c in enumerate(tables.SIGMA_COLUMNS)})
    m = _FRAME_CSV.match(path.name)
    df = pd.DataFrame(cols)
    if m:
        df.insert(0, "frame", np.full(len(df), int(m.group(1)), dtype=np.int64))
    return df


def _numbered(folder: Path, pattern: re.Pattern) -> list[tuple[int, Path]]:
    found = [(int(m.group(1)), p) for p in folder.iterdir() if (m := pattern.match(p.name))]
    return sorted(found)


def read_particles(path: str | os.PathLike) -> pd.DataFrame:
    """Particle tables (``particles/NNNNNN.csv``) as one DataFrame.

    Parameters
    ----------
    path : path
        One particle table, a folder of them (``NNNNNN.csv``), or a results folder holding
        ``particles/``.

    Returns
    -------
    DataFrame
        ``frame`` (int; from the file name ``NNNNNN.csv``, absent for another name),
        ``row`` (int, 0-based row in its table), ``x_um, y_um, z_um`` (µm) and, when the
        tables have them, ``intensity`` and ``sigma_x_um, sigma_y_um, sigma_z_um`` (µm).
        Frames in increasing order.

    Raises
    ------
    InputError
        A missing path, a folder without particle tables, or a bad table (the message of
        :func:`track.tables.read_points_csv`, naming the file and line).
    """
    path = Path(path)
    if path.is_dir():
        folder = path / "particles" if (path / "particles").is_dir() else path
        files = _numbered(folder, _FRAME_CSV)
        if not files:
            raise InputError(f"{folder}: no particle tables NNNNNN.csv")
        return pd.concat([_particle_table(p) for _, p in files], ignore_index=True)
    return _particle_table(path)


def _ref_frames(folder: Path) -> dict[int, int]:
    """``{deformed frame: reference frame}`` from the folder's ``summary.json`` (empty when
    the folder has none)."""
    p = folder / _SUMMARY
    if not p.is_file():
        return {}
    summary = read_json(p)
    incs = summary.get("increments", []) if isinstance(summary, dict) else []
    try:
        return {int(e["def_frame"]): int(e["ref_frame"]) for e in incs}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{p}: increments need integer ref_frame and def_frame ({exc})") from None


def _match_table(path: Path, refs: dict[int, int]) -> pd.DataFrame:
    m, d = tables.read_matches_csv(path)
    cols: dict[str, Any] = {"row_ref": m[:, 0], "row_def": m[:, 1]}
    cols.update({c: d[:, j] for j, c in enumerate(tables.MATCH_COLUMNS[2:])})
    extra = _present(path, (*tables.MATCH_SIGMA_COLUMNS, *tables.VELOCITY_COLUMNS))
    if _has_all(extra, tables.MATCH_SIGMA_COLUMNS):
        sig = tables.read_match_sigmas(path)
        cols.update({c: sig[:, j] for j, c in enumerate(tables.MATCH_SIGMA_COLUMNS)})
    if _has_all(extra, tables.VELOCITY_COLUMNS):
        cols.update({c: extra[c] for c in tables.VELOCITY_COLUMNS})
    df = pd.DataFrame(cols)
    mm = _MATCHES_CSV.match(path.name)
    if mm:
        k = int(mm.group(1))
        df.insert(0, "def_frame", np.full(len(df), k, dtype=np.int64))
        if k in refs:
            df.insert(0, "ref_frame", np.full(len(df), refs[k], dtype=np.int64))
    return df


def read_matches(path: str | os.PathLike) -> pd.DataFrame:
    """Match tables (``matches_NNNNNN.csv``) as one DataFrame.

    Parameters
    ----------
    path : path
        One match table or a results folder (all its ``matches_NNNNNN.csv``).

    Returns
    -------
    DataFrame
        ``ref_frame`` (int; when the folder's ``summary.json`` names the pair's reference
        frame), ``def_frame`` (int; from the file name, absent for another name),
        ``row_ref, row_def`` (int, 0-based rows of the two frames' particle tables: the
        ``row`` of :func:`read_particles`), ``ux_um, uy_um, uz_um`` (µm) and, when present,
        ``sigma_dx_um, sigma_dy_um, sigma_dz_um`` (µm) and ``vx_um_per_s, vy_um_per_s,
        vz_um_per_s`` (µm/s).

    Raises
    ------
    InputError
        A missing path, a folder without match tables, or a bad table (the message of
        :func:`track.tables.read_matches_csv`).
    """
    path = Path(path)
    if path.is_dir():
        files = _numbered(path, _MATCHES_CSV)
        if not files:
            raise InputError(f"{path}: no match tables matches_NNNNNN.csv")
        refs = _ref_frames(path)
        return pd.concat([_match_table(p, refs) for _, p in files], ignore_index=True)
    return _match_table(path, _ref_frames(path.parent))


def read_tracks(path: str | os.PathLike) -> pd.DataFrame:
    """``tracks.csv`` as a DataFrame.

    Parameters
    ----------
    path : path
        ``tracks.csv`` or a results folder holding it.

    Returns
    -------
    DataFrame
        ``frame, track_id`` (int), ``x_um, y_um, z_um`` (µm) and, when the table has them,
        ``sigma_x_um, sigma_y_um, sigma_z_um`` (µm) and ``time_s`` (s); rows in the file's
        order (by frame, then track). :func:`to_trackpy` gives trackpy's names.

    Raises
    ------
    InputError
        The message of :func:`track.tables.read_tracks_csv`.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "tracks.csv"
    t = tables.read_tracks_csv(path)
    cols = {c: t[c] for c in tables.TRACK_COLUMNS}
    if _has_all(_present(path, tables.SIGMA_COLUMNS), tables.SIGMA_COLUMNS):
        cols.update({c: t[c] for c in tables.SIGMA_COLUMNS})
    if tables.TIME_COLUMN in t:
        cols[tables.TIME_COLUMN] = t[tables.TIME_COLUMN]
    return pd.DataFrame(cols)


def field_frame(fld: GridField) -> pd.DataFrame:
    """One row per node of a :class:`~track.fields.GridField` (the columns of
    :func:`read_fields` without ``frame`` and ``time_s``)."""
    nz, ny, nx = fld.shape
    n = nx * ny * nz
    z, y, x = np.meshgrid(fld.z_um, fld.y_um, fld.x_um, indexing="ij")
    cols: dict[str, Any] = {"x_um": x.ravel(), "y_um": y.ravel(), "z_um": z.ravel()}
    u = fld.u.reshape(n, 3)
    cols.update({f"u{a}_um": u[:, j] for j, a in enumerate(_COMPONENTS)})
    F = fld.F.reshape(n, 3, 3)
    cols.update(
        {
            f"F_{a}{b}": F[:, i, j]
            for i, a in enumerate(_COMPONENTS)
            for j, b in enumerate(_COMPONENTS)
        }
    )
    for name in ("E", "e"):
        t = getattr(fld, name).reshape(n, 3, 3)
        cols.update({f"{name}_{c}": t[:, _IJ[c][0], _IJ[c][1]] for c in _SYM})
    cols["mask"] = fld.mask.ravel()
    if fld.u_std is not None:
        s = fld.u_std.reshape(n, 3)
        cols.update({f"sigma_u{a}_um": s[:, j] for j, a in enumerate(_COMPONENTS)})
    if fld.F_std is not None:
        s = fld.F_std.reshape(n, 3, 3)
        cols.update(
            {
                f"sigma_F_{a}{b}": s[:, i, j]
                for i, a in enumerate(_COMPONENTS)
                for j, b in enumerate(_COMPONENTS)
            }
        )
    if fld.e_std is not None:
        s = fld.e_std.reshape(n, 3, 3)
        cols.update({f"sigma_e_{c}": s[:, _IJ[c][0], _IJ[c][1]] for c in _SYM})
    return pd.DataFrame(cols)


def _field_file(path: Path) -> pd.DataFrame:
    if path.suffix == ".vti":
        fld = field_files.read_field_vti(path)
    else:
        fld = field_files.read_field_npz(path)
    frame, time_s = field_files.read_field_time(path)
    df = field_frame(fld)
    if frame is not None:
        df["frame"] = np.int64(frame)
        df["time_s"] = np.nan if time_s is None else float(time_s)
    return df


def read_fields(path: str | os.PathLike) -> pd.DataFrame:
    """Gridded fields (``fields/NNNNNN.npz`` or ``.vti``) as one DataFrame.

    Parameters
    ----------
    path : path
        One field file (``.npz``, full precision; or ``.vti``, Float32 with NaN at the
        nodes outside the mask), a folder of them or a results folder holding ``fields/``:
        then every total field ``NNNNNN.npz`` (increments ``increment_NNNNNN.npz`` are read
        one file at a time).

    Returns
    -------
    DataFrame
        One row per node, in VTK point order: ``x_um, y_um, z_um``, ``ux_um, uy_um,
        uz_um``, ``F_xx … F_zz``, ``E_xx, E_yy, E_zz, E_xy, E_xz, E_yz``, ``e_xx … e_yz``,
        ``mask`` (bool) and, when the field has them, ``sigma_ux_um … sigma_uz_um``,
        ``sigma_F_xx … sigma_F_zz``, ``sigma_e_xx … sigma_e_yz``; ``frame`` (int) and
        ``time_s`` (s, NaN when unknown) when the file records them (every field a run
        writes does).

    Raises
    ------
    InputError
        A missing or unreadable file, a folder without fields (names the path).
    """
    path = Path(path)
    if path.is_dir():
        folder = path / "fields" if (path / "fields").is_dir() else path
        files = [p for _, p in _numbered(folder, _FIELD_FILE) if p.suffix == ".npz"]
        if not files:
            raise InputError(f"{folder}: no field files NNNNNN.npz")
        return pd.concat([_field_file(p) for p in files], ignore_index=True)
    if path.suffix not in (".npz", ".vti"):
        raise InputError(f"{path}: expected a field file .npz or .vti")
    return _field_file(path)


@dataclass(frozen=True)
class ResultsTables:
    """A ``track run | detect | link`` results folder as DataFrames (:func:`read_results`).

    Attributes
    ----------
    folder : Path
    particles : DataFrame
        Every frame's particles (:func:`read_particles`, with ``frame`` and ``row``).
    matches : DataFrame or None
        Every pair's matches (:func:`read_matches`); None when the folder has none
        (``track detect``).
    tracks : DataFrame or None
        :func:`read_tracks`; None without ``tracks.csv``.
    field_files : dict of int to Path
        The total field of each deformed frame (``fields/NNNNNN.npz``), read with
        :func:`read_fields`.
    summary : dict
        ``summary.json``.
    """

    folder: Path
    particles: pd.DataFrame
    matches: pd.DataFrame | None
    tracks: pd.DataFrame | None
    field_files: dict[int, Path] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


def read_results(folder: str | os.PathLike) -> ResultsTables:
    """Read a results folder of ``track run | detect | link`` (its particles, matches,
    tracks and summary; the fields, which can be large, are listed in
    :attr:`ResultsTables.field_files` and read with :func:`read_fields`).

    Raises
    ------
    InputError
        Not a folder, no ``summary.json``, or a bad file (named).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder; expected a track results folder")
    summary = read_json(folder / _SUMMARY)
    if not isinstance(summary, dict):
        raise InputError(f"{folder / _SUMMARY}: expected a JSON object")
    matches = read_matches(folder) if _numbered(folder, _MATCHES_CSV) else None
    tracks = read_tracks(folder) if (folder / "tracks.csv").is_file() else None
    fdir = folder / "fields"
    fields = {}
    if fdir.is_dir():
        fields = {k: p for k, p in _numbered(fdir, _FIELD_FILE) if p.suffix == ".npz"}
    return ResultsTables(folder, read_particles(folder), matches, tracks, fields, summary)


def to_trackpy(df: pd.DataFrame) -> pd.DataFrame:
    """Our columns renamed to trackpy's: ``x_um, y_um, z_um → x, y, z`` (µm) and
    ``track_id → particle`` (:data:`TRACKPY_COLUMNS`); other columns and all values
    unchanged. ``trackpy.link`` then takes ``search_range`` in µm."""
    return df.rename(columns=TRACKPY_COLUMNS)


def from_trackpy(df: pd.DataFrame) -> pd.DataFrame:
    """trackpy's columns renamed to ours: ``x, y, z → x_um, y_um, z_um`` (their values
    taken as µm) and ``particle → track_id``; the inverse of :func:`to_trackpy`."""
    return df.rename(columns={v: k for k, v in TRACKPY_COLUMNS.items()})


def _columns(df: pd.DataFrame, names, path, what: str, dtype=float) -> np.ndarray:
    missing = [c for c in names if c not in df.columns]
    if missing:
        raise InputError(f"{path}: the {what} DataFrame has no column(s) {', '.join(missing)}")
    return df[list(names)].to_numpy(dtype=dtype)


def write_particles(path: str | os.PathLike, df: pd.DataFrame, *, overwrite: bool = False) -> Path:
    """Write a DataFrame's ``x_um, y_um, z_um`` (and ``intensity``, ``sigma_x_um,
    sigma_y_um, sigma_z_um`` when present) as a particle table with
    :func:`track.tables.write_points_csv` (other columns are not written). A table read
    with :func:`read_particles` is written back byte for byte."""
    xyz = _columns(df, tables.POINT_COLUMNS, path, "particle")
    inten = df["intensity"].to_numpy(dtype=float) if "intensity" in df.columns else None
    sig = None
    if any(c in df.columns for c in tables.SIGMA_COLUMNS):
        sig = _columns(df, tables.SIGMA_COLUMNS, path, "particle")
    return tables.write_points_csv(path, xyz, inten, sigma_xyz_um=sig, overwrite=overwrite)


def write_tracks(path: str | os.PathLike, df: pd.DataFrame, *, overwrite: bool = False) -> Path:
    """Write a DataFrame of trajectories as ``tracks.csv`` with
    :func:`track.tables.write_tracks_csv` (rows sorted by frame, then track).

    Parameters
    ----------
    df : DataFrame
        ``frame, track_id`` (int), ``x_um, y_um, z_um`` (µm); optional ``sigma_x_um,
        sigma_y_um, sigma_z_um`` (µm) and ``time_s`` (s, one time per frame). trackpy's
        linked output after :func:`from_trackpy` qualifies.
    """
    ids = _columns(df, ("frame", "track_id"), path, "tracks", dtype=float)
    if not np.all(np.isfinite(ids)) or np.any(ids != np.round(ids)):
        raise InputError(f"{path}: frame and track_id must be integers")
    xyz = _columns(df, tables.POINT_COLUMNS, path, "tracks")
    sig = None
    if any(c in df.columns for c in tables.SIGMA_COLUMNS):
        sig = _columns(df, tables.SIGMA_COLUMNS, path, "tracks")
    frame = ids[:, 0].astype(np.int64)
    times = None
    if tables.TIME_COLUMN in df.columns:
        t = df[tables.TIME_COLUMN].to_numpy(dtype=float)
        times = {}
        for f, s in zip(frame.tolist(), t.tolist(), strict=True):
            first = times.setdefault(f, s)
            if first != s and not (np.isnan(first) and np.isnan(s)):
                raise InputError(f"{path}: frame {f} has more than one time_s")
    tr = SimpleNamespace(
        frame=frame, track_id=ids[:, 1].astype(np.int64), xyz_um=xyz, sigma_xyz_um=sig
    )
    return tables.write_tracks_csv(path, tr, times_s=times, overwrite=overwrite)


__all__ = [
    "TRACKPY_COLUMNS",
    "ResultsTables",
    "field_frame",
    "from_trackpy",
    "read_fields",
    "read_matches",
    "read_particles",
    "read_results",
    "read_tracks",
    "to_trackpy",
    "write_particles",
    "write_tracks",
]
