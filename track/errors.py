"""Exception types raised by :mod:`track`.

Every error a user can provoke with bad input is one of these, and its message names the
file, parameter or frame at fault and what was expected. The ``track`` command line turns
them into ``track: error: <message>`` and exit status 2.
"""

from __future__ import annotations

from hrvbase import errors as base


class TrackError(base.HrvError):
    """Base class of every error :mod:`track` raises on purpose."""


class InputError(TrackError, base.InputError):
    """An argument, array or file holds a missing, unknown or invalid value."""


class TrackingError(TrackError):
    """Particles cannot be tracked (too few particles, no consistent matches...)."""
