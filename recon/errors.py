"""Exception types raised by :mod:`recon`.

Every error a user can provoke with bad input is one of these, and its message names the file,
key or parameter at fault and what was expected. The command line turns them into
``recon: error: <message>`` and exit status 2.
"""

from __future__ import annotations

from contextlib import contextmanager

from hrvbase import errors as base


class ReconError(base.HrvError):
    """Base class of every error :mod:`recon` raises on purpose."""


class CalibrationError(ReconError, ValueError):
    """The lenslet grid cannot be found or fitted in a white image (no grid, too few lenslets,
    inconsistent lenslet positions...)."""


class InputError(ReconError, base.InputError):
    """An argument, array or file holds a missing, unknown or invalid value (non-finite pixels,
    wrong dimensionality, a malformed calibration file...)."""


@contextmanager
def recon_input_errors():
    """Raise the shared validators' :class:`hrvbase.errors.InputError` as recon's own.

    :mod:`hrvbase.validate` raises the base class; inside ``with recon_input_errors():`` it
    becomes :class:`InputError` with the same message, so that recon's callers catch one type.
    """
    try:
        yield
    except base.InputError as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(str(exc)) from None
