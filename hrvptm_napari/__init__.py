"""hrvptm_napari — the toolkit's outputs in napari (the npe2 plugin ``hrvptm``).

Install with ``pip install -e .[napari]``; then ``napari --plugin hrvptm FOLDER`` (or File ▸
Open Folder) opens an ``hrvptm study`` report, a ``track`` results folder, an OME-Zarr image
or a folder of numbered TIFF volumes, and Plugins ▸ Run recon / track docks
:class:`~hrvptm_napari.widget.RunWidget`.

Public API
----------
:func:`read_layers`, :func:`folder_kind`
    A folder's layers as napari layer data ``(data, kwargs, type)`` (:mod:`hrvptm_napari.layers`,
    which imports neither napari nor Qt): :func:`volume_layer` (one image ``(t, z, y, x)`` in
    µm), :func:`results_layers` (particles, tracks, displacement, strain), :func:`study_layers`
    (all of a report, with the truth).
:func:`napari_get_reader`
    The reader napari calls (:mod:`hrvptm_napari.reader`).
:exc:`ReadError`
    A folder that is not one of the toolkit's.
"""

from __future__ import annotations

from .layers import (
    ReadError,
    folder_kind,
    read_layers,
    results_layers,
    study_layers,
    volume_layer,
)
from .reader import napari_get_reader

__all__ = [
    "ReadError",
    "folder_kind",
    "napari_get_reader",
    "read_layers",
    "results_layers",
    "study_layers",
    "volume_layer",
]
