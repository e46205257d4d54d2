"""The napari reader of the plugin (``napari.yaml``: command ``hrvptm.read``)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence

from .layers import LayerData, folder_kind, read_layers


def napari_get_reader(
    path: str | os.PathLike | Sequence,
) -> Callable[[str | os.PathLike | Sequence], list[LayerData]] | None:
    """The reader of ``path`` when it is one of the toolkit's folders (an ``hrvptm study``
    report, a ``track`` results folder, an OME-Zarr image or a folder of numbered TIFF
    volumes, :func:`hrvptm_napari.layers.folder_kind`), else None (napari then asks other
    readers)."""
    if isinstance(path, list | tuple):
        if len(path) != 1:
            return None
        path = path[0]
    return read_layers if folder_kind(path) is not None else None
