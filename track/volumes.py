"""Volume series of :mod:`track`: numbered TIFF volumes or an OME-Zarr image, in object space.

A series is a folder of ``NNNNNN.tif`` float32 ``(z, y, x)`` volumes, or one OME-Zarr image
(``recon run --format zarr``, or any OME-NGFF image of axes ``(t, z, y, x)`` or ``(z, y, x)``,
with an optional channel axis of length 1) whose frames are the volumes (:func:`scan_volumes`
lists them without reading voxels, :func:`read_volume` reads one). In a Zarr image the voxel
size and origin are the ``scale`` and ``translation`` of its first (full-resolution) dataset,
in the units of its space axes (converted to µm). In a TIFF series they  (the voxel size
``[dz, dy, dx]`` and the origin) come, in this order of preference, from the JSON metadata of
``lfsim.io.write_tiff`` (private tag 65001, or the ``ImageDescription`` of files of the
previous layout: ``"voxel_size_um"``, ``"origin_xyz_um"`` or ``origin_um`` ``[x0, y0]`` with
``depths_um``), from the ImageJ calibration of a file saved by Fiji (``unit`` µm,
``spacing``, ``XResolution``/``YResolution``, ``xorigin``/``yorigin``/``zorigin``), or from
the folder's ``recon.json`` (``voxel_size_um``; ``grid.origin_um`` ``[x0, y0]`` and
``grid.depths_um`` place the volume in object space). Lengths in µm (docs/conventions.md).

The ``grid`` of a series' ``recon.json`` (next to TIFF volumes, or inside a Zarr store) also
gives the lenslet period of the volumes, its super-resolution factor ``s``, and the sub-lenslet
phase of their first voxel (:func:`lenslet_phases`, :attr:`VolumeInfo.lenslet_period_vox`),
which :func:`track.detect.detect_particles` uses to treat the noise of a light-field
reconstruction. ``recon run`` also writes that ``grid`` into each TIFF's metadata, so that a
TIFF copied without its ``recon.json`` keeps its period; volumes from elsewhere have none.

Frame numbers and times. ``recon run`` records, per volume, the number of the camera frame it
was reconstructed from and that frame's time (``recon.json`` frames' ``number`` and
``time_s``, also in each TIFF's metadata); an OME-Zarr t axis in a unit of time gives the
times of other images. Volumes ``000000.tif … 000002.tif`` of camera frames 0, 1 and 5 are
frames 0, 1 and 5 (:attr:`VolumeInfo.frame`) in every output of ``track``; volumes without
recorded numbers are numbered by their files. Both must increase with the volumes; a
``recon.json`` that records them must record every volume.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import itertools
import json
import logging
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import read_json

from .errors import InputError

log = logging.getLogger(__name__)

#: Pattern of the numbered files of a series (6 digits).
NUMBERED = re.compile(r"^(\d{6})\.(tif|tiff|csv)$")

#: Name of the reconstruction metadata file next to volumes.
RECON_JSON = "recon.json"


@dataclass(frozen=True)
class VolumeInfo:
    """One volume of a numbered series (metadata only; read the voxels with :func:`read_volume`).

    Attributes
    ----------
    path : Path
    index : int
        Frame number from the file name ``NNNNNN.tif``.
    shape : tuple of int
        ``(nz, ny, nx)``.
    voxel_size_um : tuple of float
        ``(dz, dy, dx)`` (µm).
    origin_xyz_um : tuple of float
        Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm).
    dataset : str or None
        OME-Zarr: the path of the array inside the store ``path`` (``index`` is then the
        position along its t axis); None for a TIFF file.
    lead : tuple of int
        OME-Zarr: the indices of the axes before ``(z, y, x)`` that select this volume.
    lenslet_period_vox : int or None
        Lateral lenslet period of a light-field reconstruction (voxels: its super-resolution
        factor ``s``), from the ``grid`` of the series' ``recon.json``
        (:func:`lenslet_phases`); None when unknown. :func:`track.detect.detect_particles`
        uses it to even out the noise of the sub-lenslet phases.
    lenslet_phase_vox : tuple of 2 int
        ``(phase_y, phase_x)``: sub-lenslet position of voxel row and column 0 (0 for the
        volumes of ``recon run``).
    snr : float or None
        SNR of the camera frame the volume was reconstructed from (``recon.json`` frames'
        ``preprocess.snr``, or the TIFF's metadata; :func:`recon.preprocess.frame_snr`);
        None when unknown or the frame held no noise.
    number : int or None
        Original (camera) frame number of the volume: ``recon.json`` frames' ``number``, or
        the TIFF's metadata ``number``; None when not recorded (:attr:`frame` is then
        ``index``).
    time_s : float or None
        Time of that camera frame (s): ``recon.json`` frames' ``time_s``, the TIFF's metadata
        ``time_s``, or an OME-Zarr t axis in a unit of time; None when unknown.
    """

    path: Path
    index: int
    shape: tuple
    voxel_size_um: tuple
    origin_xyz_um: tuple
    dataset: str | None = None
    lead: tuple = ()
    lenslet_period_vox: int | None = None
    lenslet_phase_vox: tuple = (0, 0)
    snr: float | None = None
    number: int | None = None
    time_s: float | None = None

    @property
    def frame(self) -> int:
        """The frame number of the volume in every output: its recorded camera frame
        :attr:`number`, else its :attr:`index`."""
        return self.index if self.number is None else self.number

    @property
    def name(self) -> str:
        """``NNNNNN.tif``, or ``STORE.zarr[t=K]`` for a frame of an OME-Zarr image."""
        return self.path.name if self.dataset is None else f"{self.path.name}[t={self.index}]"

    def source(self, *, resolve: bool = False) -> str:
        """The file (or store and frame) as text; ``resolve``: an absolute path."""
        p = str(Path(self.path).resolve() if resolve else self.path)
        return p if self.dataset is None else f"{p}[t={self.index}]"


#: Private TIFF tags of ``lfsim.io.write_tiff`` (track does not import lfsim): the array
#: shape ``{"shape": [...]}`` and the JSON metadata (files of the previous layout hold the JSON
#: in the ``ImageDescription``).
_SHAPE_TAG = 65000
_METADATA_TAG = 65001

#: Spellings of the micrometre in ImageJ's ``unit=`` entry.
_MICROMETRE = frozenset(
    {"um", "\u00b5m", "\\u00b5m", "micron", "microns", "micrometer", "micrometre"}
)


def _voxel_size(value, where: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: voxel_size_um must be [dz, dy, dx], got {value!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"{where}: voxel_size_um must be 3 positive numbers, got {value!r}")
    return vals


def _origin(meta: Mapping, vs, where: str) -> tuple[float, float, float] | None:
    """Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm) from metadata.

    ``origin_xyz_um`` (that centre, as ``lfsim.io.write_tiff`` records it) or, in older files
    and ``recon.json``, ``origin_um`` ``[x0, y0]`` (the corner of lenslet ``(0, 0)``) with
    ``depths_um``. ``None`` when the metadata hold neither.
    """
    xyz = meta.get("origin_xyz_um")
    if xyz is not None:
        try:
            vals = tuple(float(v) for v in xyz)
        except (TypeError, ValueError):
            vals = ()
        if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
            raise InputError(f"{where}: origin_xyz_um must be 3 numbers [x, y, z], got {xyz!r}")
        return vals
    o = meta.get("origin_um")
    d = meta.get("depths_um")
    if o is None and d is None:
        return None
    try:
        ox, oy = (float(v) for v in (o if o is not None else (0.0, 0.0))[:2])
        z0 = float(d[0]) if d else 0.0
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{where}: bad origin_um/depths_um {o!r} / {d!r}") from None
    # recon places voxel column i at origin + (i + 0.5) · dx (geometry.ReconGrid.x_um)
    return (ox + 0.5 * vs[2], oy + 0.5 * vs[1], z0)


def lenslet_phases(
    recon: Mapping, voxel_size_um, origin_xyz_um, where: str
) -> tuple[int | None, tuple[int, int]]:
    """Lenslet period (voxels) and phase of a volume from the ``grid`` of its ``recon.json``.

    ``grid.s`` is the period; ``grid.origin_um`` (the corner of lenslet ``(0, 0)``) and the
    volume's origin (centre of voxel ``(0, 0, 0)``) give the sub-lenslet position of voxel
    row and column 0 (0 for an uncropped ``recon run`` volume). When the volume's lateral
    voxel size is not ``grid.lenslet_object_um / s`` (a resampled copy) or its origin is not
    on the grid's voxel lattice, the period does not apply: ``(None, (0, 0))`` with a
    warning, and detection runs without it.

    Raises
    ------
    InputError
        A ``grid`` entry that is not a JSON object, or a bad ``s`` or ``lenslet_object_um``.
    """
    grid = recon.get("grid")
    if grid is None:
        return None, (0, 0)
    if not isinstance(grid, Mapping):
        raise InputError(f"{where}: 'grid' must be a JSON object, got {grid!r}")
    if grid.get("s") is None:
        return None, (0, 0)
    s, pitch = grid.get("s"), grid.get("lenslet_object_um")
    if isinstance(s, bool) or not isinstance(s, int) or s < 1:
        raise InputError(f"{where}: grid.s must be a positive integer, got {s!r}")
    try:
        pitch = float(pitch)
        corner = [float(v) for v in grid.get("origin_um", (0.0, 0.0))][:2]
    except (TypeError, ValueError):
        raise InputError(
            f"{where}: grid.lenslet_object_um and grid.origin_um must be numbers, got "
            f"{grid.get('lenslet_object_um')!r} and {grid.get('origin_um')!r}"
        ) from None
    if not (math.isfinite(pitch) and pitch > 0) or len(corner) != 2:
        raise InputError(
            f"{where}: grid.lenslet_object_um must be > 0 µm and grid.origin_um [x0, y0], "
            f"got {grid.get('lenslet_object_um')!r} and {grid.get('origin_um')!r}"
        )
    _, dy, dx = voxel_size_um
    vox = pitch / s
    if not (math.isclose(dy, vox, rel_tol=1e-3) and math.isclose(dx, vox, rel_tol=1e-3)):
        log.warning(
            "%s: the volumes' lateral voxel size %g × %g µm is not grid.lenslet_object_um / s "
            "= %g µm: the lenslet period does not apply (detection without it)",
            where,
            dy,
            dx,
            vox,
        )
        return None, (0, 0)
    phase = []
    for o, c, d in ((origin_xyz_um[1], corner[1], dy), (origin_xyz_um[0], corner[0], dx)):
        k = (o - c) / d - 0.5  # voxel column k + 0.5 from the corner of lenslet (0, 0)
        if abs(k - round(k)) > 1e-3:
            log.warning(
                "%s: the volumes' origin is off the reconstruction grid: the lenslet period "
                "does not apply (detection without it)",
                where,
            )
            return None, (0, 0)
        phase.append(round(k) % s)
    return s, (phase[0], phase[1])


@dataclass(frozen=True)
class _Header:
    """What :func:`_tiff_header` reads: shape, dtype, our JSON metadata, ImageJ calibration."""

    shape: tuple
    dtype: Any
    meta: dict
    imagej_vs: tuple | None = None  # (dz, dy, dx) µm from a Fiji calibration
    imagej_origin: tuple | None = None  # (x, y, z) µm of voxel (0, 0, 0)


def _imagej_calibration(ij: Mapping | None, page) -> tuple[tuple | None, tuple | None]:
    """Voxel size ``(dz, dy, dx)`` and origin ``(x, y, z)`` (µm) of an ImageJ calibration.

    ``(None, None)`` unless the unit is a micrometre and spacing and resolutions are positive.
    """
    if not ij or str(ij.get("unit", "")).strip().lower() not in _MICROMETRE:
        return None, None
    try:
        dz = float(ij["spacing"])
        xres = page.tags["XResolution"].value
        yres = page.tags["YResolution"].value
        dx = xres[1] / xres[0]
        dy = yres[1] / yres[0]
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return None, None
    vs = (dz, dy, dx)
    if not all(math.isfinite(v) and v > 0 for v in vs):
        return None, None
    keys = ("xorigin", "yorigin", "zorigin")
    if not any(k in ij for k in keys):
        return vs, None
    try:
        idx = [float(ij.get(k, 0.0)) for k in keys]
    except (TypeError, ValueError):
        return vs, None
    # ImageJ: coordinate = (index - origin) * size, so voxel 0 sits at -origin * size.
    origin = (-idx[0] * dx, -idx[1] * dy, -idx[2] * dz)
    if not all(math.isfinite(v) for v in origin):
        return vs, None
    return vs, origin


@contextlib.contextmanager
def _quiet(*names: str):
    """Hold the loggers ``names`` to errors: tifffile logs each unreadable page header of a
    damaged file, and asyncio the pending reads of a failed Zarr decode, on stderr; the one
    :class:`InputError` that follows says it."""
    loggers = [logging.getLogger(n) for n in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _data_end(tif, n_voxels: int | None = None) -> int:
    """Byte just past the last voxel data of the first series (headers only).

    ``n_voxels``: the voxels the file declares (its shape tag); contiguous data then end
    ``n_voxels`` items after the first, even where the page headers past the cut are lost.
    """
    series = tif.series[0]
    if series.dataoffset is not None:  # contiguous data
        n = int(series.nbytes) if n_voxels is None else n_voxels * series.dtype.itemsize
        return int(series.dataoffset) + max(int(series.nbytes), n)
    end = 0
    for page in tif.pages:
        for offset, count in zip(page.dataoffsets, page.databytecounts, strict=True):
            end = max(end, int(offset) + int(count))
    return end


def _tiff_header(path: Path) -> _Header:
    """Shape, dtype and metadata of a volume file, without reading its voxels."""
    import tifffile

    try:
        with _quiet("tifffile"), tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            desc = page.description or ""
            tagvals = {}
            for code in (_SHAPE_TAG, _METADATA_TAG):
                tag = page.tags.get(code)
                tagvals[code] = tag.value if tag is not None else None
            shape = readable = tuple(tif.series[0].shape)
            dtype = tif.series[0].dtype
            if tagvals[_SHAPE_TAG] is not None:
                with contextlib.suppress(ValueError, KeyError, TypeError):
                    shape = tuple(int(n) for n in json.loads(tagvals[_SHAPE_TAG])["shape"])
            ij_vs, ij_origin = _imagej_calibration(tif.imagej_metadata, page)
            end = _data_end(tif, math.prod(shape))
    except Exception as exc:  # tifffile raises assorted types on corrupt files
        raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc
    size = path.stat().st_size
    if end > size:
        raise InputError(
            f"TIFF volume {path} is truncated: its voxels end at byte {end} but the file has "
            f"{size} bytes (an interrupted copy or write?)"
        )
    if math.prod(readable) != math.prod(shape):
        raise InputError(
            f"TIFF volume {path} is truncated or damaged: it declares "
            f"{' × '.join(map(str, shape))} voxels but its pages hold "
            f"{' × '.join(map(str, readable))}"
        )
    if len(shape) == 2:
        shape = (1, *shape)
    if len(shape) != 3:
        raise InputError(f"{path}: expected a (z, y, x) volume, got shape {shape}")
    text = tagvals[_METADATA_TAG]
    if text is not None:
        try:
            meta = json.loads(text)
        except (ValueError, TypeError):
            meta = None
        if not isinstance(meta, dict):
            raise InputError(f"{path}: metadata tag {_METADATA_TAG} does not hold a JSON object")
    else:  # the previous layout: JSON, if any, in the ImageDescription
        meta = {}
        with contextlib.suppress(json.JSONDecodeError):
            obj = json.loads(desc) if desc else {}
            meta = obj if isinstance(obj, dict) else {}
    return _Header(shape, dtype, meta, ij_vs, ij_origin)


def _snr(value, where: str) -> float | None:
    """A frame's recorded SNR (None: not recorded, or a noise-free frame)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < math.inf:
        raise InputError(f"{where}: snr must be a finite number > 0 or null, got {value!r}")
    return float(value)


def _frame_snrs(recon: Mapping, where: str) -> dict[int, float | None]:
    """The SNR of each frame ``recon.json`` records (``frames[i].preprocess.snr``), by index."""
    out = {}
    for f in recon.get("frames") or []:
        if isinstance(f, Mapping) and isinstance(f.get("index"), int):
            pre = f.get("preprocess")
            if isinstance(pre, Mapping):
                out[f["index"]] = _snr(pre.get("snr"), f"{where} frame {f['index']}")
    return out


def _frame_number(value, where: str) -> int | None:
    """A recorded camera frame number (None: not recorded)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(
            f"{where}: number (the camera frame number) must be an integer >= 0 or null, "
            f"got {value!r}"
        )
    return value


def _frame_time(value, where: str) -> float | None:
    """A recorded frame time in seconds (None: not recorded)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(
            f"{where}: time_s must be a finite number of seconds or null, got {value!r}"
        )
    return float(value)


def _frame_records(recon: Mapping, where: str) -> dict[int, tuple[int | None, float | None]]:
    """``{index: (number, time_s)}`` of the frames a ``recon.json`` records."""
    frames = recon.get("frames")
    if frames is None:
        return {}
    if not isinstance(frames, list):
        raise InputError(f"{where}: 'frames' must be a list of frame records, got {frames!r:.60}")
    out = {}
    for f in frames:
        if not (isinstance(f, Mapping) and isinstance(f.get("index"), int)):
            continue
        k = f["index"]
        if k in out:
            raise InputError(f"{where}: frame index {k} is recorded twice")
        w = f"{where} frame {k}"
        out[k] = (_frame_number(f.get("number"), w), _frame_time(f.get("time_s"), w))
    return out


def _check_frames(vols: list[VolumeInfo], where: str) -> list[VolumeInfo]:
    """The series' recorded frame numbers and times, checked: both increase with the
    volumes. Recorded for some volumes only, they are dropped with a warning (numbers: the
    frames are numbered by their volumes; times: unknown)."""
    for key, what in (("number", "frame number"), ("time_s", "time")):
        values = [getattr(v, key) for v in vols]
        if all(x is None for x in values):
            continue
        if any(x is None for x in values):
            lack = next(v for v in vols if getattr(v, key) is None)
            log.warning(
                "%s: %s has no recorded %s but other volumes have: %s",
                where,
                lack.source(),
                what,
                "the frames are numbered by their volumes"
                if key == "number"
                else "the frame times are unknown",
            )
            vols = [dataclasses.replace(v, **{key: None}) for v in vols]
            continue
        for a, b in itertools.pairwise(vols):
            x, y = getattr(a, key), getattr(b, key)
            if y == x:
                raise InputError(
                    f"{where}: {what} {x:g} is recorded for both {a.source()} and {b.source()}"
                )
            if y < x:
                raise InputError(
                    f"{where}: {what}s must increase with the volumes, but {b.source()} has "
                    f"{y:g} after {x:g} of {a.source()}"
                )
    return vols


def scan_volumes(folder: str | os.PathLike) -> list[VolumeInfo]:
    """The numbered volumes ``NNNNNN.tif`` of a folder, or the frames of an OME-Zarr image,
    with voxel size and origin.

    Parameters
    ----------
    folder : path
        Folder holding ``000000.tif, 000001.tif, …`` (and optionally ``recon.json``), or an
        OME-Zarr image (see :func:`scan_zarr`).

    Returns
    -------
    list of VolumeInfo
        In frame order.

    Raises
    ------
    InputError
        No volumes, a gap in the numbering ("volume NNNNNN.tif is missing"), a truncated
        file, a volume without a voxel size, shapes (a 2-D image is one plane) or
        voxel types that differ ("mixed series") or voxel sizes that differ ("mismatched voxel
        sizes").
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"volume folder {folder} does not exist or is not a folder")
    if is_zarr(folder):
        return scan_zarr(folder)
    files = {}
    for p in folder.iterdir():
        m = NUMBERED.match(p.name)
        if m and m.group(2) in ("tif", "tiff"):
            files[int(m.group(1))] = p
    if not files:
        raise InputError(f"{folder} holds no numbered volumes NNNNNN.tif")
    idx = sorted(files)
    missing = sorted(set(range(idx[0], idx[-1] + 1)) - set(idx))
    recon = {}
    if (folder / RECON_JSON).is_file():
        recon = read_json(folder / RECON_JSON)
        if not isinstance(recon, Mapping):
            raise InputError(f"{folder / RECON_JSON} is not a JSON object")
        records = _frame_records(recon, str(folder / RECON_JSON))
        n_frames = len(recon.get("frames") or [])
        if n_frames:
            missing = sorted(set(missing) | (set(range(n_frames)) - set(idx)))
    if missing:
        names = ", ".join(f"{k:06d}.tif" for k in missing[:5])
        raise InputError(f"{folder}: volume {names} is missing from the numbered series")
    recon_vs = None
    if recon.get("voxel_size_um") is not None:
        recon_vs = _voxel_size(recon["voxel_size_um"], str(folder / RECON_JSON))
    snrs = _frame_snrs(recon, str(folder / RECON_JSON))
    records = _frame_records(recon, str(folder / RECON_JSON))  # ({} without recon.json)
    if any(n is not None or t is not None for n, t in records.values()):
        lack = [k for k in idx if k not in records]
        if lack:
            raise InputError(
                f"{folder / RECON_JSON} records the frame numbers and times of {len(records)} "
                f"frames but not of volume {files[lack[0]]} ({len(idx)} volumes in {folder})"
            )
    out, dtypes = [], []
    for k in idx:
        p = files[k]
        head = _tiff_header(p)
        dtypes.append(np.dtype(head.dtype))
        shape, meta = head.shape, head.meta
        if np.dtype(head.dtype).kind not in "uif":
            raise InputError(f"{p}: unsupported voxel type {head.dtype}")
        if meta.get("voxel_size_um") is not None:
            vs = _voxel_size(meta["voxel_size_um"], str(p))
        elif head.imagej_vs is not None:
            vs = head.imagej_vs
        elif recon_vs is not None:
            vs = recon_vs
        else:
            raise InputError(
                f"{p}: no voxel size (no 'voxel_size_um' in the TIFF metadata, no ImageJ "
                f"calibration in µm and no {RECON_JSON} in {folder})"
            )
        origin = (
            _origin(meta, vs, str(p))
            or head.imagej_origin
            or _origin(recon.get("grid") or {}, vs, RECON_JSON)
        )
        origin = origin or (0.0, 0.0, 0.0)
        # recon.json's grid, else the one recon wrote into the TIFF (copied without it)
        src, where = (recon, folder / RECON_JSON) if recon.get("grid") is not None else (meta, p)
        period, phase = lenslet_phases(src, vs, origin, str(where))
        # recon.json's record of the frame, else the SNR recon wrote into the TIFF
        snr = snrs[k] if k in snrs else _snr(meta.get("snr"), str(p))
        if k in records:
            number, time_s = records[k]
        else:  # recon writes them into the TIFF too (a volume copied without recon.json)
            number = _frame_number(meta.get("number"), str(p))
            time_s = _frame_time(meta.get("time_s"), str(p))
        out.append(
            VolumeInfo(p, k, shape, vs, origin, None, (), period, phase, snr, number, time_s)
        )
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
    where = str(folder / RECON_JSON) if records else str(folder)
    return _check_frames(out, where)


# -- OME-Zarr --------------------------------------------------------------------------------
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


def is_zarr(path: str | os.PathLike) -> bool:
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


def scan_zarr(store: str | os.PathLike) -> list[VolumeInfo]:
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
    lenslet, snrs, records = (None, (0, 0)), {}, {}
    if isinstance(recon, Mapping):
        lenslet = lenslet_phases(recon, vs, (x0, y0, z0), str(recon_json))
        snrs = _frame_snrs(recon, str(recon_json))
        records = _frame_records(recon, str(recon_json))
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
                store,
                k,
                shape[-3:],
                vs,
                (x0, y0, z0),
                str(ds["path"]),
                lead,
                *lenslet,
                snrs.get(k),
                number,
                time_s,
            )
        )
    return _check_frames(out, str(recon_json) if records else str(store))


def volume_checksum(info: VolumeInfo) -> str:
    """SHA-256 identifying a volume: of its file, or of a Zarr frame's values
    (:func:`hrvbase.io.array_sha256`; the frame is read, so that a damaged chunk or a
    frame holding NaN, e.g. one never written, is an :class:`InputError` here)."""
    from hrvbase.io import array_sha256, sha256_file

    if info.dataset is None:
        return sha256_file(info.path)
    return array_sha256(read_volume(info))


def _read_zarr(info: VolumeInfo) -> np.ndarray:
    import zarr

    try:
        with _quiet("asyncio"):
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


def read_volume(info: VolumeInfo | str | os.PathLike) -> np.ndarray:
    """Voxels of a volume as float32 ``(z, y, x)``.

    Raises
    ------
    InputError
        Unreadable file or non-finite voxels.
    """
    import tifffile

    path = Path(info.path if isinstance(info, VolumeInfo) else info)
    where = info.source() if isinstance(info, VolumeInfo) else str(path)
    if isinstance(info, VolumeInfo) and info.dataset is not None:
        arr = _read_zarr(info)
    else:
        try:
            with _quiet("tifffile"):
                arr = tifffile.imread(path)
        except Exception as exc:  # tifffile raises assorted types on corrupt files
            raise InputError(f"cannot read TIFF volume {path}: {exc}") from exc
    if arr.ndim == 2:
        arr = arr[None]
    if isinstance(info, VolumeInfo):
        if arr.size != math.prod(info.shape):
            declared = " × ".join(map(str, info.shape))
            raise InputError(
                f"volume {where} holds {arr.size} voxels, not the {declared} its header "
                "declares (changed, truncated or damaged since the series was read?)"
            )
        arr = arr.reshape(info.shape)
    if arr.ndim != 3:
        raise InputError(f"{where}: expected a (z, y, x) volume, got shape {arr.shape}")
    arr = arr.astype(np.float32, copy=False)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{where}: volume holds NaN or infinite voxels")
    return arr


def numbered(folder: str | os.PathLike, index: int, suffix: str) -> Path:
    """``folder/NNNNNN<suffix>``."""
    return Path(folder) / f"{int(index):06d}{suffix}"


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
