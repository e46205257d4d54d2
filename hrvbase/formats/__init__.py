"""File formats of the toolkit, in one place: every reader and writer of frames and volumes.

- :mod:`~hrvbase.formats.registry`: the readers of camera frames and of volume series, chosen
  by content or file name; a new format is one module listed there;
- :mod:`~hrvbase.formats.geometry`: :class:`VolumeGeometry`, where the voxels of a volume lie;
- :mod:`~hrvbase.formats.tiff_layout`: the TIFF layout of our images and volumes (ImageJ
  fields, private tags), its writer and its parsers;
- frame readers: :mod:`~hrvbase.formats.tiff_frames` (TIFF files and stacks) and
  :mod:`~hrvbase.formats.cine` (Phantom ``.cine``, through ``pims``);
- volume readers: :mod:`~hrvbase.formats.volume_tiff` (folders of numbered TIFF volumes) and
  :mod:`~hrvbase.formats.volume_zarr` (OME-Zarr), with :mod:`~hrvbase.formats.volumes` for
  what every series records (:class:`VolumeInfo`, ``recon.json``).

Heavy dependencies (tifffile, zarr, ome-zarr, pims) are imported by the functions that use
them.
"""

from __future__ import annotations

from .geometry import VolumeGeometry
from .registry import (
    FrameHeader,
    frame_format_for,
    probe_frames,
    read_volume,
    register_frame_format,
    register_volume_format,
    scan_volumes,
    volume_format_for,
)
from .volumes import VolumeInfo

__all__ = [
    "FrameHeader",
    "VolumeGeometry",
    "VolumeInfo",
    "frame_format_for",
    "probe_frames",
    "read_volume",
    "register_frame_format",
    "register_volume_format",
    "scan_volumes",
    "volume_format_for",
]
