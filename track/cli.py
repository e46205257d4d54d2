"""The ``track`` command line: detect particles, link them, grid displacement and strain.

A thin layer over :mod:`track.pipeline` (:func:`~track.pipeline.track_volumes`,
:func:`~track.pipeline.track_clouds`): options → settings dataclasses (whose defaults are the
options' defaults) → pipeline → exit status and a one-line summary.

Commands::

    track run VOLDIR -o RESULTS [--mode incremental|cumulative] [--grid-spacing-um X]
              [--threshold auto|F] [--no-deconvolution] [--overwrite] ...
    track detect VOLDIR -o RESULTS [detection options] [--overwrite]
    track link A.csv B.csv [C.csv ...] -o RESULTS [--mode ...] [--grid-spacing-um X] ...

``VOLDIR`` holds numbered float32 volumes ``NNNNNN.tif`` (voxel size and origin in the TIFF
metadata or in ``recon.json``, see :mod:`track.volumes` and docs/conventions.md §6), or is
an OME-Zarr image (``recon run --format zarr``: its frames, voxel size and origin from its
OME-NGFF metadata); ``link``
takes point clouds (CSV with columns ``x_um, y_um, z_um``) from any localisation source,
frame 0 first.

``RESULTS`` receives ``particles/NNNNNN.csv``, ``matches_NNNNNN.csv`` (one per linked pair,
``NNNNNN`` = deformed frame), ``tracks.csv``, ``fields/NNNNNN.npz`` and ``.vti`` (total
field from frame 0 to frame ``NNNNNN`` on the reference grid; incremental mode also
``fields/increment_NNNNNN.npz``) and ``summary.json`` (parameters, input checksums, counts,
tracking ratio and status of every pair, timings). Every file is written atomically.

Frames in parallel: ``run``/``detect`` ``--workers N`` detect N volumes at a time on local
Dask worker processes, ``--scheduler ADDRESS`` on the workers of an existing Dask cluster
(:mod:`hrvbase.parallel`); linking runs in this process and starts on the first frames while
the others are still being detected. ``run``/``link`` then fit and grid N increments at a time
on the workers (``run``: the detection's local cluster, or the same ``--scheduler``), the
Eulerian cumulation running here as they arrive. The results are the same as with one worker.

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
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from hrvbase.cli import (
    SettingOption,
    add_flags,
    add_parallel_options,
    add_setting_options,
    int_in,
    number,
    parallel_from_args,
    run_main,
    settings_from_args,
    show_progress,
    tool_parser,
)

from . import __version__
from .errors import FailedFramesError
from .grid import BOX_GRID_NODES, PARTICLE_GRID_MAX_NODES, GridSettings
from .series_settings import MAX_GRID_NODES, MODES, SeriesSettings, check_grid
from .tables import read_points_csv
from .volumes import VolumeInfo, scan_volumes

log = logging.getLogger("track.cli")

#: Exit status of a run that finished with failed frames (without ``--allow-partial``).
EXIT_FAILED = 3


_positive_float = number(lambda v: v > 0, "a positive number")
_non_negative = number(lambda v: v >= 0, "a number >= 0")


def _numbers_zyx(*, one: bool, positive: bool) -> Callable[[str], float | tuple]:
    """Parser of ``Z,Y,X`` (three numbers, array order) or, with ``one``, a single number."""
    expected = (
        f"{'one number or ' if one else ''}three numbers Z,Y,X "
        f"{'> 0' if positive else '>= 0'} separated by commas"
    )

    def parse(text: str) -> float | tuple:
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            vals = []
        ok = len(vals) == 3 or (one and len(vals) == 1)
        ok = ok and all(math.isfinite(v) and (v > 0 if positive else v >= 0) for v in vals)
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return vals[0] if len(vals) == 1 else tuple(vals)

    return parse


_count = int_in(0)
_int_in = int_in
_smoothing = number(lambda v: v >= 0, "a number >= 0", keyword="gcv")
_threshold = number(lambda v: 0 < v < 1, "a fraction in (0, 1)", keyword="auto")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "-o", "--output", required=True, type=Path, metavar="RESULTS", help="results folder"
    )
    add_flags(
        p,
        {
            "--overwrite": "replace a RESULTS folder made by track from other inputs or settings "
            "(default: refuse)",
            "--allow-partial": "keep going when frames fail (warnings, exit 0, summary status "
            "'partial'; default: exit status 3)",
            "--no-progress": "no progress bars (default: shown)",
        },
    )


#: Options of the detection settings (:class:`track.detect.DetectSettings`).
DETECT_OPTIONS = (
    SettingOption(
        "threshold",
        ("--threshold",),
        "binarisation threshold: a fraction of the intensity range (the paper's 0.25) or 'auto'",
        _threshold,
        "auto|F",
    ),
    SettingOption(
        "deconvolution_iterations",
        ("--deconvolution-iterations",),
        "Richardson-Lucy iterations of the secondary deconvolution",
        _count,
        "N",
    ),
    SettingOption("blob_min_vox", ("--blob-min-vox",), "smallest blob in voxels", _count, "N"),
    SettingOption("blob_max_vox", ("--blob-max-vox",), "largest blob in voxels", _count, "N"),
    SettingOption(
        "method", ("--method",), "sub-voxel localisation", choices=("radial", "centroid")
    ),
    SettingOption(
        "edge_margin_um",
        ("--edge-margin-um",),
        "margin in µm a blob must keep from the faces of the volume",
        float,
        "UM",
    ),
    SettingOption(
        "smooth_fwhm",
        ("--smooth-fwhm",),
        "band-pass before segmentation: Gaussian smoothing of σ = this × the particles' FWHM "
        "measured on the volume, per axis (0: none)",
        _non_negative,
        "F",
    ),
    SettingOption(
        "background_fwhm",
        ("--background-fwhm",),
        "band-pass: σ of the subtracted local background, in measured FWHM (0: none; "
        "else > --smooth-fwhm)",
        _non_negative,
        "F",
    ),
    SettingOption(
        "min_peak_snr",
        ("--min-peak-snr",),
        "a blob is a particle only if its band-passed peak stands this many noise σ above "
        "the background (0: test off)",
        _non_negative,
        "K",
    ),
    SettingOption(
        "sigma_noise_factor",
        ("--sigma-noise-factor",),
        "factor on the localiser's voxel-noise σ (the random part of each particle's σ), "
        "one number or Z,Y,X; calibrate it on simulated data of your setup "
        "(benchmarks/calibrate_sigma.py)",
        _numbers_zyx(one=True, positive=True),
        "F|Z,Y,X",
    ),
    SettingOption(
        "sigma_systematic_um",
        ("--sigma-systematic-um",),
        "per-particle systematic error Z,Y,X in µm, added in quadrature to each particle's σ "
        "(it cancels in displacements)",
        _numbers_zyx(one=False, positive=False),
        "Z,Y,X",
    ),
    SettingOption(
        "sigma_snr_um",
        ("--sigma-snr-um",),
        "random error Z,Y,X in µm at a camera SNR of 1, falling as 1/SNR with each frame's "
        "SNR (recon run records it), added in quadrature to each particle's σ (default 0: off)",
        _numbers_zyx(one=False, positive=False),
        "Z,Y,X",
    ),
    SettingOption(
        "max_rel_aspect",
        ("--max-rel-aspect",),
        "largest aspect ratio of a blob relative to the median blob's (>= 1)",
        number(lambda v: v >= 1, "a number >= 1"),
        "R",
    ),
)

#: Options of the gridded fields (:class:`track.fields.GridSettings`).
GRID_OPTIONS = (
    SettingOption(
        "spacing_um",
        ("--grid-spacing-um",),
        "node spacing of the gridded fields in µm (refused when it gives more than "
        f"10 × --target-nodes nodes, {PARTICLE_GRID_MAX_NODES} without it)",
        _positive_float,
        "UM",
    ),
    SettingOption(
        "target_nodes",
        ("--target-nodes",),
        f"sample the particles' bounding box with about N nodes (the paper: {BOX_GRID_NODES}) "
        f"instead of following the particle density (at most {MAX_GRID_NODES})",
        _int_in(8, MAX_GRID_NODES),
        "N",
    ),
    SettingOption(
        "nodes_per_spacing",
        ("--nodes-per-spacing",),
        "the default grid follows the particles: node spacing = their median nearest-neighbour "
        f"distance / this (at most {PARTICLE_GRID_MAX_NODES} nodes; ignored with "
        "--target-nodes or --grid-spacing-um)",
        _positive_float,
        "K",
    ),
    SettingOption("method", ("--interpolation",), "gridding method", choices=("rbf", "linear")),
    SettingOption(
        "smoothing",
        ("--smoothing",),
        "RBF smoothing of the gridded fields: 'gcv' (chosen per displacement component by "
        "generalised cross-validation) or a number >= 0 (0: exact interpolation)",
        _smoothing,
        "gcv|LAMBDA",
    ),
)

#: Options of the series (:class:`track.series.SeriesSettings`).
SERIES_OPTIONS = (
    SettingOption(
        "mode", ("--mode",), "link each frame to the previous one or to frame 0", choices=MODES
    ),
    SettingOption(
        "bias_sigma_um",
        ("--bias-sigma-um",),
        "per-match σ: the part Z,Y,X (µm) of a particle's bias that changes as it moves",
        _numbers_zyx(one=False, positive=False),
        "Z,Y,X",
    ),
    SettingOption(
        "bias_length_um",
        ("--bias-length-um",),
        "displacement (µm; one number or Z,Y,X) over which that bias decorrelates",
        _numbers_zyx(one=True, positive=True),
        "L|Z,Y,X",
    ),
    SettingOption(
        "bias_period_um",
        ("--bias-period-um",),
        "lateral period P (µm) of that bias: the microlens pitch in the object (MLA pitch / "
        "magnification); 0: none",
        _non_negative,
        "P",
    ),
    SettingOption(
        "bias_lateral_depth_length_um",
        ("--bias-lateral-depth-length-um",),
        "move in depth (µm) over which the x and y bias decorrelates (default: the z length "
        "of --bias-length-um)",
        _positive_float,
        "D",
    ),
    SettingOption(
        "static_frames",
        ("--static-frames",),
        "the first N frames are at rest: report the spread of the displacements between them "
        "as the zero-displacement noise floor per axis (0: none)",
        _count,
        "N",
    ),
    SettingOption(
        "max_gap_frames",
        ("--max-gap-frames",),
        "incremental mode: a particle missed in up to N frames in a row keeps its track "
        "(bridged where the tracks around it predict it)",
        _count,
        "N",
    ),
)

#: Options of the linker (:class:`track.matching.LinkSettings`).
LINK_OPTIONS = (SettingOption("seed", ("--seed",), "seed of the linker's RANSAC", _count, "N"),)


def _detect_options(p: argparse.ArgumentParser) -> None:
    from .detect import DetectSettings

    g = p.add_argument_group("detection")
    add_setting_options(g, DetectSettings, DETECT_OPTIONS, prefix="detect_")
    add_flags(g, {"--no-deconvolution": "skip the secondary deconvolution (default: on)"})


def _link_options(p: argparse.ArgumentParser) -> None:
    from .matching import LinkSettings
    from .pipeline import VTI_ENCODINGS

    g = p.add_argument_group("linking and fields")
    add_setting_options(g, SeriesSettings, SERIES_OPTIONS, prefix="series_")
    add_setting_options(g, GridSettings, GRID_OPTIONS, prefix="grid_", derived="automatic")
    add_setting_options(g, LinkSettings, LINK_OPTIONS, prefix="link_")
    add_flags(
        g,
        {
            "--no-fields": "only link; no gridded fields (default: off)",
            "--no-bridge": "incremental mode: a track ends where its particle was missed or left "
            "unmatched; no bridging over gaps (default: bridged)",
            "--no-predictor": "incremental mode: do not start each pair from the previous "
            "increment's field (default: on)",
        },
    )
    g.add_argument(
        "--vti-encoding",
        choices=VTI_ENCODINGS,
        default=VTI_ENCODINGS[0],
        help=f"encoding of the ParaView .vti files (default: {VTI_ENCODINGS[0]})",
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``track`` argument parser."""
    p, sub, common = tool_parser(
        "track", "Particle tracking and strain from volumes.", f"track (hrvptm) {__version__}"
    )

    def command(name: str, text: str, func, inputs, options, parallel: str) -> None:
        """Sub-command ``name`` running ``func``: its ``inputs`` argument (name and keywords
        of ``add_argument``), the options every command takes, its own ``options`` and the
        parallel options titled ``parallel``."""
        q = sub.add_parser(name, parents=[common], help=text)
        q.add_argument(inputs[0], type=Path, **inputs[1])
        _common(q)
        for add in options:
            add(q)
        add_parallel_options(q.add_argument_group(parallel))
        q.set_defaults(func=func)

    volumes = (
        "voldir",
        {"metavar": "VOLDIR", "help": "folder of NNNNNN.tif volumes, or an OME-Zarr image (.zarr)"},
    )
    clouds = (
        "clouds",
        {
            "nargs": "+",
            "metavar": "CSV",
            "help": "point clouds with columns x_um,y_um,z_um, frame 0 first",
        },
    )

    command(
        "run",
        "detect → link → fields for a folder of volumes",
        cmd_run,
        volumes,
        (_detect_options, _link_options),
        "frames in parallel (detection and fields)",
    )
    command(
        "detect",
        "detect particles in a folder of volumes",
        cmd_detect,
        volumes,
        (_detect_options,),
        "frames in parallel",
    )
    command(
        "link",
        "link point clouds (CSV) and compute fields",
        cmd_link,
        clouds,
        (_link_options,),
        "increments in parallel (fields)",
    )
    return p


# -- options → settings ----------------------------------------------------------------------
def detect_settings(args: argparse.Namespace):
    """The :class:`~track.detect.DetectSettings` of parsed ``run``/``detect`` options."""
    from .detect import DetectSettings

    extra = {"deconvolution_iterations": 0} if args.no_deconvolution else {}
    return settings_from_args(DetectSettings, args, DETECT_OPTIONS, extra=extra, prefix="detect_")


def series_settings(args: argparse.Namespace) -> SeriesSettings:
    """The :class:`~track.series.SeriesSettings` of parsed ``run``/``link`` options."""
    from .matching import LinkSettings

    grid = settings_from_args(GridSettings, args, GRID_OPTIONS, prefix="grid_")
    link = settings_from_args(LinkSettings, args, LINK_OPTIONS, prefix="link_")
    return settings_from_args(
        SeriesSettings,
        args,
        SERIES_OPTIONS,
        extra={
            "grid": grid,
            "link": link,
            "compute_fields": not args.no_fields,
            "predictor": not args.no_predictor,
            "bridge_tracks": not args.no_bridge,
        },
        prefix="series_",
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


def _check_edge_margin(settings, volume: VolumeInfo) -> None:
    """Refuse an ``--edge-margin-um`` that leaves no voxel a blob could occupy (every blob
    would be dropped, and every frame fail)."""
    from hrvbase.errors import InputError

    margin = settings.edge_margin_um
    for n, d in zip(volume.shape, volume.voxel_size_um, strict=True):
        if 2 * math.ceil(margin / d) >= n:
            size = " × ".join(
                f"{(m - 1) * v:.4g}"
                for m, v in zip(volume.shape, volume.voxel_size_um, strict=True)
            )
            raise InputError(
                f"--edge-margin-um {margin:g} µm leaves no room inside the volumes "
                f"({size} µm, z × y × x): keep it below half the smallest size"
            )


def _common_kwargs(args) -> dict:
    from hrvbase.io import check_output_folder, guard_output

    guard_output(args.output, getattr(args, "clouds", None) or [args.voldir])
    check_output_folder(args.output)
    return {
        "overwrite": args.overwrite,
        "allow_partial": args.allow_partial,
        "progress": show_progress(args),
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
    parallel = parallel_from_args(args)
    _check_edge_margin(settings, scan_volumes(args.voldir)[0])
    return _report(
        args,
        lambda: track_volumes(
            args.voldir,
            args.output,
            detect=settings,
            series=None,
            parallel=parallel,
            **_common_kwargs(args),
        ),
    )


def cmd_run(args) -> int:
    """``track run``: detect, link, grid."""
    from .pipeline import track_volumes, volume_extent_um

    detect, series = detect_settings(args), series_settings(args)  # validate before any work
    parallel = parallel_from_args(args)
    vols = scan_volumes(args.voldir)
    _check_edge_margin(detect, vols[0])
    _check_grid_option(args, volume_extent_um(vols[0]), "the volume")
    return _report(
        args,
        lambda: track_volumes(
            args.voldir,
            args.output,
            detect=detect,
            series=series,
            vti_encoding=args.vti_encoding,
            parallel=parallel,
            **_common_kwargs(args),
        ),
    )


def cmd_link(args) -> int:
    """``track link``: link point clouds given as CSV files."""
    from .pipeline import track_clouds

    series = series_settings(args)
    parallel = parallel_from_args(args)
    if len(args.clouds) >= 2:
        first = read_points_csv(args.clouds[0])
        if first.shape[0] >= 2:
            _check_grid_option(args, np.ptp(first, axis=0), "frame 0's particles")
    return _report(
        args,
        lambda: track_clouds(
            args.clouds,
            args.output,
            series=series,
            vti_encoding=args.vti_encoding,
            parallel=parallel,
            **_common_kwargs(args),
        ),
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``track``; returns the exit status (0 success, 2 user error, 3 failed
    frames, 130 interrupted: see the module docstring)."""
    return run_main("track", build_parser(), argv, loggers=("track",))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


__all__ = ["EXIT_FAILED", "build_parser", "detect_settings", "main", "series_settings"]
