"""Volume series of :mod:`track`: numbered TIFF volumes placed in object space.

A series is a folder of ``NNNNNN.tif`` float32 ``(z, y, x)`` volumes (:func:`scan_volumes`
lists them without reading voxels, :func:`read_volume` reads one). The voxel size
``[dz, dy, dx]`` and the origin come, in this order of preference, from the JSON metadata of
``lfsim.io.write_tiff`` (private tag 65001, or the ``ImageDescription`` of files of the
previous layout: ``"voxel_size_um"``, ``"origin_xyz_um"`` or ``origin_um`` ``[x0, y0]`` with
``depths_um``), from the ImageJ calibration of a file saved by Fiji (``unit`` µm,
``spacing``, ``XResolution``/``YResolution``, ``xorigin``/``yorigin``/``zorigin``), or from
the folder's ``recon.json`` (``voxel_size_um``; ``grid.origin_um`` ``[x0, y0]`` and
``grid.depths_um`` place the volume in object space). Lengths in µm (docs/conventions.md).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import read_json

from .errors import InputError

#: Pattern of the numbered files of a series (6 digits).
NUMBERED = re.compile(r"^(\d{6})\.(tif|tiff|csv)$")

#: Name of the reconstruction metadata file next to volumes.
RECON_JSON = "recon.json"


@dataclass(frozen=True)
class VolumeInfo:
    """One volume of a numbered series (metadata only; read the voxels with :func:`read_volume`).

    Attributes
    ----------
    path : Path
    index : int
        Frame number from the file name ``NNNNNN.tif``.
    shape : tuple of int
        ``(nz, ny, nx)``.
    voxel_size_um : tuple of float
        ``(dz, dy, dx)`` (µm).
    origin_xyz_um : tuple of float
        Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm).
    """

    path: Path
    index: int
    shape: tuple
    voxel_size_um: tuple
    origin_xyz_um: tuple


#: Private TIFF tags of ``lfsim.io.write_tiff`` (track does not import lfsim): the array
#: shape ``{"shape": [...]}`` and the JSON metadata (files of the previous layout hold the JSON
#: in the ``ImageDescription``).
_SHAPE_TAG = 65000
_METADATA_TAG = 65001

#: Spellings of the micrometre in ImageJ's ``unit=`` entry.
_MICROMETRE = frozenset(
    {"um", "\u00b5m", "\\u00b5m", "micron", "microns", "micrometer", "micrometre"}
)


def _voxel_size(value, where: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: voxel_size_um must be [dz, dy, dx], got {value!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"{where}: voxel_size_um must be 3 positive numbers, got {value!r}")
    return vals


def _origin(meta: Mapping, vs, where: str) -> tuple[float, float, float] | None:
    """Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm) from metadata.

    ``origin_xyz_um`` (that centre, as ``lfsim.io.write_tiff`` records it) or, in older files
    and ``recon.json``, ``origin_um`` ``[x0, y0]`` (the corner of lenslet ``(0, 0)``) with
    ``depths_um``. ``None`` when the metadata hold neither.
    """
    xyz = meta.get("origin_xyz_um")
    if xyz is not None:
        try:
            vals = tuple(float(v) for v in xyz)
        except (TypeError, ValueError):
            vals = ()
        if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
            raise InputError(f"{where}: origin_xyz_um must be 3 numbers [x, y, z], got {xyz!r}")
        return vals
    o = meta.get("origin_um")
    d = meta.get("depths_um")
    if o is None and d is None:
        return None
    try:
        ox, oy = (float(v) for v in (o if o is not None else (0.0, 0.0))[:2])
        z0 = float(d[0]) if d else 0.0
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{where}: bad origin_um/depths_um {o!r} / {d!r}") from None
    # recon places voxel column i at origin + (i + 0.5) · dx (geometry.ReconGrid.x_um)
    return (ox + 0.5 * vs[2], oy + 0.5 * vs[1], z0)


@dataclass(frozen=True)
class _Header:
    """What :func:`_tiff_header` reads: shape, dtype, our JSON metadata, ImageJ calibration."""

    shape: tuple
    dtype: Any
    meta: dict
    imagej_vs: tuple | None = None  # (dz, dy, dx) µm from a Fiji calibration
    imagej_origin: tuple | None = None  # (x, y, z) µm of voxel (0, 0, 0)


def _imagej_calibration(ij: Mapping | None, page) -> tuple[tuple | None, tuple | None]:
    """Voxel size ``(dz, dy, dx)`` and origin ``(x, y, z)`` (µm) of an ImageJ calibration.

    ``(None, None)`` unless the unit is a micrometre and spacing and resolutions are positive.
    """
    if not ij or str(ij.get("unit", "")).strip().lower() not in _MICROMETRE:
        return None, None
    try:
        dz = float(ij["spacing"])
        xres = page.tags["XResolution"].value
        yres = page.tags["YResolution"].value
        dx = xres[1] / xres[0]
        dy = yres[1] / yres[0]
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None, None
    vs = (dz, dy, dx)
    if not all(math.isfinite(v) and v > 0 for v in vs):
        return None, None
    keys = ("xorigin", "yorigin", "zorigin")
    if not any(k in ij for k in keys):
        return vs, None
    try:
        idx = [float(ij.get(k, 0.0)) for k in keys]
    except (TypeError, ValueError):
        return vs, None
    # ImageJ: coordinate = (index - origin) * size, so voxel 0 sits at -origin * size.
    origin = (-idx[0] * dx, -idx[1] * dy, -idx[2] * dz)
    if not all(math.isfinite(v) for v in origin):
        return vs, None
    return vs, origin


def _data_end(tif) -> int:
    """Byte just past the last voxel data of the first series (headers only)."""
    series = tif.series[0]
    if series.dataoffset is not None:  # contiguous data
        return int(series.dataoffset) + int(series.nbytes)
    end = 0
    for page in tif.pages:
        for offset, count in zip(page.dataoffsets, page.databytecounts, strict=True):
            end = max(end, int(offset) + int(count))
    return end


def _tiff_header(path: Path) -> _Header:
    """Shape, dtype and metadata of a volume file, without reading its voxels."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            desc = page.description or ""
            tagvals = {}
            for code in (_SHAPE_TAG, _METADATA_TAG):
                tag = page.tags.get(code)
                tagvals[code] = tag.value if tag is not None else None
            shape = tuple(tif.series[0].shape)
            dtype = tif.series[0].dtype
            ij_vs, ij_origin = _imagej_calibration(tif.imagej_metadata, page)
            end = _data_end(tif)
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc
    size = path.stat().st_size
    if end > size:
        raise InputError(
            f"TIFF volume {path} is truncated: its voxels end at byte {end} but the file has "
            f"{size} bytes (an interrupted copy or write?)"
        )
    if tagvals[_SHAPE_TAG] is not None:
        with contextlib.suppress(ValueError, KeyError, TypeError):
            shape = tuple(json.loads(tagvals[_SHAPE_TAG])["shape"])
    if len(shape) == 2:
        shape = (1, *shape)
    if len(shape) != 3:
        raise InputError(f"{path}: expected a (z, y, x) volume, got shape {shape}")
    text = tagvals[_METADATA_TAG]
    if text is not None:
        try:
            meta = json.loads(text)
        except (ValueError, TypeError):
            meta = None
        if not isinstance(meta, dict):
            raise InputError(f"{path}: metadata tag {_METADATA_TAG} does not hold a JSON object")
    else:  # the previous layout: JSON, if any, in the ImageDescription
        meta = {}
        with contextlib.suppress(json.JSONDecodeError):
            obj = json.loads(desc) if desc else {}
            meta = obj if isinstance(obj, dict) else {}
    return _Header(shape, dtype, meta, ij_vs, ij_origin)


def scan_volumes(folder: str | os.PathLike) -> list[VolumeInfo]:
    """The numbered volumes ``NNNNNN.tif`` of a folder, with voxel size and origin.

    Parameters
    ----------
    folder : path
        Folder holding ``000000.tif, 000001.tif, …`` (and optionally ``recon.json``).

    Returns
    -------
    list of VolumeInfo
        In frame order.

    Raises
    ------
    InputError
        No volumes, a gap in the numbering ("volume NNNNNN.tif is missing"), a truncated
        file, a volume without a voxel size, shapes (a 2-D image is one plane) or
        voxel types that differ ("mixed series") or voxel sizes that differ ("mismatched voxel
        sizes").
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"volume folder {folder} does not exist or is not a folder")
    files = {}
    for p in folder.iterdir():
        m = NUMBERED.match(p.name)
        if m and m.group(2) in ("tif", "tiff"):
            files[int(m.group(1))] = p
    if not files:
        raise InputError(f"{folder} holds no numbered volumes NNNNNN.tif")
    idx = sorted(files)
    missing = sorted(set(range(idx[0], idx[-1] + 1)) - set(idx))
    recon = {}
    if (folder / RECON_JSON).is_file():
        recon = read_json(folder / RECON_JSON)
        if not isinstance(recon, Mapping):
            raise InputError(f"{folder / RECON_JSON} is not a JSON object")
        n_frames = len(recon.get("frames") or [])
        if n_frames:
            missing = sorted(set(missing) | (set(range(n_frames)) - set(idx)))
    if missing:
        names = ", ".join(f"{k:06d}.tif" for k in missing[:5])
        raise InputError(f"{folder}: volume {names} is missing from the numbered series")
    recon_vs = None
    if recon.get("voxel_size_um") is not None:
        recon_vs = _voxel_size(recon["voxel_size_um"], str(folder / RECON_JSON))
    out, dtypes = [], []
    for k in idx:
        p = files[k]
        head = _tiff_header(p)
        dtypes.append(np.dtype(head.dtype))
        shape, meta = head.shape, head.meta
        if np.dtype(head.dtype).kind not in "uif":
            raise InputError(f"{p}: unsupported voxel type {head.dtype}")
        if meta.get("voxel_size_um") is not None:
            vs = _voxel_size(meta["voxel_size_um"], str(p))
        elif head.imagej_vs is not None:
            vs = head.imagej_vs
        elif recon_vs is not None:
            vs = recon_vs
        else:
            raise InputError(
                f"{p}: no voxel size (no 'voxel_size_um' in the TIFF metadata, no ImageJ "
                f"calibration in µm and no {RECON_JSON} in {folder})"
            )
        origin = (
            _origin(meta, vs, str(p))
            or head.imagej_origin
            or _origin(recon.get("grid") or {}, vs, RECON_JSON)
        )
        out.append(VolumeInfo(p, k, shape, vs, origin or (0.0, 0.0, 0.0)))
    first = out[0]
    for v, dtype in zip(out[1:], dtypes[1:], strict=True):
        if v.shape != first.shape or dtype != dtypes[0]:
            raise InputError(
                f"mixed series: {v.path} holds {' × '.join(map(str, v.shape))} voxels of "
                f"{dtype}, {first.path} {' × '.join(map(str, first.shape))} of {dtypes[0]} "
                "(z × y × x); the volumes of a series must match"
            )
        if not np.allclose(v.voxel_size_um, first.voxel_size_um, rtol=1e-6, atol=0):
            raise InputError(
                f"mismatched voxel sizes: {v.path} has {list(v.voxel_size_um)} µm, "
                f"{first.path} has {list(first.voxel_size_um)} µm"
            )
    return out


def read_volume(info: VolumeInfo | str | os.PathLike) -> np.ndarray:
    """Voxels of a volume as float32 ``(z, y, x)``.

    Raises
    ------
    InputError
        Unreadable file or non-finite voxels.
    """
    import tifffile

    path = Path(info.path if isinstance(info, VolumeInfo) else info)
    try:
        arr = tifffile.imread(path)
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc
    if arr.ndim == 2:
        arr = arr[None]
    if isinstance(info, VolumeInfo):
        arr = arr.reshape(info.shape)
    if arr.ndim != 3:
        raise InputError(f"{path}: expected a (z, y, x) volume, got shape {arr.shape}")
    arr = arr.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: volume holds NaN or infinite voxels")
    return arr


def numbered(folder: str | os.PathLike, index: int, suffix: str) -> Path:
    """``folder/NNNNNN<suffix>``."""
    return Path(folder) / f"{int(index):06d}{suffix}"


__all__ = ["NUMBERED", "RECON_JSON", "VolumeInfo", "numbered", "read_volume", "scan_volumes"]
