"""The ``recon`` command line (light-field calibration and, later, volume reconstruction).

Commands::

    recon calibrate WHITE.tif --scene SCENE.xml -o calib.json [--overwrite]
    recon run ...            (not implemented yet)

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


def build_parser() -> argparse.ArgumentParser:
    """The ``recon`` argument parser (one sub-parser per command)."""
    parser = argparse.ArgumentParser(
        prog="recon",
        description="Light-field microscopy reconstruction (hrvptm): lenslet calibration; "
        "volume reconstruction comes in a later version.",
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

    run = sub.add_parser(
        "run",
        parents=[common],
        help="reconstruct volumes (not implemented yet)",
        description="Volume reconstruction (not implemented yet in this version).",
    )
    run.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    run.set_defaults(func=_cmd_run)
    return parser


# -- commands ---------------------------------------------------------------------------------
def read_white(path: Path) -> np.ndarray:
    """Read a white image: one 2-D TIFF of integer or real pixels.

    Raises
    ------
    InputError
        Missing or unreadable file, a stack or colour image, or a non-numeric dtype (names
        the file).
    """
    import tifffile

    if not path.exists():
        raise InputError(f"white image {path} does not exist")
    if not path.is_file():
        raise InputError(f"white image {path} is not a file")
    try:
        with tifffile.TiffFile(path) as tif:
            n_pages = len(tif.pages)
            image = tif.asarray()
    except Exception as exc:  # tifffile raises assorted types on corrupt or foreign files
        raise InputError(f"cannot read white image {path} as TIFF: {exc}") from exc
    if image.ndim != 2 or n_pages != 1:
        raise InputError(
            f"white image {path} holds an array of shape {image.shape}; expected one 2-D "
            "grey-level image (a stack or colour image cannot be calibrated)"
        )
    if image.dtype.kind not in "uif":
        raise InputError(f"white image {path} has unsupported pixel type {image.dtype}")
    return image


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


def _cmd_run(args: argparse.Namespace) -> int:
    raise ReconError(
        "'recon run' (volume reconstruction) is not implemented yet in this version of hrvptm; "
        "'recon calibrate' is available"
    )


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
    from lfsim.errors import LfsimError

    parser = build_parser()
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
    except (ReconError, LfsimError) as exc:
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
