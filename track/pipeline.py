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
import json
import logging
import math
import os
import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import HrvError
from hrvbase.io import (
    ConcurrentWrites,
    file_record,
    read_json,
    sha256_file,
    verify_record,
    write_json,
)

from .errors import FailedFramesError, InputError, TrackingError
from .field_files import write_field_npz, write_field_vti
from .fields import GridAxes, GridField
from .series import OK, SeriesSettings, Tracks, check_grid, link_pairs, noise_floor, track_series
from .tables import (
    read_point_sigmas,
    read_points_csv,
    write_matches_csv,
    write_points_csv,
    write_tracks_csv,
)
from .volumes import VolumeInfo, numbered, read_volume, scan_volumes, volume_checksum

log = logging.getLogger(__name__)

#: The record of a results folder.
SUMMARY = "summary.json"
#: Encodings of the ``.vti`` field files.
VTI_ENCODINGS = ("binary", "ascii")


# -- results ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameDetections:
    """The particles of one frame.

    Attributes
    ----------
    index : int
        Frame number: the camera frame a volume was reconstructed from when recorded
        (:attr:`track.volumes.VolumeInfo.frame`), else ``NNNNNN`` of the volume file; the
        position of a point cloud.
    source : str
        The input (volume or CSV path; ``"array <i>"`` for an array).
    positions_um : ndarray, shape (N, 3)
        Particle centres, columns x, y, z (µm).
    particles : Path
        Their table in the results folder (``particles/NNNNNN.csv``).
    reused : bool
        Detection skipped: the volume's checksum and table were found (resume).
    report : dict
        Detection report (counts per stage, threshold, ...; see
        :attr:`track.detect.Detection.report`); empty when reused or for point clouds.
    sigma_um : ndarray, shape (N, 3), or None
        Standard uncertainty of each centre (µm, x, y, z); NaN where unknown (tables written
        without uncertainties), None for point clouds given without them.
    time_s : float or None
        Time of the frame (s) when recorded.
    """

    index: int
    source: str
    positions_um: np.ndarray
    particles: Path
    reused: bool = False
    report: dict = field(default_factory=dict)
    sigma_um: np.ndarray | None = None
    time_s: float | None = None

    @property
    def n(self) -> int:
        """Number of particles."""
        return int(self.positions_um.shape[0])


@dataclass(frozen=True)
class PairOutcome:
    """One linked pair of a series and its field.

    Attributes
    ----------
    ref_frame, def_frame : int
        Frame numbers (reference, deformed).
    status : str
        ``"ok"`` or ``"skipped: <reason>"`` (linking).
    field_status : str
        ``"ok"``, ``"skipped: fields not requested"`` or ``"skipped: <reason>"``.
    matches : ndarray of int, shape (K, 2)
        Rows ``[row_ref, row_def]`` into the two frames' particle tables.
    displacement_um : ndarray, shape (K, 3)
        Displacement of each matched particle (µm, x, y, z).
    sigma_displacement_um : ndarray, shape (K, 3), or None
        Its standard uncertainty (µm, x, y, z); None when the particles came without.
    tracking_ratio : float
        Fraction of reference particles matched (NaN when not linked).
    field : GridField or None
        Total field from frame 0 to ``def_frame`` on the reference grid.
    increment_field : GridField or None
        Incremental mode: the field of this increment.
    smoothing_xyz : (float, float, float) or None
        RBF smoothing λ used for ``u_x, u_y, u_z``.
    failure : str
        Why the pair counts as failed (empty when it does not).
    """

    ref_frame: int
    def_frame: int
    status: str
    field_status: str
    matches: np.ndarray
    displacement_um: np.ndarray
    tracking_ratio: float = math.nan
    field: GridField | None = None
    increment_field: GridField | None = None
    smoothing_xyz: tuple[float, float, float] | None = None
    failure: str = ""
    sigma_displacement_um: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether the pair was linked (and, when requested, its field gridded)."""
        return not self.failure


@dataclass(frozen=True)
class TrackResult:
    """What :func:`track_volumes` or :func:`track_clouds` did (the results folder in memory).

    Attributes
    ----------
    out_dir : Path
    command : {"run", "detect", "link"}
        The command line this corresponds to (recorded in ``summary.json``).
    frames : tuple of FrameDetections
    pairs : tuple of PairOutcome
        One per frame ``i ≥ 1``; empty for detection only.
    tracks : Tracks or None
        Trajectories, :attr:`Tracks.frame` holding frame numbers; None for detection only.
    grid : GridAxes or None
        Reference grid of the fields.
    summary : dict
        The content of ``summary.json``.
    failures : tuple of str
        One message per failed frame or pair (empty: everything worked).
    """

    out_dir: Path
    command: str
    frames: tuple[FrameDetections, ...]
    pairs: tuple[PairOutcome, ...] = ()
    tracks: Tracks | None = None
    grid: GridAxes | None = None
    summary: dict = field(default_factory=dict)
    failures: tuple[str, ...] = ()

    @property
    def status(self) -> str:
        """``"complete"``, ``"partial"`` (failures allowed) or ``"failed"``."""
        return self.summary.get("status", "incomplete")

    @property
    def timings(self) -> dict:
        """Seconds per stage (``detect_s``, ``link_s``, ``fields_s``, ``write_s``,
        ``total_s``)."""
        return self.summary.get("timings", {})

    def results_line(self) -> str:
        """One line such as ``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs linked,
        tracking ratio ≥ 0.96, 6 fields, 12.3 s``."""
        return results_line(self.summary)


# -- results folder --------------------------------------------------------------------------
def _fingerprint(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


#: Hidden folder of a results folder where linking writes its outputs until all are ready.
STAGING = ".track-linking"


def _our_outputs(out: Path) -> list[Path]:
    """Files and folders ``track`` writes in a results folder."""
    items = [out / "particles", out / "fields", out / "tracks.csv", out / SUMMARY]
    items.append(out / STAGING)
    items += sorted(out.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv"))
    return [p for p in items if p.exists()]


def _open_results(out: Path, fingerprint: str, overwrite: bool) -> dict | None:
    """Check the results folder; return the previous summary to resume from, if any."""
    if out.exists() and not out.is_dir():
        raise InputError(f"results folder {out} is a file")
    if not out.exists() or not any(out.iterdir()):
        return None
    summary = out / SUMMARY
    prev = None
    if summary.is_file():
        try:
            prev = read_json(summary)
        except HrvError:
            prev = None
    if not isinstance(prev, dict) or prev.get("tool") != "track":
        raise InputError(
            f"results folder {out} is not empty and holds no {SUMMARY} written by track; "
            "choose a new folder (nothing was written)"
        )
    if prev.get("fingerprint") == fingerprint:
        return prev
    if not overwrite:
        raise InputError(
            f"results folder {out} holds results made from other inputs or settings; "
            "use a new folder or --overwrite (nothing was written)"
        )
    for p in _our_outputs(out):
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()
    log.info("%s: previous results removed (overwrite)", out)
    return None


def _new_staging(out: Path) -> Path:
    """An empty :data:`STAGING` folder (what an interrupted run left there is removed)."""
    stage = out / STAGING
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir()
    return stage


def _publish_derived(stage: Path, out: Path) -> None:
    """Move the linking outputs written in ``stage`` into ``out``, replacing those of an
    earlier run; its files the new run did not write (a pair no longer in the series, fields
    no longer requested) are removed only then."""
    new = {p.name for p in stage.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv")}
    for name in [*sorted(new), "tracks.csv"]:
        if (stage / name).exists():
            os.replace(stage / name, out / name)
    for p in sorted(out.glob("matches_[0-9][0-9][0-9][0-9][0-9][0-9].csv")):
        if p.name not in new:
            p.unlink()
    if (out / "fields").is_dir():
        os.replace(out / "fields", stage / "fields.old")
    if (stage / "fields").is_dir():
        os.replace(stage / "fields", out / "fields")
    shutil.rmtree(stage)


def _new_summary(command: str, fingerprint: str, parameters: dict, provenance) -> dict:
    from . import __version__

    summary = {
        "tool": "track",
        "version": __version__,
        "command": command,
        "argv": [],
        "fingerprint": fingerprint,
        "status": "incomplete",
        "parameters": parameters,
        "timings": {},
    }
    summary.update(dict(provenance or {}))
    return summary


def _bar(total: int, progress: bool, desc: str, unit: str):
    """tqdm bar on stderr (shown on a terminal when ``progress``), advanced by ``update()``."""
    import sys

    from tqdm.auto import tqdm

    disable = None if (progress and total > 0) else True
    return tqdm(total=total, desc=desc, unit=unit, disable=disable, file=sys.stderr)


# -- settings --------------------------------------------------------------------------------
def _settings_dict(obj) -> dict:
    return dict(dataclasses.asdict(obj))


def _series(series: SeriesSettings | None) -> SeriesSettings:
    """``series`` (default ``SeriesSettings()``) with explicit :class:`LinkSettings`."""
    from .matching import LinkSettings

    series = SeriesSettings() if series is None else series
    if not isinstance(series, SeriesSettings):
        raise InputError(f"series must be a SeriesSettings, got {type(series).__name__}")
    if series.link is None:
        series = dataclasses.replace(series, link=LinkSettings())
    return series


def _detect(detect):
    from .detect import DetectSettings

    detect = DetectSettings() if detect is None else detect
    if not isinstance(detect, DetectSettings):
        raise InputError(f"detect must be a DetectSettings, got {type(detect).__name__}")
    return detect


def frame_times(vols: Sequence[VolumeInfo]) -> list[float] | None:
    """The recorded times (s) of the volumes' frames; None unless every one has one."""
    times = [v.time_s for v in vols]
    return None if any(t is None for t in times) else times


def volume_extent_um(volume: VolumeInfo) -> np.ndarray:
    """Size ``(x, y, z)`` (µm) spanned by the voxel centres of a volume."""
    shape = np.asarray(volume.shape, dtype=float)  # (nz, ny, nx)
    vs = np.asarray(volume.voxel_size_um, dtype=float)  # (dz, dy, dx)
    return ((shape - 1) * vs)[::-1]


def _check_vti(vti_encoding: str) -> None:
    if vti_encoding not in VTI_ENCODINGS:
        raise InputError(f"vti_encoding must be one of {VTI_ENCODINGS}, got {vti_encoding!r}")


# -- detection -------------------------------------------------------------------------------
def _first_psf(vol, info, settings):
    """PSF of the first volume, used for the whole sequence (paper §3.2)."""
    from .psf_estimate import estimate_psf

    if settings.deconvolution_iterations == 0:
        return None, "not used (deconvolution off)"
    if info.lenslet_period_vox is not None:
        # the volume detect_particles deconvolves: its lenslet phases equalised
        from .detect import equalize_lenslet_phases

        vol, _ = equalize_lenslet_phases(vol, info.lenslet_period_vox, info.lenslet_phase_vox)
    try:
        psf = estimate_psf(
            vol, info.voxel_size_um, n_particles=settings.psf_particles, box_um=settings.psf_box_um
        )
    except (TrackingError, InputError) as exc:
        log.warning("no PSF from the first volume (%s); each volume estimates its own", exc)
        return None, f"not available from the first volume: {exc}"
    return psf, f"estimated from {info.name}, shape {list(psf.shape)}"


def _known_sigmas(sigma_um: np.ndarray) -> np.ndarray | None:
    """A table's uncertainties, or None when it has none (all NaN: an older table)."""
    return None if sigma_um.size == 0 or np.all(np.isnan(sigma_um)) else sigma_um


def _detect_frame(job, ctx) -> dict:
    """Detect the particles of one volume and write its table (atomically); any process.

    ``job`` is ``(i, VolumeInfo)``, ``ctx`` ``(DetectSettings, psf or None, results folder)``.
    Returns the positions ``(N, 3)``, their uncertainties ``(N, 3)`` (µm), the detection
    report and the frame's summary entries.
    """
    from .detect import detect_particles

    _, v = job
    settings, psf, out = ctx
    t0 = time.perf_counter()
    vol = read_volume(v)
    det = detect_particles(
        vol,
        v.voxel_size_um,
        settings,
        psf,
        origin_xyz_um=v.origin_xyz_um,
        lenslet_period_vox=v.lenslet_period_vox,
        lenslet_phase_vox=v.lenslet_phase_vox,
        snr=v.snr,
    )
    part = numbered(out / "particles", v.frame, ".csv")
    write_points_csv(
        part, det.positions_um, det.intensities, sigma_xyz_um=det.sigma_um, overwrite=True
    )
    positions = np.asarray(det.positions_um, dtype=float).reshape(-1, 3)
    sigma = None
    if det.sigma_um is not None:
        sigma = np.asarray(det.sigma_um, dtype=float).reshape(-1, 3)
    entry = {
        "particles": str(part.relative_to(out)),
        "n_particles": int(positions.shape[0]),
        "voxel_size_um": list(v.voxel_size_um),
        "origin_xyz_um": list(v.origin_xyz_um),
        "seconds": time.perf_counter() - t0,
        "report": det.report,
        "particles_file": file_record(part),
    }
    return {"positions": positions, "sigma": sigma, "report": det.report, "entry": entry}


def _psf_context(settings, psf, out):
    return settings, psf, out


class _Detections:
    """The detections of a series as they arrive (:mod:`hrvbase.parallel`).

    A sequence of the frames' clouds (positions ``(N, 3)``, µm): item ``i`` waits until frame
    ``i`` is detected, so that linking starts on the first frames while the others are still
    being detected. :meth:`finish` waits for all and returns the :class:`FrameDetections`.
    """

    def __init__(
        self, vols, checksums, settings, out: Path, summary: dict, prev, progress, parallel
    ):
        from hrvbase.parallel import WorkerContext, frame_map

        self.vols, self.out, self.summary = vols, out, summary
        prev_frames = {e.get("index"): e for e in (prev or {}).get("frames", [])}
        frames = [
            {
                "index": v.index,
                "frame": v.frame,
                "time_s": v.time_s,
                "input": v.source(),
                "input_sha256": sha,
            }
            for v, sha in zip(vols, checksums, strict=True)
        ]
        summary["frames"] = frames
        summary["inputs"] = [{"path": f["input"], "sha256": f["input_sha256"]} for f in frames]
        self.frames = frames
        self.clouds: list[np.ndarray | None] = [None] * len(vols)
        self._sigmas: list[np.ndarray | None] = [None] * len(vols)
        self.reports: list[dict] = [{} for _ in vols]
        for i, (v, f) in enumerate(zip(vols, frames, strict=True)):
            old = prev_frames.get(v.index)
            part = numbered(out / "particles", v.frame, ".csv")
            same = old and old.get("frame", old.get("index")) == v.frame
            if same and old.get("input_sha256") == f["input_sha256"]:
                if verify_record(part, old.get("particles_file")):
                    self.clouds[i] = read_points_csv(part)
                    self._sigmas[i] = _known_sigmas(read_point_sigmas(part))
                    frames[i] = {**old, **f, "reused": True}
                elif part.is_file():
                    log.warning(
                        "%s changed on disk since it was written (truncated or edited); "
                        "detecting volume %s again",
                        part,
                        v.name,
                    )
        todo = [i for i in range(len(vols)) if self.clouds[i] is None]
        if prev is not None:  # the earlier results stay unless the volumes to detect are sound
            for i in todo:
                if vols[i].dataset is None:  # (a Zarr frame was read for its checksum)
                    read_volume(vols[i])
        if todo:
            log.info("detecting particles in %d of %d volumes", len(todo), len(vols))
        else:
            log.info("all %d volumes already detected; detection skipped", len(vols))
        self.psf_note = (prev or {}).get("psf", "")
        self.t0 = time.perf_counter()
        self._map = None
        self._results = iter(())
        if todo:
            psf, self.psf_note = _first_psf(read_volume(vols[0]), vols[0], settings)
            here = out.resolve()  # workers may run in another folder
            self._map = frame_map(
                _detect_frame,
                [(i, dataclasses.replace(vols[i], path=vols[i].path.resolve())) for i in todo],
                parallel=parallel,
                context=WorkerContext(_psf_context, (settings, psf, here)),
                progress=progress,
                desc="detect",
                unit="volume",
            )
            self._results = iter(self._map)

    def _take(self, job, result) -> None:
        i, v = job
        self.clouds[i] = result["positions"]
        self._sigmas[i] = result["sigma"]
        self.reports[i] = result["report"]
        self.frames[i].update(result["entry"])
        if self.clouds[i].shape[0] == 0:
            log.info("volume %s: no particle found", v.name)
        self.summary["psf"] = self.psf_note
        write_json(self.out / SUMMARY, self.summary, overwrite=True)  # resumable after each

    def __len__(self) -> int:
        return len(self.vols)

    def __getitem__(self, i: int) -> np.ndarray:
        while self.clouds[i] is None:
            self._take(*next(self._results))
        return self.clouds[i]

    @property
    def sigmas(self) -> _SigmaView:
        """The frames' position uncertainties ``(N, 3)`` (µm; None: unknown), as they arrive."""
        return _SigmaView(self)

    def close(self) -> None:
        if self._map is not None:
            self._map.close()

    def release(self) -> None:
        """Once every frame has arrived (linking read them all): end the detection's map (its
        client; the workers stay for the fields when the cluster is shared)."""
        if all(c is not None for c in self.clouds):
            for job, result in self._results:  # nothing left: the map ends
                self._take(job, result)
            self.close()

    def finish(self) -> list[FrameDetections]:
        """Wait for every detection; record the detection's summary entries."""
        try:
            for job, result in self._results:
                self._take(job, result)
        finally:
            self.close()
        summary = self.summary
        summary["psf"] = self.psf_note
        summary["timings"]["detect_s"] = time.perf_counter() - self.t0
        summary["frame_ids"] = [v.frame for v in self.vols]
        summary["frame_times_s"] = frame_times(self.vols)
        return [
            FrameDetections(
                v.frame,
                v.source(),
                c,
                numbered(self.out / "particles", v.frame, ".csv"),
                bool(f.get("reused", False)),
                r,
                sg,
                v.time_s,
            )
            for v, c, f, r, sg in zip(
                self.vols, self.clouds, self.frames, self.reports, self._sigmas, strict=True
            )
        ]


class _SigmaView:
    """``detections.sigmas[i]``: frame ``i``'s uncertainties, waiting for its detection."""

    def __init__(self, detections: _Detections) -> None:
        self._d = detections

    def __len__(self) -> int:
        return len(self._d)

    def __getitem__(self, i: int) -> np.ndarray | None:
        self._d[i]  # waits until frame i is detected
        return self._d._sigmas[i]


# -- linking and outputs ---------------------------------------------------------------------
def _link_and_write(
    settings: SeriesSettings,
    out: Path,
    summary: dict,
    clouds: Sequence[np.ndarray],
    frame_ids: Sequence[int],
    vti_encoding: str,
    progress: bool,
    sigmas: Sequence[np.ndarray | None] | None = None,
    common_sigma_xyz_um=None,
    parallel=None,
    after_linking: Callable[[], None] | None = None,
    times_s: Sequence[float] | None = None,
    linker: Callable[..., Any] | None = None,
) -> tuple[list[PairOutcome], Tracks, GridAxes | None]:
    """Link ``clouds`` (a list, or :class:`_Detections` arriving), grid and write the fields.

    ``frame_ids``: the frame numbers (increasing); ``times_s``: the frames' times (s), None
    when unknown. ``sigmas``: the frames' position uncertainties ``(N_i, 3)`` (µm; None
    items: unknown), a list or ``_Detections.sigmas``; None: the clouds came without.
    ``parallel``: the increments' fields on its Dask workers
    (:func:`track.series.track_series`); ``after_linking`` is called between linking and
    fields. The incremental predictor scales each step by the frames' times, else by their
    numbers (frames 1 → 5 span 4 camera frames). ``linker``: links one pair
    (:func:`track.series.link_pairs`; None: :func:`track.matching.link_pair`).
    """
    summary["fields_requested"] = settings.compute_fields
    summary["parameters"]["series"] = {
        "mode": settings.mode,
        "min_particles": settings.min_particles,
        "static_frames": settings.static_frames,
        "predictor": settings.predictor,
        "bridge_tracks": settings.bridge_tracks,
        "max_gap_frames": settings.max_gap_frames,
        # the per-match σ model's moving bias (z, y, x; µm)
        "bias_sigma_um": list(settings.bias_sigma_um),
        "bias_length_um": list(settings.bias_length_um),
        "bias_period_um": settings.bias_period_um,
        "bias_lateral_depth_length_um": settings.bias_lateral_depth_length_um,
        "grid": _settings_dict(settings.grid),
        "link": _settings_dict(settings.link),
    }
    if len(clouds) < 2:
        raise InputError(f"linking needs at least 2 frames, got {len(clouds)}")
    if settings.compute_fields and clouds[0].shape[0] >= settings.min_particles:
        check_grid(np.ptp(clouds[0], axis=0), settings.grid, where="frame 0's particles")
    # the earlier run's outputs stay until this run's are all written (_publish_derived)
    stage = _new_staging(out)
    t0 = time.perf_counter()
    n_pairs = len(clouds) - 1
    with _bar(n_pairs, progress, "link", "pair") as bar:
        pairs = link_pairs(
            clouds,
            settings,
            linker=linker,
            on_pair=lambda _p: bar.update(),
            sigmas=sigmas,
            common_sigma_xyz_um=common_sigma_xyz_um,
            frame_times=frame_ids if times_s is None else times_s,
        )
    t1 = time.perf_counter()
    if after_linking is not None:
        after_linking()
    floor = noise_floor(pairs, settings.static_frames)
    if floor is not None:
        summary["noise_floor"] = floor.as_dict()
        log.info(
            "zero-displacement noise floor over the first %d (static) frames, %d displacements: "
            "RMS x/y/z = %s µm (predicted σ %s µm)",
            floor.frames,
            floor.n_displacements,
            "/".join(f"{v:.3g}" for v in floor.rms_xyz_um),
            "/".join(f"{v:.3g}" for v in floor.predicted_xyz_um),
        )
    elif settings.static_frames >= 2:
        log.warning(
            "no noise floor: no pair among the first %d (static) frames was linked",
            settings.static_frames,
        )
    increments, outcomes = [], []
    # The files are independent: a few writer threads write each increment's field files
    # while the next fields are computed (their fsync waits overlap the work and each other),
    # then the matches; every file is atomic, a failed write fails the run at the end.
    with ConcurrentWrites() as writes:
        with _bar(n_pairs if settings.compute_fields else 0, progress, "fields", "field") as bar:

            def field_done(k: int, total, inc) -> None:
                bar.update()
                j = pairs[k].def_frame
                t = None if times_s is None else times_s[j]
                _write_fields(stage, frame_ids[j], t, total, inc, vti_encoding, writes)

            res = track_series(
                clouds,
                settings,
                pairs=pairs,
                on_field=field_done,
                sigmas=sigmas,
                parallel=parallel,
            )
        t2 = time.perf_counter()
        _write_increments(
            stage, res, clouds, frame_ids, times_s, settings, writes, increments, outcomes
        )
    ids = np.asarray(frame_ids, dtype=np.int64)
    tracks = dataclasses.replace(res.tracks, frame=ids[res.tracks.frame])
    times = None if times_s is None else dict(zip(frame_ids, times_s, strict=True))
    write_tracks_csv(stage / "tracks.csv", tracks, times_s=times, overwrite=True)
    _publish_derived(stage, out)
    summary["increments"] = increments
    summary["counts"] = {
        "frames": len(clouds),
        "particles_per_frame": [int(c.shape[0]) for c in clouds],
        "pairs_linked": sum(p.ok for p in res.pairs),
        "pairs_skipped": sum(not p.ok for p in res.pairs),
        "tracks": int(np.unique(tracks.track_id).size),
    }
    if res.axes is not None:
        summary["grid"] = {
            "shape_zyx": list(res.axes.shape),
            "spacing_xyz_um": list(res.axes.spacing_xyz_um),
            "origin_xyz_um": list(res.axes.origin_xyz_um),
        }
    summary["timings"]["link_s"] = t1 - t0
    summary["timings"]["fields_s"] = t2 - t1
    summary["timings"]["write_s"] = time.perf_counter() - t2
    return outcomes, tracks, res.axes


def _write_fields(
    out: Path,
    def_id: int,
    time_s: float | None,
    total,
    inc,
    vti_encoding: str,
    writes: ConcurrentWrites,
) -> None:
    """Queue the field files of the increment ending in frame ``def_id`` (at ``time_s``, s;
    None: unknown) on ``writes``: the total field (``fields/NNNNNN.npz`` and ``.vti``) and
    the increment (``.npz``)."""
    when = {"frame": def_id, "time_s": time_s, "overwrite": True}
    if total is not None:
        base = out / "fields" / f"{def_id:06d}"
        writes.submit(write_field_npz, base.with_suffix(".npz"), total, **when)
        writes.submit(
            write_field_vti, base.with_suffix(".vti"), total, encoding=vti_encoding, **when
        )
    if inc is not None:
        p = out / "fields" / f"increment_{def_id:06d}.npz"
        writes.submit(write_field_npz, p, inc, **when)


def _write_increments(
    out: Path,
    res,
    clouds: Sequence[np.ndarray],
    frame_ids: Sequence[int],
    times_s: Sequence[float] | None,
    settings: SeriesSettings,
    writes: ConcurrentWrites,
    increments: list,
    outcomes: list,
) -> None:
    """Queue every increment's matches on ``writes`` (its field files were queued as they
    were made, :func:`_write_fields`); fill ``increments`` (summary entries) and
    ``outcomes``."""
    for k, pair in enumerate(res.pairs):
        ref_id, def_id = frame_ids[pair.ref_frame], frame_ids[pair.def_frame]
        t_ref = t_def = dt = None
        if times_s is not None:
            t_ref, t_def = times_s[pair.ref_frame], times_s[pair.def_frame]
            dt = t_def - t_ref
        mfile = out / f"matches_{def_id:06d}.csv"
        writes.submit(
            write_matches_csv,
            mfile,
            pair.matches,
            pair.displacement_um,
            sigma_um=pair.sigma_displacement_um,
            dt_s=dt,
            overwrite=True,
        )
        lam = None if res.smoothing[k] is None else tuple(res.smoothing[k])
        entry = {
            "ref_frame": ref_id,
            "def_frame": def_id,
            "frames_spanned": def_id - ref_id,
            "ref_time_s": t_ref,
            "def_time_s": t_def,
            "dt_s": dt,
            "status": pair.status,
            "n_ref": int(clouds[pair.ref_frame].shape[0]),
            "n_def": int(clouds[pair.def_frame].shape[0]),
            "n_matches": int(pair.matches.shape[0]),
            "tracking_ratio": pair.tracking_ratio,
            "iterations": pair.iterations,
            "matches": mfile.name,
            "field_status": res.field_status[k],
            "field": None,
            "smoothing_xyz": None if lam is None else list(lam),
        }
        if not pair.ok:  # reported once at the end (_finish)
            log.info("frames %d → %d %s", ref_id, def_id, pair.status)
        fld = res.total_fields[k]
        if fld is not None:
            entry["field"] = f"fields/{def_id:06d}"
            entry["mask_fraction"] = float(fld.mask.mean())
        inc = res.increment_fields[k]
        if inc is not None:
            entry["increment_field"] = f"fields/increment_{def_id:06d}.npz"
        increments.append(entry)
        outcomes.append(
            PairOutcome(
                ref_id,
                def_id,
                pair.status,
                res.field_status[k],
                pair.matches,
                pair.displacement_um,
                pair.tracking_ratio,
                fld,
                inc,
                lam,
                _pair_failure(entry, settings.compute_fields),
                pair.sigma_displacement_um,
            )
        )


# -- failures and the closing line -----------------------------------------------------------
def _pair_failure(entry: Mapping, fields_requested: bool) -> str:
    where = f"frames {entry['ref_frame']} → {entry['def_frame']}"
    if entry["status"] != OK:
        return f"{where}: {entry['status']}"
    if fields_requested and entry["field_status"] != OK:
        return f"{where}: field {entry['field_status']}"
    return ""


def failures_of(summary: Mapping) -> list[str]:
    """One message per failed frame or pair recorded in a ``summary.json`` (empty: none).

    A pair that was not linked, a requested field that was not gridded and, for a detection
    only (``command == "detect"``), a volume without particles.
    """
    out = []
    if summary.get("command") == "detect":
        for f in summary.get("frames", []):
            if f.get("n_particles", 1) == 0:
                out.append(f"volume {Path(f['input']).name}: no particle found")
    requested = summary.get("fields_requested", True)
    for inc in summary.get("increments", []):
        if reason := _pair_failure(inc, requested):
            out.append(reason)
    return out


def failure_message(failures: Sequence[str], *, hint: str = "allow_partial=True") -> str:
    """One line: the first failure, how many others, and how to keep partial results."""
    more = len(failures) - 1
    what = "pair" if failures[0].startswith("frames ") else "volume"
    extra = f"; and {more} more {what}{'s' if more > 1 else ''} failed" if more else ""
    where = f" (results kept, see {SUMMARY}; " if more else " ("
    return f"{failures[0]}{extra}{where}use {hint} to keep partial results)"


def results_line(summary: Mapping) -> str:
    """``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs linked, tracking ratio ≥ 0.96,
    6 fields, 12.3 s`` from a ``summary.json`` (``(PARTIAL)``/``(FAILED)`` appended)."""
    frames = summary.get("frames", [])
    kind = "clouds" if summary.get("command") == "link" else "volumes"
    parts = [f"{len(frames)} {kind}"]
    counts = [f["n_particles"] for f in frames if "n_particles" in f]
    if counts:
        lo, hi = min(counts), max(counts)
        parts.append(f"{lo}–{hi} particles/frame" if lo != hi else f"{lo} particles/frame")
    incs = summary.get("increments")
    if incs is not None:
        linked = [i for i in incs if i["status"] == OK]
        parts.append(f"{len(linked)}/{len(incs)} pairs linked")
        ratios = [i["tracking_ratio"] for i in linked if i["tracking_ratio"] is not None]
        ratios = [r for r in ratios if math.isfinite(r)]
        if ratios:
            parts.append(f"tracking ratio ≥ {math.floor(100 * min(ratios)) / 100:.2f}")
        if summary.get("fields_requested", True):
            parts.append(f"{sum(i['field'] is not None for i in incs)} fields")
        else:
            parts.append("no fields")
    floor = summary.get("noise_floor")
    if floor:
        rms = "/".join(f"{v:.2g}" for v in floor["rms_xyz_um"])
        parts.append(f"noise floor x/y/z {rms} µm")
    parts.append(f"{summary.get('timings', {}).get('total_s', 0.0):.1f} s")
    status = summary.get("status", "complete")
    return "RESULTS: " + ", ".join(parts) + ("" if status == "complete" else f" ({status.upper()})")


def _finish(
    out: Path,
    summary: dict,
    t0: float,
    allow_partial: bool,
    command: str,
    frames,
    pairs=(),
    tracks=None,
    grid=None,
) -> TrackResult:
    """Set the status, write ``summary.json``; raise on failures unless ``allow_partial``."""
    failures = failures_of(summary)
    summary["failures"] = failures
    summary["allow_partial"] = bool(allow_partial)
    if not failures:
        summary["status"] = "complete"
    else:
        summary["status"] = "partial" if allow_partial else "failed"
    summary["timings"]["total_s"] = time.perf_counter() - t0
    write_json(out / SUMMARY, summary, overwrite=True)
    log.info("results in %s", out)
    result = TrackResult(
        out, command, tuple(frames), tuple(pairs), tracks, grid, summary, tuple(failures)
    )
    if failures and not allow_partial:
        raise FailedFramesError(failure_message(failures), failures, result)
    for f in failures:
        log.warning("%s (kept: partial results allowed)", f)
    return result


# -- public entry points ---------------------------------------------------------------------
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
    if isinstance(volumes, str | os.PathLike):
        voldir = Path(volumes)
        vols = scan_volumes(voldir)  # validate the series before touching out_dir
        where: dict = {"voldir": str(voldir.resolve())}
    else:
        vols = list(volumes)
        if not vols or not all(isinstance(v, VolumeInfo) for v in vols):
            raise InputError("volumes must be a folder or a non-empty list of VolumeInfo")
        where = {"volumes": [v.source(resolve=True) for v in vols]}
    if series is not None and series.compute_fields:
        check_grid(volume_extent_um(vols[0]), series.grid, where="the volume")
    params = {"detect": _settings_dict(settings)}
    if any(v.frame != v.index for v in vols):  # the particle tables' names
        params["frame_numbers"] = [v.frame for v in vols]
    periods = sorted({v.lenslet_period_vox for v in vols if v.lenslet_period_vox is not None})
    if periods:  # an input of the detector (recon.json): a folder detected without it is redone
        params["lenslet_period_vox"] = periods
    if any(settings.sigma_snr_um):  # the frames' SNR sets their σ
        unknown = [v for v in vols if v.snr is None]
        if unknown:
            raise InputError(
                f"sigma_snr_um is set but {unknown[0].source()} has no camera SNR (recon run "
                f"records it in recon.json; {len(unknown)} of {len(vols)} volumes lack it); "
                "set sigma_snr_um to 0 for volumes from elsewhere"
            )
        params["frame_snr"] = [v.snr for v in vols]
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
        frames.append(FrameDetections(i, name, c, part, sigma_um=sg))
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
    "SUMMARY",
    "VTI_ENCODINGS",
    "FrameDetections",
    "PairOutcome",
    "TrackResult",
    "failure_message",
    "failures_of",
    "results_line",
    "track_clouds",
    "track_volumes",
    "volume_extent_um",
]
