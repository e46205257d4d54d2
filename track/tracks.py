"""Lagrangian trajectories from pairwise matches: track ids through a series
(:func:`link_tracks`), tracks bridged over frames where a particle was missed, and the total
displacements of the tracks between two frames (:func:`lagrangian_displacements`)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InputError, TrackingError
from .series_settings import MODES

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Tracks:
    """Lagrangian trajectories: one row per particle and frame.

    Attributes
    ----------
    frame, track_id, row : ndarray of int, shape (M,)
        Frame index, track id, and row of the particle in its frame's point table.
    xyz_um : ndarray, shape (M, 3)
        Position (µm).
    sigma_xyz_um : ndarray, shape (M, 3), or None
        Standard uncertainty of each position (µm), when the frames came with one.
    """

    frame: np.ndarray
    track_id: np.ndarray
    row: np.ndarray
    xyz_um: np.ndarray
    sigma_xyz_um: np.ndarray | None = None

    def positions(self, track_id: int) -> tuple[np.ndarray, np.ndarray]:
        """``(frames, xyz_um)`` of one track, in frame order."""
        sel = self.track_id == track_id
        order = np.argsort(self.frame[sel])
        return self.frame[sel][order], self.xyz_um[sel][order]


def _check_matches(m, n_ref: int, n_def: int, where: str) -> np.ndarray:
    m = np.asarray(m)
    if m.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if m.ndim != 2 or m.shape[1] != 2 or m.dtype.kind not in "iu":
        raise TrackingError(f"{where}: matches must be an (K, 2) integer array, got {m.shape}")
    m = m.astype(np.int64)
    if (
        np.any(m < 0)
        or np.any(m[:, 0] >= n_ref)
        or np.any(m[:, 1] >= n_def)
        or np.unique(m[:, 0]).size != m.shape[0]
        or np.unique(m[:, 1]).size != m.shape[0]
    ):
        raise TrackingError(f"{where}: matches hold rows out of range or used twice")
    return m


def link_tracks(
    n_particles: Sequence[int],
    matches: Sequence[np.ndarray | None],
    *,
    mode: str = "incremental",
    positions_um: Sequence[np.ndarray] | None = None,
    sigmas_um: Sequence[np.ndarray] | None = None,
    max_gap_frames: int | None = None,
    link_settings: Any = None,
) -> Tracks:
    """Assign track ids from pairwise matches.

    Parameters
    ----------
    n_particles : sequence of int
        Particles in each frame (``T`` frames).
    matches : sequence of (ndarray, shape (K, 2)) or None
        ``T − 1`` entries: rows ``[row_ref, row_def]`` linking frame ``i−1 → i``
        (incremental) or ``0 → i`` (cumulative); ``None`` for a skipped pair.
    mode : {"incremental", "cumulative"}
    positions_um : sequence of (ndarray, shape (N_i, 3)), optional
        Positions of each frame's particles, copied into :attr:`Tracks.xyz_um`.
    sigmas_um : sequence of (ndarray, shape (N_i, 3)), optional
        Their standard uncertainties, copied into :attr:`Tracks.sigma_xyz_um`.
    max_gap_frames : int, optional
        Incremental mode with ``positions_um``: bridge tracks (:func:`_bridge`). A particle
        of frame ``i`` that no match continues is linked to a track that ended in frame
        ``i − g``, ``g = 1 … max_gap_frames + 1`` (a particle missed by detection in up to
        ``max_gap_frames`` frames in a row, or left unmatched by a pair), when
        :func:`track.matching.bridge_tracks` finds it unambiguously where the tracks
        present in both frames predict it. None (default): no bridging.
    link_settings : LinkSettings, optional
        The linker's settings used by the bridging.

    Returns
    -------
    Tracks
        Frame 0 particle ``r`` has track id ``r``. A particle matched from a particle with
        id ``t`` has id ``t`` (incremental: through every increment; cumulative: to frame 0);
        a bridged particle has the id of the track it continues; every other particle starts
        a new track with the next unused id. A bridged track has no row in the frames where
        the particle was missed.
    """
    if mode not in MODES:
        raise InputError(f"mode must be one of {MODES}, got {mode!r}")
    n = [int(v) for v in n_particles]
    if len(matches) != max(len(n) - 1, 0):
        raise InputError(
            f"expected {len(n) - 1} match arrays for {len(n)} frames, got {len(matches)}"
        )
    if max_gap_frames is not None and (
        isinstance(max_gap_frames, bool)
        or int(max_gap_frames) != max_gap_frames
        or max_gap_frames < 0
    ):
        raise InputError(f"max_gap_frames must be an integer >= 0, got {max_gap_frames!r}")
    bridge = max_gap_frames is not None and mode == "incremental" and positions_um is not None
    if bridge:
        pos = [np.asarray(p, dtype=float).reshape(-1, 3) for p in positions_um]
        if [p.shape[0] for p in pos] != n:
            raise InputError("positions_um do not have n_particles rows per frame")
    ids = [np.arange(n[0], dtype=np.int64)] if n else []
    next_id = n[0] if n else 0
    for i in range(1, len(n)):
        cur = np.full(n[i], -1, dtype=np.int64)
        src = ids[i - 1] if mode == "incremental" else ids[0]
        m = matches[i - 1]
        if m is not None:
            ref_n = n[i - 1] if mode == "incremental" else n[0]
            m = _check_matches(m, ref_n, n[i], f"matches of frame {i}")
            cur[m[:, 1]] = src[m[:, 0]]
        if bridge:
            _bridge(pos, ids, cur, int(max_gap_frames), link_settings)
        new = cur < 0
        cur[new] = next_id + np.arange(int(new.sum()))
        next_id += int(new.sum())
        ids.append(cur)
    frame = np.concatenate([np.full(k, i, dtype=np.int64) for i, k in enumerate(n)]) if n else []
    row = np.concatenate([np.arange(k, dtype=np.int64) for k in n]) if n else []
    if positions_um is not None:
        xyz = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 3) for p in positions_um])
        if xyz.shape[0] != sum(n):
            raise InputError("positions_um do not have n_particles rows per frame")
    else:
        xyz = np.full((sum(n), 3), np.nan)
    sig = None
    if sigmas_um is not None:
        sig = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 3) for p in sigmas_um])
        if sig.shape[0] != sum(n):
            raise InputError("sigmas_um do not have n_particles rows per frame")
    return Tracks(
        frame=np.asarray(frame, dtype=np.int64),
        track_id=np.concatenate(ids) if ids else np.zeros(0, dtype=np.int64),
        row=np.asarray(row, dtype=np.int64),
        xyz_um=xyz,
        sigma_xyz_um=sig,
    )


def _bridge(pos, ids, cur, max_gap_frames: int, link_settings) -> None:
    """Give the particles of frame ``i = len(ids)`` that no match continues (``cur < 0``)
    the ids of tracks that ended in frame ``i − g``, ``g = 1 … max_gap_frames + 1``, nearest
    frame first (:func:`track.matching.bridge_tracks`, predicted from the tracks present in
    both frames); ``cur`` is updated in place. ``link_settings``: a LinkSettings, or None
    (the defaults)."""
    from .matching import LinkSettings, bridge_tracks

    link_settings = link_settings if isinstance(link_settings, LinkSettings) else LinkSettings()
    i = len(ids)
    for g in range(1, max_gap_frames + 2):
        j = i - g
        if j < 0:
            break
        starts = np.flatnonzero(cur < 0)
        if starts.size == 0:
            break
        # tracks seen in frame j and in none of the frames after it up to i
        later = np.concatenate([*ids[j + 1 : i], cur[cur >= 0]])
        ends = np.flatnonzero(~np.isin(ids[j], later))
        if ends.size == 0:
            continue
        known = cur >= 0
        _, r_j, r_i = np.intersect1d(ids[j], cur[known], return_indices=True)
        pairs = np.column_stack([r_j, np.flatnonzero(known)[r_i]])
        # Consecutive frames: the pair's linker compared these particles and left them
        # unmatched, so a bridge must be as clear as its first matches (growth_q); across
        # a gap the linker never saw the pair, and the whole ellipsoid counts.
        q_max = link_settings.growth_q if g == 1 else 1.0
        found = bridge_tracks(pos[j], pos[i], pairs, ends, starts, link_settings, q_max=q_max)
        if found.shape[0]:
            cur[found[:, 1]] = ids[j][found[:, 0]]
            log.info("frame %d: %d tracks bridged from frame %d", i, found.shape[0], j)


def lagrangian_displacements(
    tracks: Tracks, frame: int, reference_frame: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Total displacement of the tracks present in both ``reference_frame`` and ``frame``.

    This is the Lagrangian framework of the paper (§3.2): the total particle displacement
    follows from the linked trajectories; grid it on the reference positions with
    :func:`track.fields.gridded_field` to get the total field at ``frame``.

    Returns
    -------
    track_id : ndarray of int, shape (K,)
    reference_um : ndarray, shape (K, 3)
        Positions in ``reference_frame`` (µm).
    displacement_um : ndarray, shape (K, 3)
        ``x(frame) − x(reference_frame)`` (µm).
    """
    ref = tracks.frame == reference_frame
    cur = tracks.frame == frame
    common, i_ref, i_cur = np.intersect1d(
        tracks.track_id[ref], tracks.track_id[cur], assume_unique=True, return_indices=True
    )
    x0 = tracks.xyz_um[ref][i_ref]
    x1 = tracks.xyz_um[cur][i_cur]
    return common, x0, x1 - x0


__all__ = ["Tracks", "lagrangian_displacements", "link_tracks"]
