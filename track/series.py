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

Eulerian cumulation (the MATLAB reference composes in reverse order and symmetrises the
increment, which loses rotation; here the composition is exact):

Let ``X`` be a node of the fixed reference grid (frame 0 configuration), ``u_prev(X)`` and
``F_prev(X)`` the totals up to frame ``i−1``, and ``u_inc``, ``F_inc = I + ∂u_inc/∂x`` the
increment ``i−1 → i``, a field over the frame ``i−1`` configuration ``x``. The material
point ``X`` sits at ``x(X) = X + u_prev(X)`` in frame ``i−1``, so

    u_total(X) = u_prev(X) + u_inc(x(X))
    F_total(X) = F_inc(x(X)) · F_prev(X)

``u_inc`` and ``F_inc`` are evaluated **at the displaced positions** ``x(X)`` from the
increment's continuous interpolant (:func:`track.fields.fit_displacement`); ``∂u_inc/∂x``
exactly for the global thin-plate spline (one kernel evaluation gives values and gradients),
otherwise by central differences with the grid spacing as step (the same stencil
:func:`numpy.gradient` uses on the grid). By the chain rule ``F_total = I + ∂u_total/∂X``,
and the node is supported (:attr:`GridField.mask`) only while every increment was supported
at ``x(X)``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hrvbase.threads import heap_kept, one_blas_thread
from hrvbase.validate import points_xyz

from .errors import InputError, TrackError, TrackingError
from .fields import (
    DisplacementInterpolant,
    GridAxes,
    GridField,
    GridSettings,
    field_on_grid,
    fit_displacement,
    grid_axes,
    grid_spacing_um,
    strain_std,
)
from .strain import green_lagrange, infinitesimal

log = logging.getLogger(__name__)

MODES = ("incremental", "cumulative")

#: Status of a pair, increment or field that was computed.
OK = "ok"

#: Most nodes a gridded field may have. A series keeps about 60 floats per node and frame in
#: memory (increment and total ``u, F, E, e``), 0.5 kB: 1 GB per frame at this size.
MAX_GRID_NODES = 2_000_000
#: An explicit grid spacing may give at most this many times ``GridSettings.target_nodes``.
SPACING_NODES_FACTOR = 10


@dataclass(frozen=True)
class SeriesSettings:
    """How a series of point clouds is linked and cumulated.

    Attributes
    ----------
    mode : {"incremental", "cumulative"}
        Link ``i−1 → i`` (and cumulate) or ``0 → i``.
    min_particles : int
        Frames with fewer particles are not linked; their pairs are marked
        ``"skipped: fewer than N particles ..."`` (≥ 4, the minimum for a 3-D affine fit).
    grid : GridSettings
        Gridding of the displacement fields.
    link : object, optional
        Settings passed to the linker (:class:`track.matching.LinkSettings`).
    compute_fields : bool
        Grid displacements and strains (default) or only link.
    static_frames : int
        The first ``static_frames`` frames are known to be at rest (0: none): the spread of
        the displacements between them is the series' zero-displacement noise floor
        (:func:`noise_floor`), reported per axis. Needs ≥ 2 to be used.
    bias_sigma_um : tuple of 3 float
        Standard deviation ``(z, y, x)`` (µm, ≥ 0) of the per-particle localisation bias
        that changes as a particle moves (a light-field reconstruction's error depends on
        where the particle sits under the lenslets): it adds
        ``2 b² (1 − ρ)`` to a displacement's variance, ``ρ`` the correlation of the bias
        before and after the move (:func:`bias_decorrelation`; :func:`match_sigma`).
        Default 0 (no such term).
    bias_length_um : float or tuple of 3 float
        ``L`` (µm, > 0): the move ``(z, y, x)`` over which the bias changes (one number:
        the same along every axis).
    bias_period_um : float
        Lateral period ``P`` (µm, ≥ 0) of the bias: the microlens pitch in the object (MLA
        pitch / magnification; 25 µm for the paper's 100 µm lenslets behind a 4× objective).
        A light-field reconstruction's error follows the particle's phase under the
        lenslets, so a lateral move of one pitch brings the bias back, and a lateral
        coordinate's bias changes only with moves along its own axis (and in depth), the
        axial bias with moves along both. 0 (default): no period, every bias changes with a
        move along any axis (:func:`bias_decorrelation`).
    bias_lateral_depth_length_um : float or None
        The move in depth (µm, > 0) over which the *lateral* coordinates' bias changes; None
        (default): ``bias_length_um``'s z, as the axial bias. A light-field reconstruction's
        lateral bias follows the particle's phase under the lenslets far more than its depth
        (paper-size Fig. 5b: a layer moved 20-500 µm in z keeps its x and y bias; σ with
        the axial length 1.0 µm against errors of 0.21 µm).
    predictor : bool
        Incremental mode: link each pair from the previous increment's displacement field
        (:func:`track.matching.increment_predictor`) as the linker's initial guess; the
        linker checks the guess and falls back to its global bootstrap when it fails.
    bridge_tracks : bool
        Incremental mode: continue a track that ended (its particle was missed by detection
        in a frame, or left unmatched by a pair) where the tracks around it predict the
        particle in a later frame (:func:`link_tracks`, :func:`track.matching.bridge_tracks`);
        the pairs' matches and fields are unchanged. Default on.
    max_gap_frames : int
        Most frames in a row a bridged particle may be missing (≥ 0; 0: only particles of
        consecutive frames that their pair left unmatched). Default 2.
    """

    mode: str = "incremental"
    min_particles: int = 4
    grid: GridSettings = field(default_factory=GridSettings)
    link: Any = None
    compute_fields: bool = True
    static_frames: int = 0
    bias_sigma_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_length_um: float | tuple[float, float, float] = 5.0
    bias_period_um: float = 0.0
    bias_lateral_depth_length_um: float | None = None
    predictor: bool = True
    bridge_tracks: bool = True
    max_gap_frames: int = 2

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise InputError(f"mode must be one of {MODES}, got {self.mode!r}")
        if isinstance(self.min_particles, bool) or int(self.min_particles) < 4:
            raise InputError(f"min_particles must be an integer >= 4, got {self.min_particles!r}")
        sf = self.static_frames
        if isinstance(sf, bool) or not isinstance(sf, int | np.integer) or sf < 0:
            raise InputError(f"static_frames must be an integer >= 0, got {sf!r}")
        b = self.bias_sigma_um
        try:
            b = tuple(float(v) for v in b)
        except (TypeError, ValueError):
            b = ()
        if len(b) != 3 or not all(math.isfinite(v) and v >= 0 for v in b):
            raise InputError(f"bias_sigma_um must be three numbers >= 0 (z, y, x), got {b!r}")
        object.__setattr__(self, "bias_sigma_um", b)
        L = self.bias_length_um
        try:
            lengths = (float(L),) * 3 if isinstance(L, int | float) else tuple(map(float, L))
        except (TypeError, ValueError):
            lengths = ()
        if isinstance(L, bool) or len(lengths) != 3 or not all(0 < v < math.inf for v in lengths):
            raise InputError(
                f"bias_length_um must be one or three finite numbers > 0 (z, y, x), got {L!r}"
            )
        object.__setattr__(self, "bias_length_um", lengths)
        P = self.bias_period_um
        if isinstance(P, bool) or not isinstance(P, int | float) or not 0 <= P < math.inf:
            raise InputError(f"bias_period_um must be a finite number >= 0 (µm), got {P!r}")
        object.__setattr__(self, "bias_period_um", float(P))
        D = self.bias_lateral_depth_length_um
        if D is not None:
            if isinstance(D, bool) or not isinstance(D, int | float) or not 0 < D < math.inf:
                raise InputError(
                    f"bias_lateral_depth_length_um must be a finite number > 0 (µm) or unset, "
                    f"got {D!r}"
                )
            object.__setattr__(self, "bias_lateral_depth_length_um", float(D))
        if not isinstance(self.predictor, bool):
            raise InputError(f"predictor must be true or false, got {self.predictor!r}")
        if not isinstance(self.bridge_tracks, bool):
            raise InputError(f"bridge_tracks must be true or false, got {self.bridge_tracks!r}")
        g = self.max_gap_frames
        if isinstance(g, bool) or not isinstance(g, int | np.integer) or g < 0:
            raise InputError(f"max_gap_frames must be an integer >= 0, got {g!r}")
        if not isinstance(self.grid, GridSettings):
            raise InputError(f"grid must be a GridSettings, got {type(self.grid).__name__}")
        if int(self.grid.target_nodes) > MAX_GRID_NODES:
            raise InputError(
                f"target_nodes must be at most {MAX_GRID_NODES}, got {self.grid.target_nodes!r}"
            )

    @property
    def bias_lengths_xyz_um(self) -> tuple[float, float, float, float]:
        """``(L_x, L_y, L_z, L_z,lateral)`` (µm) for :func:`bias_decorrelation`."""
        lz, ly, lx = self.bias_length_um
        lat = self.bias_lateral_depth_length_um
        return (lx, ly, lz, lz if lat is None else lat)


def grid_node_count(extent_xyz_um, spacing_um: float) -> float:
    """Nodes of the grid :func:`track.fields.grid_axes` builds with ``spacing_um`` over a box.

    Parameters
    ----------
    extent_xyz_um : sequence of 3 float
        Size of the box along x, y, z (µm), each > 0.
    spacing_um : float
        Node spacing (µm), > 0.

    Returns
    -------
    float
        ``Π max(2, ⌈extent / spacing⌉ + 1)``, in floating point (no integer overflow for
        absurd spacings).
    """
    ext = np.asarray(extent_xyz_um, dtype=float).reshape(3)
    n = np.maximum(2.0, np.ceil(ext / float(spacing_um) - 1e-9) + 1.0)
    return float(np.prod(n))


def check_grid(
    extent_xyz_um,
    grid: GridSettings,
    *,
    where: str = "the particles",
    spacing_name: str = "spacing_um",
    target_name: str = "target_nodes",
) -> None:
    """Refuse an explicit grid spacing that gives too many nodes, or a single cell.

    Parameters
    ----------
    extent_xyz_um : sequence of 3 float
        Size along x, y, z (µm) of the box the grid covers (frame 0's particles, or a volume
        that holds them: an upper bound).
    grid : GridSettings
        Only an explicit ``spacing_um`` is checked (the default spacing gives about
        ``target_nodes`` nodes).
    where : str
        What the box is, for the message.
    spacing_name, target_name : str
        Names of the two settings in the message (e.g. the command-line options).

    Raises
    ------
    InputError
        More than ``min(SPACING_NODES_FACTOR × target_nodes, MAX_GRID_NODES)`` nodes, or a
        spacing at least as large as the box's largest extent (the grid would be one cell).
    """
    h = grid.spacing_um
    ext = np.asarray(extent_xyz_um, dtype=float).reshape(3)
    if h is None or not np.all(np.isfinite(ext)) or np.any(ext <= 0):
        return
    size = " × ".join(f"{v:.4g}" for v in ext)
    limit = min(SPACING_NODES_FACTOR * int(grid.target_nodes), MAX_GRID_NODES)
    count = grid_node_count(ext, h)
    if count > limit:
        raise InputError(
            f"{spacing_name} {h:g} µm gives {count:.3g} grid nodes over {where} ({size} µm), "
            f"more than {limit} (at most {SPACING_NODES_FACTOR} × {target_name} and "
            f"{MAX_GRID_NODES}); choose a larger spacing"
        )
    if h >= float(ext.max()):
        raise InputError(
            f"{spacing_name} {h:g} µm is not smaller than {where} ({size} µm): the grid would be "
            "a single cell; choose a smaller spacing"
        )


@dataclass(frozen=True)
class PairResult:
    """The link between two frames.

    Attributes
    ----------
    ref_frame, def_frame : int
        Frame indices (reference, deformed).
    status : str
        ``"ok"`` or ``"skipped: <reason>"``.
    matches : ndarray of int, shape (K, 2)
        Rows ``[row_ref, row_def]`` into the two frames' point tables (0-based).
    displacement_um : ndarray, shape (K, 3)
        Displacement of each matched particle (µm).
    tracking_ratio : float
        Fraction of reference particles matched (NaN when skipped).
    iterations : int
        Linker iterations (0 when skipped).
    sigma_displacement_um : ndarray, shape (K, 3), or None
        Standard uncertainty of each displacement (µm, x, y, z):
        ``sqrt(σ_ref² + σ_def²)`` per axis from the two particles' uncertainties; None when
        the clouds came without uncertainties (NaN where a particle's is unknown).
    """

    ref_frame: int
    def_frame: int
    status: str
    matches: np.ndarray
    displacement_um: np.ndarray
    tracking_ratio: float = math.nan
    iterations: int = 0
    sigma_displacement_um: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether the pair was linked."""
        return self.status == OK


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


def compose_step(
    reference_um: np.ndarray,
    u_prev_um: np.ndarray,
    F_prev: np.ndarray,
    increment: DisplacementInterpolant,
    step_um: float | tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One Eulerian cumulation step at reference points ``X``.

    Parameters
    ----------
    reference_um : ndarray, shape (P, 3)
        Reference positions ``X`` (µm).
    u_prev_um : ndarray, shape (P, 3)
        Total displacement up to the previous frame at ``X``.
    F_prev : ndarray, shape (P, 3, 3)
        Total deformation gradient up to the previous frame at ``X``.
    increment : DisplacementInterpolant
        Increment field over the previous frame's configuration.
    step_um : float or (hx, hy, hz)
        Central-difference step for ``∂u_inc/∂x`` where the interpolant has no exact
        gradient (:meth:`~track.fields.DisplacementInterpolant.value_and_gradient`).

    Returns
    -------
    u_total : ndarray, shape (P, 3)
        ``u_prev(X) + u_inc(X + u_prev(X))``.
    F_total : ndarray, shape (P, 3, 3)
        ``F_inc(X + u_prev(X)) · F_prev(X)``.
    supported : ndarray of bool, shape (P,)
        Whether the increment is supported by data at ``X + u_prev(X)``.
    """
    x = np.asarray(reference_um, float) + np.asarray(u_prev_um, float)
    u_inc, G_inc = increment.value_and_gradient(x, step_um)
    F_inc = np.eye(3) + G_inc
    F_total = np.einsum("pij,pjk->pik", F_inc, np.asarray(F_prev, float))
    return np.asarray(u_prev_um, float) + u_inc, F_total, increment.supported(x)


class EulerianCumulation:
    """Total fields on the reference grid, one increment at a time (module docstring).

    Parameters
    ----------
    axes : GridAxes
        Reference grid (frame 0 configuration).
    """

    def __init__(self, axes: GridAxes) -> None:
        self.axes = axes
        self._X = axes.points()
        self._u = np.zeros_like(self._X)
        self._F = np.broadcast_to(np.eye(3), (self._X.shape[0], 3, 3)).copy()
        self._mask = np.ones(self._X.shape[0], dtype=bool)
        self._var = None  # accumulated variances of u and ∂u/∂X
        self._with_std = True

    def add(
        self, increment: DisplacementInterpolant, increment_field: GridField | None = None
    ) -> GridField:
        """Compose the next increment (a field over the previous frame's configuration);
        the total field from frame 0 to the increment's deformed frame.

        Standard uncertainties (when the increments have them): the variances of the
        increments at the displaced positions add up, as for independent increments
        (``u_std² = Σ_k u_std,k²``, the same for ``F_std``; the first-order product rule is
        left out). Consecutive increments share a frame's localisation noise, with opposite
        signs, but drop-outs and each increment's own smoothing keep most of it from
        cancelling: on bench_fields' 11-frame series 61 % / 85 % of the total displacement
        errors fall within 1σ / 2σ (smoothing bias included), against 32 % / 56 % with the
        last increment's σ alone.

        ``increment_field``, the increment gridded on the same grid (:func:`field_on_grid`),
        lends its values, gradients and uncertainties at the displaced positions
        (:func:`_grid_lookup`: trilinear gradients and σ, Taylor-corrected values), instead
        of evaluating the spline there: exact for the first increment and for affine fields;
        on bench_fields' 41-frame series the last total differs from the spline's by
        1e-4 RMS in E (its error against the truth: 2.8e-2), for 17 % less CPU in the fields.
        Without it the spline is evaluated (:meth:`DisplacementInterpolant.value_and_gradient`,
        :meth:`~DisplacementInterpolant.std`).
        """
        x = self._X + self._u
        self._with_std &= increment.has_uncertainty
        on_grid = increment_field is not None and increment_field.shape == self.axes.shape
        u_sd = G_sd = None
        if on_grid:
            std = self._with_std and increment_field.u_std is not None
            got = _grid_lookup(increment_field, x, values=True, std=std)
            u_inc, G_inc = got[:2]
            if std:
                u_sd, G_sd = got[2:]
        else:
            u_inc, G_inc = increment.value_and_gradient(x, self.axes.spacing_xyz_um)
        self._F = np.matmul(np.eye(3) + G_inc, self._F)  # (compose_step)
        self._u = self._u + u_inc
        keep = np.flatnonzero(self._mask)  # a node once unsupported stays so
        # a new array: the fields returned before keep theirs (their files may still be
        # being written, by the writer threads of track.pipeline, while this one is made)
        mask = self._mask.copy()
        mask[keep] = increment.supported(x[keep])
        self._mask = mask
        shape = self.axes.shape
        Fg = self._F.reshape(*shape, 3, 3)
        stds = {}
        if self._with_std:
            if u_sd is None:
                u_sd, G_sd = increment.std(x)
            var = (u_sd**2, G_sd**2)
            if self._var is not None:
                var = (self._var[0] + var[0], self._var[1] + var[1])
            self._var = var
            G_sd = np.sqrt(var[1]).reshape(*shape, 3, 3)
            stds = {
                "u_std": np.sqrt(var[0]).reshape(*shape, 3),
                "F_std": G_sd,
                "e_std": strain_std(G_sd),
            }
        return GridField(
            self.axes.x_um,
            self.axes.y_um,
            self.axes.z_um,
            self._u.reshape(*shape, 3),
            Fg,
            green_lagrange(Fg),
            infinitesimal(Fg),
            self._mask.reshape(shape),
            **stds,
        )


def _trilinear(fld: GridField, values: np.ndarray, xyz_um: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of nodal ``values`` (nodes, C) of ``fld``'s grid at ``xyz_um``
    (P, 3); outside the grid, the nearest border cell's weights (clamped). Returns (P, C)."""
    from scipy.sparse import csr_matrix

    shape = np.asarray(fld.shape)
    h = np.asarray(fld.spacing_xyz_um)[::-1]
    t = (np.asarray(xyz_um, float)[:, ::-1] - np.asarray(fld.origin_xyz_um)[::-1]) / h  # z,y,x
    t = np.clip(t, 0.0, shape - 1.0)
    i0 = np.minimum(np.floor(t).astype(np.int64), shape - 2)
    w = t - i0
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    base = i0 @ strides
    ws = (1.0 - w, w)
    n = t.shape[0]
    # the eight corners' weights as a sparse (P, nodes) matrix: one product for all columns
    # (the same sums, in the same order, as adding the corners one by one; 5x faster)
    wt, idx = np.empty((n, 8)), np.empty((n, 8), dtype=np.int64)
    for corner in range(8):
        d = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
        wt[:, corner] = ws[d[0]][:, 0] * ws[d[1]][:, 1] * ws[d[2]][:, 2]
        idx[:, corner] = base + int(np.dot(d, strides))
    A = csr_matrix((wt.ravel(), idx.ravel(), np.arange(0, 8 * n + 1, 8)), (n, values.shape[0]))
    return np.asarray(A @ values)


def _grid_lookup(fld: GridField, xyz_um: np.ndarray, *, values: bool = False, std: bool = True):
    """A gridded field at ``xyz_um`` (P, 3), from its nodes only.

    Returns ``(u, G)`` when ``values`` — the displacement (P, 3) and ``∂u_i/∂x_j`` (P, 3, 3):
    the gradient trilinear in the nodes' exact gradients (second order in the node spacing),
    the displacement the same weighting of each corner's first-order Taylor value
    ``u(c) + G(c) (x − c)``, exact at the nodes and on affine fields (linear extrapolation
    from the border cells outside the grid) — followed, when ``std``, by ``u_std`` (P, 3) and
    ``F_std`` (P, 3, 3), trilinear.
    """
    n = np.shape(xyz_um)[0]
    cols = []
    if values:
        G = (fld.F - np.eye(3)).reshape(-1, 3, 3)
        nodes = fld.axes.points()
        # Σ_c w_c (u_c + G_c (x − c)) = Σ_c w_c (u_c − G_c c) + (Σ_c w_c G_c) x
        cols += [fld.u.reshape(-1, 3) - np.einsum("nij,nj->ni", G, nodes), G.reshape(-1, 9)]
    if std:
        cols += [fld.u_std.reshape(-1, 3), fld.F_std.reshape(-1, 9)]
    out = _trilinear(fld, np.concatenate(cols, axis=1), xyz_um)
    got = []
    if values:
        G = out[:, 3:12].reshape(n, 3, 3)
        got += [out[:, :3] + np.einsum("pij,pj->pi", G, np.asarray(xyz_um, float)), G]
        out = out[:, 12:]
    if std:
        got += [out[:, :3], out[:, 3:].reshape(n, 3, 3)]
    return tuple(got)


def cumulate_eulerian(
    axes: GridAxes, increments: Sequence[DisplacementInterpolant]
) -> list[GridField]:
    """Total fields on the reference grid from a sequence of increment fields.

    Parameters
    ----------
    axes : GridAxes
        Reference grid (frame 0 configuration).
    increments : sequence of DisplacementInterpolant
        Increment ``k`` (frame ``k → k+1``) is a field over the frame ``k`` configuration.

    Returns
    -------
    list of GridField
        Entry ``k``: total displacement and ``F = F_inc,k · … · F_inc,0`` from frame 0 to
        frame ``k + 1`` (module docstring), with ``E`` and ``e`` of that ``F``.
    """
    cumulation = EulerianCumulation(axes)
    return [cumulation.add(inc) for inc in increments]


def _points(arr, name: str) -> np.ndarray:
    return points_xyz(arr, name, error=InputError)


def _default_linker():
    try:
        from .matching import link_pair
    except ImportError as exc:  # pragma: no cover - depends on the installed modules
        raise TrackingError(f"particle matching (track.matching) is not available: {exc}") from exc
    return link_pair


class _CheckedSigmas:
    """Per-frame ``(N_i, 3)`` uncertainties (µm) checked against the clouds one by one as
    they are first used (like :class:`_Checked`: a frame may still be being detected)."""

    def __init__(self, sigmas, pts) -> None:
        if len(sigmas) != len(pts):
            raise InputError(f"sigmas: {len(sigmas)} arrays for {len(pts)} frames")
        self._sigmas, self._pts = sigmas, pts
        self._checked: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._pts)

    def __getitem__(self, i: int) -> np.ndarray:
        if not 0 <= i < len(self):
            raise IndexError(i)
        if i not in self._checked:
            p, sg = self._pts[i], self._sigmas[i]
            a = np.full(p.shape, np.nan) if sg is None else np.asarray(sg, dtype=float)
            if a.shape != p.shape or np.any(a < 0):
                raise InputError(
                    f"frame {i} uncertainties must be an ({p.shape[0]}, 3) array of σ >= 0 µm "
                    f"(NaN: unknown), got shape {a.shape}"
                )
            self._checked[i] = a
        return self._checked[i]


def _sigmas(sigmas, pts) -> _CheckedSigmas | None:
    """Per-frame (N_i, 3) uncertainties (µm) checked against the clouds as used, or None."""
    return None if sigmas is None else _CheckedSigmas(sigmas, pts)


def bias_decorrelation(displacement_um, length_xyz_um, period_um: float = 0.0) -> np.ndarray:
    """``1 − ρ``: how much of a particle's moving bias changes with its displacement, per axis.

    The bias of a light-field localisation depends on where the particle sits: its depth and
    its phase under the lenslets. Its correlation ``ρ_a`` between the two places of a move
    ``u`` (per coordinate ``a``) is modelled as a product of one factor per direction ``c``:

    - in depth, and without a period laterally: ``g_c = exp(−½ (u_c / L_c)²)``;
    - laterally with a period ``P`` (``period_um > 0``), the periodic kernel
      ``k_c = exp(−½ (P / (π L_c))² sin²(π u_c / P))``, which equals ``g_c`` for
      ``u_c ≪ P`` and returns to 1 at every multiple of ``P``.

    Without a period every coordinate's bias changes with a move along any axis:
    ``ρ_a = g_x g_y g_z``. With one, ``ρ_x = k_x g_z``, ``ρ_y = k_y g_z`` and
    ``ρ_z = k_x k_y g_z``: a lateral coordinate's bias follows the phase along its own axis
    (measured: calibration runs translated along y keep their x bias), the axial bias both.
    The lateral coordinates' depth factor may have its own length ``L_z,lat`` (a fourth
    length): their bias changes with depth more slowly than the axial one.

    Parameters
    ----------
    displacement_um : ndarray, shape (K, 3)
        Displacements (µm, x, y, z).
    length_xyz_um : sequence of 3 or 4 float
        ``L`` per direction (µm, > 0; x, y, z order), and optionally ``L_z,lat``, the depth
        length of the lateral coordinates' bias (default: ``L_z``).
    period_um : float
        ``P`` (µm, ≥ 0): lateral period, the microlens pitch in the object; 0 = none.

    Returns
    -------
    ndarray, shape (K, 3)
        ``1 − ρ`` per coordinate (x, y, z), in [0, 1].
    """
    u = np.asarray(displacement_um, float).reshape(-1, 3)
    lengths = np.asarray(length_xyz_um, float).reshape(-1)
    L, lz_lat = lengths[:3], lengths[3] if lengths.size > 3 else lengths[2]
    g = np.exp(-0.5 * np.square(u / L))  # (K, 3)
    g_lat = np.exp(-0.5 * np.square(u[:, 2] / lz_lat))  # the lateral bias's depth factor
    if not period_um:
        rho_xy = g[:, 0] * g[:, 1]
        rho = np.column_stack([rho_xy * g_lat, rho_xy * g_lat, rho_xy * g[:, 2]])
        return 1.0 - rho
    P = float(period_um)
    k = np.exp(-0.5 * np.square(P / (np.pi * L[:2]) * np.sin(np.pi * u[:, :2] / P)))
    rho = np.column_stack([k[:, 0] * g_lat, k[:, 1] * g_lat, k[:, 0] * k[:, 1] * g[:, 2]])
    return 1.0 - rho


def match_sigma(
    matches: np.ndarray,
    sigma_ref_um: np.ndarray,
    sigma_def_um: np.ndarray,
    common_sigma_xyz_um=None,
    *,
    displacement_um: np.ndarray | None = None,
    bias_sigma_xyz_um=None,
    bias_length_xyz_um=(5.0, 5.0, 5.0),
    bias_period_um: float = 0.0,
) -> np.ndarray:
    """Standard uncertainty of matched displacements: ``sqrt(σ_ref² + σ_def²)`` per axis.

    Parameters
    ----------
    matches : ndarray of int, shape (K, 2)
        Rows ``[row_ref, row_def]``.
    sigma_ref_um, sigma_def_um : ndarray, shape (N_ref, 3), (N_def, 3)
        Position uncertainties of the two frames (µm, x, y, z).
    common_sigma_xyz_um : sequence of 3 float, optional
        Part ``s`` of every position's σ that both images of a particle share (a
        per-particle bias, e.g. ``DetectSettings.sigma_systematic_um`` in x, y, z order): it
        cancels in the displacement, ``sqrt(σ_ref² + σ_def² − 2 s²)``.
    displacement_um : ndarray, shape (K, 3), optional
        The displacements, for the moving-bias term.
    bias_sigma_xyz_um : sequence of 3 float, optional
        ``b`` (x, y, z order) of :attr:`SeriesSettings.bias_sigma_um`: adds
        ``2 b² (1 − ρ)`` to each displacement's variance (:func:`bias_decorrelation`).
    bias_length_xyz_um : sequence of 3 or 4 float
        ``L`` (µm, x, y, z order), and optionally the lateral bias's depth length
        (:attr:`SeriesSettings.bias_lengths_xyz_um`; :func:`bias_decorrelation`).
    bias_period_um : float
        Lateral period ``P`` (µm; 0 = none) of :attr:`SeriesSettings.bias_period_um`.

    Returns
    -------
    ndarray, shape (K, 3)
        µm; the random parts of the two localisations are independent (separate images).
    """
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    var = sigma_ref_um[m[:, 0]] ** 2 + sigma_def_um[m[:, 1]] ** 2
    if common_sigma_xyz_um is not None:
        var = np.clip(var - 2 * np.square(np.asarray(common_sigma_xyz_um, float)), 0.0, None)
    if bias_sigma_xyz_um is not None and displacement_um is not None:
        omr = bias_decorrelation(displacement_um, bias_length_xyz_um, bias_period_um)
        var = var + 2 * np.square(np.asarray(bias_sigma_xyz_um, float)) * omr
    return np.sqrt(var)


def _skipped(ref: int, dfm: int, reason: str) -> PairResult:
    return PairResult(
        ref, dfm, f"skipped: {reason}", np.zeros((0, 2), np.int64), np.zeros((0, 3)), math.nan, 0
    )


class _Checked:
    """``clouds`` checked one by one as they are first used (a cloud may still be arriving,
    e.g. from a detection running in parallel: ``clouds[i]`` waits for it)."""

    def __init__(self, clouds: Sequence[np.ndarray]) -> None:
        self._clouds = clouds
        self._checked: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._clouds)

    def __getitem__(self, i: int) -> np.ndarray:
        if i not in self._checked:
            self._checked[i] = _points(self._clouds[i], f"frame {i} positions")
        return self._checked[i]


def link_pairs(
    clouds: Sequence[np.ndarray],
    settings: SeriesSettings | None = None,
    *,
    linker: Callable[..., Any] | None = None,
    on_pair: Callable[[PairResult], None] | None = None,
    sigmas: Sequence[np.ndarray | None] | None = None,
    common_sigma_xyz_um=None,
    frame_times: Sequence[float] | None = None,
) -> list[PairResult]:
    """Link the frames of a series pairwise (``i−1 → i`` or ``0 → i``).

    Parameters
    ----------
    clouds : sequence of ndarray, shape (N_i, 3)
        Particle positions of each frame (µm); read in frame order as the pairs are linked
        (a sequence whose items are still being computed may wait for them).
    settings : SeriesSettings, optional
    linker : callable, optional
        ``linker(ref_xyz, def_xyz, link_settings, initial_guess=None) -> result`` with
        ``.matches``, ``.displacement_um``, ``.tracking_ratio``, ``.iterations`` (and
        optionally ``.ok``, ``.reason``, ``.displacement_field``). Default
        :func:`track.matching.link_pair`. In cumulative mode the previous pair's
        ``displacement_field`` (frame 0 → i−1) is passed as ``initial_guess`` for 0 → i;
        in incremental mode (with ``settings.predictor``) the previous increment's field
        through :func:`track.matching.increment_predictor` (each particle repeats its last
        step) for ``i−1 → i``, when the previous pair was linked.
    on_pair : callable, optional
        Called with each :class:`PairResult` as it is finished (progress).
    sigmas : sequence of (ndarray, shape (N_i, 3)), optional
        Position uncertainties of each frame (µm); gives every pair's
        :attr:`PairResult.sigma_displacement_um` (:func:`match_sigma`).
    common_sigma_xyz_um : sequence of 3 float, optional
        The part of every σ shared by a particle's images, see :func:`match_sigma`.
    frame_times : sequence of float, optional
        When each frame was taken, increasing (seconds, or camera frame numbers: any unit);
        the incremental predictor scales the previous increment by the ratio of the two
        intervals (constant velocity). Default: evenly spaced frames (ratio 1).

    Returns
    -------
    list of PairResult
        Pairs with a frame of fewer than ``settings.min_particles`` particles, or that the
        linker could not track (``ok=False``, or a :class:`~track.errors.TrackError` such as
        coplanar clouds), are returned with a
        ``"skipped: ..."`` status.
    """
    settings = settings or SeriesSettings()
    pts = _Checked(clouds)  # each cloud is read when its first pair is linked
    if len(pts) < 2:
        raise InputError(f"a series needs at least 2 frames, got {len(pts)}")
    sig = _sigmas(sigmas, pts)
    times = _frame_times(frame_times, len(pts))
    linker = linker or _default_linker()
    out: list[PairResult] = []
    prev_field = None
    for i in range(1, len(pts)):
        r = i - 1 if settings.mode == "incremental" else 0
        few = [f for f in (r, i) if pts[f].shape[0] < settings.min_particles]
        if few:
            f = few[0]
            res = _skipped(
                r,
                i,
                f"fewer than {settings.min_particles} particles in frame {f} "
                f"({pts[f].shape[0]} found)",
            )
        else:
            try:
                guess = None
                if out and out[-1].ok and prev_field is not None:
                    if settings.mode == "cumulative":
                        guess = prev_field
                    elif settings.predictor:
                        scale = 1.0 if times is None else _interval_ratio(times, i)
                        guess = _increment_guess(prev_field, scale)
                lr = linker(pts[r], pts[i], settings.link, initial_guess=guess)
                if not getattr(lr, "ok", True):
                    raise TrackingError(getattr(lr, "reason", "") or "no consistent matches")
                m = _check_matches(
                    lr.matches, pts[r].shape[0], pts[i].shape[0], f"frames {r} → {i}"
                )
                d = np.asarray(lr.displacement_um, dtype=float).reshape(-1, 3)
                if d.shape[0] != m.shape[0]:
                    raise TrackingError(
                        f"frames {r} → {i}: {m.shape[0]} matches but {d.shape[0]} displacements"
                    )
                res = PairResult(
                    r,
                    i,
                    OK,
                    m,
                    d,
                    float(lr.tracking_ratio),
                    int(getattr(lr, "iterations", 0)),
                    None
                    if sig is None
                    else match_sigma(
                        m,
                        sig[r],
                        sig[i],
                        common_sigma_xyz_um,
                        displacement_um=d,
                        bias_sigma_xyz_um=settings.bias_sigma_um[::-1],
                        bias_length_xyz_um=settings.bias_lengths_xyz_um,
                        bias_period_um=settings.bias_period_um,
                    ),
                )
                prev_field = getattr(lr, "displacement_field", None)
            except TrackError as exc:
                log.info("frames %d → %d not tracked: %s", r, i, exc)
                res = _skipped(r, i, f"tracking failed: {exc}")
        log.info("frames %d → %d: %s, %d matches", r, i, res.status, res.matches.shape[0])
        if on_pair is not None:
            on_pair(res)
        out.append(res)
    return out


def _frame_times(frame_times, n: int) -> np.ndarray | None:
    """``frame_times`` as ``n`` finite increasing numbers (None stays None)."""
    if frame_times is None:
        return None
    try:
        t = np.asarray(frame_times, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        t = np.zeros(0)
    if t.size != n or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError(
            f"frame_times must be {n} increasing finite numbers (one per frame), got "
            f"{list(frame_times) if np.iterable(frame_times) else frame_times!r}"
        )
    return t


def _interval_ratio(times: np.ndarray, i: int) -> float:
    """``(t_i − t_{i−1}) / (t_{i−1} − t_{i−2})``: the increment ``i−1 → i`` over the one
    before it, in time (the constant-velocity scale of the incremental predictor)."""
    return float((times[i] - times[i - 1]) / (times[i - 1] - times[i - 2]))


def _increment_guess(prev_field, scale: float = 1.0):
    from .matching import increment_predictor

    return increment_predictor(prev_field, scale=scale)


@dataclass(frozen=True)
class NoiseFloor:
    """Zero-displacement noise floor of a series from frames known to be at rest.

    Attributes
    ----------
    frames : int
        Static frames used (the first ``frames`` of the series).
    n_displacements : int
        Matched displacements pooled (pairs among the static frames).
    rms_xyz_um : (float, float, float)
        RMS of those displacements per axis (µm): the floor, since the truth is zero.
    std_xyz_um : (float, float, float)
        Their standard deviation about the mean (µm); a mean much larger than the spread
        means the "static" frames drifted.
    mean_xyz_um : (float, float, float)
    predicted_xyz_um : (float, float, float)
        RMS of the predicted displacement uncertainties (:attr:`PairResult.sigma_displacement_um`)
        of the same matches (NaN without uncertainties): close to ``rms_xyz_um`` when the
        per-particle σ is right.
    """

    frames: int
    n_displacements: int
    rms_xyz_um: tuple[float, float, float]
    std_xyz_um: tuple[float, float, float]
    mean_xyz_um: tuple[float, float, float]
    predicted_xyz_um: tuple[float, float, float]

    def as_dict(self) -> dict:
        return {
            "frames": self.frames,
            "n_displacements": self.n_displacements,
            "rms_xyz_um": list(self.rms_xyz_um),
            "std_xyz_um": list(self.std_xyz_um),
            "mean_xyz_um": list(self.mean_xyz_um),
            "predicted_xyz_um": list(self.predicted_xyz_um),
        }


def noise_floor(pairs: Sequence[PairResult], static_frames: int) -> NoiseFloor | None:
    """Per-axis zero-displacement noise floor from the linked pairs among the first
    ``static_frames`` frames (both frames ``< static_frames``).

    Returns
    -------
    NoiseFloor or None
        None when ``static_frames < 2`` or no such pair was linked.
    """
    if static_frames < 2:
        return None
    use = [p for p in pairs if p.ok and p.ref_frame < static_frames and p.def_frame < static_frames]
    d = [p.displacement_um for p in use]
    if not use or sum(len(x) for x in d) == 0:
        return None
    d = np.concatenate(d)
    s = [p.sigma_displacement_um for p in use]
    pred = (math.nan,) * 3
    if all(x is not None for x in s):
        s = np.concatenate(s)
        pred = tuple(float(v) for v in np.sqrt(np.nanmean(s**2, axis=0)))

    def trio(a):
        return tuple(float(v) for v in a)

    return NoiseFloor(
        frames=int(static_frames),
        n_displacements=int(d.shape[0]),
        rms_xyz_um=trio(np.sqrt(np.mean(d**2, axis=0))),
        std_xyz_um=trio(d.std(axis=0)),
        mean_xyz_um=trio(d.mean(axis=0)),
        predicted_xyz_um=pred,
    )


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
    sigma = getattr(pair, "sigma_displacement_um", None)
    if sigma is not None and not np.all(np.isfinite(sigma)):
        sigma = None
    return ref, pair.displacement_um, sigma


def _fit(pts, pair: PairResult, settings: SeriesSettings) -> DisplacementInterpolant:
    ref, disp, sigma = _fit_job(pts, pair, settings)
    return fit_displacement(ref, disp, settings.grid, sigma_um=sigma)


class _NotFitted:
    """An increment whose field could not be fitted (its InputError's message)."""

    def __init__(self, message: str) -> None:
        self.message = message


def _grid_increment(job, grid: GridSettings, axes: GridAxes):
    """The interpolant of one increment and its field on ``axes`` (:class:`_NotFitted` when
    the fit refuses the data), with BLAS on one thread (:func:`one_blas_thread`)."""
    with one_blas_thread():
        try:
            interp = fit_displacement(job[0], job[1], grid, sigma_um=job[2])
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


__all__ = [
    "MAX_GRID_NODES",
    "MODES",
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
