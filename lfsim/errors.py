"""Exception types raised by :mod:`lfsim`.

Every error a user can provoke with bad input is one of these, and its message names the file,
key or parameter at fault and what was expected.
"""

from __future__ import annotations


class LfsimError(Exception):
    """Base class of every error :mod:`lfsim` raises on purpose."""


class BackendError(LfsimError):
    """The Dr.Jit/Mitsuba backend cannot be initialised (no libLLVM >= 16, bad variant...)."""


class ConfigError(LfsimError, ValueError):
    """A parameter, scene file or experiment file holds a missing, unknown or invalid value."""


class SceneError(ConfigError):
    """A Mitsuba scene file is missing, malformed, or does not describe a light-field microscope."""


class OutputError(LfsimError, OSError):
    """An output path cannot be written, or writing it would overwrite user data."""
