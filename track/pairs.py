"""Linking the frames of a series pairwise (``i−1 → i`` or ``0 → i``) with any linker:
:func:`link_pairs` and its :class:`PairResult`."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hrvbase.validate import points_xyz

from .errors import InputError, TrackError, TrackingError
from .series_settings import OK, SeriesSettings
from .sigma_model import match_sigma
from .tracks import _check_matches

log = logging.getLogger(__name__)


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
    sigma_displacement_xyz_um : ndarray, shape (K, 3), or None
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
    sigma_displacement_xyz_um: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether the pair was linked."""
        return self.status == OK


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
        :attr:`PairResult.sigma_displacement_xyz_um` (:func:`match_sigma`).
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


__all__ = ["PairResult", "link_pairs"]
