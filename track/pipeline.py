"""The ``track`` pipeline as a library: detect → link → fields, into a results folder.

:func:`track_volumes` detects the particles of a series of volumes and, given
:class:`~track.series.SeriesSettings`, links them and grids the displacement and strain
fields; :func:`track_clouds` links point clouds from any localisation source. Both write the
results folder that ``track run | detect | link`` writes (the command line is a thin layer
over them, :mod:`track.cli`) and return a :class:`TrackResult` with the same data in memory.

Results folder ``out_dir`` (``NNNNNN``: the frame number, the camera frame a volume was
reconstructed from when ``recon run`` recorded it, :attr:`track.volumes.VolumeInfo.frame`)::

    particles/NNNNNN.csv      x_um, y_um, z_um, intensity, sigma_{x,y,z}_um of each frame's
                              particles (standard uncertainties, µm)
    matches_NNNNNN.csv        one per linked pair (NNNNNN = deformed frame), with the
                              displacements' uncertainties sigma_d{x,y,z}_um and, when the
                              frame times are known, the velocities v{x,y,z}_um_per_s
    tracks.csv                frame, track_id, x_um, y_um, z_um, sigma_{x,y,z}_um (, time_s)
    fields/NNNNNN.npz, .vti   total field from frame 0 to frame NNNNNN (reference grid),
                              with its frame number and time
    fields/increment_NNNNNN.npz   incremental mode: the increment's field
    summary.json              parameters, input checksums, each frame's number and time,
                              counts, tracking ratio, frames spanned, time step and status
                              of every pair, the zero-displacement noise floor
                              (``SeriesSettings.static_frames``), failures, timings

Every file is written atomically. The volumes may be detected on Dask workers (``parallel``,
:mod:`hrvbase.parallel`); linking runs in this process and starts on the first frames while
the others are still being detected; the increments' fields are then fitted and gridded on
the same kind of workers (:func:`track.series.track_series`); the results are the same.
Resuming: the SHA-256 of each volume is recorded and the detection of volumes whose particle
table exists with the same checksum is skipped; linking and fields are recomputed, written
into the hidden folder ``.track-linking`` and moved into place once all are written, so that
an earlier run's matches, tracks and fields stay until the new ones are ready (and the
volumes to detect again are read before anything is replaced: a damaged one leaves the
folder as it was). A folder made from other inputs or detection settings is refused unless
``overwrite`` (which then deletes only files ``track`` writes); a non-empty folder without a
``summary.json`` written by ``track`` is always refused.

Failures: a pair that cannot be linked (fewer than ``min_particles`` particles, no
consistent matches), a field that cannot be gridded or (detection only) a volume without
particles is a *failure*. Everything that worked is written and ``summary.json`` lists the
failures; its status is ``"failed"`` and :class:`~track.errors.FailedFramesError` is raised
(carrying the :class:`TrackResult`), or, with ``allow_partial=True``, ``"partial"`` with a
warning per failure. An explicit grid spacing that gives more than
``min(10 × target_nodes, 2 000 000)`` nodes, or a single cell, is refused
(:func:`track.series.check_grid`) before any work when the box is known (the volume's, or
frame 0's particles).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import sha256_file, write_json

from . import results
from .detections import _detect, _Detections, _known_sigmas, frame_times, volume_extent_um
from .detections import _first_psf as _first_psf  # re-exported (benchmarks/bench_detect.py)
from .errors import InputError
from .link_outputs import _link_and_write
from .results import *  # noqa: F403  (re-exported: the results of a run)
from .results import (
    STAGING,
    SUMMARY,
    FrameDetections,
    TrackResult,
    _fingerprint,
    _finish,
    _new_summary,
    _open_results,
    _settings_dict,
)
from .series_settings import OK, SeriesSettings, check_grid
from .tables import read_point_sigmas, read_points_csv, write_points_csv
from .volumes import VolumeInfo, numbered, scan_volumes, volume_checksum

log = logging.getLogger(__name__)


#: Encodings of the ``.vti`` field files.
VTI_ENCODINGS = ("binary", "ascii")


def _series(series: SeriesSettings | None) -> SeriesSettings:
    """``series`` (default ``SeriesSettings()``) with explicit :class:`LinkSettings`."""
    from .matching import LinkSettings

    series = SeriesSettings() if series is None else series
    if not isinstance(series, SeriesSettings):
        raise InputError(f"series must be a SeriesSettings, got {type(series).__name__}")
    if series.link is None:
        series = dataclasses.replace(series, link=LinkSettings())
    return series


def _check_vti(vti_encoding: str) -> None:
    if vti_encoding not in VTI_ENCODINGS:
        raise InputError(f"vti_encoding must be one of {VTI_ENCODINGS}, got {vti_encoding!r}")


def track_volumes(
    volumes: str | os.PathLike | Sequence[VolumeInfo],
    out_dir: str | os.PathLike,
    *,
    detect=None,
    series: SeriesSettings | None = None,
    overwrite: bool = False,
    allow_partial: bool = False,
    progress: bool = False,
    vti_encoding: str = "binary",
    provenance: Mapping[str, Any] | None = None,
    parallel=None,
    linker: Callable[..., Any] | None = None,
) -> TrackResult:
    """Detect the particles of a series of volumes and, with ``series``, link and grid them.

    Parameters
    ----------
    volumes : path or sequence of VolumeInfo
        Folder of numbered float volumes ``NNNNNN.tif`` or an OME-Zarr image (see
        :func:`track.volumes.scan_volumes`), or its scanned volumes.
    out_dir : path
        Results folder (module docstring); created.
    detect : DetectSettings, optional
        Detection settings (default ``DetectSettings()``); the PSF of the first volume
        serves the whole series.
    series : SeriesSettings, optional
        Linking and gridding; None: detection only (``track detect``).
    overwrite : bool
        Replace a results folder made by ``track`` from other inputs or detection settings.
    allow_partial : bool
        Failed frames are warnings (status ``"partial"``) instead of an error.
    progress : bool
        Progress bars on stderr (on a terminal).
    vti_encoding : {"binary", "ascii"}
    provenance : mapping, optional
        Extra entries of ``summary.json`` (e.g. ``{"argv": [...]}``).
    parallel : hrvbase.parallel.Parallel, optional
        Where the volumes are detected (default: in this process, one after the other);
        linking runs here, on the first frames while the others are still being detected.
        The results are the same however they run.
    linker : callable, optional
        Extension point: the function that links one pair of frames,
        ``linker(ref_xyz, def_xyz, link_settings, initial_guess=None) -> result`` (positions
        (N, 3) in µm, x, y, z; ``link_settings`` is ``series.link``); the result has
        ``.matches`` (M, 2) int, ``.displacement_um`` (M, 3), ``.tracking_ratio``,
        ``.iterations`` and optionally ``.ok``, ``.reason``, ``.displacement_field``
        (:func:`track.series.link_pairs`). Default :func:`track.matching.link_pair`. A new
        linker is this one function; the tracks, fields and output files follow from its
        matches.

    Returns
    -------
    TrackResult
        ``command`` is ``"run"`` with ``series``, ``"detect"`` without.

    Raises
    ------
    InputError
        Bad volumes, settings, results folder or grid spacing (nothing was written, except
        for a grid spacing refused after detection on frame 0's particles).
    FailedFramesError
        Frames failed and ``allow_partial`` is False; the results are written and the
        exception carries the :class:`TrackResult`.
    """
    t0 = time.perf_counter()
    settings = _detect(detect)
    series = None if series is None else _series(series)
    _check_vti(vti_encoding)
    vols, where = _scan(volumes)
    if series is not None and series.compute_fields:
        check_grid(volume_extent_um(vols[0]), series.grid, where="the volume")
    params = _volume_parameters(vols, settings)
    fp = _fingerprint({**where, **params})
    # every volume read once before out_dir is touched: a damaged file is refused here
    checksums = [volume_checksum(v) for v in vols]
    out = Path(out_dir)
    prev = _open_results(out, fp, overwrite)
    command = "detect" if series is None else "run"
    summary = _new_summary(command, fp, params, provenance)
    out.mkdir(parents=True, exist_ok=True)
    from hrvbase.parallel import shared_cluster

    # one local cluster for the detection and the increments' fields (not one each)
    with shared_cluster(parallel) as parallel:
        detections = _Detections(vols, checksums, settings, out, summary, prev, progress, parallel)
        if series is None:
            return _finish(out, summary, t0, allow_partial, command, detections.finish())
        common = settings.sigma_systematic_um[::-1]  # shared by a particle's images: cancels
        try:  # linking starts on the first frames while the others are being detected
            ids = [v.frame for v in vols]
            pairs, tracks, grid = _link_and_write(
                series,
                out,
                summary,
                detections,
                ids,
                vti_encoding,
                progress,
                times_s=frame_times(vols),
                sigmas=detections.sigmas,
                common_sigma_xyz_um=common,
                parallel=parallel,
                after_linking=detections.release,
                linker=linker,
            )
        finally:
            detections.close()
        frames = detections.finish()
    return _finish(out, summary, t0, allow_partial, command, frames, pairs, tracks, grid)


def _scan(volumes) -> tuple[list[VolumeInfo], dict]:
    """The volumes of :func:`track_volumes` (scanned and validated before the results folder
    is touched) and where they come from (for the fingerprint)."""
    if isinstance(volumes, str | os.PathLike):
        voldir = Path(volumes)
        vols = scan_volumes(voldir)
        return vols, {"voldir": str(voldir.resolve())}
    vols = list(volumes)
    if not vols or not all(isinstance(v, VolumeInfo) for v in vols):
        raise InputError("volumes must be a folder or a non-empty list of VolumeInfo")
    return vols, {"volumes": [v.source(resolve=True) for v in vols]}


def _volume_parameters(vols: Sequence[VolumeInfo], settings) -> dict:
    """The detection's inputs recorded in ``summary.json`` (and fingerprinted): its settings,
    the frame numbers, lenslet periods, camera SNRs and specimen surface of the volumes."""
    params = {"detect": _settings_dict(settings)}
    if any(v.frame != v.index for v in vols):  # the particle tables' names
        params["frame_numbers"] = [v.frame for v in vols]
    periods = sorted({v.lenslet_period_vox for v in vols if v.lenslet_period_vox is not None})
    if periods:  # an input of the detector (recon.json): a folder detected without it is redone
        params["lenslet_period_vox"] = periods
    surfaces = sorted({v.surface_z_um for v in vols if v.surface_z_um is not None})
    if surfaces:  # detections in front of it are rejected
        params["surface_z_um"] = surfaces
    if any(settings.sigma_snr_um):  # the frames' SNR sets their σ
        unknown = [v for v in vols if v.snr is None]
        if unknown:
            raise InputError(
                f"sigma_snr_um is set but {unknown[0].source()} has no camera SNR (recon run "
                f"records it in recon.json; {len(unknown)} of {len(vols)} volumes lack it); "
                "set sigma_snr_um to 0 for volumes from elsewhere"
            )
        params["frame_snr"] = [v.snr for v in vols]
    return params


def track_clouds(
    clouds: Sequence[str | os.PathLike | np.ndarray],
    out_dir: str | os.PathLike,
    *,
    series: SeriesSettings | None = None,
    overwrite: bool = False,
    allow_partial: bool = False,
    progress: bool = False,
    vti_encoding: str = "binary",
    provenance: Mapping[str, Any] | None = None,
    parallel=None,
    common_sigma_xyz_um=None,
) -> TrackResult:
    """Link point clouds (frame 0 first) and grid their displacement and strain fields.

    Parameters
    ----------
    clouds : sequence of (path or ndarray, shape (N_i, 3))
        CSV tables with columns ``x_um, y_um, z_um`` (:func:`track.tables.read_points_csv`) or
        arrays of positions (µm, x, y, z); at least 2.
    out_dir : path
        Results folder (module docstring); created.
    series : SeriesSettings, optional
        Default ``SeriesSettings()``.
    overwrite, allow_partial, progress, vti_encoding, provenance
        As in :func:`track_volumes`.
    parallel : hrvbase.parallel.Parallel, optional
        Fit and grid the increments on Dask workers (same results); default: in this process.
    common_sigma_xyz_um : sequence of 3 float, optional
        The part of the tables' σ that a particle's images share (µm; x, y, z), which cancels
        in its displacements: ``DetectSettings.sigma_systematic_um`` reversed for tables that
        ``track`` detected (as :func:`track_volumes` uses); default none.

    Returns
    -------
    TrackResult
        ``command == "link"``; frame numbers are the positions in ``clouds``.

    Raises
    ------
    InputError
        Fewer than 2 clouds, a bad table or array (the message names it), bad settings,
        results folder or grid spacing (nothing was written).
    FailedFramesError
        Pairs failed and ``allow_partial`` is False (results written, see
        :func:`track_volumes`).
    """
    t0 = time.perf_counter()
    if len(clouds) < 2:
        raise InputError(f"link needs at least 2 point clouds, got {len(clouds)}")
    series = _series(series)
    _check_vti(vti_encoding)
    points, sources, checks, names, sigmas = [], [], [], [], []
    for i, c in enumerate(clouds):
        if isinstance(c, str | os.PathLike):
            points.append(read_points_csv(c))
            sigmas.append(_known_sigmas(read_point_sigmas(c)))
            checks.append(sha256_file(c))
            sources.append(str(Path(c).resolve()))
            names.append(str(c))
        else:
            a = np.asarray(c, dtype=float)
            if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
                raise InputError(
                    f"point cloud {i} must be a finite (N, 3) array (x, y, z µm), got "
                    f"shape {a.shape}"
                )
            points.append(np.ascontiguousarray(a))
            sigmas.append(None)
            checks.append(hashlib.sha256(points[-1].tobytes()).hexdigest())
            sources.append(f"array {i}")
            names.append(f"array {i}")
    if series.compute_fields and points[0].shape[0] >= 2:
        check_grid(np.ptp(points[0], axis=0), series.grid, where="frame 0's particles")
    fp = _fingerprint({"sources": sources, "sha256": checks})
    out = Path(out_dir)
    _open_results(out, fp, overwrite)
    summary = _new_summary("link", fp, {}, provenance)
    summary["inputs"] = [{"path": p, "sha256": s} for p, s in zip(names, checks, strict=True)]
    out.mkdir(parents=True, exist_ok=True)
    entries, frames = [], []
    for i, (name, c, sg) in enumerate(zip(names, points, sigmas, strict=True)):
        part = numbered(out / "particles", i, ".csv")
        write_points_csv(part, c, sigma_xyz_um=sg, overwrite=True)
        entries.append(
            {
                "index": i,
                "frame": i,
                "input": name,
                "particles": str(part.relative_to(out)),
                "n_particles": int(c.shape[0]),
            }
        )
        frames.append(FrameDetections(i, name, c, part, sigma_xyz_um=sg))
    summary["frames"] = entries
    summary["frame_ids"] = list(range(len(points)))
    summary["frame_times_s"] = None
    write_json(out / SUMMARY, summary, overwrite=True)
    pairs, tracks, grid = _link_and_write(
        series,
        out,
        summary,
        points,
        list(range(len(points))),
        vti_encoding,
        progress,
        sigmas=sigmas if any(sg is not None for sg in sigmas) else None,
        common_sigma_xyz_um=common_sigma_xyz_um,
        parallel=parallel,
    )
    return _finish(out, summary, t0, allow_partial, "link", frames, pairs, tracks, grid)


__all__ = [
    *results.__all__,
    "OK",
    "STAGING",
    "VTI_ENCODINGS",
    "track_clouds",
    "track_volumes",
    "volume_extent_um",
]
