"""Light-field frame series: which images are the frames, in which order, and when.

``recon run`` takes its frames in any of these forms (mixed freely, in the order given):

- a **folder**: every frame file in it (TIFF ``.tif``/``.tiff``, Phantom ``.cine``, or any
  format of the reader registry :mod:`hrvbase.formats.registry`; any letter case, hidden
  files skipped), in **natural order** of the frame number in the file name (below);
- a **glob pattern** (quoted, so that the shell does not expand it, e.g. ``'run3/img_*.tif'``):
  the matching files, in natural order;
- a **list file**: a text file naming one frame per line (paths relative to the list file);
  blank lines and lines starting with ``#`` are ignored; the list gives the order, and a frame
  it names twice is refused;
- a **frame file**: a TIFF holds one frame, or, for a multi-page stack (the usual high-speed
  camera export), one frame per page in page order; a Phantom ``.cine`` file holds one frame
  per recorded image. A file is recognised by its content, else by its name. Explicit files
  keep the order they are given in.

Natural order. The frame number of ``img_0012.tif`` is the last run of digits in the name
without its extension (12). All files of a folder or pattern must be named alike around
that number (same text before and after it); a file without a number, two naming patterns
or two files with the same number (``img_1.tif``, ``img_01.tif``) cannot be ordered
unambiguously and are refused (:class:`recon.errors.InputError`) — the user then gives the
order explicitly. Gaps in the numbering are reported with a warning (``missing frames 4-6,
9``); files numbered in steps (0, 2, 4, …) are not gaps.

Series checks (:func:`build_series`). Every frame must have the same size, pixel type and bit
depth; this is read from the files' headers (no pixels) before anything is reconstructed, and
the first file that differs is refused. A file may appear once in a series (given twice, or as
a folder and a file in it, it is refused: it would be reconstructed twice), and no two frames
may carry the same frame number (:func:`check_distinct`).

Frame numbers and times. Every frame carries its original number: the number in its file
name, or for a page of a stack its page index (counted on across consecutive stacks, as
cameras split a long recording into several files), or the number the file records (a
``.cine`` image's position in its recording). Its time is ``number / fps`` when a frame
rate is given; otherwise it is read from the file's metadata when present (the time block of
a ``.cine`` file, the ``finterval`` of an ImageJ stack, or a ``"time_s"`` entry in the JSON
metadata that :func:`hrvbase.formats.tiff_layout.write_tiff` writes, or in a JSON image
description); otherwise unknown. What a file records of its camera (the frame rate,
exposure and bit depth of a ``.cine`` recording) goes into ``recon.json``
(:func:`camera_records`).
"""

from __future__ import annotations

import glob
import hashlib
import itertools
import logging
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hrvbase.formats import tiff_frames
from hrvbase.formats.registry import (
    SNIFF_BYTES,
    FrameHeader,
    format_by_name,
    frame_format_for,
    frame_suffixes,
    probe_frames,
)
from hrvbase.formats.tiff_frames import SUFFIXES as TIFF_SUFFIXES

from .errors import InputError, recon_input_errors

log = logging.getLogger(__name__)

#: What the user is told when a folder or pattern cannot be ordered by its file names.
ORDER_HINT = "give the order explicitly (a list file or explicit files)"

_GLOB_CHARS = frozenset("*?[")
_NAME_NUMBER = re.compile(r"^(.*?)(\d+)(\D*)$")
#: Runs listed in a "missing frames" message before it is cut short.
_MAX_RUNS_SHOWN = 10


@dataclass(frozen=True)
class FrameRef:
    """One frame of a series: a single-image file, or one page (image) of a stack or recording.

    Parameters
    ----------
    path : Path
        The frame file (TIFF, ``.cine``, …).
    page : int or None
        Page (0-based) of a multi-page stack, or image of a ``.cine`` recording; ``None`` for
        a file holding one image.
    number : int or None
        Original frame number: from the file name, or the page index for a stack (see the
        module docstring); ``None`` when unknown.
    time_s : float or None
        Time of the frame in seconds (from a frame rate or the file's metadata), if known.
    """

    path: Path
    page: int | None = None
    number: int | None = None
    time_s: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        if self.page is not None and (int(self.page) != self.page or self.page < 0):
            raise InputError(f"page must be an integer >= 0 or None, got {self.page!r}")

    @property
    def label(self) -> str:
        """The file, and the page for a stack, as shown in messages."""
        return str(self.path) if self.page is None else f"{self.path} [page {self.page}]"

    @classmethod
    def of(cls, frame: FrameRef | str | os.PathLike) -> FrameRef:
        """A :class:`FrameRef` as is; a path as a single-image frame numbered from its name."""
        if isinstance(frame, FrameRef):
            return frame
        parsed = parse_frame_name(frame)
        return cls(Path(frame), None, None if parsed is None else parsed[1])


#: What a frame reader reads from a file's header (the name of the TIFF reader's days).
TiffHeader = FrameHeader


# -- names and natural order ------------------------------------------------------------
def is_tiff_name(path: str | os.PathLike) -> bool:
    """Whether the file name ends in ``.tif`` or ``.tiff`` (any letter case)."""
    return Path(path).suffix.lower() in TIFF_SUFFIXES


def is_frame_name(path: str | os.PathLike) -> bool:
    """Whether the file name ends like a frame file of a registered format (``.tif``,
    ``.tiff``, ``.cine``, …; any letter case)."""
    return Path(path).suffix.lower() in frame_suffixes()


def _stem(path: str | os.PathLike) -> str:
    p = Path(path)
    return p.name[: -len(p.suffix)] if is_frame_name(p) else p.stem


def parse_frame_name(path: str | os.PathLike) -> tuple[str, int, str] | None:
    """``(prefix, number, suffix)`` of a frame file name, or ``None`` without a number.

    The number is the last run of digits of the name without its frame-file extension:
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
    paths = sorted((Path(p) for p in paths), key=str)  # messages independent of listing order
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
                "%s); they are reconstructed in the order given — quote a pattern "
                "('DIR/*.tif') or give the folder to have them ordered by number",
                len(paths),
                paths[i].name,
                paths[i + 1].name,
            )
            return


# -- the forms of input -------------------------------------------------------------------
def has_glob_chars(text: str) -> bool:
    """Whether ``text`` contains a glob wildcard (``*``, ``?``, ``[``)."""
    return any(c in _GLOB_CHARS for c in text)


def is_tiff_file(path: str | os.PathLike) -> bool:
    """Whether the file starts like a TIFF (classic or BigTIFF, either byte order)."""
    try:
        with open(path, "rb") as fh:
            return tiff_frames.sniff(fh.read(SNIFF_BYTES))
    except OSError:
        return False


def folder_frames(folder: Path) -> list[Path]:
    """The frame files of a folder (TIFF, ``.cine``, …; not hidden ones) in natural order.

    Raises
    ------
    InputError
        No frame file in the folder, or names that cannot be ordered (:func:`natural_order`).
    """
    folder = Path(folder)
    files = [
        p
        for p in folder.iterdir()
        if is_frame_name(p) and not p.name.startswith(".") and p.is_file()
    ]
    if not files:
        others = ", ".join(s for s in frame_suffixes() if s not in TIFF_SUFFIXES)
        raise InputError(
            f"no TIFF frames (.tif, .tiff) nor other frame files ({others}) in folder "
            f"{str(folder)!r}"
        )
    return natural_order(files, where=f"folder {str(folder)!r}")


def pattern_frames(pattern: str) -> list[Path]:
    """The files matching a glob pattern, in natural order.

    Raises
    ------
    InputError
        Nothing matches, or names that cannot be ordered (:func:`natural_order`).
    """
    files = [Path(p) for p in glob.glob(pattern) if os.path.isfile(p)]
    if not files:
        raise InputError(f"pattern {pattern!r} matches no file")
    return natural_order(files, where=f"pattern {pattern!r}")


def list_file_frames(path: Path) -> list[Path]:
    """The frames named by a list file, in its order (see the module docstring).

    Raises
    ------
    InputError
        Not a text file, no entries, or an entry that is not an existing file (names the
        list file, line and entry).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        raise InputError(
            f"{str(path)!r} is neither a frame file ({', '.join(frame_suffixes())}) nor a "
            "text file listing frames"
        ) from None
    out = []
    lines: dict[Path, int] = {}  # resolved file -> its first line
    for i, line in enumerate(text.splitlines(), start=1):
        entry = line.strip()
        if not entry or entry.startswith("#"):
            continue
        p = Path(entry).expanduser()
        if not p.is_absolute():
            p = path.parent / p
        if not p.is_file():
            what = "is a folder, not a frame file" if p.is_dir() else "does not exist"
            raise InputError(f"list file {str(path)!r} line {i}: {entry!r} ({p}) {what}")
        first = lines.setdefault(p.resolve(), i)
        if first != i:
            raise InputError(
                f"list file {str(path)!r} names {entry!r} ({p}) twice (lines {first} and {i}); "
                "each frame is reconstructed once: remove the repeated line"
            )
        out.append(p)
    if not out:
        raise InputError(f"list file {str(path)!r} names no frames")
    return out


def expand_argument(arg: str | os.PathLike) -> tuple[list[Path], str]:
    """Frame files named by one command-line argument, and how they were named.

    Returns
    -------
    files : list of Path
        In the order they are to be reconstructed (stacks not yet split into pages).
    kind : {"folder", "pattern", "list", "file"}

    Raises
    ------
    InputError
        A missing file, an empty folder, a pattern matching nothing, a bad list file or names
        that cannot be ordered.
    """
    path = Path(arg)
    text = os.fspath(arg)
    if path.is_dir():
        return folder_frames(path), "folder"
    if not path.exists() and has_glob_chars(text):
        return pattern_frames(text), "pattern"
    if not path.is_file():
        raise InputError(f"frame {text!r} does not exist")
    if is_frame_name(path) or frame_format_for(path) is not None:
        return [path], "file"
    return list_file_frames(path), "list"


# -- headers, series and pages --------------------------------------------------------------
def probe_tiff(path: str | os.PathLike, what: str = "frame") -> FrameHeader:
    """Image count, size, pixel type, bit depth and timing metadata of a frame file (TIFF,
    ``.cine``, any registered format), from its header only
    (:func:`hrvbase.formats.registry.probe_frames`).

    Raises
    ------
    InputError
        Missing or unreadable file, images of several sizes or types in one file, colour or
        multi-channel images, a non-numeric pixel type (names the file).
    """
    with recon_input_errors():
        return probe_frames(path, what)


def check_uniform(headers: Sequence[tuple[Path, TiffHeader]]) -> None:
    """Refuse a series whose images differ in size, pixel type or bit depth.

    Raises
    ------
    InputError
        One line naming the first file that differs from the series' first file and what
        differs.
    """
    if not headers:
        return
    p0, h0 = headers[0]
    for p, h in headers[1:]:
        diff = []
        if h.shape != h0.shape:
            diff.append(f"size {h.shape[1]} × {h.shape[0]} px, not {h0.shape[1]} × {h0.shape[0]}")
        if h.dtype != h0.dtype:
            diff.append(f"pixel type {h.dtype}, not {h0.dtype}")
        if h.bits != h0.bits:
            diff.append(f"bit depth {h.bits}, not {h0.bits}")
        if diff:
            raise InputError(
                f"mixed series: frame {str(p)!r} differs from the first frame {str(p0)!r} in "
                f"{'; '.join(diff)}"
            )


def check_distinct(refs: Sequence[FrameRef]) -> None:
    """Refuse a series that holds a frame twice or two frames of the same frame number.

    Raises
    ------
    InputError
        One line naming the two frames: the same file (or page of a stack) given twice,
        or two frames carrying the same original number (e.g. the pages of a stack, numbered
        0, 1, … and a file named ``img_0.tif``).
    """
    seen: dict[tuple[Path, int | None], FrameRef] = {}
    numbers: dict[int, FrameRef] = {}
    for r in refs:
        key = (r.path.resolve(), r.page)
        if key in seen:
            also = "" if seen[key].label == r.label else f" (also as {seen[key].label!r})"
            raise InputError(
                f"frame {r.label!r} is given twice{also}; each frame is reconstructed once: "
                "give every file once"
            )
        seen[key] = r
        if r.number is None:
            continue
        if r.number in numbers:
            raise InputError(
                f"frames {numbers[r.number].label!r} and {r.label!r} both carry frame number "
                f"{r.number} (the pages of stacks are numbered 0, 1, … in series order, a "
                "single file by the number in its name); rename the files, or reconstruct "
                "them in separate runs"
            )
        numbers[r.number] = r


def check_frames(refs: Sequence[FrameRef]) -> dict[Path, FrameHeader]:
    """Check a series from its files' headers: files exist, pages exist, equal images.

    Returns
    -------
    dict
        The header of every file of the series.

    Raises
    ------
    InputError
        A missing or unreadable file, a stack given as one frame (``page=None``), a page
        beyond the end of its stack, a mixed series (:func:`check_uniform`), a frame given
        twice or two frames of one number (:func:`check_distinct`).
    """
    check_distinct(refs)
    headers: dict[Path, FrameHeader] = {}
    for r in refs:
        if r.path not in headers:
            headers[r.path] = probe_tiff(r.path)
        h = headers[r.path]
        if r.page is None and h.n_images != 1:
            raise InputError(
                f"frame {str(r.path)!r} is a stack of {h.n_images} images; give it to `recon "
                "run` (or pass one FrameRef per page) to reconstruct every page"
            )
        if r.page is not None and r.page >= h.n_images:
            raise InputError(f"frame {r.label!r}: the stack has only {h.n_images} page(s)")
    check_uniform(list(headers.items()))
    return headers


def build_series(files: Sequence[Path], *, fps: float | None = None) -> list[FrameRef]:
    """The frames of these files (a stack gives one frame per page), checked and timed.

    Parameters
    ----------
    files : sequence of Path
        Frame files in series order (e.g. from :func:`expand_argument`).
    fps : float, optional
        Frame rate (frames per second): frame times are ``number / fps``. Without it, times
        come from the files' metadata where recorded (module docstring), else ``None``.

    Returns
    -------
    list of FrameRef

    Raises
    ------
    InputError
        Unreadable files, stacks of unequal images, a mixed series (:func:`check_uniform`),
        a file given twice or two frames of one number (:func:`check_distinct`), an ``fps``
        that is not a finite number > 0 or that gives a frame a time that is not finite
        (``--fps 1e-320``).
    """
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"--fps must be a finite number > 0 (frames per second), got {fps!r}")
    headers: dict[Path, FrameHeader] = {}
    for f in files:
        if f not in headers:
            headers[f] = probe_tiff(f)
    check_uniform([(f, headers[f]) for f in files])
    refs: list[FrameRef] = []
    pages_before = 0  # pages of the stacks earlier in the series
    for f in files:
        h = headers[f]
        if h.numbers is not None:  # the file numbers (and times) its images itself
            refs += _recorded_frames(f, h, fps)
            continue
        if h.n_images == 1:
            parsed = parse_frame_name(f)
            number = None if parsed is None else parsed[1]
            t = h.time_s if fps is None else (None if number is None else number / fps)
            refs.append(FrameRef(f, None, number, t))
            continue
        for page in range(h.n_images):
            number = pages_before + page
            if fps is not None:
                t = number / fps
            else:
                t = None if h.frame_interval_s is None else number * h.frame_interval_s
            refs.append(FrameRef(f, page, number, t))
        pages_before += h.n_images
    check_distinct(refs)
    for r in refs:
        if r.time_s is not None and not math.isfinite(r.time_s):
            raise InputError(
                f"--fps {fps!r} gives frame {r.label!r} (number {r.number}) a time of "
                f"{r.number} / {fps!r} s, which is not a finite number; expected a frame rate "
                "in frames per second (e.g. 500)"
            )
    if fps is not None:
        unnumbered = [r for r in refs if r.number is None]
        if unnumbered:
            log.warning(
                "%d frame(s) have no number in their file name (e.g. %s); their time is "
                "unknown despite --fps",
                len(unnumbered),
                unnumbered[0].path.name,
            )
    return refs


def _recorded_frames(path: Path, h: FrameHeader, fps: float | None) -> list[FrameRef]:
    """The frames of a file that records its images' numbers (and times): a ``.cine``."""
    out = []
    for i, number in enumerate(h.numbers):
        t = h.times_s[i] if h.times_s is not None else None
        if fps is not None:
            t = number / fps
        out.append(FrameRef(path, None if h.n_images == 1 else i, int(number), t))
    return out


def camera_records(refs: Sequence[FrameRef]) -> list[dict] | None:
    """What the series' files record of their camera (``.cine``: format, frame rate,
    exposure, bit depth, first image number, trigger time), one entry per file, for
    ``recon.json``; None when no file records anything (TIFF frames)."""
    out = []
    for path in dict.fromkeys(r.path for r in refs):
        camera = probe_tiff(path).camera
        if camera:
            out.append({"input": str(path), **camera})
    return out or None


def time_source(refs: Sequence[FrameRef], fps: float | None) -> str | None:
    """Where the frame times came from: ``"fps"``, ``"metadata"`` or ``None`` (unknown)."""
    if not any(r.time_s is not None for r in refs):
        return None
    return "fps" if fps is not None else "metadata"


def parse_selection(text: str) -> slice:
    """``START:STOP[:STEP]`` (indices into the ordered series, STOP excluded) as a slice.

    START and STOP may be left out (``:100``, ``50:``); all are integers >= 0, STEP >= 1.

    Raises
    ------
    InputError
        Anything else (names ``--frames``).
    """
    bad = InputError(
        f"--frames must look like START:STOP or START:STOP:STEP (indices into the ordered "
        f"series, STOP excluded; e.g. 0:100:2), got {text!r}"
    )
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise bad
    try:
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise bad from None
    start, stop = vals[0], vals[1]
    step = vals[2] if len(vals) == 3 else None
    if any(v is not None and v < 0 for v in (start, stop)) or (step is not None and step < 1):
        raise bad
    if start is not None and stop is not None and stop <= start:
        raise InputError(f"--frames {text}: STOP must be larger than START")
    return slice(start, stop, step)


def select_frames(refs: Sequence[FrameRef], text: str | None) -> list[FrameRef]:
    """The frames ``--frames START:STOP[:STEP]`` selects from the ordered series.

    Raises
    ------
    InputError
        A malformed selection, or one that starts beyond the end of the series.
    """
    refs = list(refs)
    if text is None:
        return refs
    sel = parse_selection(text)
    n = len(refs)
    if (sel.start or 0) >= n:
        raise InputError(f"--frames {text} selects nothing: the series has {n} frame(s)")
    if sel.stop is not None and sel.stop > n:
        log.warning("--frames %s: the series has only %d frame(s); up to the last one", text, n)
    return refs[sel]


class FrameReader:
    """Reads frames one by one, keeping the current file open between its pages.

    Use as a context manager (``with FrameReader() as reader: reader.read(ref)``); a page
    of a long stack (or an image of a ``.cine`` recording) is then read without parsing the
    file again. Each file is read by the reader of its format
    (:func:`hrvbase.formats.registry.frame_format_for`; TIFF when none claims it).
    """

    def __init__(self) -> None:
        self._key: tuple[Path, str] | None = None
        self._file = None

    def __enter__(self) -> FrameReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
        self._file, self._key = None, None

    def _open(self, path: Path, what: str):
        if self._key != (path, what) or self._file is None:
            self.close()
            fmt = frame_format_for(path) or format_by_name("tiff")
            self._file = fmt.open_file(path, what)
            self._key = (path, what)
        return self._file

    def read(self, ref: FrameRef, what: str = "frame") -> np.ndarray:
        """Pixels of one frame as stored (2-D, the file's dtype).

        Raises
        ------
        InputError
            Missing or unreadable file, a page beyond the end of the stack, or (``page=None``)
            a file holding more than one image (names the file).
        """
        with recon_input_errors():
            try:
                return self._open(ref.path, what).read(ref.page, ref.label)
            except Exception:
                self.close()
                raise


def read_raw(ref: FrameRef, what: str = "frame") -> np.ndarray:
    """Pixels of one frame as stored (see :meth:`FrameReader.read`)."""
    with FrameReader() as reader:
        return reader.read(ref, what)


def frame_checksums(refs: Sequence[FrameRef]) -> list[str]:
    """SHA-256 of every frame: of the file for a single image, of the pixel bytes for a page
    of a stack (so that a stack's pages are recognised one by one when a run resumes)."""
    from hrvbase.io import sha256_file

    out = []
    with FrameReader() as reader:
        for r in refs:
            if r.page is None:
                out.append(sha256_file(r.path))
            else:
                arr = np.ascontiguousarray(reader.read(r))
                out.append(hashlib.sha256(arr.tobytes()).hexdigest())
    return out


__all__ = [
    "ORDER_HINT",
    "TIFF_SUFFIXES",
    "FrameReader",
    "FrameRef",
    "TiffHeader",
    "build_series",
    "camera_records",
    "check_distinct",
    "check_frames",
    "check_uniform",
    "expand_argument",
    "folder_frames",
    "format_numbers",
    "frame_checksums",
    "is_frame_name",
    "list_file_frames",
    "natural_order",
    "parse_frame_name",
    "parse_selection",
    "pattern_frames",
    "probe_tiff",
    "read_raw",
    "select_frames",
    "time_source",
    "warn_if_unordered",
]
