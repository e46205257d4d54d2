"""Tracking a time series of point clouds: incremental or cumulative, Lagrangian and Eulerian.

Modes (:class:`SeriesSettings.mode`):

``"incremental"``
    Link frame ``i−1 → i`` for every ``i``. Small displacements per pair keep the matching
    easy. Results are cumulated two ways:

    - **Lagrangian trajectories** (:func:`link_tracks`): a particle matched from ``i−1`` to
      ``i`` keeps its track id; unmatched particles start new tracks. Rows
      ``frame, track_id, x_um, y_um, z_um`` (``tracks.csv``).
    - **Eulerian cumulation on the reference grid** (:func:`cumulate_eulerian`), with the
      finite-deformation composition described there.

``"cumulative"``
    Link frame ``0 → i`` directly for every ``i``. Displacements are total already; track
    ids are the rows of frame 0 (unmatched particles of later frames get fresh ids).

The modes' parts live in their own modules: the settings (:mod:`track.series_settings`), the
pairwise linking (:mod:`track.pairs`), the trajectories (:mod:`track.tracks`), the per-match
uncertainty model (:mod:`track.sigma_model`), the increments' fields
(:mod:`track.increments`) and the Eulerian cumulation (:mod:`track.eulerian`);
:func:`track_series` runs them in order.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InputError
from .eulerian import EulerianCumulation, compose_step, cumulate_eulerian
from .grid import GridAxes, GridField, grid_axes, grid_spacing_um
from .increments import _fields
from .pairs import PairResult, _points, _sigmas, link_pairs
from .series_settings import (
    MAX_GRID_NODES,
    MODES,
    OK,
    SPACING_NODES_FACTOR,
    SeriesSettings,
    check_grid,
    grid_node_count,
)
from .sigma_model import NoiseFloor, bias_decorrelation, match_sigma, noise_floor
from .tracks import Tracks, lagrangian_displacements, link_tracks


@dataclass(frozen=True)
class SeriesResult:
    """Everything :func:`track_series` computed.

    Attributes
    ----------
    mode : str
    pairs : tuple of PairResult
        One per frame ``i ≥ 1``: ``i−1 → i`` (incremental) or ``0 → i`` (cumulative).
    tracks : Tracks
    axes : GridAxes or None
        Reference grid (over frame 0's particles); ``None`` when it could not be built.
    increment_fields : tuple of (GridField or None)
        Incremental mode: the field of each increment on the grid (over the frame ``i−1``
        configuration). Cumulative mode: all ``None``.
    total_fields : tuple of (GridField or None)
        Total field from frame 0 to each frame ``i ≥ 1`` on the reference grid (Eulerian
        cumulation in incremental mode; direct in cumulative mode).
    field_status : tuple of str
        ``"ok"`` or ``"skipped: <reason>"`` for each entry of ``total_fields``.
    smoothing : tuple of ((float, float, float) or None)
        RBF smoothing λ of ``u_x, u_y, u_z`` used for each pair's field (chosen by GCV by
        default, see :func:`track.fields.gcv_smoothing`); ``None`` where no field was fitted.
    """

    mode: str
    pairs: tuple[PairResult, ...]
    tracks: Tracks
    axes: GridAxes | None
    increment_fields: tuple[GridField | None, ...]
    total_fields: tuple[GridField | None, ...]
    field_status: tuple[str, ...]
    smoothing: tuple[tuple[float, float, float] | None, ...] = ()


def track_series(
    clouds: Sequence[np.ndarray],
    settings: SeriesSettings | None = None,
    *,
    linker: Callable[..., Any] | None = None,
    pairs: Sequence[PairResult] | None = None,
    on_pair: Callable[[PairResult], None] | None = None,
    on_field: Callable[[int, GridField | None, GridField | None], None] | None = None,
    sigmas: Sequence[np.ndarray | None] | None = None,
    parallel=None,
    frame_times: Sequence[float] | None = None,
) -> SeriesResult:
    """Link a series of point clouds and compute trajectories and displacement/strain fields.

    Parameters
    ----------
    clouds : sequence of ndarray, shape (N_i, 3)
        Particle positions of each frame (µm), frame 0 first (the reference).
    settings : SeriesSettings, optional
    linker : callable, optional
        See :func:`link_pairs`.
    pairs : sequence of PairResult, optional
        Already linked pairs (skip the linking).
    on_pair : callable, optional
        Progress callback, see :func:`link_pairs`.
    on_field : callable, optional
        Called as ``on_field(k, total, increment)`` once pair ``k``'s field is done, in order:
        its total and increment fields (:attr:`SeriesResult.total_fields`,
        :attr:`SeriesResult.increment_fields`; None where skipped or not made), e.g. to write
        them while the next ones are computed.
    sigmas : sequence of (ndarray, shape (N_i, 3)), optional
        Position uncertainties of each frame (µm), see :func:`link_pairs`; also copied into
        the tracks.
    parallel : hrvbase.parallel.Parallel, optional
        Fit and grid the increments on Dask workers (:func:`hrvbase.parallel.frame_map`);
        the Eulerian cumulation runs here, in order, as they arrive. Default (or one worker):
        in this process. The results are the same.
    frame_times : sequence of float, optional
        When each frame was taken, see :func:`link_pairs`.

    Returns
    -------
    SeriesResult
        Skipped pairs and fields carry a ``"skipped: <reason>"`` status; nothing is silently
        extrapolated across them (the Eulerian total stops at the first missing increment).
    """
    settings = settings or SeriesSettings()
    pts = [_points(c, f"frame {i} positions") for i, c in enumerate(clouds)]
    checked = _sigmas(sigmas, pts)
    sig = None if checked is None else [checked[i] for i in range(len(pts))]
    if pairs is None:
        pairs = link_pairs(
            pts, settings, linker=linker, on_pair=on_pair, sigmas=sig, frame_times=frame_times
        )
    pairs = tuple(pairs)
    if len(pairs) != len(pts) - 1:
        raise InputError(f"expected {len(pts) - 1} pairs for {len(pts)} frames, got {len(pairs)}")
    tracks = link_tracks(
        [p.shape[0] for p in pts],
        [p.matches if p.ok else None for p in pairs],
        mode=settings.mode,
        positions_um=pts,
        sigmas_um=sig,
        max_gap_frames=settings.max_gap_frames if settings.bridge_tracks else None,
        link_settings=settings.link,
    )
    n = len(pairs)
    inc_fields: list[GridField | None] = [None] * n
    totals: list[GridField | None] = [None] * n
    status = ["skipped: fields not requested"] * n
    lams: list[tuple[float, float, float] | None] = [None] * n
    axes = None
    if settings.compute_fields:
        try:
            if pts[0].shape[0] < settings.min_particles:
                raise InputError(f"fewer than {settings.min_particles} particles in frame 0")
            g = settings.grid
            check_grid(np.ptp(pts[0], axis=0), g, where="frame 0's particles")
            axes = grid_axes(pts[0], grid_spacing_um(pts[0], g), target_nodes=g.target_nodes)
        except InputError as exc:
            status = [f"skipped: no reference grid ({exc})"] * n
        if axes is not None:
            _fields(
                pts, pairs, settings, axes, inc_fields, totals, status, lams, on_field, parallel
            )
    return SeriesResult(
        mode=settings.mode,
        pairs=pairs,
        tracks=tracks,
        axes=axes,
        increment_fields=tuple(inc_fields),
        total_fields=tuple(totals),
        field_status=tuple(status),
        smoothing=tuple(lams),
    )


__all__ = [
    "MAX_GRID_NODES",
    "MODES",
    "OK",
    "SPACING_NODES_FACTOR",
    "EulerianCumulation",
    "NoiseFloor",
    "PairResult",
    "SeriesResult",
    "SeriesSettings",
    "Tracks",
    "bias_decorrelation",
    "check_grid",
    "compose_step",
    "cumulate_eulerian",
    "grid_node_count",
    "lagrangian_displacements",
    "link_pairs",
    "link_tracks",
    "match_sigma",
    "noise_floor",
    "track_series",
]
