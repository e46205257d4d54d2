"""Volume reader: one OME-Zarr image (``recon run --format zarr``, or any OME-NGFF image).

OME-NGFF 0.4 on Zarr format 2 (``.zgroup``, ``.zattrs``: what ``recon run`` writes) and
OME-NGFF 0.5 on Zarr format 3 (``zarr.json``) are read alike, through the ``ome-zarr`` reader
(as napari-ome-zarr reads them) and zarr-python. The image's axes are ``(t, z, y, x)`` or
``(z, y, x)``, with an optional channel axis of length 1; its frames are the volumes. The
voxel size and origin are the ``scale`` and ``translation`` of its first (full-resolution)
dataset, in the units of its space axes (converted to µm). A store written by ``recon run``
holds ``recon.json``, which gives the frames' numbers, times and SNRs and the lenslet period
(:mod:`hrvbase.formats.volumes`); an OME-Zarr t axis in a unit of time gives the times of
other images.
"""

from __future__ import annotations

import gc
import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import read_json
from .tiff_layout import quiet
from .volumes import (
    RECON_JSON,
    VolumeInfo,
    check_frames,
    frame_records,
    frame_snrs,
    lenslet_phases,
    parse_surface,
)

#: Name of this format in the registry.
NAME = "ome-zarr"

#: Zarr metadata files: a folder holding one of them is read as a Zarr store.
_ZARR_MARKERS = ("zarr.json", ".zgroup", ".zattrs")

#: Length units of OME-NGFF space axes, in µm.
_LENGTH_UM = {
    "angstrom": 1e-4,
    "nanometer": 1e-3,
    "micrometer": 1.0,
    "millimeter": 1e3,
    "centimeter": 1e4,
    "meter": 1e6,
}


#: Time units of an OME-NGFF t axis, in seconds.
_TIME_S = {
    "nanosecond": 1e-9,
    "microsecond": 1e-6,
    "millisecond": 1e-3,
    "second": 1.0,
    "minute": 60.0,
    "hour": 3600.0,
}


def matches(path: str | os.PathLike) -> bool:
    """Whether ``path`` is to be read as a Zarr store: a folder named ``*.zarr`` or holding
    Zarr metadata (``zarr.json``, ``.zgroup``)."""
    p = Path(path)
    return p.is_dir() and (
        p.suffix.lower() == ".zarr" or any((p / m).is_file() for m in _ZARR_MARKERS)
    )


def _transforms(items, where: str, ndim: int) -> tuple[np.ndarray, np.ndarray]:
    """``(scale, translation)`` of a list of OME-NGFF coordinate transformations."""
    scale, shift = np.ones(ndim), np.zeros(ndim)
    for tr in items or ():
        kind = tr.get("type") if isinstance(tr, Mapping) else None
        if kind == "identity":
            continue
        value = tr.get(kind) if kind in ("scale", "translation") else None
        try:
            v = np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            v = np.zeros(0)
        if v.size != ndim or not np.all(np.isfinite(v)):
            raise InputError(
                f"{where}: unsupported coordinate transformation {tr!r} (expected a scale or "
                f"translation of {ndim} numbers)"
            )
        if kind == "scale":
            scale, shift = scale * v, shift * v
        else:
            shift = shift + v
    return scale, shift


def _recon_records(recon, vs, origin_xyz_um, where: str) -> tuple:
    """What a store's ``recon.json`` records of its frames: the lenslet period and phase, the
    frames' SNRs, their numbers and times, and the specimen's near surface (none without
    one)."""
    if not isinstance(recon, Mapping):
        return (None, (0, 0)), {}, {}, None
    return (
        lenslet_phases(recon, vs, origin_xyz_um, where),
        frame_snrs(recon, where),
        frame_records(recon, where),
        parse_surface(recon, where),
    )


def scan(store: str | os.PathLike) -> list[VolumeInfo]:
    """The frames of an OME-Zarr image as volumes, without reading voxels.

    Read with the ``ome-zarr`` reader (as napari-ome-zarr does): the first multiscales image
    of ``store``, its first dataset. Its axes must be ``[t,] [c,] z, y, x`` (a channel axis
    of length 1), the space axes in units of length. A store written by ``recon run
    --format zarr`` holds ``recon.json``: a frame it has no volume for is missing.

    Raises
    ------
    InputError
        Not an OME-NGFF image, other axes, no length unit, bad transformations, an
        unsupported voxel type, or frames ``recon`` has not written yet.
    """
    import zarr
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Multiscales, Reader

    store = Path(store)
    quiet = logging.getLogger("ome_zarr")  # it warns of e.g. an NGFF 0.4 store ("version mismatch")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        loc = parse_url(str(store), mode="r")
        nodes = list(Reader(loc)()) if loc is not None else []
    except Exception as exc:  # ome-zarr and zarr raise assorted types on bad stores
        raise InputError(f"{store}: cannot read as an OME-Zarr image: {exc}") from None
    finally:
        quiet.setLevel(level)
    node = next((n for n in nodes if n.load(Multiscales) is not None), None)
    if node is None:
        raise InputError(
            f"{store} is not an OME-NGFF image (no 'multiscales' metadata in a Zarr group)"
        )
    ms = loc.root_attrs["multiscales"][0]
    axes = ms.get("axes") or []
    names = [a.get("name") if isinstance(a, Mapping) else a for a in axes]
    lead_names = names[:-3]
    if names[-3:] != ["z", "y", "x"] or lead_names not in ([], ["t"], ["c"], ["t", "c"]):
        raise InputError(
            f"{store}: expected the axes (t, z, y, x) or (z, y, x) (an optional channel axis "
            f"c of length 1 before z), got ({', '.join(map(str, names))})"
        )
    ds = ms["datasets"][0]
    try:
        arr = zarr.open_array(store=str(store), path=ds["path"], mode="r")
    except Exception as exc:  # zarr raises assorted types on bad stores
        raise InputError(f"{store}: cannot open dataset {ds.get('path')!r}: {exc}") from None
    if arr.ndim != len(names):
        raise InputError(f"{store}: {len(names)} axes but a {arr.ndim}-D array")
    if np.dtype(arr.dtype).kind not in "uif":
        raise InputError(f"{store}: unsupported voxel type {arr.dtype}")
    where = f"{store} dataset {ds['path']!r}"
    scale, shift = _transforms(ds.get("coordinateTransformations"), where, arr.ndim)
    g_scale, g_shift = _transforms(ms.get("coordinateTransformations"), str(store), arr.ndim)
    scale, shift = scale * g_scale, shift * g_scale + g_shift
    factors = []
    for a in axes[-3:]:
        unit = a.get("unit") if isinstance(a, Mapping) else None
        if unit not in _LENGTH_UM:
            raise InputError(
                f"{store}: axis {a.get('name') if isinstance(a, Mapping) else a!r} has unit "
                f"{unit!r}; expected a length (micrometer, nanometer, millimeter, …)"
            )
        factors.append(_LENGTH_UM[unit])
    vs = tuple(float(v) for v in scale[-3:] * factors)
    if not all(math.isfinite(v) and v > 0 for v in vs):
        raise InputError(f"{where}: voxel size {list(vs)} µm must be positive")
    z0, y0, x0 = (float(v) for v in shift[-3:] * factors)
    shape = tuple(int(v) for v in arr.shape)
    if "c" in lead_names and shape[lead_names.index("c")] != 1:
        raise InputError(f"{store}: {shape[lead_names.index('c')]} channels; expected one")
    n = shape[0] if lead_names[:1] == ["t"] else 1
    missing = []
    recon_json = store / RECON_JSON
    recon = {}
    if recon_json.is_file():
        recon = read_json(recon_json)
        frames = recon.get("frames") if isinstance(recon, Mapping) else None
        if isinstance(frames, list):
            done = {f.get("index") for f in frames if isinstance(f, Mapping) and f.get("output")}
            missing = [k for k in range(n) if k not in done]
    if missing:
        raise InputError(
            f"{store}: frame(s) t = {', '.join(map(str, missing[:5]))} not written yet "
            f"({RECON_JSON} has no volume for them; an interrupted recon run?)"
        )
    lenslet, snrs, records, surface = _recon_records(recon, vs, (x0, y0, z0), str(recon_json))
    t_unit = (
        axes[0].get("unit") if lead_names[:1] == ["t"] and isinstance(axes[0], Mapping) else None
    )
    out = []
    for k in range(n):
        lead = tuple([k] if lead_names[:1] == ["t"] else []) + (0,) * ("c" in lead_names)
        number, time_s = records.get(k, (None, None))
        if time_s is None and k not in records and t_unit in _TIME_S:
            time_s = float((shift[0] + k * scale[0]) * _TIME_S[t_unit])
        out.append(
            VolumeInfo(
                shape=shape[-3:],
                voxel_size_um=vs,
                origin_xyz_um=(x0, y0, z0),
                path=store,
                index=k,
                dataset=str(ds["path"]),
                lead=lead,
                lenslet_period_vox=lenslet[0],
                lenslet_phase_vox=lenslet[1],
                snr=snrs.get(k),
                number=number,
                time_s=time_s,
                format=NAME,
                surface_z_um=surface,
            )
        )
    return check_frames(out, str(recon_json) if records else str(store))


def read(info: VolumeInfo) -> np.ndarray:
    """The voxels of one frame of the image (``info.lead`` selects it) as stored.

    Raises
    ------
    InputError
        A truncated or damaged chunk (names the store and frame).
    """
    import zarr

    try:
        with quiet("asyncio"):
            try:
                arr = zarr.open_array(store=str(info.path), path=info.dataset, mode="r")
                return np.asarray(arr[(*info.lead, Ellipsis)])
            except Exception:
                gc.collect()  # the reads still pending after the failure end here, quietly
                raise
    except Exception as exc:  # zarr and its codecs raise assorted types on corrupt chunks
        raise InputError(
            f"cannot read volume {info.source()} (a truncated or damaged chunk?): {exc}"
        ) from None


#: Whether a path is read as a Zarr store (the registry's test).
is_zarr = matches

__all__ = ["NAME", "is_zarr", "matches", "read", "scan"]
