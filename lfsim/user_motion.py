"""User-defined motions: :class:`UserField` wraps a displacement function ``f(X_um, frame,
**params)`` given as a callable or as ``"module:function"`` / ``"path/file.py:function"``."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import logging
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .errors import ConfigError, LfsimError
from .motion_base import Motion, _check_frame, _check_points

log = logging.getLogger(__name__)


def _split_spec(spec: str) -> tuple[str, str]:
    if not isinstance(spec, str) or ":" not in spec:
        raise ConfigError(
            f"user_field function must be 'module:function' or 'path/to/file.py:function', "
            f"got {spec!r}"
        )
    module, _, name = spec.rpartition(":")
    if not module or not name.isidentifier():
        raise ConfigError(
            f"user_field function must be 'module:function' or 'path/to/file.py:function', "
            f"got {spec!r}"
        )
    return module, name


def _is_path(module: str) -> bool:
    return module.endswith(".py") or "/" in module or os.sep in module


def _load_function(spec: str) -> Callable:
    module, name = _split_spec(spec)
    if _is_path(module):
        path = Path(module)
        if not path.is_file():
            raise ConfigError(f"user_field {spec!r}: the file {path} does not exist")
        digest = hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
        mod_name = f"_lfsim_user_field_{path.stem}_{digest}"
        mspec = importlib.util.spec_from_file_location(mod_name, path)
        if mspec is None or mspec.loader is None:
            raise ConfigError(f"user_field {spec!r}: cannot import {path} as a Python module")
        mod = importlib.util.module_from_spec(mspec)
        sys.modules[mod_name] = mod
        try:
            mspec.loader.exec_module(mod)
        except Exception as exc:
            sys.modules.pop(mod_name, None)
            raise ConfigError(
                f"user_field {spec!r}: importing {path} failed: {type(exc).__name__}: {exc}"
            ) from exc
    else:
        try:
            mod = importlib.import_module(module)
        except Exception as exc:
            raise ConfigError(
                f"user_field {spec!r}: cannot import module {module!r}: {type(exc).__name__}: {exc}"
            ) from exc
    func = getattr(mod, name, None)
    if func is None:
        raise ConfigError(f"user_field {spec!r}: {module} has no attribute {name!r}")
    if not callable(func):
        raise ConfigError(f"user_field {spec!r}: {module}.{name} is not callable")
    return func


@dataclass(frozen=True)
class UserField(Motion):
    """A displacement field given by a Python function.

    The function is imported on construction and called as
    ``f(X_um, frame, **params) -> u`` with ``X_um`` the reference positions (N, 3) µm (a
    read-only copy), ``frame`` the frame index, and ``u`` the displacement (N, 3) µm.

    Parameters
    ----------
    function : str
        ``"package.module:function"`` (imported from ``sys.path``) or
        ``"path/to/file.py:function"`` (a file path; relative paths are relative to the current
        folder, or to the experiment file's folder through :func:`~lfsim.motion.motion_from_dict`).
    params : Mapping
        Extra keyword arguments for the function.

    Raises
    ------
    ConfigError
        When the function cannot be imported, or (on use) returns something other than a
        finite (N, 3) array; the message names the function.
    """

    function: str
    params: Mapping[str, Any] = field(default_factory=dict)

    type_name: ClassVar[str] = "user_field"

    def __post_init__(self) -> None:
        if not isinstance(self.params, Mapping):
            raise ConfigError(
                f"user_field {self.function!r}: params must be a table/dict, got {self.params!r}"
            )
        object.__setattr__(self, "params", dict(self.params))
        object.__setattr__(self, "_func", _load_function(self.function))

    def displacement(self, X_um, frame) -> np.ndarray:
        """``u = f(X_um, frame, **params)``, shape (N, 3), µm (validated)."""
        X = _check_points(X_um)
        _check_frame(frame)
        arg = X.copy()
        arg.setflags(write=False)
        try:
            u = self._func(arg, frame, **self.params)  # type: ignore[attr-defined]
        except Exception as exc:
            raise LfsimError(
                f"user_field {self.function!r} raised {type(exc).__name__} at frame {frame!r}: "
                f"{exc}"
            ) from exc
        try:
            u = np.asarray(u, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"user_field {self.function!r} must return a numeric (N, 3) displacement array in "
                f"µm, got {type(u).__name__}"
            ) from exc
        if u.shape != X.shape:
            raise ConfigError(
                f"user_field {self.function!r} returned shape {u.shape} at frame {frame!r}; "
                f"expected {X.shape} (one displacement per reference position, µm)"
            )
        if not np.all(np.isfinite(u)):
            raise ConfigError(
                f"user_field {self.function!r} returned non-finite displacements at frame {frame!r}"
            )
        return u

    def positions(self, X_um, frame) -> np.ndarray:
        """``x = X + u`` (N, 3) µm."""
        X = _check_points(X_um)
        return X + self.displacement(X, frame)

    def deformation_gradient(self, frame) -> np.ndarray:
        """Not defined: a user field is not homogeneous."""
        raise LfsimError(
            f"user_field {self.function!r} is not a homogeneous motion; it has no single "
            "deformation gradient"
        )
