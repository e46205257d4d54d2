"""Exception types raised by :mod:`recon`.

Every error a user can provoke with bad input is one of these, and its message names the file,
key or parameter at fault and what was expected. The command line turns them into
``recon: error: <message>`` and exit status 2.
"""

from __future__ import annotations

from hrvbase import errors as base


class ReconError(base.HrvError):
    """Base class of every error :mod:`recon` raises on purpose."""


class CalibrationError(ReconError, ValueError):
    """The lenslet grid cannot be found or fitted in a white image (no grid, too few lenslets,
    inconsistent lenslet positions...)."""


class InputError(ReconError, base.InputError):
    """An argument, array or file holds a missing, unknown or invalid value (non-finite pixels,
    wrong dimensionality, a malformed calibration file...)."""


def recon_input_errors():
    """Raise the shared validators' :class:`hrvbase.errors.InputError` as recon's own
    :class:`InputError` inside the block (:func:`hrvbase.errors.raised_as`)."""
    return base.raised_as(InputError)
