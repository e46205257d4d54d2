"""Frame reader: TIFF camera frames, one image per file or a multi-page stack.

A multi-page stack (the usual high-speed camera export) holds one frame per page, in page
order. The header gives the image count, size, pixel type and recorded bit depth, and the
times where recorded: the ``finterval`` of an ImageJ stack, or a ``"time_s"`` entry in the
JSON metadata of :func:`hrvbase.formats.tiff_layout.write_tiff` (or in a JSON image
description).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from .registry import FrameHeader
from .tiff_layout import METADATA_TAG

#: Name of this format in the registry and in ``recon.json``.
NAME = "tiff"

#: File name endings (compared in lower case) of the TIFFs a folder contributes.
SUFFIXES = (".tif", ".tiff")

_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def sniff(head: bytes) -> bool:
    """Whether the file starts like a TIFF (classic or BigTIFF, either byte order)."""
    return head[:4] in _MAGIC


def _errors():
    import tifffile

    return (OSError, ValueError, IndexError, KeyError, tifffile.TiffFileError)


def _finite_or_none(value) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _check_file(path: Path, what: str) -> None:
    if path.is_dir():
        raise InputError(f"{what} {str(path)!r} is a folder, not a TIFF file")
    if not path.is_file():
        raise InputError(f"{what} {str(path)!r} does not exist")


def probe(path: Path, what: str = "frame") -> FrameHeader:
    """Image count, size, pixel type and timing metadata of a TIFF, from its header only.

    Raises
    ------
    InputError
        Missing or unreadable file, images of several sizes or types in one file, colour or
        multi-channel images, a non-numeric pixel type (names the file).
    """
    import tifffile

    path = Path(path)
    _check_file(path, what)
    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series
            first = series[0]
            shape, axes, dtype = tuple(first.shape), first.axes, np.dtype(first.dtype)
            page = tif.pages[0]
            bits = int(page.bitspersample)
            tag = page.tags.get(METADATA_TAG)  # our JSON; older files: the description
            description = str(tag.value) if tag is not None else page.description or ""
            ij = tif.imagej_metadata or {}
    except _errors() as exc:
        raise InputError(f"cannot read {what} {str(path)!r} as TIFF: {exc}") from exc
    if len(series) > 1:
        raise InputError(
            f"{what} {str(path)!r} holds images of {len(series)} different sizes or pixel "
            "types; expected one image or a stack of equal images"
        )
    colour = {a: n for a, n in zip(axes, shape, strict=True) if a in "SC" and n > 1}
    if len(shape) < 2 or colour:
        raise InputError(
            f"{what} {str(path)!r} holds an array of shape {shape} (axes {axes}); expected "
            "grey-level images (y, x), one per page"
        )
    if dtype.kind not in "uif":
        raise InputError(f"{what} {str(path)!r} has unsupported pixel type {dtype}")
    time_s = None
    if description.lstrip().startswith("{"):
        try:
            meta = json.loads(description)
        except json.JSONDecodeError:
            meta = {}
        if isinstance(meta, dict):
            time_s = _finite_or_none(meta.get("time_s"))
    interval = _finite_or_none(ij.get("finterval"))
    return FrameHeader(
        n_images=math.prod(shape[:-2]),
        shape=(int(shape[-2]), int(shape[-1])),
        dtype=str(dtype),
        bits=bits,
        frame_interval_s=interval if interval and interval > 0 else None,
        time_s=time_s,
    )


class TiffFrames:
    """An open TIFF frame file: a single image, or the pages of a stack (kept open between
    pages, so that a page of a long stack is read without parsing the file again)."""

    def __init__(self, path: Path, what: str = "frame") -> None:
        self.path = Path(path)
        self.what = what
        self._tif = None
        self._n_pages = 0

    def close(self) -> None:
        if self._tif is not None:
            self._tif.close()
        self._tif = None

    def _single(self, label: str) -> np.ndarray:
        import tifffile

        what, path = self.what, self.path
        try:
            with tifffile.TiffFile(path) as tif:
                n_pages = len(tif.pages)
                arr = tif.asarray()
        except _errors() as exc:
            raise InputError(f"cannot read {what} {label!r} as TIFF: {exc}") from exc
        if arr.ndim != 2 or n_pages != 1:
            hint = " (`recon run` reconstructs every page of a stack)" if what == "frame" else ""
            raise InputError(
                f"{what} {str(path)!r} holds an array of shape {arr.shape}; expected one "
                f"2-D grey-level image (y, x){hint}"
            )
        return arr

    def read(self, page: int | None, label: str) -> np.ndarray:
        """Pixels of the file's only image (``page`` None) or of one page, as stored (2-D).

        Raises
        ------
        InputError
            Missing or unreadable file, a page beyond the end of the stack, or (``page``
            None) a file holding more than one image (names the file).
        """
        import tifffile

        what = self.what
        _check_file(self.path, what)
        if page is None:
            return self._single(label)
        try:
            if self._tif is None:
                self._tif = tifffile.TiffFile(self.path)
                self._n_pages = math.prod(self._tif.series[0].shape[:-2])
            if page >= self._n_pages:
                raise InputError(f"{what} {label!r}: the stack has only {self._n_pages} page(s)")
            arr = self._tif.asarray(key=page, series=0)
        except InputError:
            raise
        except _errors() as exc:
            self.close()
            raise InputError(f"cannot read {what} {label!r} as TIFF: {exc}") from exc
        if arr.ndim != 2:
            raise InputError(f"{what} {label!r} is not a 2-D image (shape {arr.shape})")
        return arr


def open_file(path: Path, what: str = "frame") -> TiffFrames:
    """The file, opened for :meth:`TiffFrames.read` (the file is read at the first page)."""
    return TiffFrames(path, what)


__all__ = ["NAME", "SUFFIXES", "TiffFrames", "open_file", "probe", "sniff"]
