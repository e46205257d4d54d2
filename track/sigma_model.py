"""Uncertainty of matched displacements (:func:`match_sigma`), with the moving part of a
particle's localisation bias (:func:`bias_decorrelation`), and the zero-displacement noise
floor of a series from frames at rest (:func:`noise_floor`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .pairs import PairResult


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
    (docs/validation_notes.md, "Standard uncertainties"), the axial bias both.
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
    sigma_ref_xyz_um: np.ndarray,
    sigma_def_xyz_um: np.ndarray,
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
    sigma_ref_xyz_um, sigma_def_xyz_um : ndarray, shape (N_ref, 3), (N_def, 3)
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
    var = sigma_ref_xyz_um[m[:, 0]] ** 2 + sigma_def_xyz_um[m[:, 1]] ** 2
    if common_sigma_xyz_um is not None:
        var = np.clip(var - 2 * np.square(np.asarray(common_sigma_xyz_um, float)), 0.0, None)
    if bias_sigma_xyz_um is not None and displacement_um is not None:
        omr = bias_decorrelation(displacement_um, bias_length_xyz_um, bias_period_um)
        var = var + 2 * np.square(np.asarray(bias_sigma_xyz_um, float)) * omr
    return np.sqrt(var)


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
        RMS of the predicted displacement uncertainties
        (:attr:`PairResult.sigma_displacement_xyz_um`) of the same matches (NaN without
        uncertainties): close to ``rms_xyz_um`` when the per-particle σ is right.
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
    s = [p.sigma_displacement_xyz_um for p in use]
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


__all__ = ["NoiseFloor", "bias_decorrelation", "match_sigma", "noise_floor"]
