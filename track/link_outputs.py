"""Linking stage of the ``track`` pipeline: link the frames, grid the fields and write the
matches, tracks and field files of a results folder (:func:`_link_and_write`), staged and
published together.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.io import ConcurrentWrites

from .errors import InputError
from .field_files import write_field_npz, write_field_vti
from .grid import GridAxes
from .pairs import link_pairs
from .results import (
    PairOutcome,
    _bar,
    _new_staging,
    _pair_failure,
    _publish_derived,
    _settings_dict,
)
from .series import track_series
from .series_settings import SeriesSettings, check_grid
from .sigma_model import noise_floor
from .tables import write_matches_csv, write_tracks_csv
from .tracks import Tracks

log = logging.getLogger(__name__)


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
    summary["parameters"]["series"] = _series_parameters(settings)
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
    _record_noise_floor(summary, pairs, settings.static_frames)
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
    _record_counts(summary, increments, clouds, res, tracks)
    summary["timings"]["link_s"] = t1 - t0
    summary["timings"]["fields_s"] = t2 - t1
    summary["timings"]["write_s"] = time.perf_counter() - t2
    return outcomes, tracks, res.axes


def _series_parameters(settings: SeriesSettings) -> dict:
    """The series settings as recorded in ``summary.json``."""
    return {
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


def _record_noise_floor(summary: dict, pairs, static_frames: int) -> None:
    """The zero-displacement noise floor of the static frames into ``summary`` (and the log)."""
    floor = noise_floor(pairs, static_frames)
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
    elif static_frames >= 2:
        log.warning(
            "no noise floor: no pair among the first %d (static) frames was linked",
            static_frames,
        )


def _record_counts(summary: dict, increments: list, clouds, res, tracks: Tracks) -> None:
    """The pairs' entries, the counts and the reference grid into ``summary``."""
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
            sigma_xyz_um=pair.sigma_displacement_xyz_um,
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
                pair.sigma_displacement_xyz_um,
            )
        )
