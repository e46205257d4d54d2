"""Validators for numbers and arrays: one place for each check, one message style.

Every validator returns the cleaned value or raises :class:`hrvbase.errors.InputError` whose
message names the parameter (as the user typed it, e.g. ``--z-step`` or ``z_step_um``) and
what was expected.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from .errors import InputError


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return v


def finite_float(value: Any, name: str) -> float:
    """``value`` as a finite float."""
    return _number(value, name)


def positive_float(value: Any, name: str) -> float:
    """``value`` as a finite float > 0."""
    v = _number(value, name)
    if not v > 0:
        raise InputError(f"{name} must be > 0, got {value!r}")
    return v


def nonnegative_float(value: Any, name: str) -> float:
    """``value`` as a finite float ≥ 0."""
    v = _number(value, name)
    if v < 0:
        raise InputError(f"{name} must be >= 0, got {value!r}")
    return v


def int_in_range(value: Any, name: str, lo: int, hi: int | None = None) -> int:
    """``value`` as an integer in ``[lo, hi]`` (``hi=None``: no upper bound)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise InputError(f"{name} must be an integer, got {value!r}")
    if not math.isfinite(float(value)) or int(value) != value:
        raise InputError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < lo or (hi is not None and v > hi):
        bound = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise InputError(f"{name} must be an integer {bound}, got {value!r}")
    return v


def one_of(value: Any, name: str, choices: Iterable[str]) -> str:
    """``value`` if it is one of ``choices`` (strings)."""
    choices = tuple(choices)
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{name} must be one of {', '.join(choices)}; got {value!r}")
    return value


def points_xyz(
    arr: Any, name: str, *, min_points: int = 0, error: type[InputError] = InputError
) -> np.ndarray:
    """``arr`` as a finite float64 array of shape ``(N, 3)`` in (x, y, z) order (µm).

    Parameters
    ----------
    arr : array_like, shape (N, 3)
    name : str
        Parameter name for the message.
    min_points : int
        Smallest accepted ``N``.
    error : type
        The :class:`InputError` subclass to raise (a package's own).
    """
    try:
        a = np.asarray(arr, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name} must be a numeric (N, 3) array of x, y, z in µm") from None
    if a.ndim == 1 and a.size == 0:
        a = a.reshape(0, 3)
    if a.ndim != 2 or a.shape[1] != 3:
        raise error(f"{name} must have shape (N, 3) in x, y, z order (µm), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise error(f"{name} holds NaN or infinite values")
    if a.shape[0] < min_points:
        raise error(f"{name} needs at least {min_points} points, got {a.shape[0]}")
    return a


def fixed_length(value: Any, name: str, n: int, what: str) -> tuple:
    """``value`` as a tuple of exactly ``n`` items (``what`` says what they are)."""
    try:
        items = tuple(value)
    except TypeError:
        raise InputError(f"{name} must be {what}, got {value!r}") from None
    if len(items) != n:
        raise InputError(f"{name} must be {what}, got {value!r}")
    return items


def known_keys(cls: type, mapping: Any, what: str, *, error: type[InputError] = InputError) -> dict:
    """``mapping`` as a dict whose keys are all fields of the dataclass ``cls`` (else one
    ``error`` naming the unknown keys and the known ones)."""
    from dataclasses import fields

    if not isinstance(mapping, Mapping):
        raise error(f"{what} must be a mapping of parameters, got {type(mapping).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(mapping) - known)
    if unknown:
        raise error(f"{what}: unknown key(s) {unknown}; expected a subset of {sorted(known)}")
    return dict(mapping)


def per_axis(value: Any, name: str, *, positive: bool = True) -> tuple[float, float, float]:
    """A per-axis triple in array order ``(z, y, x)``; one number is used for all three."""
    if isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool):
        vals = (value,) * 3
    else:
        vals = fixed_length(value, name, 3, "a number or 3 numbers (z, y, x)")
    check = positive_float if positive else finite_float
    z, y, x = (check(v, name) for v in vals)
    return (z, y, x)


#: Keys of the files users write whose names do not say the order of their values → the key
#: to write instead, whose name does, and what it holds (docs/conventions.md §3). Such a key is
#: refused with a message naming the new one, so that no value is read in an order its file
#: did not state.
RENAMED_KEYS: dict[str, tuple[str, str]] = {
    "center_um": ("center_xyz_um", "the centre (x, y, z) in µm"),
    "centre_um": ("center_xyz_um", "the centre (x, y, z) in µm"),
    "box_um": ("bounds_xyz_um", "the (lo, hi) ranges in x, y, z order, µm"),
    "roi_px": ("roi_xy_px", "(x0, x1, y0, y1): the x range then the y range in pixels"),
    "sensor_px": ("sensor_xy_px", "the sensor's (width, height) in pixels"),
    "axis_px": ("axis_xy_px", "the optical axis on the sensor, (column, row) in pixels"),
}


def renamed_key_message(key: Any, allowed: Iterable[str]) -> str | None:
    """Why ``key`` is refused if it is a :data:`RENAMED_KEYS` name of an ``allowed`` key
    (``"'center_um' is named 'center_xyz_um' (...); rename the key"``), else None."""
    new, meaning = RENAMED_KEYS.get(str(key), (None, ""))
    if new is None or new not in allowed:
        return None
    return f"{key!r} is named {new!r} ({meaning}); rename the key"


def check_table_keys(
    where: str,
    section: str,
    table: Any,
    allowed: Iterable[str],
    *,
    error: type[InputError] = InputError,
) -> Mapping:
    """``table`` (a parsed TOML/JSON table) if all its keys are ``allowed``.

    An unknown key raises ``error`` naming the file (``where``), the section, the key, the
    closest allowed key and every allowed key; a key of :data:`RENAMED_KEYS` raises it naming
    the key to write instead.
    """
    if not isinstance(table, Mapping):
        raise error(f"{where}: [{section}] must be a table, got {type(table).__name__} {table!r}")
    allowed = list(allowed)
    for key in table:
        if key not in allowed:
            renamed = renamed_key_message(key, allowed)
            if renamed is not None:
                raise error(f"{where}: [{section}] {renamed}")
            hint = difflib.get_close_matches(str(key), allowed, n=1)
            did = f" (did you mean {hint[0]!r}?)" if hint else ""
            raise error(
                f"{where}: [{section}] unknown key {key!r}{did}; allowed: {', '.join(allowed)}"
            )
    return table


__all__ = [
    "RENAMED_KEYS",
    "check_table_keys",
    "finite_float",
    "fixed_length",
    "int_in_range",
    "known_keys",
    "nonnegative_float",
    "one_of",
    "per_axis",
    "points_xyz",
    "positive_float",
    "renamed_key_message",
]
