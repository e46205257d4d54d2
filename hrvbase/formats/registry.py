"""The readers of camera frames and of volume series, chosen by content or file name.

Every package reads its files through this registry: ``recon run`` its frames
(:mod:`recon.frames`), ``track run``, the studies and the napari/Fiji path their volumes
(:mod:`track.volumes`). A format is **one module**, listed once in :data:`FRAME_FORMATS` or
:data:`VOLUME_FORMATS` (or added at run time with :func:`register_frame_format` /
:func:`register_volume_format`); nothing else changes when one is added.

A **frame format** module defines:

``NAME`` : str
    Its name in messages and in ``recon.json`` (``"tiff"``, ``"cine"``).
``SUFFIXES`` : tuple of str
    Lower-case file name endings (``(".cine",)``): the files of a folder or pattern that are
    frames.
``sniff(head: bytes) -> bool``
    Whether a file starting with ``head`` (its first :data:`SNIFF_BYTES` bytes) is of this
    format; a file is recognised by its content first, then by its suffix.
``probe(path, what) -> FrameHeader``
    The file's :class:`FrameHeader`, from its header only (no pixels).
``open_file(path, what) -> FrameFile``
    An open file whose ``read(page, label)`` returns one image ``(y, x)`` as stored (``page``
    None: the file's only image) and whose ``close()`` releases it.

A **volume format** module defines ``NAME``, ``matches(path) -> bool`` (whether a folder or
file is a series of this format), ``scan(path) -> list[VolumeInfo]`` (the volumes, without
voxels) and ``read(info) -> ndarray`` (one volume's voxels as stored).

Errors are :class:`hrvbase.errors.InputError` with one line naming the file; each package
raises them as its own type (:func:`hrvbase.errors.raised_as`).
"""

from __future__ import annotations

import importlib
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from ..errors import InputError
from .volumes import VolumeInfo

#: Bytes read from the start of a file to recognise its format.
SNIFF_BYTES = 16

#: Built-in frame formats (modules of this package), tried in this order.
FRAME_FORMATS = ("tiff_frames", "cine")

#: Built-in volume formats (modules of this package), tried in this order.
VOLUME_FORMATS = ("volume_zarr", "volume_tiff")

_EXTRA_FRAME: list[ModuleType | Any] = []
_EXTRA_VOLUME: list[ModuleType | Any] = []


@dataclass(frozen=True)
class FrameHeader:
    """What a frame reader's ``probe`` reads from a file's header (no pixels).

    Attributes
    ----------
    n_images : int
        Images (pages, frames) in the file: 1 for a plain frame.
    shape : tuple of int
        ``(height, width)`` of one image in pixels.
    dtype : str
        NumPy pixel type (``"uint16"``).
    bits : int
        Bits per sample the camera recorded (12 for a 12-bit camera image in uint16).
    frame_interval_s : float or None
        Time between frames (s) of a stack (ImageJ ``finterval``; 1 / frame rate), if recorded.
    time_s : float or None
        Time of a single-image file (``"time_s"`` of its JSON metadata), if recorded.
    numbers : tuple of int or None
        The camera's number of every image, when the file records them (``.cine``: counted
        from the first image of the recording); None: numbered by the reader of the series.
    times_s : tuple of float or None
        The time of every image (s), when the file records them (``.cine``: from the trigger).
    camera : dict
        What the file records of the camera and recording (format, frame rate, exposure,
        bit depth, …) for ``recon.json``; empty when nothing is recorded.
    """

    n_images: int
    shape: tuple[int, int]
    dtype: str
    bits: int
    frame_interval_s: float | None = None
    time_s: float | None = None
    numbers: tuple[int, ...] | None = None
    times_s: tuple[float, ...] | None = None
    camera: Mapping[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        return f"{self.shape[1]} × {self.shape[0]} px {self.dtype} ({self.bits} bit)"


def _modules(builtin: tuple[str, ...], extra: list) -> list:
    return [importlib.import_module(f"{__package__}.{m}") for m in builtin] + list(extra)


def frame_formats() -> list:
    """The frame format modules, in the order they are tried."""
    return _modules(FRAME_FORMATS, _EXTRA_FRAME)


def volume_formats() -> list:
    """The volume format modules, in the order they are tried."""
    return _modules(VOLUME_FORMATS, _EXTRA_VOLUME)


def _check_module(fmt, names: tuple[str, ...], kind: str) -> None:
    lack = [n for n in names if not hasattr(fmt, n)]
    if lack:
        raise InputError(f"a {kind} format must define {', '.join(names)}; {fmt!r} lacks {lack}")


def register_frame_format(fmt) -> None:
    """Add a frame format (a module or object defining ``NAME``, ``SUFFIXES``, ``sniff``,
    ``probe`` and ``open_file``; module docstring), tried after the built-in ones."""
    _check_module(fmt, ("NAME", "SUFFIXES", "sniff", "probe", "open_file"), "frame")
    if fmt not in _EXTRA_FRAME:
        _EXTRA_FRAME.append(fmt)


def register_volume_format(fmt) -> None:
    """Add a volume format (defining ``NAME``, ``matches``, ``scan`` and ``read``), tried
    after the built-in ones."""
    _check_module(fmt, ("NAME", "matches", "scan", "read"), "volume")
    if fmt not in _EXTRA_VOLUME:
        _EXTRA_VOLUME.append(fmt)


def frame_suffixes() -> tuple[str, ...]:
    """Lower-case file name endings of every frame format (``(".tif", ".tiff", ".cine")``)."""
    return tuple(s for fmt in frame_formats() for s in fmt.SUFFIXES)


def frame_format_for(path: str | os.PathLike, *, content: bool = True):
    """The frame format of a file: by its first bytes (``content``), else by its suffix;
    None when no format claims it."""
    path = Path(path)
    formats = frame_formats()
    if content:
        try:
            with open(path, "rb") as fh:
                head = fh.read(SNIFF_BYTES)
        except OSError:
            head = b""
        for fmt in formats:
            if head and fmt.sniff(head):
                return fmt
    suffix = path.name.lower()
    return next((f for f in formats if any(suffix.endswith(s) for s in f.SUFFIXES)), None)


def format_by_name(name: str, *, volume: bool = False):
    """The frame (or ``volume``) format called ``name``."""
    for fmt in volume_formats() if volume else frame_formats():
        if fmt.NAME == name:
            return fmt
    raise InputError(f"no {'volume' if volume else 'frame'} format named {name!r}")


def probe_frames(path: str | os.PathLike, what: str = "frame") -> FrameHeader:
    """The :class:`FrameHeader` of a frame file, by its format (TIFF when none claims it, so
    that the TIFF reader's message says what is wrong with the file)."""
    fmt = frame_format_for(path) or format_by_name("tiff")
    return fmt.probe(Path(path), what)


def volume_format_for(path: str | os.PathLike):
    """The volume format of a folder or store, or None."""
    p = Path(path)
    return next((f for f in volume_formats() if f.matches(p)), None)


def scan_volumes(folder: str | os.PathLike) -> list[VolumeInfo]:
    """The volumes of a series (a folder of numbered TIFF volumes, an OME-Zarr image, or any
    registered format), in frame order, with their geometry, without reading voxels.

    Raises
    ------
    InputError
        Not a folder, a folder no format claims, or what the format's ``scan`` refuses.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"volume folder {folder} does not exist or is not a folder")
    fmt = volume_format_for(folder) or format_by_name("tiff-folder", volume=True)
    return [v if v.format is not None else _with_format(v, fmt.NAME) for v in fmt.scan(folder)]


def _with_format(info: VolumeInfo, name: str) -> VolumeInfo:
    import dataclasses

    return dataclasses.replace(info, format=name)


def read_volume(info: VolumeInfo | str | os.PathLike) -> np.ndarray:
    """Voxels of a volume as float32 ``(z, y, x)`` (a path: a TIFF volume file).

    Raises
    ------
    InputError
        Unreadable file, voxels that do not fill the declared shape, or non-finite voxels.
    """
    if isinstance(info, VolumeInfo):
        where = info.source()
        fmt = format_by_name(info.format or "tiff-folder", volume=True)
        arr = np.asarray(fmt.read(info))
    else:
        where = str(info)
        arr = np.asarray(format_by_name("tiff-folder", volume=True).read(Path(info)))
    if arr.ndim == 2:
        arr = arr[None]
    if isinstance(info, VolumeInfo):
        if arr.size != math.prod(info.shape):
            declared = " × ".join(map(str, info.shape))
            raise InputError(
                f"volume {where} holds {arr.size} voxels, not the {declared} its header "
                "declares (changed, truncated or damaged since the series was read?)"
            )
        arr = arr.reshape(info.shape)
    if arr.ndim != 3:
        raise InputError(f"{where}: expected a (z, y, x) volume, got shape {arr.shape}")
    arr = arr.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: volume holds NaN or infinite voxels")
    return arr


def volume_checksum(info: VolumeInfo) -> str:
    """SHA-256 identifying a volume: of its file, or of a Zarr frame's values
    (:func:`hrvbase.io.array_sha256`; the frame is read, so that a damaged chunk or a
    frame holding NaN, e.g. one never written, is an :class:`InputError` here)."""
    from ..io import array_sha256, sha256_file

    if info.dataset is None:
        return sha256_file(info.path)
    return array_sha256(read_volume(info))


__all__ = [
    "FRAME_FORMATS",
    "SNIFF_BYTES",
    "VOLUME_FORMATS",
    "FrameHeader",
    "format_by_name",
    "frame_format_for",
    "frame_formats",
    "frame_suffixes",
    "probe_frames",
    "read_volume",
    "register_frame_format",
    "register_volume_format",
    "scan_volumes",
    "volume_checksum",
    "volume_format_for",
]
