"""Prescribed particle motions: reference positions X → current positions x at frame k.

Every motion maps reference positions ``X`` (shape (N, 3), µm, object-space frame of
docs/conventions.md) and a frame index ``k`` to current positions ``x`` (N, 3). The homogeneous
motions follow

    x = c + F(k) (X − c) + t(k),        u = x − X,

with deformation gradient ``F`` (reference configuration, ``F = I + ∇u``), centre ``c``
(``center_xyz_um``) and translation ``t``. Frame 0 is normally the reference configuration.

Schedules. Each homogeneous motion has one scalar (a 3-vector for :class:`Translation`)
*amplitude* per frame, ``amplitude(k) = k · step`` by default. Passing ``values=[a0, a1, ...]``
instead gives an explicit per-frame amplitude ``amplitude(k) = values[k]`` (for example the
lagging, overshooting shear ramp of the paper's Fig. 7); a frame outside ``0 .. len(values)-1``
is then an error. What the amplitude means:

=====================  ===============  =====================================================
motion                 amplitude        deformation
=====================  ===============  =====================================================
``Translation``        ``t`` (µm, 3)    ``F = I``, ``x = X + t``
``Rotation``           angle (deg)      right-handed about ``axis`` through ``center_xyz_um``
``UniaxialTension``    ``λ − 1``        stretch ``λ`` along ``axis``, ``1/√λ`` across (det F = 1)
``SimpleShear``        ``γ``            plane ``"ab"``: ``x_a = X_a + γ (X_b − c_b)``
=====================  ===============  =====================================================

Heterogeneous motions scale a known field (:mod:`hrvbase.known_fields`, the fields that
``track.synthetic`` tests the linker on) by the same kind of per-frame amplitude:

==========================  ===================  ============================================
motion                      amplitude            deformation
==========================  ===================  ============================================
``GaussianIndentation``     depth (µm)           ``u_z = −A exp(−ρ²/2w²) exp(−(s − Z)/D)``
``StiffInclusion``          far-field strain ε   stretch ε along ``axis`` around a rigid sphere
==========================  ===================  ============================================

Their deformation gradient varies in space: ``deformation_gradient_at(X_um, frame)``
(analytic, shape (N, 3, 3)).

:class:`UserField` wraps an arbitrary displacement function ``f(X_um, frame, **params)``.
:func:`motion_from_dict` builds any of them from an experiment file's table.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import ClassVar

import numpy as np

from hrvbase.known_fields import (
    inclusion_displacement,
    inclusion_gradient,
    indentation_displacement,
    indentation_gradient,
)
from hrvbase.validate import renamed_key_message

from .errors import ConfigError, LfsimError
from .motion_base import (
    Motion,
    _check_frame,
    _check_points,
    _finite,
    _positive,
    _Scheduled,
    _vec3,
    rotation_matrix,
)
from .user_motion import UserField, _is_path

log = logging.getLogger(__name__)

_AXES = {"x": 0, "y": 1, "z": 2}


# -- helpers ----------------------------------------------------------------------------------


# -- base classes -----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Homogeneous(_Scheduled):
    """Homogeneous motion ``x = c + F (X − c) + t`` with a per-frame amplitude."""

    homogeneous: ClassVar[bool] = True

    @property
    def center(self) -> np.ndarray:
        """Centre ``c`` (3,) µm of the deformation."""
        return np.asarray(getattr(self, "center_xyz_um", (0.0, 0.0, 0.0)), dtype=np.float64)

    def translation(self, frame) -> np.ndarray:
        """Rigid translation ``t`` (3,) µm at a frame (zero except for :class:`Translation`)."""
        _check_frame(frame)
        return np.zeros(3)

    def positions(self, X_um, frame) -> np.ndarray:
        """Current positions ``x = c + F(k) (X − c) + t(k)``.

        Parameters
        ----------
        X_um : array_like, shape (N, 3)
            Reference positions in µm.
        frame : int
            Frame index.

        Returns
        -------
        numpy.ndarray, shape (N, 3)
            Current positions in µm.
        """
        X = _check_points(X_um)
        F = self.deformation_gradient(frame)
        c = self.center
        return c + (X - c) @ F.T + self.translation(frame)


# -- homogeneous motions --------------------------------------------------------------------
@dataclass(frozen=True)
class Translation(_Homogeneous):
    """Rigid translation ``x = X + t``, ``t(k) = k · step_um`` (or ``values[k]``).

    Parameters
    ----------
    step_um : array_like, shape (3,)
        Translation per frame ``(dx, dy, dz)`` in µm.
    values : sequence of shape (K, 3), optional, keyword-only
        Explicit translation of every frame in µm, instead of ``step_um``.
    """

    step_um: tuple[float, float, float] | None = None

    type_name: ClassVar[str] = "translation"
    _step_name: ClassVar[str] = "step_um"
    _vector_amplitude: ClassVar[bool] = True

    def deformation_gradient(self, frame) -> np.ndarray:
        """``F = I`` (3, 3)."""
        _check_frame(frame)
        return np.eye(3)

    def translation(self, frame) -> np.ndarray:
        """``t(k)`` (3,) µm."""
        return np.array(self.amplitude(frame), dtype=np.float64)


@dataclass(frozen=True)
class Rotation(_Homogeneous):
    """Rigid rotation by ``k · step_deg`` (right-handed) about ``axis`` through ``center_xyz_um``.

    Parameters
    ----------
    axis : array_like, shape (3,)
        Rotation axis (normalised internally). Default z.
    step_deg : float
        Rotation per frame in degrees.
    center_xyz_um : array_like, shape (3,)
        A point on the axis, µm.
    values : sequence of float, optional, keyword-only
        Explicit angle of every frame in degrees, instead of ``step_deg``.
    """

    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    step_deg: float | None = None
    center_xyz_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    type_name: ClassVar[str] = "rotation"
    _step_name: ClassVar[str] = "step_deg"

    def __post_init__(self) -> None:
        axis = _vec3("rotation axis", self.axis)
        if axis == (0.0, 0.0, 0.0):
            raise ConfigError("rotation axis must be a non-zero vector")
        object.__setattr__(self, "axis", axis)
        object.__setattr__(
            self, "center_xyz_um", _vec3("rotation center_xyz_um", self.center_xyz_um)
        )
        super().__post_init__()

    def deformation_gradient(self, frame) -> np.ndarray:
        """Rotation matrix ``R(k)`` (3, 3), det 1."""
        return rotation_matrix(self.axis, self.amplitude(frame))


@dataclass(frozen=True)
class UniaxialTension(_Homogeneous):
    """Isochoric uniaxial tension: stretch ``λ = 1 + k · step_stretch`` along ``axis``.

    ``F = diag`` with ``λ`` on ``axis`` and ``1/√λ`` on the two other axes, so ``det F = 1``
    (the paper's volume-conserving tension, Fig. 6a). The amplitude is the engineering strain
    ``λ − 1`` along the axis; it must stay > −1.

    Parameters
    ----------
    axis : {"x", "y", "z"}
        Tension axis.
    step_stretch : float
        Engineering strain added per frame (0.05 for 5 % steps).
    center_xyz_um : array_like, shape (3,)
        Fixed point of the deformation, µm.
    values : sequence of float, optional, keyword-only
        Explicit engineering strain ``λ − 1`` of every frame, instead of ``step_stretch``.
    """

    axis: str = "x"
    step_stretch: float | None = None
    center_xyz_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    type_name: ClassVar[str] = "uniaxial_tension"
    _step_name: ClassVar[str] = "step_stretch"

    def __post_init__(self) -> None:
        if self.axis not in _AXES:
            raise ConfigError(f"uniaxial_tension axis must be 'x', 'y' or 'z', got {self.axis!r}")
        object.__setattr__(
            self, "center_xyz_um", _vec3("uniaxial_tension center_xyz_um", self.center_xyz_um)
        )
        super().__post_init__()

    def stretch(self, frame) -> float:
        """Stretch ``λ = 1 + amplitude(frame)`` along the axis."""
        lam = 1.0 + self.amplitude(frame)
        if not lam > 0:
            raise ConfigError(
                f"uniaxial_tension: frame {frame!r} gives stretch {lam!r}; it must be > 0"
            )
        return lam

    def deformation_gradient(self, frame) -> np.ndarray:
        """``F`` (3, 3): ``λ`` on the axis, ``1/√λ`` on the others."""
        lam = self.stretch(frame)
        d = np.full(3, 1.0 / math.sqrt(lam))
        d[_AXES[self.axis]] = lam
        return np.diag(d)


@dataclass(frozen=True)
class SimpleShear(_Homogeneous):
    """Simple shear with amount ``γ = k · step_gamma`` in the plane ``"ab"``.

    Convention: the first letter ``a`` of ``plane`` is the **displacement direction**, the
    second ``b`` the **gradient direction** (normal of the sheared faces):

        x_a = X_a + γ (X_b − c_b),     F = I + γ ê_a ê_bᵀ,     γ = 2 e_ab (engineering shear).

    The default ``"xz"`` gives ``u_x = γ (Z − c_z)``: planes of constant z slide along x, as in
    the paper's synthetic simple shear ("applied to the z-face in the x-direction", Fig. 6c)
    and shear impact device (Fig. 7), where the paper calls it ε_zx. Note that the paper's
    subscript order is the reverse of ``plane``'s: the paper's zx shear is ``plane="xz"``.

    Parameters
    ----------
    plane : str
        Two different letters of x, y, z: displacement direction then gradient direction.
    step_gamma : float
        Engineering shear strain added per frame (0.025 for 2.5 % steps).
    center_xyz_um : array_like, shape (3,)
        Point with zero displacement, µm (only its b component matters).
    values : sequence of float, optional, keyword-only
        Explicit ``γ`` of every frame, instead of ``step_gamma``.
    """

    plane: str = "xz"
    step_gamma: float | None = None
    center_xyz_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    type_name: ClassVar[str] = "simple_shear"
    _step_name: ClassVar[str] = "step_gamma"

    def __post_init__(self) -> None:
        p = self.plane
        if not isinstance(p, str) or len(p) != 2 or p[0] not in _AXES or p[1] not in _AXES:
            raise ConfigError(
                f"simple_shear plane must be two of 'x', 'y', 'z' (displacement direction then "
                f"gradient direction, e.g. 'xz' for u_x = γ (Z − c_z)), got {p!r}"
            )
        if p[0] == p[1]:
            raise ConfigError(f"simple_shear plane needs two different axes, got {p!r}")
        object.__setattr__(
            self, "center_xyz_um", _vec3("simple_shear center_xyz_um", self.center_xyz_um)
        )
        super().__post_init__()

    def deformation_gradient(self, frame) -> np.ndarray:
        """``F = I + γ ê_a ê_bᵀ`` (3, 3)."""
        F = np.eye(3)
        F[_AXES[self.plane[0]], _AXES[self.plane[1]]] = self.amplitude(frame)
        return F


# -- heterogeneous motions ------------------------------------------------------------------


@dataclass(frozen=True)
class _Heterogeneous(_Scheduled):
    """A known heterogeneous field ``u(X, k) = amplitude(k) · û(X)``, linear in its amplitude.

    Subclasses define ``_field(X, amplitude)`` and ``_gradient(X, amplitude)`` (the shared
    definitions of :mod:`hrvbase.known_fields`). The deformation gradient varies in space:
    :meth:`deformation_gradient_at` gives it at reference points.
    """

    homogeneous: ClassVar[bool] = False

    def displacement(self, X_um, frame) -> np.ndarray:
        """Displacement ``u`` (N, 3) µm at reference positions ``X_um`` (N, 3) µm."""
        X = _check_points(X_um)
        return self._field(X, self.amplitude(frame))

    def positions(self, X_um, frame) -> np.ndarray:
        """Current positions ``x = X + u(X, k)`` (N, 3) µm."""
        X = _check_points(X_um)
        return X + self._field(X, self.amplitude(frame))

    def displacement_gradient(self, X_um, frame) -> np.ndarray:
        """``∂u_i/∂X_j`` (N, 3, 3) at reference positions ``X_um`` (N, 3) µm (analytic)."""
        X = _check_points(X_um)
        return self._gradient(X, self.amplitude(frame))

    def deformation_gradient_at(self, X_um, frame) -> np.ndarray:
        """``F = I + ∂u/∂X`` (N, 3, 3) at reference positions ``X_um`` (N, 3) µm."""
        return np.eye(3) + self.displacement_gradient(X_um, frame)

    def deformation_gradient(self, frame) -> np.ndarray:
        """Not defined: use :meth:`deformation_gradient_at`."""
        raise LfsimError(
            f"{self.type_name} is not a homogeneous motion; it has no single deformation "
            "gradient (use deformation_gradient_at(X_um, frame))"
        )

    def _field(self, X: np.ndarray, amplitude: float) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def _gradient(self, X: np.ndarray, amplitude: float) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError


@dataclass(frozen=True)
class GaussianIndentation(_Heterogeneous):
    """A Gaussian punch pressed into the face ``z = surface_z_um``, deeper every frame.

    ``u_z = −A(k) exp(−ρ²/(2 w²)) exp(−(surface_z_um − Z)/D)``, ``u_x = u_y = 0``, with ``ρ``
    the lateral distance from ``center_xy_um``, ``A(k) = k · step_um`` (or ``values[k]``) the
    indentation depth at the punch centre on the face (µm, > 0 towards −z), ``w = width_um``
    and ``D = decay_um`` (:func:`hrvbase.known_fields.indentation_displacement`, the field of
    ``track.synthetic``'s ``gaussian_indentation``). Meant for particles below the face
    (``Z ≤ surface_z_um``), where the field decays into the volume.

    Parameters
    ----------
    surface_z_um : float
        z of the indented face, µm.
    width_um : float
        Lateral standard deviation of the punch, µm (> 0).
    decay_um : float
        Decay depth into the volume, µm (> 0).
    step_um : float
        Indentation depth added per frame, µm.
    center_xy_um : array_like, shape (2,)
        Punch centre (x, y), µm.
    values : sequence of float, optional, keyword-only
        Explicit indentation depth of every frame in µm, instead of ``step_um``.
    """

    surface_z_um: float
    width_um: float
    decay_um: float
    step_um: float | None = None
    center_xy_um: tuple[float, float] = (0.0, 0.0)

    type_name: ClassVar[str] = "gaussian_indentation"
    _step_name: ClassVar[str] = "step_um"

    def __post_init__(self) -> None:
        n = self.type_name
        object.__setattr__(self, "surface_z_um", _finite(f"{n} surface_z_um", self.surface_z_um))
        object.__setattr__(self, "width_um", _positive(f"{n} width_um", self.width_um))
        object.__setattr__(self, "decay_um", _positive(f"{n} decay_um", self.decay_um))
        c = self.center_xy_um
        if isinstance(c, str | bytes) or not hasattr(c, "__len__") or len(c) != 2:
            raise ConfigError(f"{n} center_xy_um must be two numbers (x, y), got {c!r}")
        xy = tuple(_finite(f"{n} center_xy_um", v) for v in c)
        object.__setattr__(self, "center_xy_um", xy)
        super().__post_init__()

    def _params(self, amplitude: float) -> dict:
        return {
            "depth_um": float(amplitude),
            "center_xy_um": self.center_xy_um,
            "surface_z_um": self.surface_z_um,
            "width_um": self.width_um,
            "decay_um": self.decay_um,
        }

    def _field(self, X, amplitude):
        return indentation_displacement(X, **self._params(amplitude))

    def _gradient(self, X, amplitude):
        return indentation_gradient(X, **self._params(amplitude))


@dataclass(frozen=True)
class StiffInclusion(_Heterogeneous):
    """A nearly rigid sphere in an incompressible matrix stretched along ``axis``.

    ``u = (1 − φ(r)) ε(k) M (X − c)`` with ``M = ê êᵀ − ½ (I − ê êᵀ)``, ``φ = 1 − δ`` inside the
    sphere (radius ``a``) and ``(1 − δ)(a/r)³`` outside, ``ε(k) = k · step_strain`` (or
    ``values[k]``) the far-field engineering strain along the axis and ``δ = inner_fraction``
    (:func:`hrvbase.known_fields.inclusion_displacement`, the field of ``track.synthetic``'s
    ``stiff_inclusion``): the far-field stretch away from the sphere, almost none inside it and
    a strain concentration of about ``3 ε`` at its poles.

    Parameters
    ----------
    radius_um : float
        Radius of the sphere, µm (> 0).
    axis : {"x", "y", "z"}
        Stretch axis.
    step_strain : float
        Far-field engineering strain added per frame.
    center_xyz_um : array_like, shape (3,)
        Centre of the sphere (x, y, z), µm.
    inner_fraction : float
        Strain inside the sphere as a fraction of the far field, in [0, 1) (0: rigid).
    values : sequence of float, optional, keyword-only
        Explicit far-field strain of every frame, instead of ``step_strain``.
    """

    radius_um: float
    axis: str = "x"
    step_strain: float | None = None
    center_xyz_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inner_fraction: float = 0.05

    type_name: ClassVar[str] = "stiff_inclusion"
    _step_name: ClassVar[str] = "step_strain"

    def __post_init__(self) -> None:
        n = self.type_name
        if self.axis not in _AXES:
            raise ConfigError(f"{n} axis must be 'x', 'y' or 'z', got {self.axis!r}")
        object.__setattr__(self, "radius_um", _positive(f"{n} radius_um", self.radius_um))
        object.__setattr__(self, "center_xyz_um", _vec3(f"{n} center_xyz_um", self.center_xyz_um))
        f = _finite(f"{n} inner_fraction", self.inner_fraction)
        if not 0.0 <= f < 1.0:
            raise ConfigError(f"{n} inner_fraction must be in [0, 1), got {self.inner_fraction!r}")
        object.__setattr__(self, "inner_fraction", f)
        super().__post_init__()

    def _params(self, amplitude: float) -> dict:
        return {
            "strain": float(amplitude),
            "center_xyz_um": self.center_xyz_um,
            "radius_um": self.radius_um,
            "inner_fraction": self.inner_fraction,
            "axis": self.axis,
        }

    def _field(self, X, amplitude):
        return inclusion_displacement(X, **self._params(amplitude))

    def _gradient(self, X, amplitude):
        return inclusion_gradient(X, **self._params(amplitude))


# -- user-defined fields ----------------------------------------------------------------------


MOTION_TYPES: dict[str, type[Motion]] = {
    cls.type_name: cls
    for cls in (
        Translation,
        Rotation,
        UniaxialTension,
        SimpleShear,
        GaussianIndentation,
        StiffInclusion,
        UserField,
    )
}


def motion_from_dict(d: Mapping, base_dir: str | os.PathLike | None = None) -> Motion:
    """Build a motion from a plain dict, e.g. ``{"type": "simple_shear", "step_gamma": 0.025}``.

    Parameters
    ----------
    d : Mapping
        ``type`` (one of :data:`MOTION_TYPES`) plus that class's fields; unknown types and keys
        are rejected by name.
    base_dir : str or os.PathLike, optional
        Folder that a relative ``.py`` path in a user field's ``function`` is relative to.

    Returns
    -------
    Motion
    """
    if not isinstance(d, Mapping):
        raise ConfigError(f"a motion must be a table/dict, got {type(d).__name__}")
    kind = d.get("type")
    if kind is None:
        raise ConfigError(f"a motion needs the key 'type', one of {sorted(MOTION_TYPES)}")
    cls = MOTION_TYPES.get(kind)
    if cls is None:
        raise ConfigError(f"unknown motion type {kind!r}; expected one of {sorted(MOTION_TYPES)}")
    allowed = [f.name for f in fields(cls)]  # type: ignore[arg-type]
    unknown = sorted(set(d) - {"type", *allowed})
    for key in unknown:
        renamed = renamed_key_message(key, allowed)
        if renamed is not None:
            raise ConfigError(f"motion type {kind!r}: {renamed}")
    if unknown:
        raise ConfigError(
            f"unknown key(s) {unknown} for motion type {kind!r}; expected some of "
            f"{['type', *allowed]}"
        )
    kw = {k: v for k, v in d.items() if k != "type"}
    if cls is UserField and isinstance(kw.get("function"), str) and base_dir is not None:
        module, sep, name = kw["function"].rpartition(":")
        if sep and _is_path(module) and not Path(module).is_absolute():
            kw["function"] = f"{Path(base_dir) / module}:{name}"
    try:
        return cls(**kw)
    except TypeError as exc:  # a required field is missing
        raise ConfigError(f"motion type {kind!r}: {exc}") from exc
