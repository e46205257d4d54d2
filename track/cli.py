"""The ``track`` command line: detect particles, link them, grid displacement and strain.

A thin layer over :mod:`track.pipeline` (:func:`~track.pipeline.track_volumes`,
:func:`~track.pipeline.track_clouds`): options → settings dataclasses (whose defaults are the
options' defaults) → pipeline → exit status and a one-line summary.

Commands::

    track run VOLDIR -o RESULTS [--mode incremental|cumulative] [--grid-spacing-um X]
              [--threshold auto|F] [--no-deconvolution] [--overwrite] ...
    track detect VOLDIR -o RESULTS [detection options] [--overwrite]
    track link A.csv B.csv [C.csv ...] -o RESULTS [--mode ...] [--grid-spacing-um X] ...

``VOLDIR`` holds numbered float32 volumes ``NNNNNN.tif`` (voxel size in the TIFF description
or in ``recon.json``, see :mod:`track.io`); ``link`` takes point clouds (CSV with columns
``x_um, y_um, z_um``) from any localisation source, frame 0 first.

``RESULTS`` receives ``particles/NNNNNN.csv``, ``matches_NNNNNN.csv`` (one per linked pair,
``NNNNNN`` = deformed frame), ``tracks.csv``, ``fields/NNNNNN.npz`` and ``.vti`` (total
field from frame 0 to frame ``NNNNNN`` on the reference grid; incremental mode also
``fields/increment_NNNNNN.npz``) and ``summary.json`` (parameters, input checksums, counts,
tracking ratio and status of every pair, timings). Every file is written atomically.

Resuming: ``run``/``detect`` record each volume's SHA-256 in ``summary.json`` and skip the
detection of volumes whose particle table exists with the same checksum; linking and fields
are recomputed. A ``RESULTS`` folder made from other inputs or detection settings is refused
unless ``--overwrite`` (which then deletes only files ``track`` writes); a non-empty folder
without a ``summary.json`` written by ``track`` is always refused.

Exit status and failures:

- ``0``: every step worked (``summary.json`` status ``"complete"``), or some failed and
  ``--allow-partial`` was given (status ``"partial"``; each failure is a warning);
- ``2``: an error a user can cause (bad option, input file or results folder), printed as
  one line ``track: error: <message>``; an explicit ``--grid-spacing-um`` that gives more
  nodes than ``10 × --target-nodes`` (and at most 2 000 000) or a single cell is refused
  before any work;
- ``3``: the run finished but some frames failed: a pair that could not be linked (fewer
  than 4 particles, no consistent matches), a field that could not be gridded, or (``detect``)
  a volume without particles. The results of everything that worked are written (each pair's
  status in ``summary.json``, whose status is ``"failed"``), and one line names the first
  failing frames and the reason, e.g. ``track: error: frames 3 → 4: skipped: fewer than 4
  particles in frame 4 (2 found) (use --allow-partial to keep partial results)``;
- ``130``: interrupted.

Unless ``-q``, ``run``, ``detect`` and ``link`` show progress bars (on a terminal) and end
with one line on stdout such as ``RESULTS: 7 volumes, 24–25 particles/frame, 6/6 pairs
linked, tracking ratio ≥ 0.96, 6 fields, 12.3 s``.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

from hrvbase.errors import HrvError

from . import __version__
from . import io as tio
from .errors import FailedFramesError
from .fields import GridSettings
from .series import MAX_GRID_NODES, MODES, SeriesSettings, check_grid

log = logging.getLogger("track.cli")

#: Exit status of a run that finished with failed frames (without ``--allow-partial``).
EXIT_FAILED = 3


class _Parser(argparse.ArgumentParser):
    """Argument parser whose errors are one line ``track: error: ...`` (exit 2)."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"track: error: {message}\n")
        raise SystemExit(2)


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def _int_in(lo: int, hi: int):
    """argparse type: an integer in ``lo..hi``."""
    message = f"expected an integer in {lo}..{hi}, got {{!r}}"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(message.format(text)) from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(message.format(text))
        return v

    return parse


def _keyword_or_number(keyword: str, ok, expected: str):
    """argparse type: ``keyword`` itself, or a finite number for which ``ok(v)`` holds."""
    message = f"expected '{keyword}' or {expected}, got {{!r}}"

    def parse(text: str) -> float | str:
        if text == keyword:
            return text
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(message.format(text)) from None
        if not (math.isfinite(v) and ok(v)):
            raise argparse.ArgumentTypeError(message.format(text))
        return v

    return parse


_smoothing = _keyword_or_number("gcv", lambda v: v >= 0, "a number >= 0")
_threshold = _keyword_or_number("auto", lambda v: 0 < v < 1, "a fraction in (0, 1)")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, type=Path, metavar="RESULTS")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a RESULTS folder made by track from other inputs or settings",
    )
    p.add_argument(
        "--allow-partial",
        action="store_true",
        help="keep going when frames fail (warnings, exit 0, summary status 'partial') "
        "instead of exit status 3",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more messages")
    p.add_argument("-q", "--quiet", action="store_true", help="errors only")


def _detect_options(p: argparse.ArgumentParser) -> None:
    from .detect import DetectSettings

    d = DetectSettings()
    g = p.add_argument_group("detection")
    g.add_argument(
        "--threshold",
        type=_threshold,
        default=d.threshold,
        help=f"binarisation threshold: fraction of the intensity range (default: "
        f"{d.threshold}, the paper's 0.25) or 'auto'",
    )
    g.add_argument(
        "--no-deconvolution", action="store_true", help="skip the secondary deconvolution"
    )
    g.add_argument(
        "--deconvolution-iterations",
        type=_count,
        default=d.deconvolution_iterations,
        metavar="N",
        help="Richardson-Lucy iterations of the secondary deconvolution "
        f"(default {d.deconvolution_iterations})",
    )
    g.add_argument("--blob-min-vox", type=_count, default=d.blob_min_vox, metavar="N")
    g.add_argument("--blob-max-vox", type=_count, default=d.blob_max_vox, metavar="N")
    g.add_argument("--method", choices=("radial", "centroid"), default=d.method)
    g.add_argument("--edge-margin-um", type=float, default=d.edge_margin_um, metavar="UM")


def _link_options(p: argparse.ArgumentParser) -> None:
    from .matching import LinkSettings
    from .pipeline import VTI_ENCODINGS

    grid, series = GridSettings(), SeriesSettings()
    g = p.add_argument_group("linking and fields")
    g.add_argument("--mode", choices=MODES, default=series.mode)
    g.add_argument(
        "--grid-spacing-um",
        type=_positive_float,
        default=grid.spacing_um,
        metavar="UM",
        help="node spacing of the gridded fields (default: about --target-nodes nodes); "
        "refused when it gives more than 10 × --target-nodes nodes",
    )
    g.add_argument(
        "--target-nodes",
        type=_int_in(8, MAX_GRID_NODES),
        default=grid.target_nodes,
        metavar="N",
        help=f"nodes of the default grid (default {grid.target_nodes}, at most {MAX_GRID_NODES})",
    )
    g.add_argument(
        "--interpolation", choices=("rbf", "linear"), default=grid.method, help="gridding method"
    )
    g.add_argument(
        "--smoothing",
        type=_smoothing,
        default=grid.smoothing,
        metavar="gcv|LAMBDA",
        help="RBF smoothing of the gridded fields: 'gcv' (default: chosen per displacement "
        "component by generalised cross-validation) or a number >= 0 (0: exact interpolation)",
    )
    g.add_argument("--no-fields", action="store_true", help="only link; no gridded fields")
    g.add_argument("--vti-encoding", choices=VTI_ENCODINGS, default=VTI_ENCODINGS[0])
    g.add_argument(
        "--seed", type=_count, default=LinkSettings().seed, help="seed of the linker's RANSAC"
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``track`` argument parser."""
    p = _Parser(prog="track", description="Particle tracking and strain from volumes.")
    p.add_argument("--version", action="version", version=f"track {__version__}")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)
    r = sub.add_parser("run", help="detect → link → fields for a folder of volumes")
    r.add_argument("voldir", type=Path, metavar="VOLDIR")
    _common(r)
    _detect_options(r)
    _link_options(r)
    r.set_defaults(func=cmd_run)
    d = sub.add_parser("detect", help="detect particles in a folder of volumes")
    d.add_argument("voldir", type=Path, metavar="VOLDIR")
    _common(d)
    _detect_options(d)
    d.set_defaults(func=cmd_detect)
    k = sub.add_parser("link", help="link point clouds (CSV) and compute fields")
    k.add_argument("clouds", type=Path, nargs="+", metavar="CSV")
    _common(k)
    _link_options(k)
    k.set_defaults(func=cmd_link)
    return p


# -- options → settings ----------------------------------------------------------------------
def detect_settings(args: argparse.Namespace):
    """The :class:`~track.detect.DetectSettings` of parsed ``run``/``detect`` options."""
    from .detect import DetectSettings

    iters = 0 if args.no_deconvolution else args.deconvolution_iterations
    return DetectSettings(
        deconvolution_iterations=iters,
        threshold=args.threshold,
        blob_min_vox=args.blob_min_vox or None,
        blob_max_vox=args.blob_max_vox or None,
        method=args.method,
        edge_margin_um=args.edge_margin_um,
    )


def series_settings(args: argparse.Namespace) -> SeriesSettings:
    """The :class:`~track.series.SeriesSettings` of parsed ``run``/``link`` options."""
    from .matching import LinkSettings

    grid = GridSettings(
        spacing_um=args.grid_spacing_um,
        target_nodes=int(args.target_nodes),
        method=args.interpolation,
        smoothing=args.smoothing,
    )
    return SeriesSettings(
        mode=args.mode,
        grid=grid,
        link=LinkSettings(seed=int(args.seed)),
        compute_fields=not args.no_fields,
    )


def _check_grid_option(args, extent_xyz_um, where: str) -> None:
    """Refuse a ``--grid-spacing-um`` that gives too many nodes, or a single cell (before
    the pipeline does, so that the message names the options)."""
    if args.no_fields:
        return
    check_grid(
        extent_xyz_um,
        series_settings(args).grid,
        where=where,
        spacing_name="--grid-spacing-um",
        target_name="--target-nodes",
    )


def _common_kwargs(args) -> dict:
    return {
        "overwrite": args.overwrite,
        "allow_partial": args.allow_partial,
        "progress": not (args.no_progress or args.quiet),
        "provenance": {"argv": list(args.argv)},
    }


# -- commands --------------------------------------------------------------------------------
def _report(args, call) -> int:
    """Run a pipeline call; print the RESULTS line (unless -q); the exit status."""
    from .pipeline import failure_message

    try:
        result = call()
    except FailedFramesError as exc:
        if not args.quiet and exc.result is not None:
            sys.stdout.write(exc.result.results_line() + "\n")
            sys.stdout.flush()
        line = failure_message(exc.failures, hint="--allow-partial")
        sys.stderr.write(f"track: error: {line}\n")
        return EXIT_FAILED
    if not args.quiet:
        sys.stdout.write(result.results_line() + "\n")
    return 0


def cmd_detect(args) -> int:
    """``track detect``: detect particles in every volume."""
    from .pipeline import track_volumes

    settings = detect_settings(args)
    return _report(
        args,
        lambda: track_volumes(
            args.voldir, args.output, detect=settings, series=None, **_common_kwargs(args)
        ),
    )


def cmd_run(args) -> int:
    """``track run``: detect, link, grid."""
    from .pipeline import track_volumes, volume_extent_um

    detect, series = detect_settings(args), series_settings(args)  # validate before any work
    vols = tio.scan_volumes(args.voldir)
    _check_grid_option(args, volume_extent_um(vols[0]), "the volume")
    return _report(
        args,
        lambda: track_volumes(
            args.voldir,
            args.output,
            detect=detect,
            series=series,
            vti_encoding=args.vti_encoding,
            **_common_kwargs(args),
        ),
    )


def cmd_link(args) -> int:
    """``track link``: link point clouds given as CSV files."""
    from .pipeline import track_clouds

    series = series_settings(args)
    if len(args.clouds) >= 2:
        first = tio.read_points_csv(args.clouds[0])
        if first.shape[0] >= 2:
            _check_grid_option(args, np.ptp(first, axis=0), "frame 0's particles")
    return _report(
        args,
        lambda: track_clouds(
            args.clouds,
            args.output,
            series=series,
            vti_encoding=args.vti_encoding,
            **_common_kwargs(args),
        ),
    )


class _Formatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"track: {record.levelname.lower()}: {record.getMessage()}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``track``; returns the exit status (0 success, 2 user error, 3 failed
    frames, 130 interrupted: see the module docstring)."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error (already printed)
        return int(exc.code or 0)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    args.argv = argv
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter())
    level = logging.ERROR if args.quiet else (logging.WARNING, logging.INFO)[min(args.verbose, 1)]
    if args.verbose >= 2:
        level = logging.DEBUG
    root = logging.getLogger("track")
    saved = root.level
    root.setLevel(level)
    root.addHandler(handler)
    try:
        return int(args.func(args))
    except HrvError as exc:
        message = " ".join(str(exc).split())
        sys.stderr.write(f"track: error: {message}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("track: interrupted\n")
        return 130
    finally:
        root.removeHandler(handler)
        root.setLevel(saved)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


__all__ = ["EXIT_FAILED", "build_parser", "detect_settings", "main", "series_settings"]
