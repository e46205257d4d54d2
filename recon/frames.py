"""Light-field frame series: which files are the frames, and in which order.

A **folder** of frames contributes every TIFF in it (``.tif``/``.tiff``, any letter case,
hidden files skipped) in **natural order** of the frame number in the file name; explicit
files keep the order they are given in.

Natural order. The frame number of ``img_0012.tif`` is the last run of digits in the name
without its extension (12). All files of a folder must be named alike around that number
(same text before and after it); a file without a number, two naming patterns or two files
with the same number (``img_1.tif``, ``img_01.tif``) cannot be ordered unambiguously and are
refused (:class:`recon.errors.InputError`) — the user then gives the order explicitly. Gaps in
the numbering are reported with a warning (``missing frames 4-6, 9``); files numbered in
steps (0, 2, 4, …) are not gaps.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import re
from collections.abc import Iterable, Sequence
from pathlib import Path

from .errors import InputError

log = logging.getLogger(__name__)

#: File name endings (compared in lower case) of the TIFFs a folder contributes.
TIFF_SUFFIXES = (".tif", ".tiff")

#: What the user is told when a folder cannot be ordered by its file names.
ORDER_HINT = "give the order explicitly (a list file or explicit files)"

_NAME_NUMBER = re.compile(r"^(.*?)(\d+)(\D*)$")
#: Runs listed in a "missing frames" message before it is cut short.
_MAX_RUNS_SHOWN = 10


# -- names and natural order ------------------------------------------------------------
def is_tiff_name(path: str | os.PathLike) -> bool:
    """Whether the file name ends in ``.tif`` or ``.tiff`` (any letter case)."""
    return Path(path).suffix.lower() in TIFF_SUFFIXES


def _stem(path: str | os.PathLike) -> str:
    p = Path(path)
    return p.name[: -len(p.suffix)] if is_tiff_name(p) else p.stem


def parse_frame_name(path: str | os.PathLike) -> tuple[str, int, str] | None:
    """``(prefix, number, suffix)`` of a frame file name, or ``None`` without a number.

    The number is the last run of digits of the name without its TIFF extension:
    ``img_0012.tif`` → ``("img_", 12, "")``, ``run2_f7_cam.TIF`` → ``("run2_f", 7, "_cam")``.
    """
    m = _NAME_NUMBER.match(_stem(path))
    if m is None:
        return None
    return m.group(1), int(m.group(2)), m.group(3)


def format_numbers(numbers: Iterable[int], step: int = 1) -> str:
    """Compact text for sorted frame numbers: runs of ``step`` as ``a-b`` (``"4-6, 9"``)."""
    nums = sorted(set(numbers))
    runs: list[list[int]] = []
    for n in nums:
        if runs and n - runs[-1][-1] == step:
            runs[-1].append(n)
        else:
            runs.append([n])
    parts = []
    for run in runs[:_MAX_RUNS_SHOWN]:
        if len(run) >= 3:
            parts.append(f"{run[0]}-{run[-1]}")
        else:
            parts.extend(str(n) for n in run)
    text = ", ".join(parts)
    if len(runs) > _MAX_RUNS_SHOWN:
        text += f", … ({len(nums)} in all)"
    return text


def missing_numbers(numbers: Sequence[int]) -> tuple[list[int], int]:
    """Numbers absent from the sorted, distinct ``numbers``, and the numbering step.

    The step is the greatest common divisor of the differences (files numbered 0, 2, 4, …
    have step 2 and no gap).
    """
    nums = sorted(numbers)
    if len(nums) < 2:
        return [], 1
    step = math.gcd(*(b - a for a, b in itertools.pairwise(nums)))
    present = set(nums)
    return [n for n in range(nums[0], nums[-1] + 1, step) if n not in present], step


def natural_order(paths: Sequence[Path], *, where: str) -> list[Path]:
    """Frame files in the order of the number in their names (see the module docstring).

    Parameters
    ----------
    paths : sequence of Path
        Files of one folder or pattern, in any order.
    where : str
        The folder or pattern, for messages.

    Returns
    -------
    list of Path
        Ordered by frame number. A gap in the numbering is logged as a warning naming the
        missing numbers.

    Raises
    ------
    InputError
        A file without a number, files named differently around their numbers, or two files
        with the same number (one line naming ``where`` and two offending files).
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        return paths
    parsed = [(p, parse_frame_name(p)) for p in paths]
    bare = [p for p, q in parsed if q is None]
    numbered = [(p, q) for p, q in parsed if q is not None]
    head = f"cannot order the frames of {where} by the numbers in their names"
    if bare:
        other = numbered[0][0] if numbered else bare[1]
        raise InputError(
            f"{head}: {bare[0].name!r} has no number (next to {other.name!r}); {ORDER_HINT}"
        )
    first_path, (prefix, _, suffix) = numbered[0]
    by_number: dict[int, Path] = {}
    for p, (pre, num, suf) in numbered:
        if (pre, suf) != (prefix, suffix):
            raise InputError(
                f"{head}: {first_path.name!r} and {p.name!r} are named differently around "
                f"their numbers; {ORDER_HINT}"
            )
        if num in by_number:
            raise InputError(
                f"{head}: {by_number[num].name!r} and {p.name!r} both carry frame number "
                f"{num}; {ORDER_HINT}"
            )
        by_number[num] = p
    order = sorted(by_number)
    missing, step = missing_numbers(order)
    if missing:
        steps = "" if step == 1 else f" (numbered in steps of {step})"
        log.warning(
            "%s: missing frames %s%s; %d frames found, numbered %d to %d",
            where,
            format_numbers(missing, step),
            steps,
            len(order),
            order[0],
            order[-1],
        )
    return [by_number[n] for n in order]


def warn_if_unordered(paths: Sequence[Path]) -> None:
    """Warn when explicit files are not in the order of their frame numbers.

    A shell expands ``frames/*.tif`` in text order (``img_1, img_10, img_2``); the files are
    reconstructed in the order given, so say so when that order is not the numeric one.
    """
    parsed = [parse_frame_name(p) for p in paths]
    if len(paths) < 2 or any(q is None for q in parsed):
        return
    if len({(q[0], q[2]) for q in parsed}) != 1 or len({q[1] for q in parsed}) != len(parsed):
        return
    nums = [q[1] for q in parsed]
    for i in range(len(nums) - 1):
        if nums[i + 1] < nums[i]:
            log.warning(
                "the %d frame files given are not in the order of their numbers (%s before "
                "%s); they are reconstructed in the order given — give their folder to have "
                "them ordered by number",
                len(paths),
                paths[i].name,
                paths[i + 1].name,
            )
            return


# -- folders ---------------------------------------------------------------------------
def folder_frames(folder: Path) -> list[Path]:
    """The TIFFs of a folder (not hidden ones) in natural order.

    Raises
    ------
    InputError
        No TIFF in the folder, or names that cannot be ordered (:func:`natural_order`).
    """
    folder = Path(folder)
    files = [
        p
        for p in folder.iterdir()
        if is_tiff_name(p) and not p.name.startswith(".") and p.is_file()
    ]
    if not files:
        raise InputError(f"no TIFF frames (.tif, .tiff) in folder {str(folder)!r}")
    return natural_order(files, where=f"folder {str(folder)!r}")


__all__ = [
    "ORDER_HINT",
    "TIFF_SUFFIXES",
    "folder_frames",
    "format_numbers",
    "missing_numbers",
    "natural_order",
    "parse_frame_name",
    "warn_if_unordered",
]
