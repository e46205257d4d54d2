"""Backward-compatible façade: re-exports track.tables, track.field_files and track.volumes."""

from __future__ import annotations

from . import field_files, tables
from .field_files import *  # noqa: F403
from .tables import *  # noqa: F403
from .volumes import VolumeInfo, numbered, read_volume, scan_volumes

__all__ = [
    *tables.__all__,
    *field_files.__all__,
    "VolumeInfo",
    "numbered",
    "read_volume",
    "scan_volumes",
]
