"""Exception types shared by every package of the toolkit.

Each package derives its own errors from :class:`HrvError`, so that every command line turns
any error a user can cause into one line ``PROG: error: <message>`` and exit status 2
(:func:`hrvbase.cli.run_main`). Messages name the file, key or parameter at fault and what was
expected.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


class HrvError(Exception):
    """Base class of every error the toolkit raises on purpose."""


class InputError(HrvError, ValueError):
    """An argument, array or file holds a missing, unknown or invalid value."""


class OutputError(HrvError, OSError):
    """An output cannot be written, or writing it would overwrite or lose the user's data."""


@contextlib.contextmanager
def raised_as(error: type[InputError]) -> Iterator[None]:
    """Inside the block, the shared validators' :class:`InputError` is raised as ``error``, a
    package's own subclass, with the same message (so a package's callers catch one type)."""
    try:
        yield
    except InputError as exc:
        if isinstance(exc, error):
            raise
        raise error(str(exc)) from None


__all__ = ["HrvError", "InputError", "OutputError", "raised_as"]
