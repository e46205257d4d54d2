"""Files of :mod:`lfsim`: TIFF images/volumes with JSON metadata.

Atomic writes, JSON and checksums come from the shared base (:mod:`hrvbase.io`) and are
re-exported here: every writer is atomic and refuses to replace a file without ``overwrite``.

TIFF layout (:func:`write_tiff`, :func:`read_tiff`; DESIGN.md §2):

- images ``(y, x)`` and volumes ``(z, y, x)`` (one page per z slice), any numeric dtype;
- the ``ImageDescription`` tag of the first page holds the caller's ``metadata`` as JSON;
  for 3-D float32 volumes with a voxel size it also holds ``"voxel_size_um": [dz, dy, dx]``;
- with a pixel size the ``XResolution``/``YResolution`` tags hold ``1e4 / dx`` and
  ``1e4 / dy`` pixels per centimetre (standard TIFF units; the JSON stays authoritative);
- a private tag (65000) records the array shape so that ``(1, y, x)`` volumes come back 3-D.
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

#: Metadata key under which 3-D float32 volumes store their voxel size ``[dz, dy, dx]`` (µm).
VOXEL_SIZE_KEY = "voxel_size_um"


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


def write_tiff(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    metadata: Mapping[str, Any],
    pixel_size_um: float | tuple | None = None,
    overwrite: bool = False,
) -> Path:
    """Write an image ``(y, x)`` or volume ``(z, y, x)`` as TIFF with JSON metadata, atomically.

    Parameters
    ----------
    path : path
        Destination ``.tif``.
    array : ndarray, 2-D or 3-D
        Any numeric dtype (camera frames are uint8/uint16, volumes float32).
    metadata : Mapping
        JSON-serialisable dict stored in the ``ImageDescription`` tag; :func:`read_tiff`
        returns it unchanged (plus ``voxel_size_um`` for volumes, below).
    pixel_size_um : float or tuple, optional
        ``dx = dy`` (a number) or ``(dy, dx)`` for images; a number or ``(dz, dy, dx)`` for
        volumes. Written to the resolution tags; for 3-D float32 volumes also as
        ``metadata["voxel_size_um"] = [dz, dy, dx]``.
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
        Bad array, pixel size or non-JSON metadata.
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
    meta = dict(metadata)
    if sizes is not None and arr.ndim == 3 and arr.dtype == np.float32:
        meta[VOXEL_SIZE_KEY] = list(sizes)
    description = to_json(meta, indent=None)
    kw: dict[str, Any] = {}
    if sizes is not None:
        dy, dx = sizes[-2], sizes[-1]
        kw["resolution"] = (1e4 / dx, 1e4 / dy)
        kw["resolutionunit"] = "CENTIMETER"
    shape_tag = (SHAPE_TAG, "s", 0, json.dumps({"shape": list(arr.shape)}), True)
    with atomic_path(path, overwrite=overwrite) as tmp:
        try:
            tifffile.imwrite(
                tmp,
                arr,
                photometric="minisblack",
                description=description,
                metadata=None,
                software=False,
                extratags=[shape_tag],
                **kw,
            )
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"write_tiff({path}): {exc}") from exc
    log.debug("wrote %s %s %s", path, arr.dtype, arr.shape)
    return path


def read_tiff(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read a TIFF written by :func:`write_tiff`: ``(array, metadata)``.

    The array has the dtype and shape written; ``metadata`` is the JSON object of the
    ``ImageDescription`` tag (``{}`` when there is none; ``{"description": text}`` for a
    foreign TIFF whose description is not a JSON object).

    Raises
    ------
    ConfigError
        The file is missing or not a readable TIFF (names ``path``).
    """
    import tifffile

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"TIFF file {path} does not exist")
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            text = page.description or ""
            tag = page.tags.get(SHAPE_TAG)
            arr = tif.asarray()
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise ConfigError(f"cannot read TIFF file {path}: {exc}") from exc
    if tag is not None:
        try:
            shape = tuple(json.loads(tag.value)["shape"])
            arr = arr.reshape(shape)
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"TIFF file {path}: bad shape tag {tag.value!r}") from exc
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
