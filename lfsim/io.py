"""Files: atomic writes, JSON, checksums and TIFF images/volumes with JSON metadata.

Every writer here is **atomic**: the data go to a temporary file in the destination folder
(``.NAME.XXXX.tmp``), are flushed to disk, and only then take the destination's name
(``os.replace``, or a hard link when an existing file must not be replaced). A reader therefore
sees either the old file, no file, or the complete new file — never a partial one — and an
interrupted program leaves at most a hidden ``*.tmp`` file behind.

TIFF layout (:func:`write_tiff`, :func:`read_tiff`; DESIGN.md §2):

- images ``(y, x)`` and volumes ``(z, y, x)`` (one page per z slice), any numeric dtype;
- the ``ImageDescription`` tag of the first page holds the caller's ``metadata`` as JSON;
  for 3-D float32 volumes with a voxel size it also holds ``"voxel_size_um": [dz, dy, dx]``;
- with a pixel size the ``XResolution``/``YResolution`` tags hold ``1e4 / dx`` and
  ``1e4 / dy`` pixels per centimetre (standard TIFF units; the JSON stays authoritative);
- a private tag (65000) records the array shape so that ``(1, y, x)`` volumes come back 3-D.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, OutputError

log = logging.getLogger(__name__)

#: Private TIFF tag holding ``{"shape": [...]}`` (the reusable private range starts at 65000).
SHAPE_TAG = 65000

#: Metadata key under which 3-D float32 volumes store their voxel size ``[dz, dy, dx]`` (µm).
VOXEL_SIZE_KEY = "voxel_size_um"


# -- atomic writes -------------------------------------------------------------------------
def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _publish(tmp: str, path: Path, overwrite: bool) -> None:
    """Give the finished temporary file ``tmp`` the name ``path``."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        # A hard link fails if ``path`` exists: no window in which another file is clobbered.
        os.link(tmp, path)
    except FileExistsError:
        raise OutputError(
            f"{path} already exists; refusing to overwrite it (pass overwrite=True / --overwrite)"
        ) from None
    except OSError:
        # File systems without hard links: check, then rename.
        if os.path.lexists(path):
            raise OutputError(
                f"{path} already exists; refusing to overwrite it "
                "(pass overwrite=True / --overwrite)"
            ) from None
        os.replace(tmp, path)
        return
    os.unlink(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = True) -> Iterator[Path]:
    """Context manager yielding a temporary path that becomes ``path`` on success.

    Write the complete file to the yielded path inside the ``with`` block; on normal exit it
    is flushed to disk and renamed to ``path``; on an exception it is deleted and ``path`` is
    left as it was. Missing parent folders are created.

    Parameters
    ----------
    path : path
        Destination.
    overwrite : bool
        Replace an existing ``path`` (default). With ``False`` an existing file raises
        :class:`OutputError` (checked before and, race-free, at the rename).

    Raises
    ------
    OutputError
        When ``path`` exists (``overwrite=False``) or its folder cannot be created or written;
        the message names ``path``.
    """
    path = Path(path)
    if not overwrite and os.path.lexists(path):
        raise OutputError(
            f"{path} already exists; refusing to overwrite it (pass overwrite=True / --overwrite)"
        )
    if path.is_dir():
        raise OutputError(f"{path} is a folder; expected a file name")
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
    except OSError as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise OutputError(
            f"cannot write {path}: folder {path.parent} is not writable ({exc})"
        ) from exc
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        _publish(tmp, path, overwrite)
        tmp = None
        _fsync_dir(path.parent)
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc}") from exc
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder + rename).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        When the folder is not writable, or ``path`` exists and ``overwrite`` is false.
    """
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return path


def atomic_write_text(
    path: str | os.PathLike, text: str, *, overwrite: bool = True, encoding: str = "utf-8"
) -> Path:
    """Write ``text`` to ``path`` atomically; see :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, text.encode(encoding), overwrite=overwrite)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def to_json(obj: Any, *, indent: int | None = 2) -> str:
    """``obj`` as JSON text (numpy scalars/arrays and paths converted; NaN/inf refused)."""
    try:
        return json.dumps(obj, indent=indent, default=_json_default, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"cannot write metadata as JSON: {exc}") from exc


def write_json(path: str | os.PathLike, obj: Any, *, overwrite: bool = True) -> Path:
    """Write ``obj`` as indented JSON (trailing newline), atomically."""
    return atomic_write_text(path, to_json(obj, indent=2) + "\n", overwrite=overwrite)


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing or invalid file raises :class:`ConfigError` naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read JSON file {path}: {exc}") from exc


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes (a missing file raises :class:`ConfigError`)."""
    path = Path(path)
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            while block := fh.read(chunk):
                h.update(block)
    except OSError as exc:
        raise ConfigError(f"cannot read {path}: {exc}") from exc
    return h.hexdigest()


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
