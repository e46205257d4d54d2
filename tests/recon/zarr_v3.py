"""An OME-NGFF 0.5 image on Zarr format 3, laid out as ``recon run --format zarr`` writes a
store of that format (group ``zarr.json`` holding the ``ome`` metadata, the array ``0`` with
the chunk key encoding "default" and "/" and the dimension names t, z, y, x), made with zarr
and ome-zarr directly from a store ``recon`` wrote in OME-NGFF 0.4."""

from __future__ import annotations

import json
import math
from pathlib import Path


def as_ngff05(src: Path, dst: Path, *, drop: tuple[int, ...] = ()) -> Path:
    """``dst``: the image of ``src`` (NGFF 0.4, Zarr format 2) as NGFF 0.5 on Zarr format 3,
    with the same voxels, chunks, metadata, ``recon`` attribute and ``recon.json`` (which names
    NGFF 0.5); the frames ``drop`` are left unwritten (an interrupted run)."""
    import zarr
    from ome_zarr.format import FormatV05
    from ome_zarr.writer import write_multiscales_metadata

    old = zarr.open_group(str(src), mode="r", zarr_format=2)
    arr = old["0"]
    ms = old.attrs["multiscales"][0]
    group = zarr.open_group(str(dst), mode="w", zarr_format=3)
    new = group.create_array(
        "0",
        shape=arr.shape,
        chunks=arr.chunks,
        dtype="float32",
        fill_value=math.nan,
        chunk_key_encoding={"name": "default", "separator": "/"},
        dimension_names=("t", "z", "y", "x"),
    )
    for k in range(arr.shape[0]):
        if k not in drop:
            new[k] = arr[k]
    write_multiscales_metadata(
        group, datasets=ms["datasets"], fmt=FormatV05(), axes=ms["axes"], name=ms["name"]
    )
    group.attrs["recon"] = old.attrs["recon"]
    if (src / "recon.json").is_file():
        meta = json.loads((src / "recon.json").read_text())
        meta["zarr"]["ngff_version"] = "0.5"
        (dst / "recon.json").write_text(json.dumps(meta))
    return dst
