"""Compute threads of the detection stage, and separable filters split over them.

A frame uses :func:`compute_threads` threads: ``HRVPTM_THREADS`` when set (a Dask worker of
:mod:`hrvbase.parallel` gets its share of the cores there), else every core this process may
run on. The FFTs of the secondary deconvolution (:mod:`track.deconvolve`) and the separable
filters below use them; the results do not depend on the count.

The filters apply :func:`scipy.ndimage.gaussian_filter1d` / ``maximum_filter1d`` one axis at
a time, as :func:`scipy.ndimage.gaussian_filter` and ``maximum_filter`` do, each pass on
slabs cut along another axis, one per thread (SciPy releases the GIL while filtering). Every
1-D line is filtered exactly as in one call, so the result is identical, bit for bit.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy import ndimage

from hrvbase.errors import raised_as
from hrvbase.threads import compute_threads as _compute_threads

from .errors import InputError


def compute_threads() -> int:
    """Threads for one frame's computation: ``HRVPTM_THREADS`` if set, else the cores this
    process may run on (:func:`hrvbase.threads.compute_threads`).

    Raises
    ------
    InputError
        ``HRVPTM_THREADS`` is not an integer >= 1.
    """
    with raised_as(InputError):
        return _compute_threads()


#: Slabs thinner than this (voxels along the split axis) are not worth a thread.
_MIN_SLAB = 4


def _split_axis(shape: tuple[int, ...], axis: int) -> int:
    """The longest axis other than ``axis``."""
    others = [a for a in range(len(shape)) if a != axis]
    return max(others, key=lambda a: shape[a])


def _by_slabs(pool, func, src: np.ndarray, dst: np.ndarray, axis: int, threads: int) -> None:
    """``dst = func(src)`` for a 1-D filter along ``axis``, on slabs along another axis."""
    split = _split_axis(src.shape, axis)
    n = src.shape[split]
    parts = min(threads, max(1, n // _MIN_SLAB))
    if pool is None or parts < 2:
        func(src, dst)
        return
    bounds = np.linspace(0, n, parts + 1).astype(int)

    def run(k: int) -> None:
        sl = [slice(None)] * src.ndim
        sl[split] = slice(bounds[k], bounds[k + 1])
        sl = tuple(sl)
        func(src[sl], dst[sl])

    for f in [pool.submit(run, k) for k in range(parts)]:
        f.result()


def _separable(img, passes, threads):
    """Apply ``passes`` (``(axis, func(src, dst))`` in order) like SciPy's separable filters:
    the first pass reads ``img``, each writes an array of ``img``'s dtype."""
    threads = compute_threads() if threads is None else int(threads)
    out = np.empty_like(img)
    if not passes:
        out[...] = img
        return out
    src = img
    with ThreadPoolExecutor(threads) if threads > 1 else _NoPool() as pool:
        for axis, func in passes:
            _by_slabs(pool, func, src, out, axis, threads)
            src = out
    return out


class _NoPool:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def gaussian_filter(
    img: np.ndarray, sigma, *, mode: str = "reflect", threads: int | None = None
) -> np.ndarray:
    """:func:`scipy.ndimage.gaussian_filter` of ``img`` (same dtype, identical values) on
    ``threads`` threads (default :func:`compute_threads`)."""
    img = np.asarray(img)
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), (img.ndim,))
    passes = []
    for axis, s in enumerate(sig):
        if s > 1e-15:  # as scipy: a zero σ leaves the axis alone

            def func(src, dst, axis=axis, s=float(s)):
                ndimage.gaussian_filter1d(src, s, axis=axis, mode=mode, output=dst)

            passes.append((axis, func))
    return _separable(img, passes, threads)


def maximum_filter3(
    img: np.ndarray, *, mode: str = "reflect", threads: int | None = None
) -> np.ndarray:
    """:func:`scipy.ndimage.maximum_filter` of ``img`` with ``size=3`` (same dtype, identical
    values) on ``threads`` threads (default :func:`compute_threads`)."""
    img = np.asarray(img)
    passes = []
    for axis in range(img.ndim):

        def func(src, dst, axis=axis):
            ndimage.maximum_filter1d(src, 3, axis=axis, output=dst, mode=mode)

        passes.append((axis, func))
    return _separable(img, passes, threads)
