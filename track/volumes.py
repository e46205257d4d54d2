"""Volume series of :mod:`track`: numbered TIFF volumes or an OME-Zarr image, in object space.

A series is a folder of ``NNNNNN.tif`` float32 ``(z, y, x)`` volumes, or one OME-Zarr image
(``recon run --format zarr``, or any OME-NGFF image of axes ``(t, z, y, x)`` or ``(z, y, x)``,
with an optional channel axis of length 1) whose frames are the volumes, or a series of any
format of the reader registry. :func:`scan_volumes` lists them without reading voxels,
:func:`read_volume` reads one.

The readers live in :mod:`hrvbase.formats` (one module per format, chosen by
:func:`hrvbase.formats.registry.volume_format_for`): the TIFF layout in
:mod:`hrvbase.formats.tiff_layout`, the folder of numbered TIFFs in
:mod:`hrvbase.formats.volume_tiff`, OME-Zarr in :mod:`hrvbase.formats.volume_zarr`, and what
``recon.json`` records of a series (voxel size, origin, lenslet period and phase, the SNR,
number and time of each camera frame) in :mod:`hrvbase.formats.volumes`. This module gives
them to ``track`` with its own :class:`~track.errors.InputError`.
"""

from __future__ import annotations

import os

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.formats import registry, volume_zarr
from hrvbase.formats import volumes as _volumes
from hrvbase.formats.volume_zarr import is_zarr
from hrvbase.formats.volumes import NUMBERED, RECON_JSON, VolumeInfo, numbered

from .errors import InputError


def scan_volumes(folder: str | os.PathLike) -> list[VolumeInfo]:
    """The volumes of a series, in frame order, with voxel size and origin
    (:func:`hrvbase.formats.registry.scan_volumes`).

    Raises
    ------
    InputError
        No volumes, a gap in the numbering ("volume NNNNNN.tif is missing"), a truncated
        file, a volume without a voxel size, shapes or voxel types that differ ("mixed
        series") or voxel sizes that differ ("mismatched voxel sizes").
    """
    with raised_as(InputError):
        return registry.scan_volumes(folder)


def scan_zarr(store: str | os.PathLike) -> list[VolumeInfo]:
    """The frames of an OME-Zarr image as volumes (:func:`hrvbase.formats.volume_zarr.scan`).

    Raises
    ------
    InputError
        Not an OME-NGFF image, other axes, no length unit, bad transformations, an
        unsupported voxel type, or frames ``recon`` has not written yet.
    """
    with raised_as(InputError):
        return volume_zarr.scan(store)


def read_volume(info: VolumeInfo | str | os.PathLike) -> np.ndarray:
    """Voxels of a volume as float32 ``(z, y, x)`` (:func:`hrvbase.formats.registry.read_volume`).

    Raises
    ------
    InputError
        Unreadable file or non-finite voxels.
    """
    with raised_as(InputError):
        return registry.read_volume(info)


def volume_checksum(info: VolumeInfo) -> str:
    """SHA-256 identifying a volume (:func:`hrvbase.formats.registry.volume_checksum`)."""
    with raised_as(InputError):
        return registry.volume_checksum(info)


def lenslet_phases(recon, voxel_size_um, origin_xyz_um, where: str):
    """Lenslet period (voxels) and phase of a volume from the ``grid`` of its ``recon.json``
    (:func:`hrvbase.formats.volumes.lenslet_phases`)."""
    with raised_as(InputError):
        return _volumes.lenslet_phases(recon, voxel_size_um, origin_xyz_um, where)


__all__ = [
    "NUMBERED",
    "RECON_JSON",
    "VolumeInfo",
    "is_zarr",
    "lenslet_phases",
    "numbered",
    "read_volume",
    "scan_volumes",
    "scan_zarr",
    "volume_checksum",
]
