"""Compute threads of one process: the cores it may use and ``HRVPTM_THREADS``.

Every package sizes its thread pools (the Dr.Jit backend, the CPU projector, the detection's
filters and FFTs) from the same two numbers, so that a Dask worker of
:mod:`hrvbase.parallel`, which gets its share of the cores through ``HRVPTM_THREADS``, never
oversubscribes its machine.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

from .errors import InputError

#: Environment variable that caps the compute threads of a process.
THREADS_ENV = "HRVPTM_THREADS"


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def env_threads() -> int | None:
    """``HRVPTM_THREADS`` as an integer, or ``None`` when it is unset or empty.

    Raises
    ------
    InputError
        It is set to anything but an integer >= 1.
    """
    env = os.environ.get(THREADS_ENV, "").strip()
    if not env:
        return None
    try:
        n = int(env)
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(f"environment variable {THREADS_ENV} must be an integer >= 1, got {env!r}")
    return n


def compute_threads() -> int:
    """Threads for one frame's computation: ``HRVPTM_THREADS`` if set, else
    :func:`available_cores`."""
    n = env_threads()
    return available_cores() if n is None else n


#: Depth of :func:`one_blas_thread` blocks on each thread.
_blas_limited = threading.local()


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every loaded BLAS (numpy's and SciPy's OpenBLAS, MKL …) on one thread.

    OpenBLAS's products and eigen-decompositions round differently with other thread counts,
    so a result that must not depend on the process it was computed in (a Dask worker, whose
    nanny sets ``OPENBLAS_NUM_THREADS=1``, or this one) is computed on one BLAS thread. Uses
    `threadpoolctl <https://github.com/joblib/threadpoolctl>`_; the limits are set back after.
    Only the libraries loaded when the block starts are limited: a caller that uses SciPy's
    linear algebra imports it first (``track.increments`` does). A block nested in another on
    the same thread changes nothing (the outer one has limited them; finding the loaded
    libraries again takes milliseconds).
    """
    depth = getattr(_blas_limited, "depth", 0)
    if depth:
        _blas_limited.depth = depth + 1
        try:
            yield
        finally:
            _blas_limited.depth = depth
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        _blas_limited.depth = 1
        try:
            yield
        finally:
            _blas_limited.depth = 0


#: glibc ``mallopt`` parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


@contextlib.contextmanager
def heap_kept() -> Iterator[None]:
    """Run the block with glibc's heap kept between the block's temporaries (Linux only).

    A Dask worker's nanny starts it with ``MALLOC_TRIM_THRESHOLD_=65536``: every freed
    temporary above 128 kB goes back to the system and the next one is faulted in again, page
    by page, which made an increment's fit and grid (:mod:`track.series`) 2.3 times as slow
    as in the main process (measured). Outside such a process this does nothing; inside, the
    process's own settings are set back afterwards.
    """
    import ctypes

    libc = None
    if sys.platform.startswith("linux") and os.environ.get("MALLOC_TRIM_THRESHOLD_"):
        try:
            libc = ctypes.CDLL("libc.so.6")
            libc.mallopt(_M_TRIM_THRESHOLD, 256 << 20)
            libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20)
        except (OSError, AttributeError):
            libc = None
    try:
        yield
    finally:
        if libc is not None:
            libc.mallopt(_M_TRIM_THRESHOLD, int(os.environ["MALLOC_TRIM_THRESHOLD_"]))
            libc.mallopt(_M_MMAP_THRESHOLD, 128 << 10)
            libc.malloc_trim(0)


__all__ = [
    "THREADS_ENV",
    "available_cores",
    "compute_threads",
    "env_threads",
    "heap_kept",
    "one_blas_thread",
]
