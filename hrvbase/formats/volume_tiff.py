"""Volume reader: a folder of numbered TIFF volumes ``NNNNNN.tif`` (``recon run``'s default).

Each file is a float32 ``(z, y, x)`` volume in the layout of
:mod:`hrvbase.formats.tiff_layout`. Its voxel size ``[dz, dy, dx]`` and origin come, in this
order of preference, from its JSON metadata (private tag 65001, or the ``ImageDescription`` of
files of the previous layout: ``"voxel_size_um"``, ``"origin_xyz_um"`` or ``origin_xy_um``
``[x0, y0]`` with ``depths_um``), from the ImageJ calibration of a file saved by Fiji
(``unit`` µm, ``spacing``, ``XResolution``/``YResolution``, ``xorigin``/``yorigin``/
``zorigin``), or from the folder's ``recon.json`` (``voxel_size_um``; ``grid.origin_xy_um``
``[x0, y0]`` and ``grid.depths_um`` place the volume in object space). Files of the
older layout name the corner ``[x0, y0]`` ``origin_um``; it is read under either name
(:func:`hrvbase.formats.volumes.record_entry`). The frame numbers,
times, SNRs and lenslet period come from ``recon.json``, else from each file's metadata
(:mod:`hrvbase.formats.volumes`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import read_json
from .tiff_layout import quiet, read_volume_header
from .volumes import (
    NUMBERED,
    RECON_JSON,
    VolumeInfo,
    check_frames,
    frame_records,
    frame_snrs,
    lenslet_phases,
    parse_frame_number,
    parse_frame_time,
    parse_origin,
    parse_snr,
    parse_surface,
    parse_voxel_size,
)

#: Name of this format in the registry.
NAME = "tiff-folder"


def matches(path: Path) -> bool:
    """A folder holding at least one numbered volume ``NNNNNN.tif``."""
    return path.is_dir() and any(
        (m := NUMBERED.match(p.name)) and m.group(2) in ("tif", "tiff") for p in path.iterdir()
    )


def _numbered_files(folder: Path) -> dict[int, Path]:
    files = {}
    for p in folder.iterdir():
        m = NUMBERED.match(p.name)
        if m and m.group(2) in ("tif", "tiff"):
            files[int(m.group(1))] = p
    if not files:
        raise InputError(f"{folder} holds no numbered volumes NNNNNN.tif")
    return files


def _read_recon(folder: Path, idx: list[int], files: dict[int, Path]) -> dict:
    """The folder's ``recon.json`` (``{}`` without one), checked against the volumes present:
    a missing volume, or frame records that leave out a volume."""
    missing = sorted(set(range(idx[0], idx[-1] + 1)) - set(idx))
    recon = {}
    where = str(folder / RECON_JSON)
    if (folder / RECON_JSON).is_file():
        recon = read_json(folder / RECON_JSON)
        if not isinstance(recon, Mapping):
            raise InputError(f"{folder / RECON_JSON} is not a JSON object")
        frame_records(recon, where)
        n_frames = len(recon.get("frames") or [])
        if n_frames:
            missing = sorted(set(missing) | (set(range(n_frames)) - set(idx)))
    if missing:
        names = ", ".join(f"{k:06d}.tif" for k in missing[:5])
        raise InputError(f"{folder}: volume {names} is missing from the numbered series")
    records = frame_records(recon, where)  # ({} without recon.json)
    if any(n is not None or t is not None for n, t in records.values()):
        lack = [k for k in idx if k not in records]
        if lack:
            raise InputError(
                f"{where} records the frame numbers and times of {len(records)} "
                f"frames but not of volume {files[lack[0]]} ({len(idx)} volumes in {folder})"
            )
    return recon


def _volume(k: int, p: Path, recon: Mapping, folder: Path) -> tuple[VolumeInfo, np.dtype]:
    """The record of volume ``k`` (file ``p``) and its voxel type."""
    where = str(folder / RECON_JSON)
    head = read_volume_header(p)
    dtype = np.dtype(head.dtype)
    meta = head.meta
    if dtype.kind not in "uif":
        raise InputError(f"{p}: unsupported voxel type {head.dtype}")
    if meta.get("voxel_size_um") is not None:
        vs = parse_voxel_size(meta["voxel_size_um"], str(p))
    elif head.imagej_vs is not None:
        vs = head.imagej_vs
    elif recon.get("voxel_size_um") is not None:
        vs = parse_voxel_size(recon["voxel_size_um"], where)
    else:
        raise InputError(
            f"{p}: no voxel size (no 'voxel_size_um' in the TIFF metadata, no ImageJ "
            f"calibration in µm and no {RECON_JSON} in {folder})"
        )
    origin = (
        parse_origin(meta, vs, str(p))
        or head.imagej_origin
        or parse_origin(recon.get("grid") or {}, vs, RECON_JSON)
    )
    origin = origin or (0.0, 0.0, 0.0)
    # recon.json's grid, else the one recon wrote into the TIFF (copied without it)
    src, src_where = (recon, where) if recon.get("grid") is not None else (meta, str(p))
    period, phase = lenslet_phases(src, vs, origin, src_where)
    # recon.json's record of the frame, else the SNR recon wrote into the TIFF
    snrs = frame_snrs(recon, where)
    snr = snrs[k] if k in snrs else parse_snr(meta.get("snr"), str(p))
    # recon.json's specimen surface, else the one recon wrote into the TIFF
    surface = (
        parse_surface(recon, where) if "surface_z_um" in recon else parse_surface(meta, str(p))
    )
    records = frame_records(recon, where)
    if k in records:
        number, time_s = records[k]
    else:  # recon writes them into the TIFF too (a volume copied without recon.json)
        number = parse_frame_number(meta.get("number"), str(p))
        time_s = parse_frame_time(meta.get("time_s"), str(p))
    info = VolumeInfo(
        shape=head.shape,
        voxel_size_um=vs,
        origin_xyz_um=origin,
        path=p,
        index=k,
        lenslet_period_vox=period,
        lenslet_phase_vox=phase,
        snr=snr,
        number=number,
        time_s=time_s,
        format=NAME,
        surface_z_um=surface,
    )
    return info, dtype


def scan(folder: Path) -> list[VolumeInfo]:
    """The numbered volumes ``NNNNNN.tif`` of a folder with voxel size and origin.

    Raises
    ------
    InputError
        No volumes, a gap in the numbering ("volume NNNNNN.tif is missing"), a truncated
        file, a volume without a voxel size, shapes (a 2-D image is one plane) or
        voxel types that differ ("mixed series") or voxel sizes that differ ("mismatched voxel
        sizes").
    """
    folder = Path(folder)
    files = _numbered_files(folder)
    idx = sorted(files)
    recon = _read_recon(folder, idx, files)
    out, dtypes = [], []
    for k in idx:
        info, dtype = _volume(k, files[k], recon, folder)
        out.append(info)
        dtypes.append(dtype)
    first = out[0]
    for v, dtype in zip(out[1:], dtypes[1:], strict=True):
        if v.shape != first.shape or dtype != dtypes[0]:
            raise InputError(
                f"mixed series: {v.path} holds {' × '.join(map(str, v.shape))} voxels of "
                f"{dtype}, {first.path} {' × '.join(map(str, first.shape))} of {dtypes[0]} "
                "(z × y × x); the volumes of a series must match"
            )
        if not np.allclose(v.voxel_size_um, first.voxel_size_um, rtol=1e-6, atol=0):
            raise InputError(
                f"mismatched voxel sizes: {v.path} has {list(v.voxel_size_um)} µm, "
                f"{first.path} has {list(first.voxel_size_um)} µm"
            )
    records = frame_records(recon, str(folder / RECON_JSON))
    where = str(folder / RECON_JSON) if records else str(folder)
    return check_frames(out, where)


def read(info: VolumeInfo | Path) -> np.ndarray:
    """The voxels of a TIFF volume (its record, or the file) as stored.

    Raises
    ------
    InputError
        Unreadable file (names it).
    """
    import tifffile

    path = info.path if isinstance(info, VolumeInfo) else Path(info)
    try:
        with quiet("tifffile"):
            return tifffile.imread(path)
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc


__all__ = ["NAME", "matches", "read", "scan"]
