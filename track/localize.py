"""Sub-voxel particle localisation in 3-D volumes: radial symmetry and weighted centroid.

The main estimator is the 3-D radial-symmetry centre of Liu, Lu, Kner & Yu (Opt. Express 21,
2013), the extension to volumes of Parthasarathy's 2-D method (Nat. Methods 9, 2012). For an
intensity distribution that is point-symmetric about a centre ``c``, the lines through every
sample point along the local intensity gradient pass (on average) through ``c``; the centre is
the point that minimises the weighted sum of squared distances to all those lines, which is a
3 × 3 linear least-squares problem with a closed-form solution:

- gradients ``g_k`` are estimated at the centres of every 2 × 2 × 2 cube of voxels (the
  midpoints between voxel centres) by averaging the four finite differences along each axis,
  optionally smoothed with a 3 × 3 × 3 box filter (as Parthasarathy does in 2-D);
- every line ``k`` passes through the cube centre ``r_k`` with unit direction
  ``m_k = g_k / |g_k|``; the distance of a point ``c`` from it is ``|(I − m_k m_kᵀ)(c − r_k)|``;
- weights ``w_k = |g_k|² / d_k``, with ``d_k`` the distance from ``r_k`` to the
  ``|g|²``-weighted centroid of the cube centres, favour strong gradients near the particle;
- ``c = [Σ w_k (I − m_k m_kᵀ)]⁻¹ Σ w_k (I − m_k m_kᵀ) r_k``.

Positions, gradients and distances are all in physical units (µm) through the voxel size,
so anisotropic voxels (e.g. ``dz = 5 µm``, ``dx = dy = 1.64 µm``) are handled without
distorting the gradient directions. The estimator is exact for any point-symmetric blob
(ellipsoids elongated along ``z`` included: a pair of mirror points contributes the same line
direction), and insensitive to a constant background.

The weighted centroid (background-subtracted first moment) is the fallback used by
:func:`localize` wherever the radial estimate is not finite or leaves its patch.

Uncertainty. Both estimators are smooth functions of the patch's intensities, so for white
voxel noise of standard deviation ``σ_n`` their covariance is, to first order,
``σ_n² J Jᵀ`` with ``J = ∂c/∂I`` the (3 × voxels) Jacobian of the centre. For the radial
fit ``J`` follows from the normal equations ``Σ w_k P_k (c − r_k) = 0`` differentiated
with respect to the gradients (directions ``m_k``, weights ``w_k`` and the weights'
centroid all vary with them) and the gradient operator's adjoint: it is exact to first order
(checked against finite differences) and, on simulated Gaussian blobs with known noise, the
predicted σ matches the RMS error within ≈ 10 % per axis from SNR 50 down to SNR 5
(``tests/track/test_localize.py``). ``σ_n`` is estimated for each particle from the fit's
residual, the patch's departure from point symmetry (:func:`antisymmetric_noise_sigma`).
Correlated noise (a reconstruction's) and systematic errors (the radial fit's own axial
sampling bias, ≈ 0.015 voxel on elongated blobs; a reconstruction's per-particle bias) are
not in this σ: :class:`track.detect.DetectSettings` scales it and adds a calibrated term.

This module also holds the input checks shared by the detection modules of :mod:`track`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from .errors import InputError

log = logging.getLogger(__name__)

METHODS = ("radial", "centroid")


# -- shared input checks ---------------------------------------------------------------------
def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def check_volume(volume: Any, name: str = "volume") -> np.ndarray:
    """Validate a 3-D volume and return it as a float array (no copy when possible).

    Parameters
    ----------
    volume : array_like, shape (nz, ny, nx)
        Intensities; every voxel must be finite.
    name : str
        Parameter name used in error messages.

    Returns
    -------
    ndarray, shape (nz, ny, nx), float32 or float64

    Raises
    ------
    InputError
        If the array is not 3-D, is empty, is not numeric or holds NaN/inf.
    """
    try:
        arr = np.asarray(volume)
    except Exception as exc:  # pragma: no cover - exotic array-likes
        raise InputError(f"{name} must be a 3-D numeric array: {exc}") from None
    if arr.ndim != 3:
        raise InputError(f"{name} must be a 3-D array (z, y, x), got shape {arr.shape}")
    if arr.size == 0:
        raise InputError(f"{name} is empty (shape {arr.shape})")
    if not (
        np.issubdtype(arr.dtype, np.number) and not np.issubdtype(arr.dtype, np.complexfloating)
    ):
        raise InputError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    if arr.dtype not in (np.float32, np.float64):
        arr = arr.astype(np.float32)
    if not np.all(np.isfinite(arr)):
        n_bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        raise InputError(f"{name} holds {n_bad} non-finite voxel(s) (NaN or inf)")
    return arr


def check_triple(value: Any, name: str, *, positive: bool = True, integer: bool = False) -> tuple:
    """Validate three numbers in (z, y, x) order (voxel sizes, half boxes, ...).

    Parameters
    ----------
    value : sequence of 3 numbers, or one number used for all three axes
    name : str
        Parameter name used in error messages.
    positive : bool
        Require every number > 0 (``integer=True``: ≥ 0 is enough when this is False).
    integer : bool
        Require (and return) integers.

    Returns
    -------
    tuple of 3 float or int

    Raises
    ------
    InputError
    """
    items = (value, value, value) if _is_number(value) else value
    try:
        items = tuple(items)
    except TypeError:
        raise InputError(f"{name} must be three numbers (z, y, x), got {value!r}") from None
    if len(items) != 3 or not all(_is_number(v) for v in items):
        raise InputError(f"{name} must be three numbers (z, y, x), got {value!r}")
    if not all(math.isfinite(float(v)) for v in items):
        raise InputError(f"{name} must be finite, got {value!r}")
    if integer:
        if not all(float(v) == int(v) for v in items):
            raise InputError(f"{name} must be three integers (z, y, x), got {value!r}")
        out = tuple(int(v) for v in items)
        low = 1 if positive else 0
        if min(out) < low:
            raise InputError(f"{name} must be integers >= {low}, got {value!r}")
        return out
    out = tuple(float(v) for v in items)
    if positive and min(out) <= 0:
        raise InputError(f"{name} must be > 0 along every axis, got {value!r}")
    return out


def check_voxel_size_um(voxel_size_um: Any) -> tuple[float, float, float]:
    """Validate a voxel size ``(dz, dy, dx)`` in µm (three positive finite numbers)."""
    return check_triple(voxel_size_um, "voxel_size_um")


# -- estimators ------------------------------------------------------------------------------
def _cube_gradients(patch: np.ndarray, spacing: tuple[float, float, float]) -> tuple:
    """Gradients (intensity / µm) at the centres of all 2 × 2 × 2 voxel cubes."""
    p = patch.astype(np.float64, copy=False)

    def avg4(d: np.ndarray, axes: tuple[int, int]) -> np.ndarray:
        a, b = axes
        lo_a = [slice(None)] * 3
        hi_a = [slice(None)] * 3
        lo_a[a], hi_a[a] = slice(None, -1), slice(1, None)
        s = d[tuple(lo_a)] + d[tuple(hi_a)]
        lo_b = [slice(None)] * 3
        hi_b = [slice(None)] * 3
        lo_b[b], hi_b[b] = slice(None, -1), slice(1, None)
        return 0.25 * (s[tuple(lo_b)] + s[tuple(hi_b)])

    gz = avg4(np.diff(p, axis=0), (1, 2)) / spacing[0]
    gy = avg4(np.diff(p, axis=1), (0, 2)) / spacing[1]
    gx = avg4(np.diff(p, axis=2), (0, 1)) / spacing[2]
    return gz, gy, gx


def _gradient_adjoint(h: np.ndarray, axis: int, step: float) -> np.ndarray:
    """Adjoint of one component of :func:`_cube_gradients`: cube values → voxel values."""
    h = 0.25 * h / step
    for a in (a for a in range(3) if a != axis):
        lo, hi = [(0, 0)] * 3, [(0, 0)] * 3
        lo[a], hi[a] = (0, 1), (1, 0)
        h = np.pad(h, lo) + np.pad(h, hi)
    lo, hi = [(0, 0)] * 3, [(0, 0)] * 3
    lo[axis], hi[axis] = (0, 1), (1, 0)
    return np.pad(h, hi) - np.pad(h, lo)


def _radial_fit(p: np.ndarray, spacing: tuple, smooth: bool, jacobian: bool):
    """Centre (µm, patch frame) and, with ``jacobian``, ``∂c/∂I`` (3, voxels) in µm per
    intensity unit; ``(None, None)`` when degenerate."""
    gz, gy, gx = _cube_gradients(p, spacing)
    if smooth:
        gz, gy, gx = (ndimage.uniform_filter(g, size=3, mode="nearest") for g in (gz, gy, gx))
    cube_shape = gz.shape
    g = np.stack([gz.ravel(), gy.ravel(), gx.ravel()], axis=1)  # (K, 3), per µm
    g2 = np.einsum("ki,ki->k", g, g)
    total = float(g2.sum())
    if not total > 0 or not math.isfinite(total):
        return None, None
    nz, ny, nx = cube_shape
    zz, yy, xx = np.meshgrid(
        (np.arange(nz) + 0.5) * spacing[0],
        (np.arange(ny) + 0.5) * spacing[1],
        (np.arange(nx) + 0.5) * spacing[2],
        indexing="ij",
    )
    r = np.stack([zz.ravel(), yy.ravel(), xx.ravel()], axis=1)  # (K, 3), µm
    centroid = (g2[:, None] * r).sum(axis=0) / total
    dist = np.sqrt(np.einsum("ki,ki->k", r - centroid, r - centroid))
    dist = np.maximum(dist, 1e-3 * min(spacing))
    keep = g2 > 0
    gn = np.sqrt(g2)
    m = np.zeros_like(g)
    m[keep] = g[keep] / gn[keep, None]
    w = np.where(keep, g2 / dist, 0.0)
    # A = Σ w (I − m mᵀ), b = Σ w (I − m mᵀ) r
    a_mat = w.sum() * np.eye(3) - np.einsum("k,ki,kj->ij", w, m, m)
    m_dot_r = np.einsum("ki,ki->k", m, r)
    b_vec = (w[:, None] * r).sum(axis=0) - np.einsum("k,k,ki->i", w, m_dot_r, m)
    if not np.all(np.isfinite(a_mat)) or np.linalg.cond(a_mat) > 1e12:
        return None, None
    centre = np.linalg.solve(a_mat, b_vec)
    if not jacobian:
        return centre, None
    # Differentiate Σ w_k P_k d_k = 0 (d_k = c − r_k, P_k = I − m_k m_kᵀ) w.r.t. g_j:
    # dm = P dg/|g|, dw = 2 gᵀdg/dist − (w/dist²) (r − centroid)·d(centroid) ...
    d = centre - r
    md = np.einsum("ki,ki->k", m, d)
    pd = d - md[:, None] * m  # P_k d_k
    proj = np.eye(3)[None] - np.einsum("ki,kj->kij", m, m)
    inv_gn = np.zeros_like(gn)
    inv_gn[keep] = 1.0 / gn[keep]
    t = (w * inv_gn)[:, None, None] * (md[:, None, None] * proj + np.einsum("ki,kj->kij", m, pd))
    t -= (2.0 / dist)[:, None, None] * np.einsum("ki,kj->kij", pd, g)
    rc = r - centroid
    q = np.einsum("k,ki,kj->ij", w / dist**2, pd, rc)
    t -= (2.0 / total) * np.einsum("ij,kj,kl->kil", q, rc, g)
    dc_dg = np.einsum("ij,kjl->kil", np.linalg.inv(a_mat), t)  # (K, 3, 3)
    jac = np.zeros((3, p.size))
    for i in range(3):
        acc = np.zeros(p.shape)
        for j in range(3):
            h = dc_dg[:, i, j].reshape(cube_shape)
            if smooth:  # the box filter is (nearly) self-adjoint
                h = ndimage.uniform_filter(h, size=3, mode="nearest")
            acc += _gradient_adjoint(h, j, spacing[j])
        jac[i] = acc.ravel()
    return centre, jac


def _radial_setup(patch, voxel_size_um, length_scale_um):
    p = check_volume(patch, "patch")
    spacing = check_voxel_size_um(voxel_size_um)
    if length_scale_um is not None:
        scale = check_triple(length_scale_um, "length_scale_um")
        spacing = tuple(d / s for d, s in zip(spacing, scale, strict=True))
    if min(p.shape) < 3:
        raise InputError(f"patch needs at least 3 voxels along every axis, got shape {p.shape}")
    return p.astype(np.float64, copy=False), spacing


def radial_symmetry_3d(
    patch: np.ndarray,
    voxel_size_um: Sequence[float] = (1.0, 1.0, 1.0),
    *,
    smooth: bool = False,
    length_scale_um: Sequence[float] | None = None,
) -> np.ndarray:
    """3-D radial-symmetry centre of a patch (Liu et al. 2013; Parthasarathy 2012).

    Parameters
    ----------
    patch : ndarray, shape (nz, ny, nx)
        Intensities around one particle; every axis needs at least 3 voxels. A constant
        background does not matter.
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` voxel size (µm); the fit is done in physical units.
    smooth : bool
        Smooth the gradient field with a 3 × 3 × 3 box filter before the fit, as
        Parthasarathy (2012) does in 2-D. Off by default: on patches of 2–3 σ it biases the
        lateral estimate (≈ 0.015 voxel at high SNR, from the patch faces) and gains little
        at low SNR.
    length_scale_um : sequence of 3 float, optional
        Per-axis lengths ``(z, y, x)`` (µm) that divide the physical coordinates before the
        fit, e.g. the particle image's σ: the fit then runs in a frame where the particle is
        round. The centre of a point-symmetric blob is the same in any scaled frame, but the
        discrete sampling bias is not: for a blob of σ = (12.5, 2, 2) µm on 5 × 1.64 × 1.64 µm
        voxels the noise-free axial bias drops from ≈ 0.013 to ≈ 0.0001 voxel, while the
        lateral noise grows (≈ 1.5× at SNR 10). Default: None, plain physical units.

    Returns
    -------
    ndarray, shape (3,), float64
        Centre ``(z, y, x)`` in voxel units relative to the patch (voxel ``(0, 0, 0)``'s
        centre is ``(0, 0, 0)``). All NaN when the problem is degenerate (flat patch,
        gradients all parallel).

    Raises
    ------
    InputError
        If ``patch`` is not 3-D with ≥ 3 voxels per axis, or ``voxel_size_um`` is invalid.
    """
    p, spacing = _radial_setup(patch, voxel_size_um, length_scale_um)
    center_xyz_um, _ = _radial_fit(p, spacing, smooth, jacobian=False)
    if center_xyz_um is None:
        return np.full(3, np.nan)
    return center_xyz_um / np.asarray(spacing)


def radial_symmetry_3d_cov(
    patch: np.ndarray,
    voxel_size_um: Sequence[float] = (1.0, 1.0, 1.0),
    noise_sigma: float = 1.0,
    *,
    smooth: bool = False,
    length_scale_um: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`radial_symmetry_3d` with the covariance of the centre for white voxel noise.

    Parameters
    ----------
    patch, voxel_size_um, smooth, length_scale_um
        As in :func:`radial_symmetry_3d`.
    noise_sigma : float
        Standard deviation of the (independent) voxel noise, in intensity units, ≥ 0.

    Returns
    -------
    centre_vox : ndarray, shape (3,)
        ``(z, y, x)`` in voxel units of the patch (NaN when degenerate).
    covariance_vox2 : ndarray, shape (3, 3)
        ``noise_sigma² J Jᵀ`` (voxel², z, y, x order) with ``J`` the first-order derivative
        of the centre with respect to every voxel (module docstring); NaN when degenerate.

    Raises
    ------
    InputError
        As :func:`radial_symmetry_3d`, or a negative or non-finite ``noise_sigma``.
    """
    if not _is_number(noise_sigma) or not math.isfinite(noise_sigma) or noise_sigma < 0:
        raise InputError(f"noise_sigma must be a finite number >= 0, got {noise_sigma!r}")
    p, spacing = _radial_setup(patch, voxel_size_um, length_scale_um)
    center_xyz_um, jac = _radial_fit(p, spacing, smooth, jacobian=True)
    if center_xyz_um is None:
        return np.full(3, np.nan), np.full((3, 3), np.nan)
    sp = np.asarray(spacing)
    jac_vox = jac / sp[:, None]
    return center_xyz_um / sp, float(noise_sigma) ** 2 * (jac_vox @ jac_vox.T)


def _centroid(p: np.ndarray, background: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (voxels) and the variance per unit noise variance of each axis."""
    if background is None:
        shell = np.ones(p.shape, dtype=bool)
        if min(p.shape) > 2:
            shell[1:-1, 1:-1, 1:-1] = False
        background = float(np.median(p[shell]))
    w = np.clip(p - background, 0.0, None)
    total = float(w.sum())
    if not total > 0:
        return np.full(3, np.nan), np.full(3, np.nan)
    out = np.empty(3)
    var = np.empty(3)
    above = w > 0
    for axis in range(3):
        other = tuple(a for a in range(3) if a != axis)
        prof = w.sum(axis=other)
        out[axis] = float(np.dot(prof, np.arange(p.shape[axis]))) / total
        # ∂c/∂I_v = (x_v − c) / W for the voxels above the background
        offset = np.arange(p.shape[axis]) - out[axis]
        n_above = above.sum(axis=other)
        var[axis] = float(np.dot(n_above, offset**2)) / total**2
    return out, var


def weighted_centroid(patch: np.ndarray, background: float | None = None) -> np.ndarray:
    """Intensity-weighted centroid of a patch after background subtraction.

    Parameters
    ----------
    patch : ndarray, shape (nz, ny, nx)
    background : float, optional
        Level subtracted before weighting; values below it get weight 0. Default: the median
        of the patch's outer shell (its six faces), a robust local background.

    Returns
    -------
    ndarray, shape (3,), float64
        Centroid ``(z, y, x)`` in voxel units relative to the patch; NaN when no voxel lies
        above the background.
    """
    p = check_volume(patch, "patch").astype(np.float64, copy=False)
    return _centroid(p, background)[0]


def _shift_noise_gain(offset: float) -> float:
    """Σ w² of the cubic-spline interpolation weights of a shift by ``offset`` voxels: the
    variance factor it applies to white noise."""
    delta = np.zeros(33)
    delta[16] = 1.0
    return float(np.sum(ndimage.shift(delta, offset, order=3, mode="constant") ** 2))


def antisymmetric_noise_sigma(patch: np.ndarray, centre_vox: np.ndarray) -> float:
    """Noise standard deviation of a patch from its departure from point symmetry.

    The radial-symmetry model says ``I(c + r) = I(c − r)``; the patch minus its mirror image
    through the fitted centre ``c`` (cubic-spline resampled) is then noise (and whatever
    asymmetry the particle image has), with variance ``σ² (1 + g)``, ``g`` the spline's
    variance factor. Voxels the mirror maps outside the patch are left out.

    Parameters
    ----------
    patch : ndarray, shape (nz, ny, nx)
    centre_vox : ndarray, shape (3,)
        Centre ``(z, y, x)`` in voxel units of the patch.

    Returns
    -------
    float
        ≥ 0; NaN when no voxel is left.
    """
    p = check_volume(patch, "patch").astype(np.float64, copy=False)
    shape = np.asarray(p.shape)
    d = (shape - 1) - 2.0 * np.asarray(centre_vox, float)  # mirror(x) = flip(x + d)
    mirror = ndimage.shift(p[::-1, ::-1, ::-1], -d, order=3, mode="nearest")
    margin = np.ceil(np.abs(d)).astype(int) + 1
    if np.any(shape - 2 * margin < 1):
        return math.nan
    inner = tuple(slice(m, n - m) for m, n in zip(margin, shape, strict=True))
    resid = (p - mirror)[inner]
    gain = math.prod(_shift_noise_gain(-v) for v in d)
    return float(np.sqrt(np.mean(resid**2) / (1.0 + gain)))


def estimate_noise_sigma(volume: np.ndarray) -> float:
    """Robust standard deviation of a volume's voxel noise.

    ``1.4826 · MAD / √2`` of the differences between neighbours along x (the fastest
    axis): for white noise of standard deviation σ such a difference has standard deviation
    ``√2 σ``, and the median ignores the few differences that cross a particle.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)

    Returns
    -------
    float
        ≥ 0 (0 for a noise-free or constant background).
    """
    vol = check_volume(volume)
    if vol.shape[2] < 2:
        return 0.0
    diff = np.diff(vol, axis=2).astype(np.float64, copy=False).ravel()
    mad = float(np.median(np.abs(diff - np.median(diff))))
    return 1.4826 * mad / math.sqrt(2.0)


# -- many particles --------------------------------------------------------------------------
@dataclass(frozen=True)
class Localization:
    """Result of :func:`localize`; unpacks as ``positions_vox, ok = localize(...)``.

    Attributes
    ----------
    positions_vox : ndarray, shape (N, 3), float64
        Sub-voxel positions ``(z, y, x)`` in voxel units of the volume (NaN where ``ok`` is
        False).
    ok : ndarray, shape (N,), bool
        A finite position inside the volume was found (by the requested method or by the
        centroid fallback).
    fallback : ndarray, shape (N,), bool
        The requested radial estimate failed and the centroid was used instead.
    sigma_vox : ndarray, shape (N, 3), float64
        Standard uncertainty of each position ``(z, y, x)`` (voxel units) from the volume's
        voxel noise (module docstring); NaN where ``ok`` is False.
    noise_sigma : ndarray, shape (N,)
        The voxel noise standard deviation used for each particle (intensity units).
    """

    positions_vox: np.ndarray
    ok: np.ndarray
    fallback: np.ndarray
    sigma_vox: np.ndarray | None = None
    noise_sigma: np.ndarray | None = None

    def __iter__(self) -> Iterator[np.ndarray]:
        yield self.positions_vox
        yield self.ok


def localize(
    volume: np.ndarray,
    seeds_vox: np.ndarray,
    voxel_size_um: Sequence[float],
    half_box_vox: Sequence[int],
    method: str = "radial",
    noise_sigma: float | None = None,
) -> Localization:
    """Refine integer seed positions to sub-voxel particle centres.

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
        Intensities.
    seeds_vox : array_like, shape (N, 3)
        Seed positions ``(z, y, x)`` in voxels (rounded to the nearest voxel; e.g. blob
        centroids).
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` (µm).
    half_box_vox : sequence of 3 int
        Patch half-size ``(hz, hy, hx)`` in voxels: the patch is ``2 h + 1`` voxels per axis
        (cut at the volume's faces), each ≥ 1. Cover about 2–3 σ of the particle image
        (:func:`track.detect.detect_particles` sizes it from the blobs, ``DetectSettings.
        half_box_vox``).
    method : {"radial", "centroid"}
        ``"radial"``: :func:`radial_symmetry_3d`, falling back to :func:`weighted_centroid`
        where it is not finite or lies outside the patch; ``"centroid"``: the centroid only.
    noise_sigma : float, optional
        Voxel noise standard deviation (intensity units, ≥ 0) for the uncertainties; default:
        each particle's own, :func:`antisymmetric_noise_sigma` of its patch (the departure
        from the point symmetry the radial fit assumes: the fit's residual).

    Returns
    -------
    Localization
        Positions and their standard uncertainties (voxel units of ``volume``), success and
        fallback masks.

    Raises
    ------
    InputError
        For a bad volume, seed table, voxel size, half box or method.
    """
    vol = check_volume(volume)
    spacing = check_voxel_size_um(voxel_size_um)
    half = check_triple(half_box_vox, "half_box_vox", integer=True)
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}, got {method!r}")
    seeds = np.asarray(seeds_vox, dtype=np.float64)
    if seeds.size == 0:
        seeds = seeds.reshape(0, 3)
    if seeds.ndim != 2 or seeds.shape[1] != 3:
        raise InputError(f"seeds_vox must have shape (N, 3) in (z, y, x), got {seeds.shape}")
    if not np.all(np.isfinite(seeds)):
        raise InputError("seeds_vox holds non-finite positions")
    if noise_sigma is not None and (
        not _is_number(noise_sigma) or not math.isfinite(noise_sigma) or noise_sigma < 0
    ):
        raise InputError(f"noise_sigma must be a finite number >= 0, got {noise_sigma!r}")
    n = seeds.shape[0]
    pos = np.full((n, 3), np.nan)
    sig = np.full((n, 3), np.nan)
    noise = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    fallback = np.zeros(n, dtype=bool)
    shape = np.asarray(vol.shape)
    for i, seed in enumerate(np.rint(seeds).astype(np.int64)):
        if np.any(seed < 0) or np.any(seed >= shape):
            continue
        lo = np.maximum(seed - half, 0)
        hi = np.minimum(seed + np.asarray(half) + 1, shape)
        patch = vol[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        est = np.full(3, np.nan)
        if method == "radial" and min(patch.shape) >= 3:
            est, cov = radial_symmetry_3d_cov(patch, spacing, 1.0)
            var = np.diag(cov)
        inside = np.all(np.isfinite(est)) and np.all(est >= -0.5) and np.all(est <= hi - lo - 0.5)
        if not inside:
            if method == "radial":
                fallback[i] = True
            est, var = _centroid(patch.astype(np.float64, copy=False), None)
        if np.all(np.isfinite(est)):
            sn = noise_sigma
            if sn is None:
                sn = antisymmetric_noise_sigma(patch, est)
                if not math.isfinite(sn):  # patch too small for the mirror test
                    sn = estimate_noise_sigma(patch)
            pos[i] = est + lo
            sig[i] = sn * np.sqrt(np.clip(var, 0.0, None))
            noise[i] = sn
            ok[i] = True
    if fallback.any():
        log.info("localize: %d of %d particles fell back to the centroid", fallback.sum(), n)
    if (~ok).any():
        log.warning("localize: %d of %d seeds could not be localised", (~ok).sum(), n)
    return Localization(
        positions_vox=pos, ok=ok, fallback=fallback, sigma_vox=sig, noise_sigma=noise
    )
