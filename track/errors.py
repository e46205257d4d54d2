"""Exception types raised by :mod:`track`.

Every error a user can provoke with bad input is one of these, and its message names the
file, parameter or frame at fault and what was expected. The ``track`` command line turns
them into ``track: error: <message>`` and exit status 2 (3 for
:class:`FailedFramesError`).
"""

from __future__ import annotations

from hrvbase import errors as base


class TrackError(base.HrvError):
    """Base class of every error :mod:`track` raises on purpose."""


class InputError(TrackError, base.InputError):
    """An argument, array or file holds a missing, unknown or invalid value."""


class TrackingError(TrackError):
    """Particles cannot be tracked (too few particles, no consistent matches...)."""


class FailedFramesError(TrackingError):
    """A run finished but frames or pairs failed, and partial results were not allowed.

    Everything that worked was written (the results folder's ``summary.json`` has status
    ``"failed"``). The ``track`` command line exits with status 3 on it.

    Attributes
    ----------
    failures : tuple of str
        One message per failed frame or pair.
    result : track.pipeline.TrackResult or None
        What was computed and written.
    """

    def __init__(self, message: str, failures=(), result=None) -> None:
        super().__init__(message)
        self.failures = tuple(failures)
        self.result = result
