"""Files of :mod:`lfsim`: TIFF images and volumes that carry their scale and our metadata.

Atomic writes, JSON and checksums come from the shared base (:mod:`hrvbase.io`) and are
re-exported here: every writer is atomic and refuses to replace a file without ``overwrite``.

TIFF layout (:func:`write_tiff`, :func:`read_tiff`; ``docs/conventions.md``):

- images ``(y, x)`` and volumes ``(z, y, x)`` (one page per z slice), any numeric dtype;
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
per centimetre) are still read: :func:`read_tiff` returns the same ``(array, metadata)``.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import (
    atomic_path,
    atomic_write_bytes,
    atomic_write_text,
    read_json,
    sha256_file,
    to_json,
    write_json,
)

from .errors import ConfigError

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


# -- TIFF ----------------------------------------------------------------------------------
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
            raise ConfigError(
                f"pixel_size_um must be a number or {ndim} numbers, got {pixel_size_um!r}"
            ) from exc
        if len(vals) != ndim:
            order = "(dy, dx)" if ndim == 2 else "(dz, dy, dx)"
            raise ConfigError(
                f"pixel_size_um for a {ndim}-D array must be one number or {ndim} numbers "
                f"{order}, got {pixel_size_um!r}"
            )
    if not all(math.isfinite(v) and v > 0 for v in vals):
        raise ConfigError(f"pixel_size_um must be positive and finite, got {pixel_size_um!r}")
    return vals


def _origin(origin_xyz_um, ndim: int) -> tuple[float, float, float] | None:
    """Object-space origin ``(x0, y0, z0)`` (µm) of a volume, validated."""
    if origin_xyz_um is None:
        return None
    if ndim != 3:
        raise ConfigError("origin_xyz_um applies to 3-D (z, y, x) volumes only")
    try:
        vals = tuple(float(v) for v in origin_xyz_um)
    except (TypeError, ValueError):
        raise ConfigError(
            f"origin_xyz_um must be 3 numbers (x, y, z) in µm, got {origin_xyz_um!r}"
        ) from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ConfigError(
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
    ConfigError
        Bad array, pixel size, origin or non-JSON metadata.
    """
    import tifffile

    path = Path(path)
    arr = np.asarray(array)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise ConfigError(
            f"write_tiff({path}): expected a non-empty 2-D (y, x) image or 3-D (z, y, x) volume, "
            f"got shape {arr.shape}"
        )
    if arr.dtype.kind not in "uif" or arr.dtype.itemsize > 8:
        raise ConfigError(f"write_tiff({path}): unsupported dtype {arr.dtype}")
    if not isinstance(metadata, Mapping):
        raise ConfigError(f"write_tiff({path}): metadata must be a dict, got {type(metadata)}")
    sizes = _sizes(pixel_size_um, arr.ndim)
    origin = _origin(origin_xyz_um, arr.ndim)
    if origin is not None and sizes is None:
        raise ConfigError(f"write_tiff({path}): origin_xyz_um needs pixel_size_um")
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
            raise ConfigError(f"write_tiff({path}): {exc}") from exc
    log.debug("wrote %s %s %s", path, arr.dtype, arr.shape)
    return path


def read_tiff(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read a TIFF written by :func:`write_tiff`: ``(array, metadata)``.

    The array has the dtype and shape written; ``metadata`` is the JSON object of the
    private tag :data:`METADATA_TAG`, or, in files of the previous layout, of the
    ``ImageDescription`` tag (``{}`` when there is none; ``{"description": text}`` for a
    foreign TIFF whose description is not a JSON object).

    Raises
    ------
    ConfigError
        The file is missing or not a readable TIFF, or its metadata tag is not a JSON object
        (names ``path``).
    """
    import tifffile

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"TIFF file {path} does not exist")
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            text = page.description or ""
            tags = {code: page.tags.get(code) for code in (SHAPE_TAG, METADATA_TAG)}
            values = {code: tag.value if tag is not None else None for code, tag in tags.items()}
            arr = tif.asarray()
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise ConfigError(f"cannot read TIFF file {path}: {exc}") from exc
    if values[SHAPE_TAG] is not None:
        try:
            shape = tuple(json.loads(values[SHAPE_TAG])["shape"])
            arr = arr.reshape(shape)
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"TIFF file {path}: bad shape tag {values[SHAPE_TAG]!r}") from exc
    if values[METADATA_TAG] is not None:
        try:
            meta = json.loads(values[METADATA_TAG])
        except (ValueError, TypeError):
            meta = None
        if not isinstance(meta, dict):
            raise ConfigError(
                f"TIFF file {path}: metadata tag {METADATA_TAG} does not hold a JSON object"
            )
        return arr, meta
    # The previous layout (and foreign files): JSON, if any, in the ImageDescription.
    if not text:
        return arr, {}
    try:
        meta = json.loads(text)
    except json.JSONDecodeError:
        return arr, {"description": text}
    if not isinstance(meta, dict):
        return arr, {"description": text}
    return arr, meta


__all__ = [
    "IMAGEJ_DTYPES",
    "METADATA_TAG",
    "ORIGIN_KEY",
    "SHAPE_TAG",
    "VOXEL_SIZE_KEY",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "read_json",
    "read_tiff",
    "sha256_file",
    "to_json",
    "write_json",
    "write_tiff",
]
