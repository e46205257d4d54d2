"""The TIFF layout of the toolkit's images and volumes, defined once: writer and parsers.

Images ``(y, x)`` and volumes ``(z, y, x)`` carry their scale and our metadata
(:func:`write_tiff`, :func:`read_tiff`; ``docs/conventions.md``):

- one page per z slice, any numeric dtype;
- uint8, uint16, int16 and float32 arrays (camera frames, volumes) are **ImageJ
  hyperstacks**, so that Fiji (and napari with the napari-tiff plugin) show them at their
  physical scale: the ``ImageDescription`` holds ImageJ's ``key=value`` lines (axes ``ZYX``
  or ``YX``, ``unit=um``, ``spacing`` = dz in µm, and ``xorigin``/``yorigin``/``zorigin``,
  the voxel index of the object-space origin, when an origin is given), and
  ``XResolution``/``YResolution`` hold ``1/dx`` and ``1/dy`` pixels per µm with
  ``ResolutionUnit`` none (ImageJ's convention: the unit is in the description);
- other dtypes (e.g. float64) are plain TIFF with ``XResolution``/``YResolution`` in pixels
  per centimetre (standard TIFF units);
- a private tag (:data:`METADATA_TAG`, 65001) holds the caller's ``metadata`` as JSON; for
  3-D float32 volumes with a voxel size it also holds ``"voxel_size_um": [dz, dy, dx]``, and
  with an origin ``"origin_xyz_um": [x0, y0, z0]`` (the JSON is authoritative);
- a private tag (:data:`SHAPE_TAG`, 65000) records the array shape so that ``(1, y, x)``
  volumes come back 3-D.

Files of the previous layout (the JSON in the ``ImageDescription`` tag, resolution in pixels
per centimetre) are still read: :func:`read_tiff` returns the same ``(array, metadata)``, and
:func:`read_volume_header` the same metadata. :func:`read_volume_header` also reads the ImageJ
calibration of a volume saved by Fiji (:func:`imagej_calibration`) and checks, from the
headers alone, that the file holds all the voxels it declares.

Errors are :class:`hrvbase.errors.InputError` (one line naming the file); each package raises
them as its own type (:func:`hrvbase.errors.raised_as`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..io import atomic_path, to_json

log = logging.getLogger(__name__)

#: Private TIFF tag holding ``{"shape": [...]}`` (the reusable private range starts at 65000).
SHAPE_TAG = 65000

#: Private TIFF tag holding the caller's metadata as JSON (files written since the ImageJ
#: layout; older files hold it in the ``ImageDescription`` tag).
METADATA_TAG = 65001

#: Metadata key under which 3-D float32 volumes store their voxel size ``[dz, dy, dx]`` (µm).
VOXEL_SIZE_KEY = "voxel_size_um"

#: Metadata key under which volumes store the object-space ``[x, y, z]`` (µm) of the centre of
#: voxel ``(0, 0, 0)``.
ORIGIN_KEY = "origin_xyz_um"

#: NumPy dtypes the ImageJ hyperstack format holds (8/16-bit integers, 32-bit float).
IMAGEJ_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.int16), np.dtype(np.float32))


#: Spellings of the micrometre in ImageJ's ``unit=`` entry.
MICROMETRE = frozenset(
    {"um", "\u00b5m", "\\u00b5m", "micron", "microns", "micrometer", "micrometre"}
)


def _sizes(pixel_size_um, ndim: int) -> tuple[float, ...] | None:
    """Pixel size as ``(dy, dx)`` (2-D) or ``(dz, dy, dx)`` (3-D), validated."""
    if pixel_size_um is None:
        return None
    if isinstance(pixel_size_um, int | float | np.integer | np.floating) and not isinstance(
        pixel_size_um, bool
    ):
        vals = (float(pixel_size_um),) * ndim
    else:
        try:
            vals = tuple(float(v) for v in pixel_size_um)
        except (TypeError, ValueError) as exc:
            raise InputError(
                f"pixel_size_um must be a number or {ndim} numbers, got {pixel_size_um!r}"
            ) from exc
        if len(vals) != ndim:
            order = "(dy, dx)" if ndim == 2 else "(dz, dy, dx)"
            raise InputError(
                f"pixel_size_um for a {ndim}-D array must be one number or {ndim} numbers "
                f"{order}, got {pixel_size_um!r}"
            )
    if not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"pixel_size_um must be positive and finite, got {pixel_size_um!r}")
    return vals


def _origin(origin_xyz_um, ndim: int) -> tuple[float, float, float] | None:
    """Object-space origin ``(x0, y0, z0)`` (µm) of a volume, validated."""
    if origin_xyz_um is None:
        return None
    if ndim != 3:
        raise InputError("origin_xyz_um applies to 3-D (z, y, x) volumes only")
    try:
        vals = tuple(float(v) for v in origin_xyz_um)
    except (TypeError, ValueError):
        raise InputError(
            f"origin_xyz_um must be 3 numbers (x, y, z) in µm, got {origin_xyz_um!r}"
        ) from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise InputError(
            f"origin_xyz_um must be 3 finite numbers (x, y, z) in µm, got {origin_xyz_um!r}"
        )
    return vals


def _imagej_metadata(ndim: int, sizes, origin) -> dict[str, Any]:
    """ImageJ description entries: axes, unit, z spacing and the origin in voxel units."""
    meta: dict[str, Any] = {"axes": "ZYX" if ndim == 3 else "YX"}
    if sizes is None:
        return meta
    meta["unit"] = "um"
    if ndim == 3:
        meta["spacing"] = sizes[0]
    if origin is not None:
        # ImageJ: physical coordinate = (index - origin) * size, so the origin is the
        # (fractional) index at which the object-space coordinate is 0.
        dz, dy, dx = sizes
        meta["xorigin"] = -origin[0] / dx
        meta["yorigin"] = -origin[1] / dy
        meta["zorigin"] = -origin[2] / dz
    return meta


def write_tiff(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    metadata: Mapping[str, Any],
    pixel_size_um: float | tuple | None = None,
    origin_xyz_um: tuple | None = None,
    overwrite: bool = False,
) -> Path:
    """Write an image ``(y, x)`` or volume ``(z, y, x)`` as TIFF with its scale, atomically.

    uint8, uint16, int16 and float32 arrays are written as ImageJ hyperstacks that carry the
    physical pixel/voxel size (and origin), so that Fiji shows them in µm; the caller's
    ``metadata`` goes, as JSON, into a private tag (see the module docstring).

    Parameters
    ----------
    path : path
        Destination ``.tif``.
    array : ndarray, 2-D or 3-D
        Any numeric dtype (camera frames are uint8/uint16, volumes float32).
    metadata : Mapping
        JSON-serialisable dict stored in the private tag :data:`METADATA_TAG`;
        :func:`read_tiff` returns it unchanged (plus ``voxel_size_um`` and ``origin_xyz_um``
        for volumes, below).
    pixel_size_um : float or tuple, optional
        ``dx = dy`` (a number) or ``(dy, dx)`` for images; a number or ``(dz, dy, dx)`` for
        volumes. Written to the resolution tags and the ImageJ ``spacing``; for 3-D float32
        volumes also as ``metadata["voxel_size_um"] = [dz, dy, dx]``.
    origin_xyz_um : tuple of 3 float, optional
        Volumes only (needs ``pixel_size_um``): object-space ``(x, y, z)`` of the centre of
        voxel ``(0, 0, 0)`` (µm). Written as ``metadata["origin_xyz_um"]`` and as ImageJ's
        ``xorigin``/``yorigin``/``zorigin`` (``-x0/dx``, ``-y0/dy``, ``-z0/dz`` voxels).
    overwrite : bool
        Replace an existing file (default: refuse).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        ``path`` exists and ``overwrite`` is false, or it cannot be written (names ``path``).
    InputError
        Bad array, pixel size, origin or non-JSON metadata.
    """
    import tifffile

    path = Path(path)
    arr = np.asarray(array)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise InputError(
            f"write_tiff({path}): expected a non-empty 2-D (y, x) image or 3-D (z, y, x) volume, "
            f"got shape {arr.shape}"
        )
    if arr.dtype.kind not in "uif" or arr.dtype.itemsize > 8:
        raise InputError(f"write_tiff({path}): unsupported dtype {arr.dtype}")
    if not isinstance(metadata, Mapping):
        raise InputError(f"write_tiff({path}): metadata must be a dict, got {type(metadata)}")
    sizes = _sizes(pixel_size_um, arr.ndim)
    origin = _origin(origin_xyz_um, arr.ndim)
    if origin is not None and sizes is None:
        raise InputError(f"write_tiff({path}): origin_xyz_um needs pixel_size_um")
    meta = dict(metadata)
    if sizes is not None and arr.ndim == 3 and arr.dtype == np.float32:
        meta[VOXEL_SIZE_KEY] = list(sizes)
    if origin is not None:
        meta[ORIGIN_KEY] = list(origin)
    text = to_json(meta, indent=None)  # ASCII: non-ASCII characters are escaped
    extratags = [
        (SHAPE_TAG, "s", 0, json.dumps({"shape": list(arr.shape)}), True),
        (METADATA_TAG, "s", 0, text, True),
    ]
    kw: dict[str, Any] = {}
    if arr.dtype in IMAGEJ_DTYPES:
        kw["imagej"] = True
        kw["metadata"] = _imagej_metadata(arr.ndim, sizes, origin)
        if sizes is not None:
            kw["resolution"] = (1.0 / sizes[-1], 1.0 / sizes[-2])  # pixels per µm
            kw["resolutionunit"] = "NONE"
    else:
        kw["metadata"] = None
        if sizes is not None:
            kw["resolution"] = (1e4 / sizes[-1], 1e4 / sizes[-2])  # pixels per cm
            kw["resolutionunit"] = "CENTIMETER"
    with atomic_path(path, overwrite=overwrite) as tmp:
        try:
            tifffile.imwrite(
                tmp, arr, photometric="minisblack", software=False, extratags=extratags, **kw
            )
        except (ValueError, TypeError) as exc:
            raise InputError(f"write_tiff({path}): {exc}") from exc
    log.debug("wrote %s %s %s", path, arr.dtype, arr.shape)
    return path


def parse_metadata(tag_value, description: str, path: Path) -> dict:
    """Our JSON metadata of a TIFF: the private tag :data:`METADATA_TAG` (``tag_value``), or in
    files of the previous layout the JSON object of the ``description`` (``{}`` when there is
    none; ``{"description": text}`` for a foreign TIFF whose description is not JSON).

    Raises
    ------
    InputError
        The private tag does not hold a JSON object (names ``path``).
    """
    if tag_value is not None:
        try:
            meta = json.loads(tag_value)
        except (ValueError, TypeError):
            meta = None
        if not isinstance(meta, dict):
            raise InputError(
                f"TIFF file {path}: metadata tag {METADATA_TAG} does not hold a JSON object"
            )
        return meta
    if not description:
        return {}
    try:
        meta = json.loads(description)
    except json.JSONDecodeError:
        return {"description": description}
    return meta if isinstance(meta, dict) else {"description": description}


def _shape_tag(value) -> tuple[int, ...] | None:
    """The array shape recorded in :data:`SHAPE_TAG` (None: no tag, or not readable)."""
    if value is None:
        return None
    try:
        return tuple(int(n) for n in json.loads(value)["shape"])
    except (ValueError, KeyError, TypeError):
        return None


def read_tiff(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read a TIFF written by :func:`write_tiff`: ``(array, metadata)``.

    The array has the dtype and shape written; ``metadata`` is the JSON object of the
    private tag :data:`METADATA_TAG`, or, in files of the previous layout, of the
    ``ImageDescription`` tag (:func:`parse_metadata`).

    Raises
    ------
    InputError
        The file is missing or not a readable TIFF, or its metadata tag is not a JSON object
        (names ``path``).
    """
    import tifffile

    path = Path(path)
    if not path.is_file():
        raise InputError(f"TIFF file {path} does not exist")
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            text = page.description or ""
            tags = {code: page.tags.get(code) for code in (SHAPE_TAG, METADATA_TAG)}
            values = {code: tag.value if tag is not None else None for code, tag in tags.items()}
            arr = tif.asarray()
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF file {path}: {exc}") from exc
    if values[SHAPE_TAG] is not None:
        shape = _shape_tag(values[SHAPE_TAG])
        try:
            arr = arr.reshape(shape)
        except (ValueError, TypeError) as exc:
            raise InputError(f"TIFF file {path}: bad shape tag {values[SHAPE_TAG]!r}") from exc
    return arr, parse_metadata(values[METADATA_TAG], text, path)


@dataclass(frozen=True)
class TiffVolumeHeader:
    """What :func:`read_volume_header` reads: shape ``(z, y, x)``, dtype, our JSON metadata
    (:func:`parse_metadata`) and the ImageJ calibration (µm) of a volume file."""

    shape: tuple
    dtype: Any
    meta: dict
    imagej_vs: tuple | None = None  # (dz, dy, dx) µm from a Fiji calibration
    imagej_origin: tuple | None = None  # (x, y, z) µm of voxel (0, 0, 0)


def imagej_calibration(ij: Mapping | None, page) -> tuple[tuple | None, tuple | None]:
    """Voxel size ``(dz, dy, dx)`` and origin ``(x, y, z)`` (µm) of an ImageJ calibration.

    ``(None, None)`` unless the unit is a micrometre and spacing and resolutions are positive.
    """
    if not ij or str(ij.get("unit", "")).strip().lower() not in MICROMETRE:
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


@contextlib.contextmanager
def quiet(*names: str):
    """Hold the loggers ``names`` to errors: tifffile logs each unreadable page header of a
    damaged file, and asyncio the pending reads of a failed Zarr decode, on stderr; the one
    :class:`InputError` that follows says it."""
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _data_end(tif, n_voxels: int | None = None) -> int:
    """Byte just past the last voxel data of the first series (headers only).

    ``n_voxels``: the voxels the file declares (its shape tag); contiguous data then end
    ``n_voxels`` items after the first, even where the page headers past the cut are lost.
    """
    series = tif.series[0]
    if series.dataoffset is not None:  # contiguous data
        n = int(series.nbytes) if n_voxels is None else n_voxels * series.dtype.itemsize
        return int(series.dataoffset) + max(int(series.nbytes), n)
    end = 0
    for page in tif.pages:
        for offset, count in zip(page.dataoffsets, page.databytecounts, strict=True):
            end = max(end, int(offset) + int(count))
    return end


def read_volume_header(path: Path) -> TiffVolumeHeader:
    """Shape, dtype and metadata of a volume file, without reading its voxels."""
    import tifffile

    try:
        with quiet("tifffile"), tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            desc = page.description or ""
            tagvals = {}
            for code in (SHAPE_TAG, METADATA_TAG):
                tag = page.tags.get(code)
                tagvals[code] = tag.value if tag is not None else None
            shape = readable = tuple(tif.series[0].shape)
            dtype = tif.series[0].dtype
            shape = _shape_tag(tagvals[SHAPE_TAG]) or shape
            ij_vs, ij_origin = imagej_calibration(tif.imagej_metadata, page)
            end = _data_end(tif, math.prod(shape))
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc
    size = path.stat().st_size
    if end > size:
        raise InputError(
            f"TIFF volume {path} is truncated: its voxels end at byte {end} but the file has "
            f"{size} bytes (an interrupted copy or write?)"
        )
    if math.prod(readable) != math.prod(shape):
        raise InputError(
            f"TIFF volume {path} is truncated or damaged: it declares "
            f"{' × '.join(map(str, shape))} voxels but its pages hold "
            f"{' × '.join(map(str, readable))}"
        )
    if len(shape) == 2:
        shape = (1, *shape)
    if len(shape) != 3:
        raise InputError(f"{path}: expected a (z, y, x) volume, got shape {shape}")
    meta = parse_metadata(tagvals[METADATA_TAG], desc, path)
    return TiffVolumeHeader(shape, dtype, meta, ij_vs, ij_origin)


__all__ = [
    "IMAGEJ_DTYPES",
    "METADATA_TAG",
    "MICROMETRE",
    "ORIGIN_KEY",
    "SHAPE_TAG",
    "VOXEL_SIZE_KEY",
    "TiffVolumeHeader",
    "imagej_calibration",
    "parse_metadata",
    "quiet",
    "read_tiff",
    "read_volume_header",
    "write_tiff",
]
