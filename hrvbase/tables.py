"""CSV tables: one writer (numpy) and one reader (with file and line in every error).

Every table of the toolkit is a header line of column names followed by one row per item:
particle positions, truth tables, matches, tracks. Integers are written as integers and floats
with 17 significant digits, so a table reads back exactly the float64 values written.
Missing values are written ``nan``; the reader refuses them unless asked to accept them.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .errors import InputError
from .io import atomic_write_text


def write_table(
    path: str | os.PathLike, columns: Mapping[str, np.ndarray], *, overwrite: bool = False
) -> Path:
    """Write named columns (equal lengths) as CSV, atomically.

    Parameters
    ----------
    path : path
        Destination; refused if it exists, unless ``overwrite``.
    columns : mapping of str to array_like, each shape (N,)
        Integer/boolean columns are written as integers, the others with ``%.17g``.

    Raises
    ------
    InputError
        Columns of different lengths (names ``path``).
    OutputError
        See :func:`hrvbase.io.atomic_path`.
    """
    names = list(columns)
    arrays = [np.asarray(columns[c]).reshape(-1) for c in names]
    lengths = {a.shape[0] for a in arrays}
    if len(lengths) > 1:
        raise InputError(f"{path}: columns of different lengths {sorted(lengths)}")
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    if arrays and arrays[0].shape[0]:
        fmt = ["%d" if a.dtype.kind in "iub" else "%.17g" for a in arrays]
        table = np.empty((arrays[0].shape[0], len(arrays)), dtype=object)
        for j, a in enumerate(arrays):
            table[:, j] = a.astype(np.int64) if a.dtype.kind in "iub" else a.astype(np.float64)
        np.savetxt(buf, table, fmt=fmt, delimiter=",")
    return atomic_write_text(path, buf.getvalue(), overwrite=overwrite)


def _cell(where: str, cell: str, integer: bool, allow_nan: bool):
    if integer:
        try:
            return int(cell)
        except ValueError:
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
            if math.isfinite(v) and v == int(v):
                return int(v)
            raise InputError(f"{where}: expected an integer, got {cell!r}") from None
    try:
        v = float(cell)
    except ValueError:
        raise InputError(f"{where}: expected a number, got {cell!r}") from None
    if not math.isfinite(v) and not allow_nan:
        raise InputError(f"{where}: expected a finite number, got {cell!r}")
    return v


def read_table(
    path: str | os.PathLike,
    *,
    required: Sequence[str],
    optional: Sequence[str] = (),
    integer: Sequence[str] = (),
    unknown: str = "ignore",
    allow_nan: bool = False,
    what: str = "table",
) -> dict[str, np.ndarray]:
    """Read the named columns of a CSV table (any column order; ``#`` lines and blank lines
    are skipped).

    Parameters
    ----------
    path : path
    required, optional : sequence of str
        Columns that must be / may be present.
    integer : sequence of str
        Columns read as int64 (a value like ``3.0`` is accepted); the others as float64.
    unknown : {"ignore", "refuse"}
        What to do with columns that are neither required nor optional.
    allow_nan : bool
        Accept ``nan``/``inf`` values.
    what : str
        What the table is, for messages (``"particle table"``).

    Returns
    -------
    dict of str to ndarray, each shape (N,)
        The required columns and the optional ones present.

    Raises
    ------
    InputError
        Missing, unreadable or empty file; missing, unknown or duplicated columns; a row of the
        wrong length; a non-numeric or non-finite value. The message names the file and line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} {path} does not exist or is not a file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {what} {path}: {exc}") from None
    known = [*required, *optional]
    ints = set(integer)
    header: list[str] | None = None
    values: dict[str, list] = {}
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if header is None:
            header = cells
            dup = sorted({c for c in header if header.count(c) > 1})
            if dup:
                raise InputError(f"{path}, line {lineno}: duplicated column(s) {dup}")
            if unknown == "refuse":
                extra = [c for c in header if c not in known]
                if extra:
                    raise InputError(
                        f"{path}, line {lineno}: unknown column(s) {extra}; expected some of "
                        f"{known}"
                    )
            missing = [c for c in required if c not in header]
            if missing:
                raise InputError(
                    f"{path}, line {lineno}: missing column(s) {', '.join(missing)} "
                    f"(the header is {','.join(header)})"
                )
            values = {c: [] for c in known if c in header}
            index = {c: header.index(c) for c in values}
            continue
        if len(cells) != len(header):
            raise InputError(
                f"{path}, line {lineno}: expected {len(header)} values ({','.join(header)}), "
                f"got {len(cells)}"
            )
        for c, j in index.items():
            where = f"{path}, line {lineno}, column {c!r}"
            values[c].append(_cell(where, cells[j], c in ints, allow_nan))
    if header is None:
        raise InputError(
            f"{what} {path} is empty; expected a header with columns {','.join(required)}"
        )
    return {
        c: np.asarray(v, dtype=np.int64 if c in ints else np.float64) for c, v in values.items()
    }


__all__ = ["read_table", "write_table"]
