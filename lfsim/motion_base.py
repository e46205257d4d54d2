"""Base of the prescribed motions (:mod:`lfsim.motion`): the :class:`Motion` interface, the
per-frame amplitude schedule and the checks of points, frames and parameters they share."""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

from hrvbase.validate import points_xyz

from .errors import ConfigError


def _vec3(name: str, value) -> tuple[float, float, float]:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be three numbers (x, y, z), got {value!r}") from exc
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} must be three finite numbers (x, y, z), got {value!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _check_points(X) -> np.ndarray:
    return points_xyz(X, "reference positions X_um", error=ConfigError)


def _check_frame(frame) -> float | int:
    if isinstance(frame, bool) or not isinstance(frame, numbers.Real):
        raise ConfigError(f"frame must be a number, got {frame!r}")
    if not math.isfinite(frame):
        raise ConfigError(f"frame must be finite, got {frame!r}")
    return frame


def _cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90°."""
    r = math.fmod(angle_deg, 360.0)
    if r % 90.0 == 0.0:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(r // 90.0) % 4]
    a = math.radians(angle_deg)
    return math.cos(a), math.sin(a)


def rotation_matrix(axis, angle_deg: float) -> np.ndarray:
    """Right-handed rotation by ``angle_deg`` about ``axis`` (Rodrigues' formula).

    Parameters
    ----------
    axis : array_like, shape (3,)
        Rotation axis (any non-zero length).
    angle_deg : float
        Angle in degrees; positive is counter-clockwise looking down the axis towards the
        origin (e.g. +90° about z maps x̂ to ŷ).

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        ``R = I + sin θ K + (1 − cos θ) K²`` with ``K`` the cross-product matrix of the unit
        axis.
    """
    k = np.asarray(_vec3("axis", axis))
    norm = float(np.linalg.norm(k))
    if norm == 0.0:
        raise ConfigError("axis must be a non-zero vector")
    k = k / norm
    c, s = _cos_sin_deg(float(angle_deg))
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


class Motion:
    """A prescribed motion: reference positions ``X`` (N, 3) µm and a frame → positions."""

    type_name: ClassVar[str] = ""
    homogeneous: ClassVar[bool] = False

    def displacement(self, X_um, frame) -> np.ndarray:
        """Displacement ``u = x − X`` at a frame.

        Parameters
        ----------
        X_um : array_like, shape (N, 3)
            Reference positions in µm.
        frame : int
            Frame index (0 = reference).

        Returns
        -------
        numpy.ndarray, shape (N, 3)
            Displacements in µm.
        """
        X = _check_points(X_um)
        return self.positions(X, frame) - X

    def positions(self, X_um, frame) -> np.ndarray:  # pragma: no cover - abstract
        """Current positions ``x`` (N, 3) µm of reference positions ``X_um`` at a frame."""
        raise NotImplementedError

    def __call__(self, X_um, frame) -> np.ndarray:
        """Same as :meth:`positions`."""
        return self.positions(X_um, frame)

    def deformation_gradient(self, frame) -> np.ndarray:  # pragma: no cover - abstract
        """Deformation gradient ``F`` (3, 3) at a frame (homogeneous motions only)."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        """Plain-JSON representation, the inverse of :func:`~lfsim.motion.motion_from_dict`."""
        out: dict[str, Any] = {"type": self.type_name}
        for f in fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if v is None:
                continue
            if isinstance(v, tuple):
                v = [list(e) if isinstance(e, tuple) else e for e in v]
            elif isinstance(v, Mapping):
                v = dict(v)
            out[f.name] = v
        return out


@dataclass(frozen=True)
class _Scheduled(Motion):
    """A motion scaled by one amplitude per frame: ``k · step`` or ``values[k]``.

    Subclasses name their step field in ``_step_name``; exactly one of it and ``values`` must
    be given.
    """

    values: tuple | None = field(default=None, kw_only=True)

    _step_name: ClassVar[str] = ""
    _vector_amplitude: ClassVar[bool] = False

    def __post_init__(self) -> None:
        step = getattr(self, self._step_name)
        if (step is None) == (self.values is None):
            raise ConfigError(
                f"{self.type_name} needs exactly one of '{self._step_name}' (amplitude per frame) "
                "and 'values' (explicit amplitude of every frame)"
            )
        if step is not None:
            object.__setattr__(self, self._step_name, self._amplitude_value(self._step_name, step))
        else:
            vals = self.values
            if isinstance(vals, str | bytes) or not hasattr(vals, "__len__") or len(vals) == 0:
                raise ConfigError(
                    f"{self.type_name} 'values' must be a non-empty list of per-frame amplitudes, "
                    f"got {vals!r}"
                )
            checked = tuple(
                self._amplitude_value(f"values[{i}]", v) for i, v in enumerate(list(vals))
            )
            object.__setattr__(self, "values", checked)

    def _amplitude_value(self, name: str, v):
        if self._vector_amplitude:
            return _vec3(f"{self.type_name} {name}", v)
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ConfigError(f"{self.type_name} {name} must be a finite number, got {v!r}")
        return float(v)

    @property
    def n_frames(self) -> int | None:
        """Number of frames of an explicit schedule (``None`` for a linear one)."""
        return None if self.values is None else len(self.values)

    def amplitude(self, frame):
        """Amplitude at a frame: ``frame · step``, or ``values[frame]`` for a schedule.

        Parameters
        ----------
        frame : int (or float for a linear schedule)
            Frame index.

        Returns
        -------
        float, or numpy.ndarray of shape (3,) for :class:`~lfsim.motion.Translation`
        """
        frame = _check_frame(frame)
        if self.values is None:
            step = getattr(self, self._step_name)
            return frame * np.asarray(step) if self._vector_amplitude else frame * step
        if frame != int(frame) or not (0 <= frame < len(self.values)):
            raise ConfigError(
                f"{self.type_name}: frame {frame!r} is outside its 'values' schedule of "
                f"{len(self.values)} frames (0 .. {len(self.values) - 1})"
            )
        a = self.values[int(frame)]
        return np.asarray(a) if self._vector_amplitude else a


def _positive(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number, got {value!r}")
    if not value > 0:
        raise ConfigError(f"{where} must be > 0, got {value!r}")
    return float(value)


def _finite(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ConfigError(f"{where} must be a finite number, got {value!r}")
    return float(value)
