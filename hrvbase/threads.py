"""Compute threads of one process: the cores it may use and ``HRVPTM_THREADS``.

Every package sizes its thread pools (the Dr.Jit backend, the CPU projector, the detection's
filters and FFTs) from the same two numbers, so that a Dask worker of
:mod:`hrvbase.parallel`, which gets its share of the cores through ``HRVPTM_THREADS``, never
oversubscribes its machine.
"""

from __future__ import annotations

import os

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


__all__ = ["THREADS_ENV", "available_cores", "compute_threads", "env_threads"]
