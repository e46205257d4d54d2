"""Helpers shared by the test packages (plain functions; fixtures live in the conftest files)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

#: The particle box of most lfsim test experiments: (x, y, z) ranges in µm.
BOX_UM = ((-150, 150), (-150, 150), (100, 300))

#: The simple shear of the lfsim tests: γ grows 0.05 a frame in the xz plane about z = 200 µm.
SHEAR_XZ = {"type": "simple_shear", "plane": "xz", "step_gamma": 0.05, "center_um": (0, 0, 200)}


def toml_value(value: object) -> str:
    """``value`` written as a TOML value: strings and paths quoted, sequences as arrays, numbers
    as Python writes them (``5`` stays ``5``, ``5.0`` stays ``5.0``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return f'"{value}"'
    if isinstance(value, Sequence):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return repr(value)


def experiment_toml(**sections: Mapping[str, object]) -> str:
    """The text of a small experiment file: one ``[section]`` per keyword argument, in the order
    given, one ``key = value`` a line, a blank line between sections, so that a test may edit
    the text with ``str.replace``.

    A scene may be given as a placeholder such as ``"{scene}"`` that the test fills in later.

    Examples
    --------
    >>> print(experiment_toml(experiment={"name": "t", "frames": 2}, render={"rays": 10}))
    [experiment]
    name = "t"
    frames = 2
    <BLANKLINE>
    [render]
    rays = 10
    <BLANKLINE>
    """
    blocks = []
    for section, keys in sections.items():
        lines = [f"[{section}]", *(f"{key} = {toml_value(v)}" for key, v in keys.items())]
        blocks.append("\n".join(lines) + "\n")
    return "\n".join(blocks)
