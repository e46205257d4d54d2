"""Frame reader: Phantom ``.cine`` files (Vision Research high-speed cameras), through ``pims``.

A ``.cine`` file holds the frames of one recording, grey-level (8 or 16 bits per pixel;
10/12-bit packed files are refused), after a header (``CINEFILEHEADER``,
``BITMAPINFOHEADER``, the camera's ``SETUP``), tagged blocks (the time of every image,
block 1002, and its exposure, block 1003) and the table of image offsets.
``pims.cine.Cine`` parses them; this module turns them into a
:class:`~hrvbase.formats.registry.FrameHeader`:

- ``numbers``: every image's position in the recording, counted from its first image
  (``FirstImageNo - FirstMovieImage + i``, ≥ 0; the camera's own image numbers count from
  the trigger, so that the first saved image is often negative);
- ``times_s``: every image's time from the trigger (s), from the time block, exactly (the
  seconds and the 32-bit fraction are subtracted separately);
- ``camera``: the frame rate (Hz), the exposure (s; one value, or one per image when they
  differ), the bit depth the camera recorded, the camera's image number of the first image
  in the file and the trigger time (UTC), which ``recon run`` writes into ``recon.json``.

Colour (CFA) and compressed recordings are refused. Errors are one line naming the file.
"""

from __future__ import annotations

import datetime
import math
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError
from .registry import FrameHeader

#: Name of this format in the registry and in ``recon.json``.
NAME = "cine"

#: File name endings (compared in lower case) of the frames a folder contributes.
SUFFIXES = (".cine",)

#: Size of the ``CINEFILEHEADER`` (its ``Headersize`` field).
HEADER_SIZE = 44

#: Size of the ``BITMAPINFOHEADER``.
BITMAP_SIZE = 40


def sniff(head: bytes) -> bool:
    """Whether the file starts like a ``.cine`` file: ``"CI"`` and a 44-byte header."""
    return len(head) >= 4 and head[:2] == b"CI" and struct.unpack("<H", head[2:4])[0] == 44


def _check_file(path: Path, what: str) -> None:
    if path.is_dir():
        raise InputError(f"{what} {str(path)!r} is a folder, not a .cine file")
    if not path.is_file():
        raise InputError(f"{what} {str(path)!r} does not exist")


def _open(path: Path, what: str):
    """``pims.cine.Cine`` of the file, its header checked; one-line errors naming it."""
    from pims.cine import Cine

    _check_file(path, what)
    head = path.read_bytes()[:HEADER_SIZE]
    if not sniff(head):
        raise InputError(
            f"{what} {str(path)!r} is not a Phantom .cine file (it does not start with the "
            "'CI' header of 44 bytes)"
        )
    try:
        cine = Cine(str(path))
    except Exception as exc:  # pims raises assorted types (struct, key, type) on bad files
        raise InputError(
            f"cannot read {what} {str(path)!r} as a Phantom .cine file (truncated or damaged "
            f"header, or no time and exposure blocks): {type(exc).__name__}: {exc}"
        ) from None
    try:
        _check(cine, path, what)
    except Exception:
        cine.close()
        raise
    return cine


def _check(cine, path: Path, what: str) -> None:
    """Refuse what this reader does not decode, and images the file does not hold."""
    where = f"{what} {str(path)!r}"
    if cine.compression != 0 or cine.cfa != 0:
        raise InputError(
            f"{where} is a colour or compressed recording (compression {cine.compression}, "
            f"CFA {cine.cfa}); expected grey-level images"
        )
    n = int(cine.image_count)
    if n < 1 or not hasattr(cine, "image_locations"):
        raise InputError(f"{where} holds no images (image count {n})")
    size = path.stat().st_size
    w, h = cine.frame_shape
    with path.open("rb") as fh:
        for k in (0, n - 1):
            offset = int(cine.image_locations[k])
            fh.seek(offset)
            annotation = fh.read(4)
            if len(annotation) < 4:
                end = offset + 4
            else:
                (n_annot,) = struct.unpack("<I", annotation)
                fh.seek(offset + n_annot - 4)
                count = fh.read(4)
                n_bytes = struct.unpack("<I", count)[0] if len(count) == 4 else w * h
                end = offset + n_annot + n_bytes
                if n_bytes * 8 // (w * h) in (10, 12):
                    raise InputError(
                        f"{where} holds packed {n_bytes * 8 // (w * h)}-bit images, which this "
                        "reader does not decode (their row order is not published); save the "
                        "recording unpacked (8 or 16 bits per pixel)"
                    )
            if end > size:
                raise InputError(
                    f"{where} is truncated: image {k} ends at byte {end} but the file has "
                    f"{size} bytes (an interrupted copy or write?)"
                )
    for key in ("image_time_only", "exposure_only"):
        if len(cine.tagged_blocks.get(key, ())) < n:
            raise InputError(f"{where}: its {key} block does not cover its {n} images")


def _seconds(stamp, origin) -> float:
    """``stamp - origin`` (s) of two ``(datetime, fraction)`` pairs, exactly in the seconds."""
    return (stamp[0] - origin[0]).total_seconds() + (stamp[1] - origin[1])


def _camera(cine, bits: int, exposures: list[float]) -> dict:
    raw = int(cine.header_dict["trigger_time"])
    trigger = datetime.datetime.fromtimestamp(raw >> 32, tz=datetime.UTC) + datetime.timedelta(
        seconds=(raw & 0xFFFFFFFF) / 2**32
    )
    uniform = all(math.isclose(e, exposures[0], rel_tol=1e-9) for e in exposures)
    return {
        "format": NAME,
        "frame_rate_hz": float(cine.frame_rate),
        "exposure_s": exposures[0] if uniform else exposures,
        "bit_depth": bits,
        "first_image_number": int(cine.header_dict["first_image_no"]),
        "trigger_time_utc": trigger.isoformat(),
    }


def probe(path: Path, what: str = "frame") -> FrameHeader:
    """Image count, size, pixel type, bit depth, numbers, times and camera record of a
    ``.cine`` file, from its header and tagged blocks (no pixels).

    Raises
    ------
    InputError
        Missing, truncated or damaged file, a colour or compressed recording, or time and
        exposure blocks that do not cover the images (names the file).
    """
    path = Path(path)
    cine = _open(path, what)
    try:
        n = int(cine.image_count)
        w, h = (int(v) for v in cine.frame_shape)
        dtype = np.dtype(cine.pixel_type)
        real = int(cine.setup_fields_dict.get("real_bpp") or 0)
        bits = real if 0 < real <= 8 * dtype.itemsize else 8 * dtype.itemsize
        first = int(cine.header_dict["first_image_no"]) - int(cine.header_dict["first_movie_image"])
        trigger = (cine.trigger_time["datetime"], cine.trigger_time["second_fraction"])
        stamps = cine.tagged_blocks["image_time_only"][:n]
        times = tuple(_seconds(s, trigger) for s in stamps)
        exposures = [float(e) for e in cine.tagged_blocks["exposure_only"][:n]]
        rate = float(cine.frame_rate)
        camera = _camera(cine, bits, exposures)
    finally:
        cine.close()
    return FrameHeader(
        n_images=n,
        shape=(h, w),
        dtype=str(dtype),
        bits=bits,
        frame_interval_s=1.0 / rate if rate > 0 else None,
        numbers=tuple(first + i for i in range(n)),
        times_s=times,
        camera=camera,
    )


class CineFrames:
    """An open ``.cine`` file: its images one by one (kept open between them)."""

    def __init__(self, path: Path, what: str = "frame") -> None:
        self.path = Path(path)
        self.what = what
        self._cine = None

    def close(self) -> None:
        if self._cine is not None:
            self._cine.close()
        self._cine = None

    def read(self, page: int | None, label: str) -> np.ndarray:
        """Pixels of one image (``page``; None: the file's only image), top row first.

        Raises
        ------
        InputError
            Unreadable file, an image beyond the end of the recording, or (``page`` None) a
            file holding more than one image (names the file).
        """
        if self._cine is None:
            self._cine = _open(self.path, self.what)
        n = int(self._cine.image_count)
        if page is None:
            if n != 1:
                raise InputError(
                    f"{self.what} {str(self.path)!r} holds {n} images; expected one (`recon "
                    "run` reconstructs every image of a recording)"
                )
            page = 0
        if not 0 <= page < n:
            raise InputError(f"{self.what} {label!r}: the recording has only {n} image(s)")
        try:
            return np.ascontiguousarray(self._cine[page])
        except Exception as exc:  # pims raises assorted types on damaged images
            self.close()
            raise InputError(
                f"cannot read {self.what} {label!r} of the .cine file: {type(exc).__name__}: {exc}"
            ) from None


def open_file(path: Path, what: str = "frame") -> CineFrames:
    """The file, opened for :meth:`CineFrames.read` (parsed at the first image)."""
    return CineFrames(path, what)


__all__ = ["NAME", "SUFFIXES", "CineFrames", "open_file", "probe", "sniff"]
