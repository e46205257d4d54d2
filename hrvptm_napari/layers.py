"""The toolkit's outputs as napari layer data: ``(data, kwargs, layer_type)`` tuples.

Nothing here imports napari or Qt: the functions return what a napari reader returns, so that
they can be used (and tested) without a display.

World coordinates. Every layer has four axes ``(t, z, y, x)``. Lengths are in µm, in the
object-space frame of docs/conventions.md §2. ``t`` is the position of the frame in the series
(0, 1, 2, …: the frame index); the camera frame number is the feature ``frame`` of the points
and tracks. An image layer's ``scale`` is ``(1, dz, dy, dx)`` and its ``translate`` the
object-space position of the centre of voxel ``(0, 0, 0)`` (:attr:`track.volumes.VolumeInfo.
origin_xyz_um`, reversed into ``(z, y, x)``); napari places the centre of data index ``i`` at
``translate + i · scale``, so a particle at ``(x, y, z)`` lies on the voxel whose centre is
there. The field grids (strain images) are placed the same way: node ``(k, j, i)`` is at
``(z_um[k], y_um[j], x_um[i])``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import HrvError, InputError
from hrvbase.io import read_json

log = logging.getLogger(__name__)

#: A napari layer: ``(data, keyword arguments of viewer.add_<type>, type)``.
LayerData = tuple[Any, dict, str]

#: Strain components shown as image layers (Green–Lagrange ``E``, x, y, z indices).
STRAIN_COMPONENTS = {"xx": (0, 0), "yy": (1, 1), "zz": (2, 2), "xy": (0, 1), "xz": (0, 2),
                     "yz": (1, 2)}  # fmt: skip

#: Percentiles of the first volume that set an image layer's contrast limits: the median
#: (background) to the particles' peaks.
CONTRAST_PERCENTILES = (50.0, 99.99)

#: At most this many grid nodes per frame in the field's displacement Vectors layer.
MAX_FIELD_VECTORS = 4000

#: Kinds of folder :func:`folder_kind` recognises.
KINDS = ("study", "results", "zarr", "volumes")


class ReadError(InputError):
    """A folder that is not (or not entirely) one of the toolkit's outputs."""


def _json(path: Path) -> dict | None:
    try:
        value = read_json(path)
    except (HrvError, OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def _numbered_tifs(folder: Path) -> bool:
    from track.volumes import NUMBERED

    return any(
        NUMBERED.match(p.name) and p.suffix.lower() in (".tif", ".tiff") for p in folder.iterdir()
    )


def folder_kind(path: str | os.PathLike) -> str | None:
    """What a folder holds: ``"study"`` (an ``hrvptm study`` report), ``"results"`` (a ``track``
    results folder), ``"zarr"`` (an OME-Zarr image), ``"volumes"`` (numbered TIFF volumes),
    or None.

    A file ``study.json``, ``summary.json`` or ``tracks.csv`` stands for its folder."""
    from track.volumes import is_zarr

    p = Path(path)
    if p.is_file() and p.name in ("study.json", "summary.json", "tracks.csv"):
        p = p.parent
    if not p.is_dir():
        return None
    state = _json(p / "study.json") if (p / "study.json").is_file() else None
    if state is not None and state.get("tool") == "hrvptm":
        return "study"
    summary = _json(p / "summary.json") if (p / "summary.json").is_file() else None
    if summary is not None and summary.get("tool") == "track":
        return "results"
    if is_zarr(p):
        return "zarr"
    if _numbered_tifs(p):
        return "volumes"
    return None


def _folder(path: str | os.PathLike) -> Path:
    p = Path(path)
    return p.parent if p.is_file() else p


# -- volumes ---------------------------------------------------------------------------------
def volume_layer(path: str | os.PathLike, *, name: str | None = None) -> LayerData:
    """One image layer ``(t, z, y, x)`` of a volume series (numbered TIFFs or OME-Zarr).

    The voxels are read lazily, one volume per frame (a dask array); the contrast limits are
    the :data:`CONTRAST_PERCENTILES` of the first volume.

    Raises
    ------
    track.errors.InputError
        Not a volume series (:func:`track.volumes.scan_volumes`).
    """
    import dask
    import dask.array as da

    from track.volumes import read_volume, scan_volumes

    path = Path(path)
    vols = scan_volumes(path)
    first = vols[0]
    dz, dy, dx = (float(v) for v in first.voxel_size_um)
    x0, y0, z0 = (float(v) for v in first.origin_xyz_um)
    frames = [
        da.from_delayed(dask.delayed(read_volume)(v), shape=tuple(v.shape), dtype=np.float32)
        for v in vols
    ]
    data = da.stack(frames)
    lo, hi = np.percentile(read_volume(first), CONTRAST_PERCENTILES)
    if not hi > lo:
        hi = lo + 1.0
    kwargs = {
        "name": name or path.name,
        "scale": (1.0, dz, dy, dx),
        "translate": (0.0, z0, y0, x0),
        "contrast_limits": (float(lo), float(hi)),
        "colormap": "gray",
        "rendering": "mip",
        "blending": "additive",
        "metadata": {
            "source": str(path),
            "frames": [v.frame for v in vols],
            "time_s": [v.time_s for v in vols],
            "voxel_size_um": (dz, dy, dx),
            "origin_xyz_um": (x0, y0, z0),
        },
    }
    return data, kwargs, "image"


# -- track results ---------------------------------------------------------------------------
def _frame_positions(summary: Mapping) -> dict[int, int]:
    """Camera frame number → position in the series, from ``summary.json``'s ``frames``."""
    out = {}
    for k, f in enumerate(summary.get("frames") or ()):
        if isinstance(f, Mapping) and f.get("frame") is not None:
            out[int(f["frame"])] = int(f.get("index", k))
    return out


def _particle_files(folder: Path) -> list[tuple[int, Path]]:
    from track.volumes import NUMBERED

    files = []
    for p in sorted((folder / "particles").glob("*.csv")):
        m = NUMBERED.match(p.name)
        if m:
            files.append((int(m.group(1)), p))
    return files


def _position(positions: Mapping[int, int], frame: int) -> int:
    return positions.get(frame, frame)


def points_layer(
    folder: str | os.PathLike, *, name: str = "particles", positions: Mapping | None = None
) -> LayerData | None:
    """The particles of every frame as one Points layer ``(t, z, y, x)`` with the features
    ``frame``, ``intensity`` and ``sigma_{x,y,z}_um`` (NaN where unknown); None when the
    folder has no particle tables (read with :func:`track.dataframes.read_particles`)."""
    from track.dataframes import read_particles

    folder = _folder(folder)
    if not _particle_files(folder):
        return None
    if positions is None:
        positions = _frame_positions(_json(folder / "summary.json") or {})
    df = read_particles(folder)
    frame = df["frame"].to_numpy(dtype=int)
    t = np.array([_position(positions, int(f)) for f in frame], dtype=float)
    data = np.column_stack([t, df["z_um"], df["y_um"], df["x_um"]]).astype(float)
    features = {"frame": frame}
    for key in ("intensity", "sigma_x_um", "sigma_y_um", "sigma_z_um"):
        features[key] = df[key].to_numpy(dtype=float) if key in df else np.full(len(df), np.nan)
    kwargs = {
        "name": name,
        "features": features,
        "size": _point_size(data),
        "face_color": "transparent",
        "border_color": "yellow",
        "border_width": 0.15,
        "symbol": "disc",
        "ndim": 4,
    }
    return data, kwargs, "points"


def _point_size(data: np.ndarray) -> float:
    """A marker diameter (µm): a tenth of the lateral extent of the points, within 5–30 µm."""
    if len(data) < 2:
        return 10.0
    extent = float(np.ptp(data[:, 2:], axis=0).max())
    return float(np.clip(extent / 10.0, 5.0, 30.0))


def tracks_layer(
    folder: str | os.PathLike, *, name: str = "tracks", positions: Mapping | None = None
) -> LayerData | None:
    """``tracks.csv`` as a Tracks layer: napari's ``track_id, t, z, y, x`` (µm; ``t`` the
    frame's position in the series), with the features ``frame`` and ``sigma_{x,y,z}_um``;
    None without ``tracks.csv`` (read with :func:`track.dataframes.read_tracks`)."""
    from track.dataframes import read_tracks

    folder = _folder(folder)
    path = folder / "tracks.csv"
    if not path.is_file():
        return None
    if positions is None:
        positions = _frame_positions(_json(folder / "summary.json") or {})
    df = read_tracks(path).sort_values(["track_id", "frame"], kind="stable")
    frame = df["frame"].to_numpy(dtype=int)
    tpos = np.array([_position(positions, int(f)) for f in frame], dtype=float)
    data = np.column_stack([df["track_id"], tpos, df["z_um"], df["y_um"], df["x_um"]])
    features = {"frame": frame}
    for c in "xyz":
        key = f"sigma_{c}_um"
        features[key] = df[key].to_numpy(dtype=float) if key in df else np.full(len(df), np.nan)
    kwargs = {"name": name, "features": features, "tail_length": 30, "tail_width": 2}
    return data.astype(float), kwargs, "tracks"


def displacement_layer(
    folder: str | os.PathLike, *, name: str = "displacement", positions: Mapping | None = None
) -> LayerData | None:
    """The linked particles' displacements as a Vectors layer: one vector per match, from the
    particle in the reference frame of its pair to its position in the deformed frame, shown
    at the deformed frame's ``t``; features ``u_um`` (length, µm) and ``frame`` (the deformed
    frame). None without linked pairs (read with :func:`track.dataframes.read_matches` and
    :func:`~track.dataframes.read_particles`)."""
    from track.dataframes import read_matches, read_particles

    folder = _folder(folder)
    if not any(folder.glob("matches_*.csv")) or not _particle_files(folder):
        return None
    if positions is None:
        positions = _frame_positions(_json(folder / "summary.json") or {})
    m = read_matches(folder)
    if "ref_frame" not in m or "def_frame" not in m:
        return None
    parts = read_particles(folder).set_index(["frame", "row"])
    start = parts.loc[list(zip(m["ref_frame"], m["row_ref"], strict=True)),
                      ["z_um", "y_um", "x_um"]].to_numpy(dtype=float)  # fmt: skip
    d = m[["uz_um", "uy_um", "ux_um"]].to_numpy(dtype=float)
    v = np.zeros((len(m), 2, 4))
    v[:, 0, 0] = [_position(positions, int(f)) for f in m["def_frame"]]
    v[:, 0, 1:] = start
    v[:, 1, 1:] = d
    kwargs = {
        "name": name,
        "features": {
            "u_um": np.linalg.norm(d, axis=1),
            "frame": m["def_frame"].to_numpy(dtype=int),
        },
        "edge_color": "cyan",
        "edge_width": 1.0,
        "length": 1.0,
        "ndim": 4,
    }
    return v, kwargs, "vectors"


def _field_files(folder: Path) -> list[tuple[int, Path]]:
    from track.volumes import NUMBERED

    out = []
    for p in sorted((folder / "fields").glob("*.npz")):
        m = NUMBERED.match(p.stem + ".csv")  # NNNNNN.npz (not increment_NNNNNN.npz)
        if m:
            out.append((int(m.group(1)), p))
    return out


def field_layers(
    folder: str | os.PathLike, *, prefix: str = "", positions: Mapping | None = None
) -> list[LayerData]:
    """The total fields ``fields/NNNNNN.npz`` as layers on the reference grid: one image layer
    per Green–Lagrange strain component ``E_xx … E_yz`` (``(t, z, y, x)``, NaN outside the
    mask and at frames without a field, a diverging colormap symmetric about 0, hidden at
    first), and the gridded displacement ``u`` as a Vectors layer ``displacement field`` (at
    most :data:`MAX_FIELD_VECTORS` nodes per frame). Empty without fields."""
    from track.field_files import read_field_npz

    folder = _folder(folder)
    files = _field_files(folder)
    if not files:
        return []
    if positions is None:
        positions = _frame_positions(_json(folder / "summary.json") or {})
    fields = [(_position(positions, f), read_field_npz(p)) for f, p in files]
    ref = fields[0][1]
    shape = ref.mask.shape
    n_t = max(t for t, _ in fields) + 1
    axes = [np.asarray(a, dtype=float) for a in (ref.z_um, ref.y_um, ref.x_um)]
    spacing = tuple(float(np.diff(a).mean()) if a.size > 1 else 1.0 for a in axes)
    origin = tuple(float(a[0]) for a in axes)
    out: list[LayerData] = []
    for comp, (i, j) in STRAIN_COMPONENTS.items():
        stack = np.full((n_t, *shape), np.nan, dtype=np.float32)
        for t, fld in fields:
            if fld.mask.shape != shape:
                raise ReadError(f"{folder / 'fields'}: the fields are on different grids")
            stack[t] = np.where(fld.mask, fld.E[..., i, j], np.nan)
        finite = stack[np.isfinite(stack)]
        lim = float(np.abs(finite).max()) if finite.size else 1.0
        lim = lim if lim > 0 else 1.0
        out.append(
            (
                stack,
                {
                    "name": f"{prefix}E_{comp}",
                    "scale": (1.0, *spacing),
                    "translate": (0.0, *origin),
                    "contrast_limits": (-lim, lim),
                    "colormap": "PiYG",
                    "visible": False,
                    "metadata": {"component": f"E_{comp}", "unit": "1 (strain)"},
                },
                "image",
            )
        )
    vecs, length = [], []
    for t, fld in fields:
        idx = np.argwhere(fld.mask)
        step = max(1, int(np.ceil(len(idx) / MAX_FIELD_VECTORS)))
        idx = idx[::step]
        u = fld.u[idx[:, 0], idx[:, 1], idx[:, 2]]
        v = np.zeros((len(idx), 2, 4))
        v[:, 0, 0] = t
        v[:, 0, 1:] = np.column_stack([axes[k][idx[:, k]] for k in range(3)])
        v[:, 1, 1:] = u[:, ::-1]
        vecs.append(v)
        length += list(np.linalg.norm(u, axis=1))
    out.append(
        (
            np.concatenate(vecs),
            {
                "name": f"{prefix}displacement field",
                "features": {"u_um": np.asarray(length)},
                "edge_color": "orange",
                "edge_width": 1.0,
                "length": 1.0,
                "visible": False,
                "ndim": 4,
            },
            "vectors",
        )
    )
    return out


def results_layers(
    folder: str | os.PathLike, *, prefix: str = "", positions: Mapping | None = None
) -> list[LayerData]:
    """Every layer of a ``track`` results folder: particles (Points), tracks (Tracks),
    displacement (Vectors), and the fields (:func:`field_layers`)."""
    folder = _folder(folder)
    if positions is None:
        positions = _frame_positions(_json(folder / "summary.json") or {})
    out = [
        points_layer(folder, name=f"{prefix}particles", positions=positions),
        tracks_layer(folder, name=f"{prefix}tracks", positions=positions),
        displacement_layer(folder, name=f"{prefix}displacement", positions=positions),
    ]
    return [x for x in out if x is not None] + field_layers(
        folder, prefix=prefix, positions=positions
    )


# -- study reports ---------------------------------------------------------------------------
def truth_layer(
    dataset: str | os.PathLike, *, name: str = "truth", positions: Mapping | None = None
) -> LayerData | None:
    """An lfsim dataset's true particles (``truth/NNNNNN.csv``) as a Points layer
    ``(t, z, y, x)`` with the feature ``id``; frames absent from ``positions`` (when given)
    are left out. None without truth tables."""
    from hrvbase.tables import read_table
    from track.volumes import NUMBERED

    folder = Path(dataset) / "truth"
    if not folder.is_dir():
        return None
    rows, ids, frames = [], [], []
    for p in sorted(folder.glob("*.csv")):
        m = NUMBERED.match(p.name)
        if not m:
            continue
        frame = int(m.group(1))
        if positions is not None and frame not in positions:
            continue
        t = read_table(p, required=("id", "x_um", "y_um", "z_um"), integer=("id",))
        n = len(t["x_um"])
        tpos = float(_position(positions or {}, frame))
        rows.append(np.column_stack([np.full(n, tpos), t["z_um"], t["y_um"], t["x_um"]]))
        ids += list(t["id"])
        frames += [frame] * n
    if not rows:
        return None
    data = np.vstack(rows)
    kwargs = {
        "name": name,
        "features": {"id": np.asarray(ids), "frame": np.asarray(frames)},
        "size": _point_size(data),
        "face_color": "transparent",
        "border_color": "magenta",
        "border_width": 0.15,
        "symbol": "cross",
        "ndim": 4,
    }
    return data, kwargs, "points"


def _variants(report: Path) -> list[Path]:
    return sorted(
        p
        for p in report.iterdir()
        if p.is_dir() and any((p / d).exists() for d in ("dataset", "volumes", "track"))
    )


def study_layers(report: str | os.PathLike) -> list[LayerData]:
    """Every layer of an ``hrvptm study`` report folder, per variant (``REPORT/<variant>/``):
    the volumes, the truth (the dataset's particles), and the tracking results
    (:func:`results_layers`). Layer names start with the variant's name when the study has
    several."""
    report = _folder(report)
    variants = _variants(report)
    if not variants:
        raise ReadError(f"{report}: a study report without variant folders (dataset, volumes)")
    out: list[LayerData] = []
    for v in variants:
        prefix = f"{v.name} " if len(variants) > 1 else ""
        positions = None
        if (v / "volumes").is_dir() and folder_kind(v / "volumes") in ("volumes", "zarr"):
            layer = volume_layer(v / "volumes", name=f"{prefix}volumes")
            positions = {f: k for k, f in enumerate(layer[1]["metadata"]["frames"])}
            out.append(layer)
        if (v / "track").is_dir():
            summary = _json(v / "track" / "summary.json") or {}
            positions = _frame_positions(summary) or positions
            out += results_layers(v / "track", prefix=prefix, positions=positions)
        truth = truth_layer(v / "dataset", name=f"{prefix}truth", positions=positions)
        if truth is not None:
            out.append(truth)
    return out


def read_layers(path: str | os.PathLike | Sequence) -> list[LayerData]:
    """The layers of any of the toolkit's folders (:func:`folder_kind`).

    Raises
    ------
    ReadError
        Not a folder of the toolkit.
    """
    if isinstance(path, list | tuple):
        if len(path) != 1:
            raise ReadError(f"open one folder at a time, got {len(path)} paths")
        path = path[0]
    kind = folder_kind(path)
    if kind == "study":
        return study_layers(path)
    if kind == "results":
        return results_layers(path)
    if kind in ("zarr", "volumes"):
        return [volume_layer(path)]
    raise ReadError(
        f"{path}: not a study report, a track results folder, an OME-Zarr image or a folder of "
        "numbered TIFF volumes"
    )
