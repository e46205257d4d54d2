"""Where ``recon run`` puts its volumes: numbered TIFF files or one OME-Zarr image.

:func:`reconstruct_series <recon.pipeline.reconstruct_series>` computes frame ``k`` and hands
it to a writer; the writer alone knows the format. Both writers have the same small
interface:

``prepare(n_frames, geometry, times_s, overwrite, numbers)``
    Once, in the main process, before any frame: creates the output (for Zarr the whole
    array, its shape known from the frame count, its OME-NGFF metadata and the frames'
    numbers and times).
``write(k, volume, meta) -> record``
    Writes frame ``k`` and returns the record that ``recon.json`` keeps for it. Frames are
    independent: each write touches only its own file or chunks, so frames may be written
    concurrently, by other threads or processes (a writer holds only paths and numbers, and
    pickles).
``verify(k, record)``
    Whether frame ``k`` on disk is still what ``record`` describes (a resumed run keeps it).
``indices()``, ``exists(k)``, ``remove(k)``, ``clear()``, ``discard()``, ``label(k)``
    The frames present, removal of one or all of them, and the name of a frame in messages.

**TIFF** (``--format tiff``, the default): ``OUT/NNNNNN.tif``, float32 ``(z, y, x)`` with
the voxel size and origin in its metadata (:func:`hrvbase.formats.tiff_layout.write_tiff`);
the record is the file's size and SHA-256 (:func:`hrvbase.io.file_record`).

**Zarr** (``--format zarr``): ``OUT`` is one OME-Zarr image, written as OME-NGFF **0.4**
on Zarr format 2 (:data:`NGFF_VERSION`), the version that napari-ome-zarr, Fiji's N5 /
OME-Zarr importer (n5-zarr), MoBIE and BigDataViewer open (their Zarr readers do not open
Zarr format 3): a group whose ``.zattrs`` holds ``multiscales`` (one dataset, no pyramid) and
an array ``OUT/0`` (``OUT/0/.zarray``) of float32 ``(t, z, y, x)``, chunked ``(1, chunk_z, ny,
nx)`` — one frame, or one slab of ``chunk_z`` planes of it, per chunk — Blosc-compressed (LZ4,
byte shuffle), with the dimension separator ``/`` so that frame ``k``'s chunks are the files
under ``OUT/0/k/``; missing chunks read as NaN. The dataset's coordinate transformations give
the voxel size (``scale``, in micrometer) and then the object-space position of the centre
of voxel ``(0, 0, 0)`` (``translation``); the t axis is in seconds when the frames have
evenly spaced times (``recon run --fps``), otherwise unitless (frame index). The group's
attribute ``recon`` holds ``frames``: for every ``t``, the frame's original ``number`` and
``time_s`` (both may be null), as ``recon.json`` records them (the t axis cannot hold
unevenly spaced times, e.g. camera frames 0, 1, 5). ``recon.json`` lies inside the store.
Zarr writes each chunk to a temporary file and renames it (atomic per chunk); the record of a
frame is the SHA-256 of its float32 values in C order (:func:`hrvbase.io.array_sha256`), which
:meth:`verify` recomputes from the chunks.

A store holding Zarr format 3 metadata (``OUT/zarr.json``: OME-NGFF 0.5, chunks under
``OUT/0/c/k/``) is continued in that format by a resumed run, so that one store never mixes
the two; a run that replaces its array (``--overwrite`` with another chunking) or all of it
(``--overwrite`` with other settings) writes OME-NGFF 0.4 anew.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hrvbase.errors import OutputError
from hrvbase.formats.geometry import VolumeGeometry

from .errors import InputError, ReconError

log = logging.getLogger(__name__)

#: Output formats of ``recon run --format``; the first is the default.
FORMATS = ("tiff", "zarr")

#: OME-NGFF version of the Zarr output (on Zarr format 2): the version napari-ome-zarr and
#: Fiji's readers (n5-zarr, MoBIE, BigDataViewer) open.
NGFF_VERSION = "0.4"

#: OME-NGFF version of a store in Zarr format 3 (``zarr.json``), which a resumed run continues.
NGFF_VERSION_V3 = "0.5"

#: Compressor of the Zarr format 2 chunks (numcodecs' Blosc codec configuration): Blosc with
#: LZ4 and byte shuffle, which the Zarr readers of Python and of Fiji (n5-zarr) decode.
ZARR_COMPRESSOR = {"id": "blosc", "cname": "lz4", "clevel": 5, "shuffle": 1, "blocksize": 0}

#: Path of the full-resolution array inside the Zarr group.
ZARR_DATASET = "0"


class OutputExistsError(ReconError):
    """The output holds something this run must not overwrite."""


def make_writer(volume_format: str, out: str | os.PathLike, *, zarr_chunk_z: int | None = None):
    """The writer of ``volume_format`` (one of :data:`FORMATS`) for the output ``out``.

    Raises
    ------
    InputError
        Unknown format, or a Zarr chunk size for another format or below 1.
    """
    if volume_format not in FORMATS:
        raise InputError(f"--format must be one of {', '.join(FORMATS)}, got {volume_format!r}")
    if volume_format == "tiff":
        if zarr_chunk_z is not None:
            raise InputError("--zarr-chunk-z applies only to --format zarr")
        return TiffSeriesWriter(Path(out))
    if zarr_chunk_z is not None and (
        isinstance(zarr_chunk_z, bool) or not isinstance(zarr_chunk_z, int) or zarr_chunk_z < 1
    ):
        raise InputError(f"--zarr-chunk-z must be an integer >= 1, got {zarr_chunk_z!r}")
    return ZarrSeriesWriter(Path(out), zarr_chunk_z)


def _os_text(exc: OSError) -> str:
    """An operating-system error as ``[Errno 27] File too large`` (and its file, if known)."""
    text = f"[Errno {exc.errno}] {exc.strerror}" if exc.errno and exc.strerror else str(exc)
    return text + (f": {exc.filename}" if exc.filename else "")


# -- TIFF ------------------------------------------------------------------------------------
@dataclass
class TiffSeriesWriter:
    """Numbered TIFF volumes ``out/NNNNNN.tif`` (see the module docstring)."""

    out: Path
    geometry: VolumeGeometry | None = None
    format: str = "tiff"

    def path(self, k: int) -> Path:
        return self.out / f"{k:06d}.tif"

    def label(self, k: int) -> str:
        return self.path(k).name

    def prepare(
        self, n_frames: int, geometry: VolumeGeometry, times_s=None, overwrite=False, numbers=None
    ):
        """Make the folder (each volume records its frame's number and time itself)."""
        self.geometry = geometry
        self.out.mkdir(parents=True, exist_ok=True)

    def write(self, k: int, volume: np.ndarray, meta: Mapping) -> dict:
        from hrvbase.formats.tiff_layout import write_tiff
        from hrvbase.io import file_record

        g = self.geometry
        write_tiff(
            self.path(k),
            np.asarray(volume, dtype=np.float32),
            metadata=dict(meta),
            pixel_size_um=g.voxel_size_um,
            origin_xyz_um=g.origin_xyz_um,
            overwrite=True,
        )
        return file_record(self.path(k))

    def verify(self, k: int, record: Mapping | None) -> bool:
        from hrvbase.io import verify_record

        return verify_record(self.path(k), record)

    def exists(self, k: int) -> bool:
        return self.path(k).is_file()

    def indices(self) -> list[int]:
        pattern = "[0-9][0-9][0-9][0-9][0-9][0-9].tif"
        return sorted(int(p.name[:6]) for p in self.out.glob(pattern))

    def remove(self, k: int) -> None:
        self.path(k).unlink(missing_ok=True)

    def clear(self) -> None:
        for k in self.indices():
            self.remove(k)

    def discard(self) -> None:
        """Nothing to undo before the first volume."""

    def record_extra(self) -> dict:
        return {}


# -- Zarr ------------------------------------------------------------------------------------
def _time_axis(times_s: Sequence | None) -> tuple[float, float, str | None]:
    """``(scale, translation, unit)`` of the t axis: seconds when the frame times are known and
    evenly spaced (at least two frames), else the frame index (unitless)."""
    t = None if times_s is None else list(times_s)
    if t and len(t) >= 2 and all(v is not None and math.isfinite(v) for v in t):
        d = np.diff(np.asarray(t, dtype=float))
        if d[0] > 0 and np.allclose(d, d[0], rtol=1e-6, atol=0):
            return float(d[0]), float(t[0]), "second"
    return 1.0, 0.0, None


@dataclass
class ZarrSeriesWriter:
    """One OME-Zarr image ``out`` of axes ``(t, z, y, x)`` (see the module docstring).

    Parameters
    ----------
    out : Path
        The store (a folder, conventionally ``NAME.zarr``).
    chunk_z : int, optional
        Planes per chunk (default: the whole frame, one chunk per frame).
    """

    out: Path
    chunk_z: int | None = None
    format: str = "zarr"

    def zarr_format(self) -> int:
        """The Zarr format of the store: 3 where it holds Zarr format 3 metadata
        (``zarr.json``), which is continued; otherwise 2 (what a new store is written in)."""
        return 3 if (self.out / "zarr.json").is_file() else 2

    def _chunk_root(self) -> Path:
        """The folder of the frames' chunk folders: ``out/0`` (format 2, dimension separator
        "/"), or ``out/0/c`` (format 3, chunk key encoding "default" with "/")."""
        base = self.out / ZARR_DATASET
        return base / "c" if self.zarr_format() == 3 else base

    def _frame_dir(self, k: int) -> Path:
        return self._chunk_root() / str(k)

    def label(self, k: int) -> str:
        return f"{self.out.name}[t={k}]"

    def _array(self, mode: str = "r+"):
        import zarr

        return zarr.open_array(
            store=str(self.out), path=ZARR_DATASET, mode=mode, zarr_format=self.zarr_format()
        )

    def chunks(self, shape: Sequence[int]) -> tuple[int, int, int, int]:
        nz, ny, nx = (int(v) for v in shape)
        cz = nz if self.chunk_z is None else min(self.chunk_z, nz)
        return (1, cz, ny, nx)

    def prepare(
        self, n_frames: int, geometry: VolumeGeometry, times_s=None, overwrite=False, numbers=None
    ):
        """Create (or, resuming, resize) the ``(n_frames, nz, ny, nx)`` array and write the
        OME-NGFF metadata and the frames' numbers and times (``numbers``, ``times_s``: one per
        frame, or None) in the group's ``recon`` attribute.

        Raises
        ------
        OutputExistsError
            The store holds an array of another voxel shape, type or chunking (without
            ``overwrite``, which replaces it).
        OutputError
            An operating-system error (no space, a file-size limit, no permission): one line
            naming the store.
        """
        try:
            self._prepare(n_frames, geometry, times_s, overwrite, numbers)
        except OSError as exc:
            raise OutputError(
                f"cannot create the OME-Zarr image {str(self.out)!r}: {_os_text(exc)}"
            ) from exc

    def _existing_array(self, shape, chunks, overwrite):
        """The store's array if it fits ``shape`` and ``chunks`` (resized to the frame count),
        or None where there is none or ``overwrite`` cleared the store of another one."""
        import zarr

        fmt = self.zarr_format()
        if not (self.out / ZARR_DATASET).exists():
            return None
        group = zarr.open_group(store=str(self.out), mode="r+", zarr_format=fmt)
        arr = group.get(ZARR_DATASET)
        same = (
            isinstance(arr, zarr.Array)
            and arr.ndim == 4
            and tuple(arr.shape[1:]) == shape[1:]
            and arr.dtype == np.float32
            and tuple(arr.chunks) == chunks
        )
        if not same:
            if not overwrite:
                had = list(getattr(arr, "chunks", []))
                raise OutputExistsError(
                    f"output {str(self.out)!r} holds a Zarr array {ZARR_DATASET!r} of "
                    f"another shape, type or chunking (chunks {had}, this run "
                    f"{list(chunks)}); use a new output or --overwrite (nothing was written)"
                )
            log.info("%s: replacing the array of another chunking", self.out)
            self.clear()  # the whole image is written anew, in format 2
            return None
        if arr.shape[0] != shape[0]:
            arr.resize(shape)
        return arr

    def _prepare(self, n_frames, geometry, times_s, overwrite, numbers) -> None:
        import zarr
        from ome_zarr.format import FormatV04, FormatV05

        shape = (int(n_frames), *(int(v) for v in geometry.shape))
        chunks = self.chunks(geometry.shape)
        self.out.mkdir(parents=True, exist_ok=True)
        arr = self._existing_array(shape, chunks, overwrite)
        fmt = self.zarr_format()
        group = zarr.open_group(store=str(self.out), mode="a", zarr_format=fmt)
        if arr is None:
            if fmt == 3:
                layout = {
                    "chunk_key_encoding": {"name": "default", "separator": "/"},
                    "dimension_names": ("t", "z", "y", "x"),
                }
            else:
                layout = {
                    "chunk_key_encoding": {"name": "v2", "separator": "/"},
                    "compressors": dict(ZARR_COMPRESSOR),
                }
            group.create_array(
                ZARR_DATASET,
                shape=shape,
                chunks=chunks,
                dtype="float32",
                fill_value=float("nan"),
                **layout,
            )
        self._write_metadata(group, FormatV05() if fmt == 3 else FormatV04(), geometry, times_s)
        times = [None] * n_frames if times_s is None else list(times_s)
        nums = [None] * n_frames if numbers is None else list(numbers)
        group.attrs["recon"] = {
            "frames": [
                {
                    "t": k,
                    "number": None if n is None else int(n),
                    "time_s": None if t is None or not math.isfinite(t) else float(t),
                }
                for k, (n, t) in enumerate(zip(nums, times, strict=True))
            ]
        }

    def _write_metadata(self, group, fmt, geometry: VolumeGeometry, times_s) -> None:
        """The ``multiscales`` metadata of OME-NGFF format ``fmt`` (ome-zarr's): axes t, z,
        y, x with their units, and the dataset's scale and translation."""
        from ome_zarr.writer import write_multiscales_metadata

        dt, t0, t_unit = _time_axis(times_s)
        axes = [
            {"name": "t", "type": "time", **({"unit": t_unit} if t_unit else {})},
            *({"name": a, "type": "space", "unit": "micrometer"} for a in "zyx"),
        ]
        x0, y0, z0 = (float(v) for v in geometry.origin_xyz_um)
        write_multiscales_metadata(
            group,
            datasets=[
                {
                    "path": ZARR_DATASET,
                    "coordinateTransformations": [
                        {"type": "scale", "scale": [dt, *map(float, geometry.voxel_size_um)]},
                        {"type": "translation", "translation": [t0, z0, y0, x0]},
                    ],
                }
            ],
            fmt=fmt,
            axes=axes,
            name=self.out.stem,
        )

    def write(self, k: int, volume: np.ndarray, meta: Mapping) -> dict:
        """Write frame ``k`` (its chunks only); its record ``{"t", "sha256", "dtype"}``.

        Raises
        ------
        OutputError
            An operating-system error (no space, a file-size limit): one line naming the store
            and the frame's chunk folder.
        """
        from hrvbase.io import array_sha256

        vol = np.ascontiguousarray(volume, dtype=np.float32)
        try:
            arr = self._array("r+")
            if vol.shape != tuple(arr.shape[1:]):
                raise InputError(
                    f"{self.label(k)}: volume is {vol.shape}, the array holds "
                    f"{tuple(arr.shape[1:])}"
                )
            self.remove(k)  # a damaged frame's chunks, and temporary files an interrupt left
            arr[k] = vol
        except OSError as exc:
            raise OutputError(
                f"cannot write frame t={k} to the OME-Zarr image {str(self.out)!r} (its chunks "
                f"{str(self._frame_dir(k))!r}): {_os_text(exc)}"
            ) from exc
        return {"t": int(k), "sha256": array_sha256(vol), "dtype": "<f4", "order": "C"}

    def read(self, k: int) -> np.ndarray:
        return np.asarray(self._array("r")[k])

    def verify(self, k: int, record: Mapping | None) -> bool:
        from hrvbase.io import array_sha256

        if not record or record.get("t") != k or "sha256" not in record:
            return False
        if not self._frame_dir(k).is_dir():
            return False
        try:
            return array_sha256(self.read(k)) == record["sha256"]
        except Exception:  # a corrupt chunk fails to decode (assorted types): redo the frame
            log.debug("%s: cannot read frame %d", self.out, k, exc_info=True)
            return False

    def exists(self, k: int) -> bool:
        return self._frame_dir(k).is_dir()

    def indices(self) -> list[int]:
        base = self._chunk_root()
        if not base.is_dir():
            return []
        return sorted(int(p.name) for p in base.iterdir() if p.name.isdigit() and p.is_dir())

    def remove(self, k: int) -> None:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(self._frame_dir(k))

    def clear(self) -> None:
        """Remove the array and the group metadata of either Zarr format (only this tool's
        files)."""
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(self.out / ZARR_DATASET)
        for name in ("zarr.json", ".zgroup", ".zattrs"):
            (self.out / name).unlink(missing_ok=True)

    def discard(self) -> None:
        """Before the first volume: remove what :meth:`prepare` made."""
        self.clear()

    def record_extra(self) -> dict:
        return {
            "zarr": {
                "ngff_version": NGFF_VERSION_V3 if self.zarr_format() == 3 else NGFF_VERSION,
                "dataset": ZARR_DATASET,
                "axes": ["t", "z", "y", "x"],
                "chunk_z": self.chunk_z,
            }
        }


__all__ = [
    "FORMATS",
    "NGFF_VERSION",
    "NGFF_VERSION_V3",
    "OutputExistsError",
    "TiffSeriesWriter",
    "VolumeGeometry",
    "ZarrSeriesWriter",
    "make_writer",
]
