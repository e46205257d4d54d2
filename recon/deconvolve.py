"""Richardson–Lucy light-field deconvolution on Dr.Jit (paper §2.1, §3.2).

The multiplicative update of Richardson (1972) and Lucy (1974) for Poisson data ``y ≈ H x``,

``x ← x · Hᵀ(y / H x) / Hᵀ 1``,

keeps ``x`` non-negative and, without further filtering, decreases the Kullback–Leibler
divergence ``KL(y ‖ H x) = Σ y log(y / H x) − y + H x`` at every iteration (it is an EM
algorithm). Pixels where ``H x`` is (numerically) zero contribute nothing instead of blowing
up, and voxels no pixel sees (``Hᵀ 1 = 0``) stay zero. After each update the depth-adaptive
anti-aliasing filter of Stefanoiu et al. (2019) may be applied (:mod:`recon.filters`).

Everything runs in the projector's array world (``projector.arrays``, :mod:`recon.arrays`):
numpy with the scipy.sparse projector on the CPU, Dr.Jit with the gather projector (CUDA on a
GPU). The image enters that world once and the volume leaves it once; projections, update,
filter and bookkeeping in between stay there.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from .arrays import NUMPY
from .errors import InputError

log = logging.getLogger(__name__)


@dataclass
class RLResult:
    """Outcome of :func:`richardson_lucy`.

    Attributes
    ----------
    volume : ndarray, shape (nz, ny, nx), float32
    iterations : int
        Iterations done.
    kl : list of float
        KL divergence of the data from the model before each update and after the last one.
    rel_change : list of float
        ``‖x_k+1 − x_k‖₁ / ‖x_k‖₁`` per iteration.
    seconds : list of float
        Wall time per iteration.
    """

    volume: np.ndarray
    iterations: int
    kl: list = field(default_factory=list)
    rel_change: list = field(default_factory=list)
    seconds: list = field(default_factory=list)


def kl_divergence(y: np.ndarray, model: np.ndarray) -> float:
    """``Σ y log(y / m) − y + m`` over pixels (0 log 0 = 0; m = 0 with y > 0 gives inf)."""
    return NUMPY.kl(y, model)


def richardson_lucy(
    image: np.ndarray,
    projector,
    iterations: int,
    *,
    depth_filter=None,
    x0: np.ndarray | None = None,
    stop_rel_change: float | None = None,
    track_kl: bool = True,
    callback=None,
    background: float = 0.0,
) -> RLResult:
    """Reconstruct a volume from a rectified light-field image.

    Parameters
    ----------
    image : ndarray, shape (ny·n, nx·n)
        Rectified, non-negative image (photons or DN): either background-subtracted
        (``background = 0``) or raw with its background level given in ``background``.
    projector : recon.projector.LightFieldProjector or recon.projector.SparseProjector
        Its array world (``projector.arrays``) is where the iterations compute.
    iterations : int
        Maximum number of updates (paper: 3).
    depth_filter : recon.filters.DepthFilter, optional
        Anti-aliasing filter applied after every update.
    x0 : ndarray, shape (nz, ny·s, nx·s), optional
        Start; default a constant volume with the image's total flux.
    stop_rel_change : float, optional
        Stop when the relative L1 change of the volume falls below this.
    track_kl : bool
        Compute the KL divergence each iteration (one extra forward projection at the end).
    callback : callable(iteration, volume), optional
        Called after every update with the volume as a numpy array (a copy out of the
        projector's world each iteration: for monitoring, not for speed).
    background : float
        Constant background ``b`` per rectified pixel in the forward model ``y ≈ H x + b``
        (Poisson RL with a known background). Passing the raw image with its black level
        here, instead of subtracting it and clipping the noise at zero, avoids the positive
        bias of clipped noise (≈ 0.4 σ per pixel) that RL would otherwise explain as a glow
        of emitters spread over the depths whose patterns are the flattest.

    Returns
    -------
    RLResult
    """
    y = np.asarray(image, dtype=np.float32)
    if y.shape != projector.image_shape:
        raise InputError(
            f"image shape {y.shape} does not match the projector's {projector.image_shape} "
            "(is the image rectified with the same calibration?)"
        )
    if not np.all(np.isfinite(y)):
        raise InputError("image holds non-finite pixels (NaN or inf)")
    if y.min() < 0:
        raise InputError("image must be non-negative (subtract the background first)")
    if not isinstance(background, int | float | np.floating) or not np.isfinite(background):
        raise InputError(f"background must be a finite number >= 0, got {background!r}")
    if background < 0:
        raise InputError(f"background must be a finite number >= 0, got {background!r}")
    b = float(background)
    if int(iterations) != iterations or iterations < 0:
        raise InputError(f"iterations must be a non-negative integer, got {iterations!r}")
    if x0 is not None and np.shape(x0) != projector.volume_shape:
        raise InputError(f"x0 shape {np.shape(x0)} != {projector.volume_shape}")
    xp = projector.arrays  # every array below lives in the projector's world
    filt = None
    if depth_filter is not None and depth_filter.active:
        filt = depth_filter.channel_filter(projector)
    yd = xp.from_numpy(projector.image_to_polyphase(y))
    ht1 = projector.backward_flat(xp.full(1.0, projector.n_res * projector.nx * projector.ny))
    xp.eval(ht1)
    inv_ht1 = xp.reciprocal_or_zero(ht1)
    if x0 is None:
        total = max(float(y.sum()) - b * y.size, 1e-6 * float(y.sum()))
        # Constant start whose forward projection has the image's total flux.
        x = xp.where_positive(ht1, total / max(xp.sum(ht1), 1e-30))
    else:
        x = xp.from_numpy(projector.volume_to_channels(x0))
    xp.eval(x)
    tiny = 1e-12 * max(float(y.max()), 1e-30)
    if b > 0:
        tiny = 0.0  # the background keeps the model positive everywhere
    result = RLResult(volume=np.empty(0, np.float32), iterations=0)
    for it in range(int(iterations)):
        t0 = time.perf_counter()
        hx = projector.forward_flat(x)
        if b > 0:
            hx = xp.add_scalar(hx, b)
        xp.eval(hx)
        if track_kl:
            result.kl.append(xp.kl(yd, hx))
        ratio = xp.ratio(yd, hx, tiny)
        new = xp.multiply(x, projector.backward_flat(ratio), inv_ht1)
        xp.eval(new)
        if filt is not None:
            new = filt(new)
        change, norm = xp.l1_change(new, x)
        rel = change / norm if norm > 0 else 0.0
        x = new
        result.rel_change.append(rel)
        result.seconds.append(time.perf_counter() - t0)
        result.iterations = it + 1
        log.info("RL iteration %d: relative change %.3g (%.2f s)", it + 1, rel, result.seconds[-1])
        if callback is not None:
            callback(it + 1, projector.channels_to_volume(xp.to_numpy(x)))
        if stop_rel_change is not None and rel < stop_rel_change:
            break
    if track_kl:
        hx = projector.forward_flat(x)
        if b > 0:
            hx = xp.add_scalar(hx, b)
        xp.eval(hx)
        result.kl.append(xp.kl(yd, hx))
    result.volume = projector.channels_to_volume(xp.to_numpy(x))
    return result
