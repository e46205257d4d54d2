"""Files: atomic writes, JSON, checksums, verified outputs and the input guard.

Every writer here is **atomic**: the data go to a hidden temporary file in the destination
folder (``.NAME.XXXX.tmp``), are flushed to disk, and only then take the destination's name
(``os.replace``, or a hard link when an existing file must not be replaced). A reader sees the
old file, no file or the complete new file, never a partial one; an interrupted program leaves
at most a hidden ``*.tmp`` file behind. Writers refuse to replace an existing file unless
``overwrite=True``.

JSON has no NaN or infinity: :func:`write_json` writes them as ``null``.

Resume verifies what it keeps: :func:`file_record` gives the size and SHA-256 of an output
when it is written, and :func:`verify_record` checks a file against it before a resumed run
reuses it.

:func:`guard_output` refuses an output that would land on an input, inside an input folder, or
around one: nothing the user gave is ever overwritten, even with ``--overwrite``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError, OutputError

log = logging.getLogger(__name__)


# -- atomic writes -------------------------------------------------------------------------
def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _refuse(path: Path) -> OutputError:
    return OutputError(
        f"{path} already exists; refusing to overwrite it (pass overwrite=True / --overwrite)"
    )


def _publish(tmp: str, path: Path, overwrite: bool) -> None:
    """Give the finished temporary file ``tmp`` the name ``path``."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        # A hard link fails if ``path`` exists: no window in which another file is clobbered.
        os.link(tmp, path)
    except FileExistsError:
        raise _refuse(path) from None
    except OSError:
        # File systems without hard links: check, then rename.
        if os.path.lexists(path):
            raise _refuse(path) from None
        os.replace(tmp, path)
        return
    os.unlink(tmp)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, overwrite: bool = False) -> Iterator[Path]:
    """Context manager yielding a temporary path that becomes ``path`` on success.

    Write the complete file to the yielded path inside the ``with`` block; on normal exit it
    is flushed to disk and renamed to ``path``; on an exception it is deleted and ``path`` is
    left as it was. Missing parent folders are created.

    Parameters
    ----------
    path : path
        Destination.
    overwrite : bool
        Replace an existing ``path``. Without it an existing file raises
        :class:`OutputError` (checked before and, race-free, at the rename).

    Raises
    ------
    OutputError
        ``path`` exists (without ``overwrite``), is a folder, lies below a file, or its folder
        cannot be created or written; the message names ``path``.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder; expected a file name")
    if not overwrite and os.path.lexists(path):
        raise _refuse(path)
    tmp = None
    try:
        for parent in path.parents:
            if parent.exists():
                if not parent.is_dir():
                    raise OutputError(f"cannot write {path}: {parent} is a file, not a folder")
                break
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
    except OSError as exc:
        if isinstance(exc, OutputError):
            raise
        raise OutputError(
            f"cannot write {path}: folder {path.parent} is not writable ({exc.strerror or exc})"
        ) from None
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        _publish(tmp, path, overwrite)
        tmp = None
        _fsync_dir(path.parent)
    except OutputError:
        raise
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


class ConcurrentWrites:
    """Run independent file writers in a few background threads.

    Each atomic write waits twice on the disk (``fsync`` of the file and of its folder), which
    releases the GIL: with several writers in flight those waits overlap with each other and
    with the caller's work, instead of adding up. Use as a context manager; :meth:`submit`
    queues ``fn(*args, **kwargs)``. On exit every queued write has finished, and the first
    error raised by one of them is raised again (the others still complete, each atomically).

    Parameters
    ----------
    threads : int
        Writer threads (≥ 1); 1 still overlaps the writes with the caller.
    """

    def __init__(self, threads: int = 4) -> None:
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
            raise InputError(f"threads must be a positive integer, got {threads!r}")
        self._threads = threads
        self._pool = None
        self._futures: list = []

    def __enter__(self) -> ConcurrentWrites:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="hrv-write")
        return self

    def submit(self, fn, /, *args, **kwargs) -> None:
        """Queue one write (call inside the ``with`` block)."""
        if self._pool is None:
            raise RuntimeError("ConcurrentWrites.submit outside its with block")
        self._futures.append(self._pool.submit(fn, *args, **kwargs))

    def __exit__(self, *exc_info) -> None:
        pool, self._pool = self._pool, None
        pool.shutdown(wait=True)
        futures, self._futures = self._futures, []
        if exc_info[0] is None:
            for fut in futures:  # in submission order: the first failed write is reported
                fut.result()


def atomic_write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically; see :func:`atomic_path`. Returns ``path``."""
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return path


def atomic_write_text(
    path: str | os.PathLike, text: str, *, overwrite: bool = False, encoding: str = "utf-8"
) -> Path:
    """Write ``text`` to ``path`` atomically; see :func:`atomic_path`. Returns ``path``."""
    return atomic_write_bytes(path, text.encode(encoding), overwrite=overwrite)


# -- JSON and checksums --------------------------------------------------------------------
def _plain(obj: Any) -> Any:
    """``obj`` with numpy scalars/arrays and paths made JSON types, NaN/inf as ``None``."""
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, Mapping):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def to_json(obj: Any, *, indent: int | None = 2) -> str:
    """``obj`` as JSON text: numpy scalars/arrays and paths converted, NaN/inf as ``null``.

    Raises
    ------
    InputError
        ``obj`` holds something JSON cannot represent (the message names its type).
    """
    try:
        return json.dumps(_plain(obj), indent=indent, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise InputError(f"cannot write as JSON: {exc}") from None


def rename_keys(obj: Any, names: Mapping[str, str]) -> Any:
    """``obj`` (plain JSON: dicts, lists, values) with every dict key found in ``names``
    renamed to ``names[key]``, at any depth (the fingerprints hash their entries under fixed
    names, docs/conventions.md §3)."""
    if isinstance(obj, dict):
        return {names.get(k, k): rename_keys(v, names) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [rename_keys(v, names) for v in obj]
    return obj


def write_json(path: str | os.PathLike, obj: Any, *, overwrite: bool = False) -> Path:
    """Write ``obj`` as indented JSON (trailing newline), atomically; see :func:`to_json`."""
    try:
        text = to_json(obj, indent=2)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    return atomic_write_text(path, text + "\n", overwrite=overwrite)


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing or invalid file raises :class:`InputError` naming it."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{path} is a folder; expected a JSON file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read JSON file {path}: {exc}") from None


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes (an unreadable file raises :class:`InputError`)."""
    path = Path(path)
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            while block := fh.read(chunk):
                h.update(block)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    return h.hexdigest()


def array_sha256(array: Any, dtype: str = "<f4") -> str:
    """Hex SHA-256 of an array's values as ``dtype`` (little-endian float32 by default), in
    C order: the checksum of a volume that does not depend on how it is stored (a TIFF file,
    chunks of a Zarr array)."""
    a = np.ascontiguousarray(np.asarray(array), dtype=np.dtype(dtype))
    return hashlib.sha256(memoryview(a).cast("B")).hexdigest()


def file_record(path: str | os.PathLike) -> dict:
    """``{"size": bytes, "sha256": hex}`` of a file just written, for :func:`verify_record`."""
    path = Path(path)
    return {"size": path.stat().st_size, "sha256": sha256_file(path)}


def verify_record(path: str | os.PathLike, record: Mapping | None) -> bool:
    """Whether ``path`` is still the file :func:`file_record` described.

    ``False`` when the file is missing, the record is missing or incomplete, or the size or
    checksum differ (a truncated or corrupt output): a resumed run then redoes that output.
    """
    path = Path(path)
    if not record or "size" not in record or "sha256" not in record:
        return False
    try:
        if not path.is_file() or path.stat().st_size != int(record["size"]):
            return False
    except OSError:
        return False
    try:
        return sha256_file(path) == record["sha256"]
    except InputError:
        return False


# -- outputs never touch the inputs --------------------------------------------------------
def _resolved(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.realpath(os.fspath(p))))


def guard_output(
    output: str | os.PathLike, inputs: Iterable[str | os.PathLike], *, option: str = "-o"
) -> None:
    """Refuse an output that would write onto, inside or around one of the user's inputs.

    The output (a file or a folder) must be none of the inputs, must not lie inside an input
    folder, and must not contain an input (a results folder around the frames it reads could
    be cleared by ``--overwrite``). Links are resolved. This holds even with ``--overwrite``.

    Parameters
    ----------
    output : path
        The file or folder about to be written.
    inputs : iterable of path
        Files and folders the user gave (missing ones are ignored).
    option : str
        How the user named the output, for the message (e.g. ``"-o"``).

    Raises
    ------
    OutputError
        One line naming the output, the input and the conflict.
    """
    out = _resolved(output)
    for item in inputs:
        if item is None:
            continue
        src = _resolved(item)
        if out == src:
            raise OutputError(
                f"{option} {output} is an input ({item}); refusing to write onto the user's "
                "data (choose another output path)"
            )
        if src.is_dir() and out.is_relative_to(src):
            raise OutputError(
                f"{option} {output} lies inside the input folder {item}; refusing to write "
                "into the user's data (choose an output outside it)"
            )
        if src.exists() and src.is_relative_to(out) and not out.is_file():
            raise OutputError(
                f"{option} {output} contains the input {item}; refusing to write around the "
                "user's data (choose a new output folder)"
            )


def check_output_file(
    path: str | os.PathLike,
    *,
    inputs: Iterable[str | os.PathLike] = (),
    overwrite: bool = False,
    option: str = "-o",
) -> Path:
    """Check, before any work, that the output file ``path`` may be written.

    Refuses (one line naming ``path``): an input or a path in or around an input
    (:func:`guard_output`, even with ``overwrite``), an existing file without ``overwrite``,
    a folder, and a path below a file.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    guard_output(path, inputs, option=option)
    if path.is_dir():
        raise OutputError(f"{option} {path} is a folder; expected a file name")
    if os.path.lexists(path) and not overwrite:
        raise OutputError(f"{path} already exists; pass --overwrite to replace it")
    _check_parents(path, "write")
    return path


def _check_parents(path: Path, verb: str) -> None:
    """The nearest existing folder above ``path`` is a writable folder."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"cannot {verb} {path}: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK):
                raise OutputError(f"cannot {verb} {path}: folder {parent} is not writable")
            return


def check_output_folder(path: str | os.PathLike) -> Path:
    """Check, before any work, that the output folder ``path`` can be created or written.

    Refuses (one line naming ``path``) a path below a file and one whose nearest existing
    folder is not writable. A ``path`` that is itself a file, or a folder of other contents,
    is the tool's to judge (its own message).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    if path.is_dir():
        if not os.access(path, os.W_OK):
            raise OutputError(f"cannot write into {path}: the folder is not writable")
        return path
    if not os.path.lexists(path):
        _check_parents(path, "create")
    return path


__all__ = [
    "ConcurrentWrites",
    "array_sha256",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_file",
    "check_output_folder",
    "file_record",
    "guard_output",
    "read_json",
    "rename_keys",
    "sha256_file",
    "to_json",
    "verify_record",
    "write_json",
]
