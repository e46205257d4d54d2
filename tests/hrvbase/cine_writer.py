"""A small writer of Phantom ``.cine`` files, to the published Cine file format (tests only).

Layout (all little-endian, packed): ``CINEFILEHEADER`` (44 bytes) at 0, ``BITMAPINFOHEADER``
(40 bytes) at 44, the camera ``SETUP`` at 84 (:data:`SETUP_LENGTH` bytes, the length in its
``Length`` field), then the tagged blocks (block 1002: every image's time as ``TIME64``,
block 1003: every image's exposure in units of 2⁻³² s), the table of image offsets
(``pImage``, one int64 per image) and the images, each after an 8-byte annotation
(``AnnotationSize``, ``ImageSize``). Pixels are grey-level, bottom row first (a
bottom-up bitmap); 8-bit, 16-bit or packed 12-bit (two pixels in three bytes, big-endian
bit order).

Only the fields a reader needs are filled; the rest of ``SETUP`` is zero.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

#: Offset of the SETUP structure (after the two headers).
SETUP_OFFSET = 44 + 40

#: Camera software version written: its SETUP structure ends at the field ``Hue``.
SOFTWARE_VERSION = 671

#: Length of that SETUP structure (bytes).
SETUP_LENGTH = 5732

#: Byte offsets of the SETUP fields written (published SETUP structure).
SETUP_FIELDS = {
    "FrameRate16": (0, "<H"),
    "Shutter16": (2, "<H"),
    "Mark": (140, "<2s"),
    "Length": (142, "<H"),
    "ImWidth": (737, "<H"),
    "ImHeight": (739, "<H"),
    "FrameRate": (768, "<I"),
    "Shutter": (772, "<I"),
    "SoftwareVersion": (800, "<I"),
    "CFA": (808, "<I"),
    "RealBPP": (896, "<I"),
    "ShutterNs": (1568, "<I"),
}

#: Seconds of the trigger time written (2026-01-02 03:04:05 UTC).
TRIGGER_SECONDS = 1_767_323_045


def time64(seconds: int, fraction: float) -> int:
    """A ``TIME64``: whole seconds since 1970 in the high 32 bits, the fraction × 2³² low."""
    return (int(seconds) << 32) | round(fraction * 2**32)


def pack12(frame: np.ndarray) -> bytes:
    """Two 12-bit pixels in three bytes (first pixel in the high bits)."""
    v = frame.astype(np.uint16).reshape(-1, 2)
    a, b = v[:, 0], v[:, 1]
    out = np.stack([a >> 4, ((a & 0xF) << 4) | (b >> 8), b & 0xFF], axis=1)
    return out.astype(np.uint8).tobytes()


def _setup(width: int, height: int, fps: int, exposure_ns: int, real_bpp: int) -> bytes:
    buf = bytearray(SETUP_LENGTH)
    values = {
        "FrameRate16": min(fps, 0xFFFF),
        "Shutter16": min(exposure_ns // 1000, 0xFFFF),
        "Mark": b"ST",
        "Length": SETUP_LENGTH,
        "ImWidth": width,
        "ImHeight": height,
        "FrameRate": fps,
        "Shutter": exposure_ns // 1000,
        "SoftwareVersion": SOFTWARE_VERSION,
        "CFA": 0,
        "RealBPP": real_bpp,
        "ShutterNs": exposure_ns,
    }
    for name, value in values.items():
        offset, fmt = SETUP_FIELDS[name]
        struct.pack_into(fmt, buf, offset, value)
    return bytes(buf)


def _tagged(kind: int, payload: bytes, more: bool) -> bytes:
    return struct.pack("<IHH", 8 + len(payload), kind, 1 if more else 0) + payload


def write_cine(
    path: str | Path,
    frames: np.ndarray,
    *,
    fps: int = 1000,
    exposure_s: float | list[float] = 200e-6,
    bits: int | None = None,
    first_image_no: int = -2,
    first_movie_image: int = -10,
    times_s: list[float] | None = None,
    packed12: bool = False,
    time_block: bool = True,
) -> Path:
    """Write ``frames`` ``(n, y, x)`` (uint8 or uint16) as a grey-level ``.cine`` file.

    ``times_s``: every image's time from the trigger (default ``(first_image_no + i) / fps``);
    ``exposure_s``: one value or one per image; ``bits``: the ``RealBPP`` recorded (default
    8 or 16 from the dtype, 12 for ``packed12``); ``time_block``: write the tagged blocks.
    """
    path = Path(path)
    frames = np.asarray(frames)
    n, h, w = frames.shape
    if packed12:
        bit_count, real = 16, 12 if bits is None else bits
    else:
        bit_count = 8 * frames.dtype.itemsize
        real = bit_count if bits is None else bits
    images = []
    for f in frames:
        rows = np.ascontiguousarray(f[::-1])  # bottom-up bitmap
        images.append(pack12(rows) if packed12 else rows.astype(f"<u{f.dtype.itemsize}").tobytes())
    exposures = [exposure_s] * n if np.isscalar(exposure_s) else list(exposure_s)
    if times_s is None:
        times_s = [(first_image_no + i) / fps for i in range(n)]
    stamps = b"".join(
        struct.pack("<Q", time64(TRIGGER_SECONDS + int(np.floor(t)), t - np.floor(t)))
        for t in times_s
    )
    expo = b"".join(struct.pack("<I", round(e * 2**32)) for e in exposures)
    tagged = _tagged(1002, stamps, True) + _tagged(1003, expo, False) if time_block else b""
    off_offsets = SETUP_OFFSET + SETUP_LENGTH + len(tagged)
    first_image = off_offsets + 8 * n
    offsets, pos = [], first_image
    for img in images:
        offsets.append(pos)
        pos += 8 + len(img)
    header = struct.pack(
        "<2sHHHiIiIIIIQ",
        b"CI",
        44,
        0,  # Compression: grey-level
        1,
        first_movie_image,
        n,  # TotalImageCount
        first_image_no,
        n,  # ImageCount
        44,  # OffImageHeader
        SETUP_OFFSET,
        off_offsets,
        time64(TRIGGER_SECONDS, 0.0),
    )
    bitmap = struct.pack("<IiiHHIIiiII", 40, w, h, 1, bit_count, 0, len(images[0]), 0, 0, 0, 0)
    body = [header, bitmap, _setup(w, h, fps, round(exposures[0] * 1e9), real), tagged]
    body.append(struct.pack(f"<{n}q", *offsets))
    for img in images:
        body.append(struct.pack("<II", 8, len(img)) + img)
    path.write_bytes(b"".join(body))
    return path
