"""Exception types raised by :mod:`lfsim`.

Every error a user can provoke with bad input is one of these, and its message names the file,
key or parameter at fault and what was expected.
"""

from __future__ import annotations

from hrvbase.errors import HrvError, InputError
from hrvbase.errors import OutputError as OutputError


class LfsimError(HrvError):
    """Base class of every error :mod:`lfsim` raises on purpose."""


class BackendError(LfsimError):
    """The Dr.Jit/Mitsuba backend cannot be initialised (no libLLVM >= 16, bad variant...)."""


class ConfigError(LfsimError, InputError):
    """A parameter, scene file or experiment file holds a missing, unknown or invalid value."""


class SceneError(ConfigError):
    """A Mitsuba scene file is missing, malformed, or does not describe a light-field microscope."""


__all__ = ["BackendError", "ConfigError", "LfsimError", "OutputError", "SceneError"]
