"""The ``recon`` command line: lenslet calibration and volume reconstruction.

Commands::

    recon calibrate WHITE.tif --scene SCENE.xml -o calib.json [--overwrite]
    recon run FRAMES... [--scene SCENE.xml] [--calib calib.json] [--z-range -80:720]
              [--z-step 5] [--iterations 3] [-s 5] -o VOLDIR [--overwrite] ...

``FRAMES`` are TIFF files, a folder of TIFFs, or an ``lfsim`` dataset folder (its
``dataset.json`` names the scene and its ``white.tif`` is calibrated when no ``--calib`` is
given).

Global options (before or after the command): ``--threads N``, ``-v`` (info; ``-vv`` debug),
``-q`` (errors only). Errors a user can cause (bad files, no lenslet grid, an existing output)
print ``recon: error: <message>`` on stderr and exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .calibration import calibrate_white
from .errors import InputError, ReconError

log = logging.getLogger("recon.cli")

#: Relative difference between fitted and nominal pitch above which ``calibrate`` warns.
PITCH_WARN_FRACTION = 0.05

#: ``"format"`` entry of the calibration files ``recon calibrate`` writes.
CALIBRATION_FORMAT = "hrvptm.recon.calibration"


def _threads(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _common_options(*, suppress: bool) -> argparse.ArgumentParser:
    """Options accepted both before and after the command name.

    The copy given to the sub-parsers (``suppress=True``) has no defaults, so that an option
    given before the command is not reset by the sub-parser.
    """

    def dflt(value: Any) -> Any:
        return argparse.SUPPRESS if suppress else value

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--threads",
        type=_threads,
        metavar="N",
        default=dflt(None),
        help="worker threads for the Dr.Jit backend of the reconstruction commands "
        "(default: all cores); calibration runs on one core",
    )
    common.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=dflt(0),
        help="more messages (-v: progress, -vv: debugging)",
    )
    common.add_argument(
        "-q", "--quiet", action="store_true", default=dflt(False), help="only errors"
    )
    return common


def _cmd_pixel_size(args: argparse.Namespace) -> int:
    """``recon pixel-size``: see :mod:`recon.pixel_size` (paper §4)."""
    from hrvbase.io import check_output_file, write_json
    from lfsim.scene import read_optics

    from .calibration import LensletGrid
    from .pixel_size import (
        apply_pixel_size,
        build_record,
        image_metadata,
        measure_pixel_size,
        write_measured_scene,
    )
    from .preprocess import read_frame

    t0 = time.perf_counter()
    if not args.division_um > 0:  # also catches NaN
        raise InputError(f"--division-um must be > 0 µm, got {args.division_um!r}")
    image = read_frame(args.micrometer, what="micrometer image")
    scene = args.scene
    if scene is None:
        named = image_metadata(args.micrometer).get("scene")
        if not isinstance(named, str) or not Path(named).is_file():
            raise InputError(
                f"--scene is required: {args.micrometer} names no scene file that exists"
            )
        scene = Path(named)
        log.info("using the scene named in %s: %s", args.micrometer, scene)
    inputs = [p for p in (args.micrometer, scene, args.calib) if p is not None]
    check_output_file(args.output, inputs=inputs, overwrite=args.overwrite)
    if args.write_scene is not None:
        check_output_file(
            args.write_scene,
            inputs=[*inputs, args.output],
            overwrite=args.overwrite,
            option="--write-scene",
        )
    optics = read_optics(scene)
    grid = LensletGrid.load(args.calib) if args.calib is not None else None
    try:
        result = measure_pixel_size(
            image,
            optics,
            args.division_um,
            grid=grid,
            axis=args.axis,
            polarity=args.polarity,
            tolerance=args.tolerance,
        )
    except ReconError as exc:
        raise type(exc)(f"{args.micrometer}: {exc}") from None
    written = None
    if args.write_scene is not None:
        measured = apply_pixel_size(optics, result)
        written = write_measured_scene(
            measured, args.write_scene, overwrite=args.overwrite, source=scene, result=result
        )
    record = build_record(
        result,
        optics,
        image=image,
        image_path=args.micrometer,
        scene_path=scene,
        calib_path=args.calib,
        grid=grid,
        settings={"axis": args.axis, "polarity": args.polarity, "tolerance": args.tolerance},
        written_scene=written,
        version=__version__,
        elapsed_s=time.perf_counter() - t0,
    )
    write_json(args.output, record, overwrite=args.overwrite)
    if not getattr(args, "quiet", False):
        sys.stdout.write(
            f"wrote {args.output}: {result.um_per_px:.5f} ± {result.um_per_px_std:.5f} µm/px "
            f"(nominal {result.nominal_um_per_px:.5f}, {100 * result.relative_deviation:+.2f} %), "
            f"magnification {result.magnification:.4f} (nominal "
            f"{result.nominal_magnification:.4g}), scale along {result.axis} rotated "
            f"{result.rotation_deg:+.2f} deg"
            + (f"; scene {written}" if written is not None else "")
            + "\n"
        )
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``recon`` argument parser (one sub-parser per command)."""
    parser = argparse.ArgumentParser(
        prog="recon",
        description="Light-field microscopy reconstruction (hrvptm): lenslet calibration and "
        "Richardson-Lucy volume reconstruction on Dr.Jit.",
        parents=[_common_options(suppress=False)],
    )
    parser.add_argument("--version", action="version", version=f"recon (hrvptm) {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    common = _common_options(suppress=True)

    cal = sub.add_parser(
        "calibrate",
        parents=[common],
        help="fit the lenslet grid of a white image",
        description="Fit the lenslet grid (pitch, rotation, offset) of a white image (a "
        "uniformly fluorescent slide) and write it with the scene's optics to a JSON file.",
    )
    cal.add_argument("white", type=Path, metavar="WHITE.tif", help="white image, one 2-D TIFF")
    cal.add_argument(
        "--scene",
        type=Path,
        required=True,
        metavar="SCENE.xml",
        help="scene file of the microscope (its optics give the nominal lenslet pitch)",
    )
    cal.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CALIB.json", help="output file"
    )
    cal.add_argument("--overwrite", action="store_true", help="replace an existing output")
    cal.set_defaults(func=_cmd_calibrate)

    pix = sub.add_parser(
        "pixel-size",
        parents=[common],
        help="measure the object-space pixel size from a stage micrometer image",
        description="Measure the object-space size of a sensor pixel (µm per pixel) and the "
        "microscope's true magnification from a light-field image of a stage micrometer in "
        "the native object plane (paper §4), with its standard uncertainty, and write them "
        "to a JSON file; --write-scene also writes the scene with the measured magnification "
        "(for `recon run`). Lines finer than two lenslets are measured from their moiré with "
        "the lenslet grid, coarser ones from their lenslet columns (which needs many lines).",
    )
    pix.add_argument("micrometer", type=Path, metavar="MICROMETER.tif", help="one 2-D TIFF")
    pix.add_argument(
        "--division-um",
        type=float,
        required=True,
        metavar="D",
        help="spacing of the micrometer's divisions in µm (e.g. 10)",
    )
    pix.add_argument(
        "--scene",
        type=Path,
        metavar="SCENE.xml",
        help="scene file of the microscope (nominal optics); default: the scene named in the "
        "image's metadata (lfsim images)",
    )
    pix.add_argument(
        "--calib",
        type=Path,
        metavar="CALIB.json",
        help="lenslet grid from `recon calibrate` (default: the scene's nominal grid)",
    )
    pix.add_argument(
        "--axis",
        choices=("auto", "x", "y"),
        default="auto",
        help="image axis along which the divisions run (default: auto)",
    )
    pix.add_argument(
        "--polarity",
        choices=("bright", "dark"),
        default="bright",
        help="lines brighter (fluorescent, default) or darker than the background",
    )
    pix.add_argument(
        "--tolerance",
        type=float,
        default=0.2,
        metavar="FRACTION",
        help="search the magnification within nominal × (1 ± FRACTION) (default 0.2)",
    )
    pix.add_argument(
        "-o", "--output", type=Path, required=True, metavar="PIXEL.json", help="output file"
    )
    pix.add_argument(
        "--write-scene",
        type=Path,
        metavar="SCENE_MEASURED.xml",
        help="also write the scene with the measured magnification (tube-lens focal length)",
    )
    pix.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    pix.set_defaults(func=_cmd_pixel_size)

    run = sub.add_parser(
        "run",
        parents=[common],
        help="reconstruct volumes from light-field frames",
        description="Reconstruct a time series of light-field frames into float32 volumes "
        "(z, y, x) with Richardson-Lucy deconvolution. Resumes an interrupted run; refuses an "
        "output folder made from other inputs unless --overwrite.",
    )
    run.add_argument(
        "frames",
        nargs="+",
        type=Path,
        metavar="FRAMES",
        help="TIFF frames, a folder of TIFFs, or an lfsim dataset folder",
    )
    run.add_argument("--scene", type=Path, metavar="SCENE.xml", help="scene file (optics)")
    run.add_argument("--calib", type=Path, metavar="CALIB.json", help="from recon calibrate")
    run.add_argument(
        "--z-range", default="-80:720", metavar="ZMIN:ZMAX", help="depths in µm (-80:720)"
    )
    run.add_argument("--z-step", type=float, default=5.0, help="depth step in µm (5)")
    run.add_argument("--iterations", type=int, default=3, help="Richardson-Lucy iterations (3)")
    run.add_argument(
        "-s", "--super-resolution", type=int, default=5, dest="s", help="voxels per lenslet (5)"
    )
    run.add_argument(
        "--lanczos", type=float, default=2.0, help="anti-aliasing filter window (2; 0 = off)"
    )
    run.add_argument("--stop-rel-change", type=float, default=None, help="early stop threshold")
    run.add_argument("--rays-per-pattern", type=int, default=200_000, help="PSF bank rays")
    run.add_argument("--dark", type=Path, metavar="DARK.tif", help="dark frame to subtract")
    run.add_argument(
        "--background",
        default="auto",
        help="constant to subtract: a number, 'auto' (the image median, default) or 'none'",
    )
    run.add_argument("--hot-pixels", action="store_true", help="suppress isolated hot pixels")
    run.add_argument("--roi", default=None, metavar="X0:X1,Y0:Y1", help="pixel region")
    run.add_argument("--device", choices=("auto", "llvm", "cuda"), default="auto")
    run.add_argument(
        "--projector",
        choices=("auto", "gather", "sparse"),
        default="auto",
        help="projector implementation (auto: fastest for the backend)",
    )
    run.add_argument(
        "--background-model",
        choices=("subtract", "model"),
        default="subtract",
        help="subtract the black level and clip at zero (default), or keep it in the forward "
        "model y = Hx + b",
    )
    run.add_argument("-o", "--output", type=Path, required=True, metavar="VOLDIR")
    run.add_argument("--overwrite", action="store_true", help="replace another run's volumes")
    run.set_defaults(func=_cmd_run)
    return parser


# -- commands ---------------------------------------------------------------------------------
def read_white(path: Path) -> np.ndarray:
    """Read a white image: one 2-D TIFF of integer or real pixels (as float32).

    Raises
    ------
    InputError
        Missing or unreadable file, a stack or colour image, a non-numeric dtype or
        non-finite pixels (names the file).
    """
    from .preprocess import read_frame

    return read_frame(path, what="white image")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from lfsim.errors import OutputError
    from lfsim.io import sha256_file, write_json
    from lfsim.scene import read_optics

    out: Path = args.output
    if out.exists() and not args.overwrite:
        raise OutputError(f"{out} already exists; refusing to overwrite it (pass --overwrite)")
    t0 = time.perf_counter()
    optics = read_optics(args.scene)
    image = read_white(args.white)
    nominal = optics.px_per_lenslet
    h, w = image.shape
    if (w, h) != tuple(optics.sensor_px):
        log.warning(
            "white image %s is %d x %d px but the scene's sensor is %d x %d px",
            args.white,
            w,
            h,
            *optics.sensor_px,
        )
    try:
        grid = calibrate_white(image, expected_pitch_px=nominal)
    except ReconError as exc:
        raise type(exc)(f"{args.white}: {exc}") from None
    deviation = grid.pitch_px / nominal - 1.0
    if abs(deviation) > PITCH_WARN_FRACTION:
        log.warning(
            "fitted lenslet pitch %.4f px differs by %+.1f %% from the scene's optics "
            "(%.4f px = mla_pitch_um / pixel_um); check that %s belongs to %s",
            grid.pitch_px,
            100 * deviation,
            nominal,
            args.white,
            args.scene,
        )
    record = {
        "format": CALIBRATION_FORMAT,
        "format_version": 1,
        "grid": grid.to_dict(),
        "optics": optics.to_dict(),
        "nominal_pitch_px": nominal,
        "pitch_deviation": deviation,
        "white_image": {
            "path": str(args.white.resolve()),
            "sha256": sha256_file(args.white),
            "shape": [h, w],
            "dtype": str(image.dtype),
        },
        "scene": {"path": str(args.scene.resolve()), "sha256": sha256_file(args.scene)},
        "tool": {"name": "recon", "version": __version__, "command": "calibrate"},
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "elapsed_s": round(time.perf_counter() - t0, 3),
    }
    write_json(out, record, overwrite=args.overwrite)
    if not getattr(args, "quiet", False):
        sys.stdout.write(
            f"wrote {out}: pitch {grid.pitch_px:.4f} px, rotation {grid.rotation_deg:+.4f} "
            f"deg, origin ({grid.origin_px[0]:.3f}, {grid.origin_px[1]:.3f}) px, "
            f"{grid.n_lenslets_used} lenslets, residual {grid.rms_residual_px:.3f} px RMS\n"
        )
    return 0


def _parse_range(text: str, what: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise InputError(f"{what} must look like MIN:MAX (e.g. -80:720), got {text!r}") from None
    return a, b


def _parse_roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    try:
        xs, ys = text.split(",")
        x0, x1 = (int(v) for v in xs.split(":"))
        y0, y1 = (int(v) for v in ys.split(":"))
    except ValueError:
        raise InputError(f"--roi must look like X0:X1,Y0:Y1 in pixels, got {text!r}") from None
    return (x0, x1, y0, y1)


def _resolve_inputs(args: argparse.Namespace):
    """Frames, optics and lenslet grid from the command line (and a dataset folder)."""
    from lfsim.io import read_json
    from lfsim.scene import read_optics

    from .calibration import LensletGrid

    frames: list[Path] = []
    dataset = None
    for f in args.frames:
        if f.is_dir():
            if (f / "dataset.json").is_file():
                dataset = f
                frames += sorted((f / "frames").glob("*.tif"))
            else:
                frames += sorted(list(f.glob("*.tif")) + list(f.glob("*.tiff")))
        else:
            frames.append(f)
    if not frames:
        raise InputError(f"no TIFF frames found in {', '.join(map(str, args.frames))}")
    scene = args.scene
    if scene is None and dataset is not None:
        scene = Path(read_json(dataset / "dataset.json")["scene"]["path"])
        if not scene.is_absolute():
            scene = (dataset / scene).resolve()
    if scene is None:
        raise InputError("--scene is required (the optics of the microscope)")
    optics = read_optics(scene)
    if args.calib is not None:
        grid = LensletGrid.load(args.calib)
    elif dataset is not None and (dataset / "white.tif").is_file():
        log.info("calibrating the lenslet grid from %s", dataset / "white.tif")
        white = read_white(dataset / "white.tif")
        grid = calibrate_white(white, expected_pitch_px=optics.px_per_lenslet)
    else:
        raise InputError("--calib is required (make one with `recon calibrate`)")
    return frames, optics, grid, scene


def _cmd_run(args: argparse.Namespace) -> int:
    from lfsim import init_backend

    from .pipeline import ReconSettings, reconstruct_series
    from .preprocess import Preprocess, read_frame

    z0, z1 = _parse_range(args.z_range, "--z-range")
    settings = ReconSettings(
        z_min_um=z0,
        z_max_um=z1,
        z_step_um=args.z_step,
        s=args.s,
        iterations=args.iterations,
        lanczos_a=args.lanczos if args.lanczos > 0 else None,
        stop_rel_change=args.stop_rel_change,
        rays_per_pattern=args.rays_per_pattern,
        roi_px=_parse_roi(args.roi),
        projector=args.projector,
        background_model=args.background_model,
    )
    background = None if args.background == "none" else args.background
    if background not in (None, "auto"):
        try:
            background = float(background)
        except ValueError:
            raise InputError(
                f"--background must be a number or 'auto', got {background!r}"
            ) from None
    dark = read_frame(args.dark, what="dark frame") if args.dark else None
    pre = Preprocess(dark=dark, background=background, hot_pixels=args.hot_pixels)
    frames, optics, grid, scene = _resolve_inputs(args)
    init_backend(device=args.device, threads=getattr(args, "threads", None))
    t0 = time.perf_counter()
    res = reconstruct_series(
        frames,
        args.output,
        optics=optics,
        grid=grid,
        settings=settings,
        preprocess=pre,
        overwrite=args.overwrite,
        progress=not getattr(args, "quiet", False),
        provenance={"scene": str(Path(scene).resolve()), "command": "recon run"},
    )
    if not getattr(args, "quiet", False):
        sys.stdout.write(
            f"{args.output}: {len(res.done)} volume(s) reconstructed, {len(res.skipped)} "
            f"already done, {time.perf_counter() - t0:.1f} s\n"
        )
    return 0


# -- entry point ------------------------------------------------------------------------------
class _Formatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"recon: {record.levelname.lower()}: {record.getMessage()}"


def _level(args: argparse.Namespace) -> int:
    if getattr(args, "quiet", False):
        return logging.ERROR
    verbose = getattr(args, "verbose", 0) or 0
    return logging.DEBUG if verbose >= 2 else logging.INFO if verbose == 1 else logging.WARNING


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``recon``; returns the exit status (0 success, 2 user error)."""
    from hrvbase.errors import HrvError

    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    # "--z-range -80:720": let a negative range follow its option like a number would.
    for i, a in enumerate(argv[:-1]):
        if a == "--z-range" and argv[i + 1].startswith("-"):
            argv[i : i + 2] = [f"--z-range={argv[i + 1]}"]
            break
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter())
    level = _level(args)
    loggers = [logging.getLogger(name) for name in ("recon", "lfsim")]
    saved = [(lg, lg.level) for lg in loggers]
    for lg in loggers:
        lg.setLevel(level)
        lg.addHandler(handler)
    try:
        return int(args.func(args))
    except HrvError as exc:
        sys.stderr.write(f"recon: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("recon: interrupted\n")
        return 130
    finally:
        for lg, old in saved:
            lg.removeHandler(handler)
            lg.setLevel(old)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


__all__ = ["CALIBRATION_FORMAT", "build_parser", "main", "read_white"]
