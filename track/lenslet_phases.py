"""Noise equalisation of the sub-lenslet phases of a light-field reconstruction.

A light-field reconstruction concentrates noise into single voxels and lines at a few of the
sub-lenslet phases of every depth; :func:`equalize_lenslet_phases` brings every phase's noise
to its depth's typical level before particles are detected (:mod:`track.detect`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import InputError

#: Noise σ (in units of its depth's typical σ) a sub-lenslet phase is brought down to by
#: :func:`equalize_lenslet_phases`: phases up to it are left as they are (with 144 lenslets
#: per phase the robust σ of a phase varies by about 10 % by chance, and particles lying on
#: the lenslets of one phase raise it further).
PHASE_SIGMA_TOL = 2.0
#: Fewest voxels per (depth, lenslet phase) for :func:`equalize_lenslet_phases` (its robust
#: statistics): a volume of fewer than 3 × 3 lenslets is left as it is.
PHASE_MIN_VOX = 9


def equalize_lenslet_phases(
    volume: np.ndarray,
    period_vox: int,
    phase_vox: Sequence[int] = (0, 0),
) -> tuple[np.ndarray, dict]:
    """The volume with the noise of every sub-lenslet phase brought to its depth's level.

    A light-field reconstruction's voxel ``(k, j, i)`` lies at sub-lenslet position
    ``((j + phase_y) mod s, (i + phase_x) mod s)`` of its lenslet (``s = period_vox``, the
    super-resolution factor; :mod:`recon.geometry`), and its noise depends on that phase: at
    a few phases the reconstruction piles noise into single voxels and lines. For every depth
    ``k`` and phase ``(a, b)`` the robust median ``m_kab`` and σ ``σ_kab`` (1.4826 × MAD over
    the voxels of that phase, one per lenslet) are measured, and the voxels become

    ``m_k + (v - m_kab) · min(1, t σ_k / σ_kab)``

    with ``m_k`` and ``σ_k`` the medians of ``m_kab`` and ``σ_kab`` over the phases of depth
    ``k`` and ``t`` = :data:`PHASE_SIGMA_TOL`: phases more than ``t`` times noisier than
    their depth's typical phase are scaled down to ``t σ_k``, none is amplified, and the
    phase offsets are removed. The particles (a few lenslets each) hardly
    move these statistics. A depth whose typical σ is 0 (a sparse volume) is left as it is.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
    period_vox : int
        Lenslet period ``s`` (voxels, lateral), ≥ 1.
    phase_vox : sequence of 2 int
        ``(phase_y, phase_x)``: sub-lenslet position of voxel row/column 0 (0 for volumes
        written by ``recon run``, whose lateral extent starts at a lenslet corner).

    Returns
    -------
    equalized : ndarray, float32, same shape
        Not below the volume's minimum.
    info : dict
        ``period_vox``, ``phase_vox``, ``equalized`` (False when the volume has fewer than
        :data:`PHASE_MIN_VOX` lenslets per phase, or s = 1), ``max_sigma_ratio`` (largest
        ``σ_kab / σ_k``).
    """
    vol = np.asarray(volume)
    s = int(period_vox)
    py, px = (int(v) % s for v in phase_vox)
    info = {"period_vox": s, "phase_vox": [py, px], "equalized": False, "max_sigma_ratio": 1.0}
    out = vol.astype(np.float32, copy=True)
    nz, ny, nx = vol.shape
    if s == 1 or (ny // s) * (nx // s) < PHASE_MIN_VOX:
        return out, info
    # views of every phase (a, b): rows j with (j + py) % s == a, columns likewise
    views = [[out[:, (a - py) % s :: s, (b - px) % s :: s] for b in range(s)] for a in range(s)]
    med = np.empty((nz, s, s))
    sig = np.empty((nz, s, s))
    for a in range(s):
        for b in range(s):
            v = views[a][b].reshape(nz, -1).astype(np.float64)
            m = np.median(v, axis=1)
            med[:, a, b] = m
            sig[:, a, b] = 1.4826 * np.median(np.abs(v - m[:, None]), axis=1)
    m_k = np.median(med.reshape(nz, -1), axis=1)
    s_k = np.median(sig.reshape(nz, -1), axis=1)
    live = s_k > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(live[:, None, None], sig / s_k[:, None, None], 1.0)
    gain = np.where(
        live[:, None, None], np.minimum(1.0, PHASE_SIGMA_TOL / np.maximum(ratio, 1e-30)), 1.0
    )
    shift = np.where(live[:, None, None], m_k[:, None, None] - med * 1.0, 0.0)
    for a in range(s):
        for b in range(s):
            v = views[a][b]
            g = gain[:, a, b][:, None, None].astype(np.float32)
            m = med[:, a, b][:, None, None].astype(np.float32)
            sh = shift[:, a, b][:, None, None].astype(np.float32)
            v[...] = m + sh + (v - m) * g
    np.maximum(out, float(vol.min()), out=out)
    info["equalized"] = True
    info["max_sigma_ratio"] = float(np.nanmax(ratio))
    return out, info


def check_lenslet(period, phase) -> tuple[int, tuple[int, int]]:
    """The validated lenslet period (voxels, ≥ 1) and phase ``(phase_y, phase_x)``, each
    phase reduced modulo the period; :class:`track.errors.InputError` otherwise."""
    if isinstance(period, bool) or not isinstance(period, int | np.integer) or period < 1:
        raise InputError(f"lenslet_period_vox must be a positive integer or None, got {period!r}")
    try:
        ph = tuple(phase)
    except TypeError:
        ph = ()
    if len(ph) != 2 or any(isinstance(v, bool) or not isinstance(v, int | np.integer) for v in ph):
        raise InputError(f"lenslet_phase_vox must be 2 integers (y, x), got {phase!r}")
    return int(period), (int(ph[0]) % int(period), int(ph[1]) % int(period))
