"""Settings of a series (:class:`SeriesSettings`) and the checks of its grid's size
(:func:`check_grid`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InputError
from .grid import BOX_GRID_NODES, GridSettings

MODES = ("incremental", "cumulative")


#: Status of a pair, increment or field that was computed.
OK = "ok"


#: Most nodes a gridded field may have. A series keeps about 60 floats per node and frame in
#: memory (increment and total ``u, F, E, e``), 0.5 kB: 1 GB per frame at this size.
MAX_GRID_NODES = 2_000_000


#: An explicit grid spacing may give at most this many times ``GridSettings.target_nodes``
#: (:data:`track.grid.BOX_GRID_NODES` when not given).
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
        (docs/validation_notes.md, "Standard uncertainties").
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
        if self.grid.target_nodes is not None and int(self.grid.target_nodes) > MAX_GRID_NODES:
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
        Only an explicit ``spacing_um`` is checked (the other grids keep within their own
        limits, :func:`track.grid.grid_spacing_um`).
    where : str
        What the box is, for the message.
    spacing_name, target_name : str
        Names of the two settings in the message (e.g. the command-line options).

    Raises
    ------
    InputError
        More than ``min(SPACING_NODES_FACTOR × target_nodes, MAX_GRID_NODES)`` nodes
        (``target_nodes`` default :data:`track.grid.BOX_GRID_NODES`), or a
        spacing at least as large as the box's largest extent (the grid would be one cell).
    """
    h = grid.spacing_um
    ext = np.asarray(extent_xyz_um, dtype=float).reshape(3)
    if h is None or not np.all(np.isfinite(ext)) or np.any(ext <= 0):
        return
    size = " × ".join(f"{v:.4g}" for v in ext)
    target = BOX_GRID_NODES if grid.target_nodes is None else int(grid.target_nodes)
    limit = min(SPACING_NODES_FACTOR * target, MAX_GRID_NODES)
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


__all__ = [
    "MAX_GRID_NODES",
    "MODES",
    "OK",
    "SPACING_NODES_FACTOR",
    "SeriesSettings",
    "check_grid",
    "grid_node_count",
]
