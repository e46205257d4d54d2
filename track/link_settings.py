"""Settings and results of the particle linker (:func:`track.matching.link_pair`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from hrvbase.errors import raised_as
from hrvbase.validate import finite_float, int_in_range, nonnegative_float, positive_float
from track.errors import InputError
from track.outliers import MEDIAN_TEST_THRESHOLD
from track.regularize import METHODS

MIN_PARTICLES = 4


#: Default lengths of :class:`LinkSettings`, in mean particle spacings
#: (:meth:`LinkSettings.radii_um`).
NN_MAX_DISTANCE_SPACINGS = 0.45


LOCAL_RADIUS_SPACINGS = 3.0


GRID_SPACING_SPACINGS = 2.0


class LinkRadii(NamedTuple):
    """The lengths (µm) of :class:`LinkSettings` for a cloud of a given mean spacing."""

    nn_max_distance_um: float
    local_radius_um: float
    local_scale_um: float
    ransac_threshold_um: float
    grid_spacing_um: float


@dataclass(frozen=True)
class LinkSettings:
    """Parameters of :func:`~track.matching.link_pair`. Lengths in µm; ``None`` means "derive from
    the data".

    Attributes
    ----------
    n_neighbors_max : int
        Neighbours of the median test that cleans the seeds (paper Table 1: 16).
    n_neighbors_min : int
        Half the neighbours of the median test of every iteration (≥ 3).
    descriptor_size : int
        Neighbours in a topology descriptor (≥ 2).
    descriptor_ratio : float
        Ratio test of descriptor matches: best distance < ratio × second best (0 < r ≤ 1).
    outlier_threshold : float
        Normalised-median-test threshold (paper: 3).
    outlier_eps_um : float or None
        Median-test noise level ε, the same on every axis. Default (with
        ``outlier_eps_xyz_um`` None too): per axis, the robust spread of the matches'
        leave-one-out residuals, at least 0.02 × the mean spacing.
    outlier_eps_xyz_um : tuple of 3 float or None
        Median-test noise levels per axis (x, y, z) in µm; wins over ``outlier_eps_um``.
    max_iterations : int
        Iteration cap of seeding, growth and validation (the polishing iterations come on
        top).
    regularization : {"gridded", "admm"}
        Global field solver (:func:`track.regularize.fit_field`).
    grid_spacing_um : float or None
        Node spacing of the field grid; default 2 × the mean particle spacing.
    smoothness : float
        Dimensionless smoothness weight of the gridded field (≥ 0).
    refine_field : bool
        Refine the gridded field per component where the data show finer detail
        (:func:`track.regularize.fit_field_refined`).
    nn_max_distance_um : float or None
        Radius of the ball whose volume caps every tolerance ellipsoid (a semi-axis may reach
        1.7 ×), and the tolerance of the seeding matches; default 0.45 mean spacings.
    nn_ratio : float
        Ratio test of the local matches (normalised distances, both sides; 0 < r ≤ 1).
    ransac_threshold_um : float or None
        Consensus radius of the affine bootstrap; default 1 mean spacing.
    bootstrap_max_particles : int
        Reference particles (random subset) used by the global bootstrap match.
    seed : int
        Seed of the RANSAC sampler and of the random subsets.
    local_neighbors : int
        Matched neighbours of each local prediction (≥ 3).
    local_degree : {1, 2}
        Degree of the local polynomial predictor (affine by default; quadratic fits the
        curvature but amplifies the axial noise).
    local_radius_um : float or None
        Largest distance of a matched neighbour used by a prediction; default 3 mean
        spacings.
    local_scale_um : float or None
        Gaussian weight length of the local fits; default 1 mean spacing.
    tolerance_sigmas : float
        Tolerance semi-axis per estimated standard deviation of the prediction error (> 0).
    growth_passes : int
        Growth passes per iteration (≥ 0).
    growth_q : float
        Normalised distance (fraction of the tolerance, 0 < q ≤ 1) a growth match must be
        within; validation then accepts up to 1.
    guess_min_fraction : float
        Fraction of the particles an ``initial_guess`` must link consistently to replace
        the bootstrap (0 ≤ f ≤ 1).
    guess_confirm_fraction : float
        When the matches grown from an ``initial_guess`` are fewer than this fraction of
        the particles, the bootstrap is run as well and the result with more matches kept
        (0 ≤ f ≤ 1): a predictor extrapolated off its data (a thin layer moving along z,
        Fig. 5b) can start a consistent but partial set that growth cannot complete.
    polish_iterations : int
        Iterations predicting relative to the regularised field of all matches (≥ 0).
    """

    n_neighbors_max: int = 16
    n_neighbors_min: int = 5
    descriptor_size: int = 5
    descriptor_ratio: float = 0.8
    outlier_threshold: float = MEDIAN_TEST_THRESHOLD
    outlier_eps_um: float | None = None
    outlier_eps_xyz_um: tuple[float, float, float] | None = None
    max_iterations: int = 20
    regularization: str = "gridded"
    grid_spacing_um: float | None = None
    smoothness: float = 1.0
    refine_field: bool = True
    nn_max_distance_um: float | None = None
    nn_ratio: float = 0.5
    ransac_threshold_um: float | None = None
    bootstrap_max_particles: int = 3000
    seed: int = 0
    local_neighbors: int = 12
    local_degree: int = 1
    local_radius_um: float | None = None
    local_scale_um: float | None = None
    tolerance_sigmas: float = 4.0
    growth_passes: int = 8
    growth_q: float = 0.5
    guess_min_fraction: float = 0.3
    guess_confirm_fraction: float = 0.9
    polish_iterations: int = 2

    def radii_um(self, spacing_um: float) -> LinkRadii:
        """The search radii and lengths for a reference cloud of mean particle spacing
        ``spacing_um`` (µm): each setting, or its default in spacings when None
        (``nn_max_distance_um`` :data:`NN_MAX_DISTANCE_SPACINGS`, ``local_radius_um``
        :data:`LOCAL_RADIUS_SPACINGS`, ``local_scale_um`` and ``ransac_threshold_um`` 1,
        ``grid_spacing_um`` :data:`GRID_SPACING_SPACINGS`)."""
        return LinkRadii(
            self.nn_max_distance_um or NN_MAX_DISTANCE_SPACINGS * spacing_um,
            self.local_radius_um or LOCAL_RADIUS_SPACINGS * spacing_um,
            self.local_scale_um or spacing_um,
            self.ransac_threshold_um or spacing_um,
            self.grid_spacing_um or GRID_SPACING_SPACINGS * spacing_um,
        )

    def __post_init__(self) -> None:
        with raised_as(InputError):
            self._validate()

    def _validate(self) -> None:
        n_min = int_in_range(self.n_neighbors_min, "n_neighbors_min", 3)
        if int_in_range(self.n_neighbors_max, "n_neighbors_max", 1) < n_min:
            raise InputError(
                f"n_neighbors_max ({self.n_neighbors_max}) must be ≥ n_neighbors_min "
                f"({self.n_neighbors_min})"
            )
        int_in_range(self.descriptor_size, "descriptor_size", 2)
        int_in_range(self.bootstrap_max_particles, "bootstrap_max_particles", MIN_PARTICLES)
        int_in_range(self.max_iterations, "max_iterations", 1)
        if not isinstance(self.seed, int | np.integer):
            raise InputError(f"seed must be an integer ≥ 0, got {self.seed!r}")
        int_in_range(self.seed, "seed", 0)
        int_in_range(self.local_neighbors, "local_neighbors", 3)
        if self.local_degree not in (1, 2):
            raise InputError(f"local_degree must be 1 or 2, got {self.local_degree}")
        for name in ("growth_passes", "polish_iterations"):
            int_in_range(getattr(self, name), name, 0)
        for name in ("descriptor_ratio", "nn_ratio", "growth_q"):
            if not 0 < finite_float(getattr(self, name), name) <= 1:
                raise InputError(f"{name} must be in (0, 1], got {getattr(self, name)}")
        for name in ("guess_min_fraction", "guess_confirm_fraction"):
            if not 0 <= finite_float(getattr(self, name), name) <= 1:
                raise InputError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        for name in ("outlier_threshold", "tolerance_sigmas"):
            positive_float(getattr(self, name), name)
        nonnegative_float(self.smoothness, "smoothness")
        if self.regularization not in METHODS:
            raise InputError(
                f"regularization must be one of {METHODS}, got {self.regularization!r}"
            )
        for name in (
            "outlier_eps_um",
            "grid_spacing_um",
            "nn_max_distance_um",
            "ransac_threshold_um",
            "local_radius_um",
            "local_scale_um",
        ):
            v = getattr(self, name)
            if v is not None:
                positive_float(v, name)
        if self.outlier_eps_xyz_um is not None:
            try:
                eps = np.asarray(self.outlier_eps_xyz_um, dtype=float)
            except (TypeError, ValueError):
                eps = np.zeros(0)
            if eps.shape != (3,) or not np.all(np.isfinite(eps) & (eps > 0)):
                raise InputError(
                    "outlier_eps_xyz_um must be None or 3 finite values > 0 (x, y, z in µm), "
                    f"got {self.outlier_eps_xyz_um!r}"
                )
            object.__setattr__(self, "outlier_eps_xyz_um", tuple(float(v) for v in eps))


@dataclass(frozen=True)
class IterationRecord:
    """What one iteration did (counts are numbers of matches).

    Attributes
    ----------
    iteration : int
        1-based.
    matcher : str
        ``"topology"``, ``"topology-moment"`` or ``"nearest"`` (seeding: the winning
        bootstrap hypothesis, or ``"nearest"`` for the matches of an ``initial_guess``),
        ``"local"`` (growth and validation) or ``"polish"``.
    n_neighbors : int
        Neighbours of the median test.
    n_candidates, n_matches, n_outliers : int
        Candidate matches (grown ones included), matches kept, candidates removed.
    update_rms_um : float
        RMS change of the predicted displacements since the previous iteration (nan for
        seeding and for the first iteration).
    residual_rms_um : float
        Robust RMS length of the matches' residuals about their predictions.
    seconds : float
        Wall time.
    """

    iteration: int
    matcher: str
    n_neighbors: int
    n_candidates: int
    n_matches: int
    n_outliers: int
    update_rms_um: float
    residual_rms_um: float
    seconds: float


@dataclass(frozen=True)
class LinkResult:
    """Outcome of :func:`~track.matching.link_pair`.

    Attributes
    ----------
    matches : ndarray of int, shape (K, 2)
        0-based rows ``[row_ref, row_def]`` of matched particles.
    displacement_um : ndarray, shape (K, 3)
        ``def − ref`` of each match in µm.
    tracking_ratio : float
        K / min(N, M).
    iterations : int
        Iterations run (bootstrap included).
    history : tuple of IterationRecord
        Per-iteration counts and field updates.
    displacement_field : callable
        ``field(xyz_um (P, 3)) -> (P, 3)`` µm, the final regularised displacement at
        reference-configuration points.
    ok : bool
        False when no consistent set of matches was found; ``reason`` says why, ``matches``
        is empty and ``displacement_field`` must not be used.
    reason : str
        Empty when ``ok``.
    mean_spacing_um : float
        Mean nearest-neighbour distance of the reference cloud.
    """

    matches: np.ndarray
    displacement_um: np.ndarray
    tracking_ratio: float
    iterations: int
    history: tuple[IterationRecord, ...]
    displacement_field: Callable[[np.ndarray], np.ndarray]
    ok: bool = True
    reason: str = ""
    mean_spacing_um: float = float("nan")
    seconds: float = field(default=0.0, compare=False)
