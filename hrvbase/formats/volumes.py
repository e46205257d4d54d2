"""Volume series: what every volume reader gives, and what ``recon.json`` records of them.

A volume reader (:mod:`hrvbase.formats.volume_tiff`, :mod:`hrvbase.formats.volume_zarr`,
chosen by :func:`hrvbase.formats.registry.volume_format_for`) lists the volumes of a series as
:class:`VolumeInfo` records, without reading voxels. The records of a series come from the
files and from the ``recon.json`` that ``recon run`` writes next to them (or inside a Zarr
store): the voxel size and origin, the lenslet period and phase (:func:`lenslet_phases`), the
SNR of each camera frame, and each volume's camera frame number and time. Lengths in µm
(docs/conventions.md).

The ``grid`` of a series' ``recon.json`` (next to TIFF volumes, or inside a Zarr store) gives
the lenslet period of the volumes, its super-resolution factor ``s``, and the sub-lenslet
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

Errors are :class:`hrvbase.errors.InputError` (one line naming the file).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from .geometry import VolumeGeometry

log = logging.getLogger(__name__)

#: Pattern of the numbered files of a series (6 digits).
NUMBERED = re.compile(r"^(\d{6})\.(tif|tiff|csv)$")

#: Name of the reconstruction metadata file next to volumes.
RECON_JSON = "recon.json"


@dataclass(frozen=True)
class VolumeInfo(VolumeGeometry):
    """One volume of a series: its geometry and where it is (metadata only; read the voxels
    with :func:`hrvbase.formats.registry.read_volume`).

    Attributes
    ----------
    shape, voxel_size_um, origin_xyz_um
        The volume's geometry (:class:`~hrvbase.formats.geometry.VolumeGeometry`).
    path : Path
        The file, or the OME-Zarr store.
    index : int
        Frame number from the file name ``NNNNNN.tif``.
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
    format : str or None
        The name of the volume format that read it (:mod:`hrvbase.formats.registry`).
    surface_z_um : float or None
        Object ``z`` (µm) of the specimen's near surface, from ``recon.json``'s
        ``surface_z_um`` (``lfsim.optics.Optics.surface_z_um``): the planes in front of it
        (smaller ``z``) are the reconstruction's guard planes, where no particle can lie.
        None when the optics have no specimen interfaces or it is not recorded.
    """

    path: Path
    index: int
    dataset: str | None = None
    lead: tuple = ()
    lenslet_period_vox: int | None = None
    lenslet_phase_vox: tuple = (0, 0)
    snr: float | None = None
    number: int | None = None
    time_s: float | None = None
    format: str | None = None
    surface_z_um: float | None = None

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


def parse_voxel_size(value, where: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: voxel_size_um must be [dz, dy, dx], got {value!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) and v > 0 for v in vals):
        raise InputError(f"{where}: voxel_size_um must be 3 positive numbers, got {value!r}")
    return vals


#: Entries of ``recon.json``'s ``grid`` and of a volume's metadata that the older layout
#: names without their order: the name ``recon`` writes → the older one, read when the
#: first is absent (:func:`record_entry`).
RECORD_ALIASES = {"origin_xy_um": "origin_um", "n_lenslets_xy": "n_lenslets"}


def record_entry(meta: Mapping, key: str):
    """``meta[key]``, else the entry of its older name (:data:`RECORD_ALIASES`), else None."""
    value = meta.get(key)
    if value is None and key in RECORD_ALIASES:
        value = meta.get(RECORD_ALIASES[key])
    return value


def parse_origin(meta: Mapping, vs, where: str) -> tuple[float, float, float] | None:
    """Object-space ``(x, y, z)`` of the centre of voxel ``(0, 0, 0)`` (µm) from metadata.

    ``origin_xyz_um`` (that centre, as ``lfsim.io.write_tiff`` records it) or, in the files
    without it and in ``recon.json``'s ``grid``, the corner ``[x0, y0]`` of lenslet
    ``(0, 0)`` (``origin_xy_um``, :func:`record_entry`) with
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
    o = record_entry(meta, "origin_xy_um")
    d = meta.get("depths_um")
    if o is None and d is None:
        return None
    try:
        ox, oy = (float(v) for v in (o if o is not None else (0.0, 0.0))[:2])
        z0 = float(d[0]) if d else 0.0
    except (TypeError, ValueError, IndexError):
        raise InputError(f"{where}: bad origin_xy_um/depths_um {o!r} / {d!r}") from None
    # recon places voxel column i at origin + (i + 0.5) · dx (geometry.ReconGrid.x_um)
    return (ox + 0.5 * vs[2], oy + 0.5 * vs[1], z0)


def lenslet_phases(
    recon: Mapping, voxel_size_um, origin_xyz_um, where: str
) -> tuple[int | None, tuple[int, int]]:
    """Lenslet period (voxels) and phase of a volume from the ``grid`` of its ``recon.json``.

    ``grid.s`` is the period; ``grid.origin_xy_um`` (the corner of lenslet ``(0, 0)``,
    :func:`record_entry`) and the
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
        corner = [float(v) for v in (record_entry(grid, "origin_xy_um") or (0.0, 0.0))][:2]
    except (TypeError, ValueError):
        raise InputError(
            f"{where}: grid.lenslet_object_um and grid.origin_xy_um must be numbers, got "
            f"{grid.get('lenslet_object_um')!r} and {record_entry(grid, 'origin_xy_um')!r}"
        ) from None
    if not (math.isfinite(pitch) and pitch > 0) or len(corner) != 2:
        raise InputError(
            f"{where}: grid.lenslet_object_um must be > 0 µm and grid.origin_xy_um [x0, y0], "
            f"got {grid.get('lenslet_object_um')!r} and {record_entry(grid, 'origin_xy_um')!r}"
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


def parse_snr(value, where: str) -> float | None:
    """A frame's recorded SNR (None: not recorded, or a noise-free frame)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < math.inf:
        raise InputError(f"{where}: snr must be a finite number > 0 or null, got {value!r}")
    return float(value)


def parse_surface(recon: Mapping, where: str) -> float | None:
    """The specimen's near surface ``recon.json`` records (``surface_z_um``, µm; None:
    none)."""
    value = recon.get("surface_z_um")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{where}: surface_z_um must be a finite number or null, got {value!r}")
    return float(value)


def frame_snrs(recon: Mapping, where: str) -> dict[int, float | None]:
    """The SNR of each frame ``recon.json`` records (``frames[i].preprocess.snr``), by index."""
    out = {}
    for f in recon.get("frames") or []:
        if isinstance(f, Mapping) and isinstance(f.get("index"), int):
            pre = f.get("preprocess")
            if isinstance(pre, Mapping):
                out[f["index"]] = parse_snr(pre.get("snr"), f"{where} frame {f['index']}")
    return out


def parse_frame_number(value, where: str) -> int | None:
    """A recorded camera frame number (None: not recorded)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(
            f"{where}: number (the camera frame number) must be an integer >= 0 or null, "
            f"got {value!r}"
        )
    return value


def parse_frame_time(value, where: str) -> float | None:
    """A recorded frame time in seconds (None: not recorded)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(
            f"{where}: time_s must be a finite number of seconds or null, got {value!r}"
        )
    return float(value)


def frame_records(recon: Mapping, where: str) -> dict[int, tuple[int | None, float | None]]:
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
        out[k] = (parse_frame_number(f.get("number"), w), parse_frame_time(f.get("time_s"), w))
    return out


def check_frames(vols: list[VolumeInfo], where: str) -> list[VolumeInfo]:
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


def numbered(folder: str | os.PathLike, index: int, suffix: str) -> Path:
    """``folder/NNNNNN<suffix>``."""
    return Path(folder) / f"{int(index):06d}{suffix}"


__all__ = [
    "NUMBERED",
    "RECON_JSON",
    "RECORD_ALIASES",
    "VolumeInfo",
    "check_frames",
    "frame_records",
    "frame_snrs",
    "lenslet_phases",
    "numbered",
    "parse_frame_number",
    "parse_frame_time",
    "parse_origin",
    "parse_snr",
    "parse_surface",
    "parse_voxel_size",
    "record_entry",
]
