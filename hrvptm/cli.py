"""The ``hrvptm`` command line: validation studies end to end.

Commands::

    hrvptm study EXPERIMENT.toml -o REPORT [--until STAGE] [--overwrite] [-q | -v]
                 [--workers N | --scheduler ADDRESS]
    hrvptm demo -o DIR [--overwrite] [-q | -v] [--workers N | --scheduler ADDRESS]
    hrvptm collect REPORT [REPORT ...] -o validation.md [--preamble INTRO.md]
    hrvptm axial VOLDIR -o RESULTS [--track-config TRACK.toml] [--sphere-diameter-um D]
                 [--reference-rays N] [--z-only] [--overwrite] [--allow-partial]
                 [--workers N | --scheduler ADDRESS]

``study`` simulates the experiment with lfsim, reconstructs it with recon, tracks it with
track and compares every frame with the truth (:mod:`hrvptm.study`); a rerun resumes.
``demo`` runs the built-in small study (simple shear at test size, a few minutes on 2 cores)
and prints its summary. ``collect`` gathers finished reports into one Markdown page (the
project's ``docs/validation.md``). ``axial`` tracks real volumes (``recon run``'s folder
or OME-Zarr image) with the simulator self-calibration of the reconstruction's position bias
(:mod:`hrvptm.calibrated`: the microscope model from ``VOLDIR/recon.json``; detection and
linking settings from the ``[track]`` tables of ``--track-config``, as in a study file);
``RESULTS`` receives ``detect/``, ``axial/`` and ``track/`` (the results, as ``track run``
writes them), and a failed frame exits with 3 as ``track run`` does. ``--workers`` /
``--scheduler`` run the frames of the simulation, reconstruction and detection stages on Dask
workers (:mod:`hrvbase.parallel`), with the same results.

Errors a user can cause print one line ``hrvptm: error: <message>`` and exit with status 2.
So does a study whose frames failed (not tracked, far too few particles detected, tracking
ratio below 50 %; :mod:`hrvptm.analysis`), after writing its report (``status: "failed"``,
no comparison with the paper met), unless ``--allow-partial``.
"""

from __future__ import annotations

import argparse
import logging
import math
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from .errors import StudyConfigError

log = logging.getLogger("hrvptm")

#: The demo study (repository file, see scenes/experiments/README.md).
DEMO = Path(__file__).resolve().parent.parent / "scenes" / "experiments" / "demo_simple_shear.toml"


def build_parser() -> argparse.ArgumentParser:
    """The ``hrvptm`` argument parser."""
    from hrvbase.cli import add_flags, add_parallel_options, tool_parser

    from . import __version__

    p, sub, shared = tool_parser(
        "hrvptm", "Validation studies of the HR-VPTM toolkit.", f"hrvptm {__version__}"
    )

    def common(
        q: argparse.ArgumentParser,
        overwrite: str = "reuse a report folder of another study",
        partial: str = "the report still says FAILED",
    ) -> None:
        add_flags(
            q,
            {
                "--overwrite": f"{overwrite} (default: refuse)",
                "--allow-partial": f"exit 0 when frames failed ({partial})",
            },
        )
        add_parallel_options(q)

    def command(
        name: str, text: str, description: str, func, output: tuple[str, str]
    ) -> argparse.ArgumentParser:
        """Sub-command ``name`` running ``func``, with its required ``-o`` (metavar, help)."""
        q = sub.add_parser(name, parents=[shared], help=text, description=description)
        q.set_defaults(func=func)
        metavar, what = output
        q.add_argument("-o", "--output", required=True, type=Path, metavar=metavar, help=what)
        return q

    st = command(
        "study",
        "run a validation study end to end",
        "Simulate → reconstruct → track → compare with the truth; writes CSV tables, plots, "
        "summary.md and summary.json into REPORT. A rerun resumes.",
        cmd_study,
        ("REPORT", "report folder"),
    )
    st.add_argument(
        "experiment", type=Path, metavar="EXPERIMENT.toml", help="study file (experiment TOML)"
    )
    st.add_argument(
        "--until",
        choices=("simulate", "reconstruct", "track", "analyse"),
        default="analyse",
        help="last stage to run (default: all, with the report)",
    )
    common(st)

    de = command(
        "demo",
        "the built-in small study (simple shear, test size)",
        f"Run {DEMO.name} end to end and print its summary.",
        cmd_demo,
        ("DIR", "report folder"),
    )
    common(de)

    co = command(
        "collect",
        "gather study reports into one Markdown page",
        "Gather the summary.md of finished reports into one page with their plots.",
        cmd_collect,
        ("PAGE.md", "Markdown page"),
    )
    co.add_argument("reports", type=Path, nargs="+", metavar="REPORT", help="finished reports")
    co.add_argument(
        "--preamble",
        type=Path,
        default=None,
        metavar="INTRO.md",
        help="Markdown file to use as the page header (default: a generated one)",
    )
    add_flags(
        co,
        {
            "--overwrite": "replace a page an earlier collect wrote (default: refuse an "
            "existing page)"
        },
    )
    from recon.reference import ReferenceSettings

    ref = ReferenceSettings()  # the references' defaults, defined there once
    ax = command(
        "axial",
        "track volumes with the simulator self-calibration of their position bias",
        "Detect the particles of VOLDIR, render noise-free spheres at the detections through "
        "the microscope model of VOLDIR/recon.json, reconstruct them as the volumes were, "
        "subtract each sphere's offset (measured again where the first correction put the "
        "particles: [track.axial] steps, default 2), then link and grid (RESULTS/track).",
        cmd_axial,
        ("RESULTS", "results folder"),
    )
    ax.add_argument(
        "voldir", type=Path, metavar="VOLDIR", help="volumes of `recon run` (folder or .zarr)"
    )
    ax.add_argument(
        "--track-config",
        type=Path,
        default=None,
        metavar="TRACK.toml",
        help="[track], [track.detect], [track.grid], [track.link], [track.axial] tables as in a "
        "study file (default: the settings' defaults)",
    )
    ax.add_argument(
        "--sphere-diameter-um",
        type=float,
        default=None,
        metavar="D",
        help="diameter of the reference spheres, the particles' (µm; default: "
        f"[track.axial] sphere_diameter_um, else {ref.sphere_diameter_um:g}); refused when "
        "wider than 1.5 times the particles' lateral FWHM measured in the first volume",
    )
    ax.add_argument(
        "--reference-rays",
        type=int,
        default=None,
        metavar="N",
        help="rays per reference sphere (default: [track.axial] rays_per_particle, else "
        f"{ref.rays_per_particle})",
    )
    add_flags(ax, {"--z-only": "subtract the z offset only (default: x, y and z)"})
    common(
        ax,
        overwrite="replace results made from other inputs or settings",
        partial="their failures are warnings",
    )
    return p


def cmd_axial(args) -> int:
    """``hrvptm axial``: detect, calibrate, link and grid real volumes."""
    import dataclasses

    from hrvbase.cli import parallel_from_args
    from hrvbase.io import check_output_folder, guard_output
    from track.errors import FailedFramesError
    from track.pipeline import failure_message

    from .calibrated import ReconModel, track_volumes_calibrated
    from .config import load_track_config

    spec = load_track_config(args.track_config)
    given = {"method": "simulated", "lateral": not args.z_only and spec.axial.lateral}
    if args.sphere_diameter_um is not None:
        given["sphere_diameter_um"] = args.sphere_diameter_um
    if args.reference_rays is not None:
        given["rays_per_particle"] = args.reference_rays
    from hrvbase.errors import HrvError

    try:
        axial = dataclasses.replace(spec.axial, **given)
    except HrvError as exc:  # the dataclass's one-line message, with the option's name
        msg = str(exc).replace("sphere_diameter_um", "--sphere-diameter-um")
        raise StudyConfigError(msg.replace("rays_per_particle", "--reference-rays")) from None
    parallel = parallel_from_args(args)
    guard_output(args.output, [args.voldir])
    check_output_folder(args.output)
    model = ReconModel.from_record(args.voldir)
    try:
        result, secs = track_volumes_calibrated(
            args.voldir,
            args.output,
            model=model,
            detect=spec.detect,
            series=spec.series,
            axial=axial,
            overwrite=args.overwrite,
            allow_partial=args.allow_partial,
            progress=not args.quiet,
            provenance={"argv": list(args.argv)},
            parallel=parallel,
            diameter_name="--sphere-diameter-um"
            if args.sphere_diameter_um is not None or spec.axial.sphere_diameter_um is None
            else f"[track.axial] sphere_diameter_um of {args.track_config}",
        )
    except FailedFramesError as exc:
        line = failure_message(exc.failures, hint="--allow-partial")
        sys.stderr.write(f"hrvptm: error: {line}\n")
        return 3
    if not args.quiet:
        sys.stdout.write(
            f"{result.results_line()} (axial calibration {secs['axial_calibration']:.1f} s)\n"
        )
    return 0


def _run(path: Path, args, command: str) -> dict:
    from hrvbase.cli import parallel_from_args
    from hrvbase.io import check_output_folder, guard_output

    from .config import load_study
    from .study import run_study

    parallel = parallel_from_args(args)
    guard_output(args.output, [path])
    check_output_folder(args.output)
    study = load_study(path)
    return run_study(
        study,
        args.output,
        until=getattr(args, "until", "analyse"),
        overwrite=args.overwrite,
        progress=not args.quiet,
        command=command,
        allow_partial=args.allow_partial,
        parallel=parallel,
    )


def cmd_study(args) -> int:
    t0 = time.perf_counter()
    _run(args.experiment, args, "hrvptm " + shlex.join(args.argv))
    if not args.quiet:
        sys.stdout.write(f"{args.output}: done in {time.perf_counter() - t0:.0f} s\n")
    return 0


def _fmt(v, pct: bool = False) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return f"{100 * v:.2f} %" if pct else f"{v:.2f}"


def summary_table(result: dict) -> str:
    """Plain-text table of a series study: per variant and frame, displacement RMSD (µm),
    shear strain measured/imposed and tracking ratio."""
    lines = []
    for variant, v in result["variants"].items():
        lines.append(f"{variant}:")
        lines.append(
            f"{'frame':>5} {'γ imposed':>10} {'2E_xz meas':>10} {'RMSD x µm':>10} "
            f"{'RMSD y µm':>10} {'RMSD z µm':>10} {'tracked':>8}"
        )
        for r in v["rows"]:
            lines.append(
                f"{r['frame']:>5} {_fmt(2 * r.get('E_true_xz', math.nan), True):>10} "
                f"{_fmt(2 * r.get('E_meas_xz', math.nan), True):>10} "
                f"{_fmt(r['u_rmsd_x']):>10} {_fmt(r['u_rmsd_y']):>10} {_fmt(r['u_rmsd_z']):>10} "
                f"{_fmt(r['tracking_ratio'], True):>8}"
            )
    return "\n".join(lines) + "\n"


def cmd_demo(args) -> int:
    if not DEMO.is_file():
        raise StudyConfigError(
            f"the demo study {DEMO} is missing: run hrvptm from a clone of the repository "
            "(installed with ./setup.sh)"
        )
    t0 = time.perf_counter()
    result = _run(DEMO, args, "hrvptm " + shlex.join(args.argv))
    if not args.quiet:
        sys.stdout.write(summary_table(result))
        sys.stdout.write(
            f"report: {args.output / 'summary.md'} ({time.perf_counter() - t0:.0f} s)\n"
        )
    return 0


def cmd_collect(args) -> int:
    from .collect import collect

    collect(args.reports, args.output, preamble=args.preamble, overwrite=args.overwrite)
    if not args.quiet:
        sys.stdout.write(f"{args.output}: {len(args.reports)} report(s)\n")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``hrvptm``; returns the exit status (0 success, 2 user error)."""
    from hrvbase.cli import run_main

    return run_main(
        "hrvptm",
        build_parser(),
        argv,
        loggers=("hrvptm", "lfsim", "recon", "track"),
        interrupted="interrupted; run the same command again to resume",
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
