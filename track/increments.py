"""The fields of a series' increments: each pair's displacements fitted and gridded, in this
process or on Dask workers (:func:`_increments`), and cumulated in order as they arrive
(:func:`_fields`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg  # noqa: F401  (its BLAS loaded before one_blas_thread limits the loaded ones)

from hrvbase.threads import heap_kept, one_blas_thread

from .errors import InputError
from .eulerian import EulerianCumulation
from .fields import DisplacementInterpolant, field_on_grid, fit_displacement
from .grid import GridAxes, GridSettings
from .pairs import PairResult
from .series_settings import OK, SeriesSettings


def _fit_job(pts, pair: PairResult, settings: SeriesSettings):
    """What an increment's field is fitted to: reference positions (K, 3), displacements
    (K, 3) and their uncertainties (K, 3) or None; InputError when it cannot be fitted."""
    if not pair.ok:
        raise InputError(pair.status.removeprefix("skipped: "))
    if pair.matches.shape[0] < settings.min_particles:
        raise InputError(
            f"fewer than {settings.min_particles} matched particles "
            f"({pair.matches.shape[0]} matched)"
        )
    ref = pts[pair.ref_frame][pair.matches[:, 0]]
    # per-match uncertainty (K, 3) µm when the linker gives it (else estimated by the fit)
    sigma = getattr(pair, "sigma_displacement_xyz_um", None)
    if sigma is not None and not np.all(np.isfinite(sigma)):
        sigma = None
    return ref, pair.displacement_um, sigma


def _fit(pts, pair: PairResult, settings: SeriesSettings) -> DisplacementInterpolant:
    ref, disp, sigma = _fit_job(pts, pair, settings)
    return fit_displacement(ref, disp, settings.grid, sigma_xyz_um=sigma)


class _NotFitted:
    """An increment whose field could not be fitted (its InputError's message)."""

    def __init__(self, message: str) -> None:
        self.message = message


def _grid_increment(job, grid: GridSettings, axes: GridAxes):
    """The interpolant of one increment and its field on ``axes`` (:class:`_NotFitted` when
    the fit refuses the data), with BLAS on one thread (:func:`one_blas_thread`)."""
    with one_blas_thread():
        try:
            interp = fit_displacement(job[0], job[1], grid, sigma_xyz_um=job[2])
        except InputError as exc:
            return _NotFitted(str(exc))
        return interp, field_on_grid(interp, axes)


def _increment_context(grid: GridSettings, axes: GridAxes, jobs: dict):
    """Worker context of :func:`_increment_task`: the grid and every increment's data."""
    return grid, axes, jobs


def _increment_task(k: int, ctx):
    """(On a worker) fit and grid increment ``k``."""
    grid, axes, jobs = ctx
    with heap_kept():
        return _grid_increment(jobs[k], grid, axes)


def _increments(pts, pairs, settings, axes, parallel):
    """``(k, (interpolant, field) or _NotFitted)`` for every pair, in pair order.

    In this process one at a time (``parallel`` None or one worker); else the fits and grids
    run on the Dask workers of ``parallel`` (:func:`hrvbase.parallel.frame_map`, the data
    sent once to each worker) and arrive here in order as they complete. Each worker computes
    exactly what this process would: the results are the same.
    """
    jobs, refused = {}, {}
    for k, pair in enumerate(pairs):
        try:
            jobs[k] = _fit_job(pts, pair, settings)
        except InputError as exc:
            refused[k] = _NotFitted(str(exc))
    if parallel is None or parallel.in_process or len(jobs) < 2:
        for k in range(len(pairs)):
            yield k, refused[k] if k in refused else _grid_increment(jobs[k], settings.grid, axes)
        return
    from hrvbase.parallel import WorkerContext, frame_map, in_order

    items = sorted(jobs)
    ctx = WorkerContext(_increment_context, (settings.grid, axes, jobs))
    with frame_map(
        _increment_task, items, parallel=parallel, context=ctx, desc="fields", unit="field"
    ) as fm:
        arrived = in_order(fm, items)
        for k in range(len(pairs)):
            yield k, refused[k] if k in refused else next(arrived)[1]


def _fields(
    pts, pairs, settings, axes, inc_fields, totals, status, lams, on_field, parallel=None
) -> None:
    with one_blas_thread():  # faster too: these products are too small for threads
        _fields_loop(
            pts, pairs, settings, axes, inc_fields, totals, status, lams, on_field, parallel
        )


def _fields_loop(pts, pairs, settings, axes, inc_fields, totals, status, lams, on_field, parallel):
    def done(k: int) -> None:
        if on_field is not None:
            on_field(k, totals[k], inc_fields[k])

    cumulation = None if settings.mode == "cumulative" else EulerianCumulation(axes)
    broken = None
    for k, got in _increments(pts, pairs, settings, axes, parallel):
        pair = pairs[k]
        if isinstance(got, _NotFitted):
            status[k] = f"skipped: {got.message}"
            if cumulation is not None:
                broken = broken or f"skipped: increment {pair.ref_frame} → {pair.def_frame} missing"
            done(k)
            continue
        interp, fld = got
        lams[k] = interp.smoothing
        if cumulation is None:
            totals[k] = fld
            status[k] = OK
            done(k)
            continue
        inc_fields[k] = fld
        if broken is not None:
            status[k] = broken
            done(k)
            continue
        totals[k] = cumulation.add(interp, inc_fields[k])
        status[k] = OK
        done(k)
