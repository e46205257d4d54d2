"""Files of :mod:`lfsim`: TIFF images and volumes that carry their scale and our metadata.

The TIFF layout (ImageJ hyperstacks with their scale, the private tags holding the shape and
our JSON metadata) is defined once, in :mod:`hrvbase.formats.tiff_layout`; :func:`write_tiff`
and :func:`read_tiff` are its writer and reader raising :class:`lfsim.errors.ConfigError`.
Atomic writes, JSON and checksums come from the shared base (:mod:`hrvbase.io`) and are
re-exported here for :mod:`lfsim`'s own modules: every writer is atomic and refuses to
replace a file without ``overwrite``.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.formats import tiff_layout
from hrvbase.formats.tiff_layout import (
    IMAGEJ_DTYPES,
    METADATA_TAG,
    ORIGIN_KEY,
    SHAPE_TAG,
    VOXEL_SIZE_KEY,
)
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


@functools.wraps(tiff_layout.write_tiff, assigned=(), updated=())  # its signature
def write_tiff(*args: Any, **kwargs: Any) -> Path:
    """Write an image ``(y, x)`` or volume ``(z, y, x)`` as TIFF with its scale, atomically
    (:func:`hrvbase.formats.tiff_layout.write_tiff`, whose parameters it takes and whose
    errors it raises, a bad array, pixel size, origin or metadata as :class:`ConfigError`)."""
    with raised_as(ConfigError):
        return tiff_layout.write_tiff(*args, **kwargs)


def read_tiff(path: str | os.PathLike) -> tuple[np.ndarray, dict]:
    """Read a TIFF written by :func:`write_tiff`: ``(array, metadata)``
    (:func:`hrvbase.formats.tiff_layout.read_tiff`).

    Raises
    ------
    ConfigError
        The file is missing or not a readable TIFF, or its metadata tag is not a JSON object
        (names ``path``).
    """
    with raised_as(ConfigError):
        return tiff_layout.read_tiff(path)


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
