"""The ``recon`` command line: lenslet calibration and volume reconstruction.

Commands::

    recon calibrate WHITE.tif --scene SCENE.xml -o calib.json [--overwrite]
                    [--allow-pitch-mismatch]
    recon pixel-size MICROMETER.tif --division-um D [--scene SCENE.xml] [--calib calib.json]
                     -o pixel.json [--write-scene SCENE_MEASURED.xml] [--overwrite]
    recon run FRAMES... [--scene SCENE.xml] [--calib calib.json] [--z-range -80:720]
              [--z-step 5] [--iterations 3] [-s 5] [--frames START:STOP[:STEP]] [--fps HZ]
              [--allow-optics-mismatch] -o VOLDIR [--overwrite] ...

``calibrate`` refuses a white image whose size is not the scene's sensor size, and a fitted
lenslet pitch more than 5 % off the scene's (``--allow-pitch-mismatch``: a warning). ``pixel-size``
measures the object-space pixel size from a stage micrometer (:mod:`recon.pixel_size`, paper
§4) and can write the scene with the measured magnification. ``run`` refuses a scene whose
optics (NA, lenslet pitch and focal length, pixel size, sensor size, optical axis; relative
tolerance 1e-6; not the magnification, which ``pixel-size`` measures) differ from those
recorded with the calibration, or with the dataset whose white image it calibrates, and a
calibration made on images of another size (``--allow-optics-mismatch``: a warning). A scene
with the glass lenslet mesh (``mla_kind="glass"``, e.g. an ``lfsim`` dataset rendered without
inverse crime) is reconstructed with ideal lenslets of the same optics, with a warning. A run
that fails before its first volume leaves nothing in ``VOLDIR`` that would block the corrected
command.

``FRAMES`` (any mix, in the order given; see :mod:`recon.frames`):

- TIFF files, reconstructed in the order given; a multi-page stack gives one frame per page;
- a folder of TIFFs, or a quoted glob pattern (``'run3/img_*.tif'``), in the order of the
  frame numbers in the names (``img_2.tif`` before ``img_10.tif``); gaps in the numbering
  are reported, names that cannot be ordered are refused;
- a text file listing frames, one path per line relative to the list file (``#`` comments);
- an ``lfsim`` dataset folder (its ``dataset.json`` names the scene and its ``white.tif`` is
  calibrated when no ``--calib`` is given).

All frames must share size, pixel type and bit depth (checked from the TIFF headers first).
``--frames START:STOP[:STEP]`` keeps part of the ordered series. ``recon.json`` records, for
each volume ``NNNNNN.tif``, its source (file, page of a stack), the frame's original number
(from the file name, or the page) and its time (``number / --fps``, else from the TIFF
metadata, else null). ``--format zarr`` (the default for an output named ``*.zarr``; ``--format
tiff`` with such a name is refused) writes one OME-Zarr image instead (axes t, z, y, x;
one chunk per frame, or per ``--zarr-chunk-z`` planes; voxel size and origin in its metadata;
``recon.json`` inside it), for napari (``napari --plugin napari-ome-zarr out.zarr``).

``run --workers N`` reconstructs N frames at a time on local Dask worker processes,
``--scheduler ADDRESS`` on the workers of an existing Dask cluster (:mod:`hrvbase.parallel`);
the volumes are the same as with one.

Global options (before or after the command): ``--threads N`` (with ``--workers``: per
worker), ``-v`` (info; ``-vv`` debug), ``-q`` (errors only). Errors a user can cause (bad
files, no lenslet grid, an existing output) print ``recon: error: <message>`` on stderr and
exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from hrvbase.cli import (
    SettingOption,
    add_flags,
    add_parallel_options,
    add_setting_options,
    common_options,
    int_in,
    number,
    parallel_from_args,
    run_main,
    settings_from_args,
    tool_parser,
)

from . import __version__
from .calibration_file import (
    CALIBRATION_FORMAT,
    calibrate_white_file,
    calibration_record,
    check_optics,
    dataset_optics,
    read_calibration,
)
from .errors import InputError, ReconError
from .projector import PROJECTORS
from .psf_wave import PSF_MODELS, WAVE_SIN_THETA, WAVE_SPOT_PX
from .settings import BACKGROUND_MODELS, ReconSettings
from .volume_store import FORMATS, NGFF_VERSION, make_writer

log = logging.getLogger("recon.cli")


def _common_options(*, suppress: bool) -> argparse.ArgumentParser:
    """``--threads`` and the shared ``-q``/``-v``, accepted before and after the command name.

    The copy given to the sub-parsers (``suppress=True``) has no defaults, so that an option
    given before the command is not reset by the sub-parser.
    """
    common = argparse.ArgumentParser(add_help=False, parents=[common_options(suppress=suppress)])
    common.add_argument(
        "--threads",
        type=int_in(1),
        metavar="N",
        default=argparse.SUPPRESS if suppress else None,
        help="CPU threads of the reconstruction commands: run's CPU projector (its threads "
        "setting) and the Dr.Jit backend (default: HRVPTM_THREADS, else all cores); with "
        "several frames reconstructed at once keep threads x frames <= cores; calibration "
        "runs on one core",
    )
    return common


def _cmd_pixel_size(args: argparse.Namespace) -> int:
    """``recon pixel-size``: see :mod:`recon.pixel_size` (paper §4)."""
    from hrvbase.io import check_output_file, write_json
    from lfsim.scene import read_optics

    from .pipeline import optics_differences
    from .pixel_size import (
        apply_pixel_size,
        build_record,
        image_metadata,
        measure_pixel_size,
        write_measured_scene,
    )
    from .preprocess import read_frame

    t0 = time.perf_counter()
    if not (math.isfinite(args.division_um) and args.division_um > 0):
        raise InputError(f"--division-um must be > 0 µm and finite, got {args.division_um!r}")
    if not 0 < args.tolerance < 0.5:  # also catches NaN
        raise InputError(f"--tolerance must lie in (0, 0.5), got {args.tolerance!r}")
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
    grid = None
    if args.calib is not None:
        grid, recorded, _ = read_calibration(args.calib)
        diffs = [] if recorded is None else optics_differences(optics, recorded)
        if diffs:
            raise InputError(
                f"scene {str(scene)!r} does not match calibration {str(args.calib)!r}: "
                f"{'; '.join(diffs)}; measure with the scene the calibration was made with"
            )
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
        text = str(exc).replace("division_um ", "--division-um ")
        raise type(exc)(f"{args.micrometer}: {text}") from None
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


def _none_or_fraction(text: str) -> float | None:
    """argparse type of ``--stop-rel-change``: ``none`` (no early stop) or a number >= 0."""
    value = number(lambda v: v >= 0, "a number >= 0", keyword="none")(text)
    return None if value == "none" else value


#: ``recon run`` options that set :class:`recon.settings.ReconSettings` fields (their defaults
#: and checks are the dataclass's).
RUN_SETTINGS = (
    SettingOption("z_step_um", ("--z-step",), "depth step in µm", float, "UM"),
    SettingOption("iterations", ("--iterations",), "Richardson-Lucy iterations", int, "N"),
    SettingOption("s", ("-s", "--super-resolution"), "voxels per lenslet along x and y", int, "S"),
    SettingOption(
        "lanczos_a",
        ("--lanczos",),
        "Lanczos window a (lobes, no unit) of the depth-adaptive anti-aliasing filter; 0: off",
        float,
        "A",
    ),
    SettingOption(
        "stop_rel_change",
        ("--stop-rel-change",),
        "stop early when the volume changes by less than this fraction (relative L1) in one "
        "iteration; 'none' (the default): run all iterations",
        _none_or_fraction,
        "X",
    ),
    SettingOption(
        "rays_per_pattern", ("--rays-per-pattern",), "rays traced per PSF-bank pattern", int, "N"
    ),
    SettingOption(
        "psf_model",
        ("--psf-model",),
        "PSF bank: ray-traced, wave optics, or auto (wave optics where a lenslet's diffraction "
        f"spot is wider than {WAVE_SPOT_PX:.1f} pixels or the aperture angle's sine in the "
        f"specimen exceeds {WAVE_SIN_THETA:g}, recon.psf_wave.choose_psf_model; rays at the "
        "paper's optics); recon.json records the model used",
        choices=PSF_MODELS,
    ),
    SettingOption(
        "projector",
        ("--projector",),
        "projector implementation (auto: the fastest for the backend)",
        choices=PROJECTORS,
    ),
    SettingOption(
        "background_model",
        ("--background-model",),
        "subtract the black level and clip at zero, or keep it in the forward model y = Hx + b",
        choices=BACKGROUND_MODELS,
    ),
)


def path_option(
    parser, flags: str | tuple[str, ...], metavar: str, text: str, *, required: bool = False
) -> None:
    """A file or folder option (``flags``: its spellings) without a default value."""
    flags = (flags,) if isinstance(flags, str) else flags
    parser.add_argument(*flags, type=Path, required=required, metavar=metavar, help=text)


def choice_option(parser, flag: str, choices: tuple[str, ...], text: str) -> None:
    """An option among ``choices``; the first is the default."""
    parser.add_argument(
        flag, choices=choices, default=choices[0], help=f"{text} (default: {choices[0]})"
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``recon`` argument parser (one sub-parser per command)."""
    parser, sub, common = tool_parser(
        "recon",
        "Light-field microscopy reconstruction (hrvptm): lenslet calibration and "
        "Richardson-Lucy volume reconstruction on Dr.Jit.",
        f"recon (hrvptm) {__version__}",
        common=_common_options,
        metavar="COMMAND",
    )

    def command(name: str, text: str, description: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[common], help=text, description=description)

    cal = command(
        "calibrate",
        "fit the lenslet grid of a white image",
        "Fit the lenslet grid (pitch, rotation, offset) of a white image (a "
        "uniformly fluorescent slide) and write it with the scene's optics to a JSON file.",
    )
    cal.add_argument("white", type=Path, metavar="WHITE.tif", help="white image, one 2-D TIFF")
    path_option(
        cal,
        "--scene",
        "SCENE.xml",
        "scene file of the microscope (required; its optics give the sensor size and the "
        "nominal lenslet pitch)",
        required=True,
    )
    path_option(cal, ("-o", "--output"), "CALIB.json", "output file (required)", required=True)
    add_flags(
        cal,
        {
            "--overwrite": "replace an existing output (default: refuse)",
            "--allow-pitch-mismatch": "accept a fitted lenslet pitch more than 5 %% off the "
            "scene's nominal pitch (a warning; default: refuse it, the white image probably "
            "belongs to another microscope)",
        },
    )
    cal.set_defaults(func=_cmd_calibrate)

    pix = command(
        "pixel-size",
        "measure the object-space pixel size from a stage micrometer image",
        "Measure the object-space size of a sensor pixel (µm per pixel) and the "
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
    path_option(
        pix,
        "--scene",
        "SCENE.xml",
        "scene file of the microscope (nominal optics); default: the scene named in the "
        "image's metadata (lfsim images)",
    )
    path_option(
        pix,
        "--calib",
        "CALIB.json",
        "lenslet grid from `recon calibrate` (default: the scene's nominal grid)",
    )
    choice_option(pix, "--axis", ("auto", "x", "y"), "image axis along which the divisions run")
    choice_option(pix, "--polarity", ("bright", "dark"), "lines brighter (fluorescent) or darker")
    pix.add_argument(
        "--tolerance",
        type=float,
        default=0.2,
        metavar="FRACTION",
        help="search the magnification within nominal × (1 ± FRACTION) (default 0.2)",
    )
    path_option(pix, ("-o", "--output"), "PIXEL.json", "output file", required=True)
    path_option(
        pix,
        "--write-scene",
        "SCENE_MEASURED.xml",
        "also write the scene with the measured magnification (tube-lens focal length); "
        "use it as recon run --scene (default: none)",
    )
    add_flags(pix, {"--overwrite": "replace existing outputs, never an input (default: refuse)"})
    pix.set_defaults(func=_cmd_pixel_size)

    run = command(
        "run",
        "reconstruct volumes from light-field frames",
        "Reconstruct a time series of light-field frames into float32 volumes "
        "(z, y, x) with Richardson-Lucy deconvolution. Resumes an interrupted run; refuses an "
        "output folder made from other inputs or settings unless --overwrite.",
    )
    run.add_argument(
        "frames",
        nargs="+",
        type=Path,
        metavar="FRAMES",
        help="TIFF frames (in the order given; a multi-page stack gives one frame per page), "
        "a folder of TIFFs or a quoted glob pattern ('run/img_*.tif') (both ordered by the "
        "frame number in the names), a text file listing frames (one path per line, relative "
        "to the list; the list gives the order), or an lfsim dataset folder",
    )
    run.add_argument(
        "--frames",
        dest="select",
        default=None,
        metavar="START:STOP[:STEP]",
        help="reconstruct only these frames: indices into the ordered series, STOP excluded "
        "(e.g. 0:100:2; default: all)",
    )
    run.add_argument(
        "--fps",
        type=float,
        default=None,
        metavar="HZ",
        help="frame rate in frames per second: recon.json records each frame's time as its "
        "number / fps in s (default: the time recorded in the TIFF metadata, else none)",
    )
    path_option(
        run,
        "--scene",
        "SCENE.xml",
        "scene file of the microscope (its optics; default: the scene named by an lfsim "
        "dataset's dataset.json, otherwise required)",
    )
    path_option(
        run,
        "--calib",
        "CALIB.json",
        "lenslet calibration from `recon calibrate` (default: calibrate an lfsim "
        "dataset's white.tif, otherwise required)",
    )
    add_flags(
        run,
        {
            "--allow-optics-mismatch": "reconstruct even when the scene's optics (NA, focal "
            "lengths, lenslet pitch and focal length, pixel size, sensor size, optical axis) "
            "differ from the calibration's (a warning; default: refuse)"
        },
    )
    run.add_argument(
        "--z-range",
        default=None,
        metavar="ZMIN:ZMAX",
        help="depths in µm from the native focal plane (default: from the optics, "
        "±6 lenslet-radii of defocus; ±730 for the paper's microscope)",
    )
    # --stop-rel-change has no derived default: its help says the default itself
    stop = next(o for o in RUN_SETTINGS if o.field == "stop_rel_change")
    add_setting_options(
        run,
        ReconSettings,
        [o for o in RUN_SETTINGS if o is not stop],
        derived="from the optics (see recon.settings)",
    )
    run.add_argument(
        *stop.flags,
        dest=f"setting_{stop.field}",
        type=stop.type,
        default=None,
        metavar=stop.metavar,
        help=stop.help,
    )
    path_option(run, "--dark", "DARK.tif", "dark frame subtracted pixel by pixel (default: none)")
    run.add_argument(
        "--background",
        default="auto",
        help="constant subtracted, in grey levels: a number >= 0, 'auto' (the image median; "
        "default) or 'none'",
    )
    add_flags(run, {"--hot-pixels": "suppress isolated hot pixels (default: off)"})
    run.add_argument(
        "--gain-dn-per-e",
        type=float,
        default=0.0,
        metavar="G",
        help="the camera's conversion gain (grey levels per photo-electron) for the shot noise "
        "in each frame's SNR (recon.json; track's sigma_snr_um uses it); default 0: additive "
        "noise only",
    )
    run.add_argument(
        "--roi",
        default=None,
        metavar="X0:X1,Y0:Y1",
        help="reconstruct only the lenslets inside this pixel region (default: whole image)",
    )
    choice_option(
        run,
        "--device",
        ("auto", "llvm", "cuda"),
        "Dr.Jit backend (auto: CUDA when available, else LLVM on the CPU)",
    )
    path_option(
        run,
        ("-o", "--output"),
        "VOLDIR",
        "output folder for NNNNNN.tif volumes and recon.json, or with --format zarr the "
        "OME-Zarr image (e.g. out.zarr, recon.json inside) (required)",
        required=True,
    )
    run.add_argument(
        "--format",
        choices=FORMATS,
        default=None,
        help="volumes as numbered float32 TIFF files, or one OME-Zarr image (OME-NGFF "
        f"{NGFF_VERSION}) of axes (t, z, y, x) chunked per frame (default: zarr when -o ends "
        "in .zarr, else tiff)",
    )
    run.add_argument(
        "--zarr-chunk-z",
        type=int_in(1),
        default=None,
        metavar="N",
        help="--format zarr: planes per chunk (default: the whole frame in one chunk)",
    )
    add_flags(
        run,
        {
            "--overwrite": "replace volumes of another run (other inputs or settings) in VOLDIR "
            "(default: refuse)"
        },
    )
    add_parallel_options(run)
    run.set_defaults(func=_cmd_run)
    return parser


# -- commands ---------------------------------------------------------------------------------
def _cmd_calibrate(args: argparse.Namespace) -> int:
    from hrvbase.io import check_output_file, write_json
    from lfsim.scene import read_optics

    out: Path = check_output_file(
        args.output, inputs=[args.white, args.scene], overwrite=args.overwrite
    )
    t0 = time.perf_counter()
    optics = read_optics(args.scene)
    image, grid, deviation = calibrate_white_file(
        args.white,
        optics,
        args.scene,
        allow_pitch_mismatch=args.allow_pitch_mismatch,
        allow_flag="--allow-pitch-mismatch",
    )
    record = calibration_record(
        grid, optics, image, white=args.white, scene=args.scene, deviation=deviation
    )
    record["elapsed_s"] = round(time.perf_counter() - t0, 3)
    write_json(out, record, overwrite=args.overwrite)
    if not getattr(args, "quiet", False):
        sys.stdout.write(
            f"wrote {out}: pitch {grid.pitch_px:.4f} px, rotation {grid.rotation_deg:+.4f} "
            f"deg, origin ({grid.origin_xy_px[0]:.3f}, {grid.origin_xy_px[1]:.3f}) px, "
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


def _volume_format(given: str | None, output: Path) -> str:
    """``--format``, or without it ``zarr`` for an output named ``*.zarr`` and else ``tiff``.

    Raises
    ------
    InputError
        ``--format tiff`` with an output named ``*.zarr`` (TIFF files in a folder that Zarr
        readers would take for a store).
    """
    named_zarr = output.suffix.lower() == ".zarr"
    if given is None:
        return "zarr" if named_zarr else "tiff"
    if given == "tiff" and named_zarr:
        raise InputError(
            f"-o {output} is named like an OME-Zarr image but --format tiff writes numbered "
            "TIFF files into a folder; leave out --format tiff (a .zarr output is written as "
            "OME-Zarr) or choose a name without .zarr"
        )
    return given


def _resolve_inputs(args: argparse.Namespace):
    """Frames, optics and lenslet grid from the command line (and a dataset folder).

    Also the input folders: those given, and the folders of the frames a glob pattern or a
    list file names (an output inside them is refused, as inside a folder given).
    """
    from hrvbase.io import read_json
    from lfsim.scene import read_optics

    from .frames import (
        build_series,
        expand_argument,
        folder_frames,
        select_frames,
        warn_if_unordered,
    )

    files: list[Path] = []
    explicit: list[Path] = []
    folders: list[Path] = []
    dataset = None
    for f in args.frames:
        if f.is_dir() and (f / "dataset.json").is_file():
            dataset = f
            if not (f / "frames").is_dir():
                raise InputError(f"dataset folder {str(f)!r} has no frames/ folder")
            files += folder_frames(f / "frames")
            continue
        paths, kind = expand_argument(f)
        files += paths
        if kind == "file":
            explicit += paths
        elif kind in ("pattern", "list"):
            folders += [p.parent for p in paths if p.parent not in folders]
    warn_if_unordered(explicit)
    frames = select_frames(build_series(files, fps=args.fps), args.select)
    scene = args.scene
    if scene is None and dataset is not None:
        record = read_json(dataset / "dataset.json")
        named = record.get("scene") if isinstance(record, dict) else None
        named = named.get("path") if isinstance(named, dict) else None
        if not isinstance(named, str) or not named:
            raise InputError(
                f'{dataset / "dataset.json"} names no scene (expected "scene": {{"path": '
                "...}, as lfsim dataset writes); give --scene SCENE.xml"
            )
        scene = Path(named)
        if not scene.is_absolute():
            scene = (dataset / scene).resolve()
    if scene is None:
        raise InputError("--scene is required (the optics of the microscope)")
    optics = read_optics(scene)
    allow = args.allow_optics_mismatch
    if args.calib is not None:
        grid, recorded, made_with = read_calibration(args.calib)
        source = f"calibration {str(args.calib)!r}"
        if made_with:
            source += f" (made with {made_with})"
    elif dataset is not None and (dataset / "white.tif").is_file():
        white = dataset / "white.tif"
        log.info("calibrating the lenslet grid from %s", white)
        _, grid, _ = calibrate_white_file(
            white, optics, scene, allow_pitch_mismatch=allow, allow_flag="--allow-optics-mismatch"
        )
        recorded = dataset_optics(dataset)
        source = f"the optics dataset {str(dataset)!r} was rendered with"
    elif dataset is not None:
        raise InputError(
            f"dataset folder {str(dataset)!r} has no white image to calibrate the lenslet grid "
            f"({str(dataset / 'white.tif')!r} does not exist); give --calib CALIB.json (make one "
            "with `recon calibrate`)"
        )
    else:
        raise InputError("--calib is required (make one with `recon calibrate`)")
    check_optics(optics, grid, recorded, scene=scene, source=source, allow=allow)
    return frames, optics, grid, scene, folders


def _cmd_run(args: argparse.Namespace) -> int:
    from hrvbase.io import check_output_folder, guard_output
    from lfsim import init_backend

    from .frames import camera_records, time_source
    from .pipeline import reconstruct_series
    from .preprocess import Preprocess, read_frame

    parallel = parallel_from_args(args, threads=getattr(args, "threads", None))
    z = (
        {}
        if args.z_range is None
        else dict(
            zip(("z_min_um", "z_max_um"), _parse_range(args.z_range, "--z-range"), strict=True)
        )
    )
    # the global --threads: the projector's (ReconSettings.threads) and Dr.Jit's threads
    threads = {} if getattr(args, "threads", None) is None else {"threads": args.threads}
    settings = settings_from_args(
        ReconSettings,
        args,
        RUN_SETTINGS,
        extra={**z, "roi_xy_px": _parse_roi(args.roi), **threads},
        names={
            "z_min_um": "--z-range",
            "z_max_um": "--z-range",
            "roi_xy_px": "--roi",
            "threads": "--threads",
        },
    )
    background = None if args.background == "none" else args.background
    if background not in (None, "auto"):
        try:
            background = float(background)
        except ValueError:
            background = math.nan
        if not (math.isfinite(background) and background >= 0):
            raise InputError(
                "--background must be a finite number >= 0 (grey levels), 'auto' or 'none', "
                f"got {args.background!r}"
            )
    dark = read_frame(args.dark, what="dark frame") if args.dark else None
    if not (math.isfinite(args.gain_dn_per_e) and args.gain_dn_per_e >= 0):
        raise InputError(f"--gain-dn-per-e must be a finite number >= 0, got {args.gain_dn_per_e}")
    pre = Preprocess(
        dark=dark,
        background=background,
        hot_pixels=args.hot_pixels,
        gain_dn_per_e=args.gain_dn_per_e,
        dark_name=f"--dark {str(args.dark)!r}",
    )
    volume_format = _volume_format(args.format, args.output)
    make_writer(volume_format, args.output, zarr_chunk_z=args.zarr_chunk_z)  # checks the options
    guard_output(args.output, [*args.frames, args.scene, args.calib, args.dark])
    check_output_folder(args.output)
    frames, optics, grid, scene, folders = _resolve_inputs(args)
    guard_output(args.output, [*folders, *sorted({f.path for f in frames})])
    if dark is not None and dark.shape != tuple(grid.image_shape):
        (h, w), (gh, gw) = dark.shape, grid.image_shape
        raise InputError(
            f"--dark {str(args.dark)!r} is {w} × {h} px but the frames and the calibration are "
            f"{gw} × {gh} px"
        )
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
        volume_format=volume_format,
        zarr_chunk_z=args.zarr_chunk_z,
        provenance={
            "scene": str(Path(scene).resolve()),
            "command": "recon run",
            "frame_selection": args.select,
            "fps": args.fps,
            "frame_times": time_source(frames, args.fps),
            "camera": camera_records(frames),
        },
        parallel=parallel,
    )
    if not getattr(args, "quiet", False):
        sys.stdout.write(
            f"{args.output}: {len(res.done)} volume(s) reconstructed, {len(res.skipped)} "
            f"already done, {time.perf_counter() - t0:.1f} s\n"
        )
    return 0


# -- entry point ------------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``recon``; returns the exit status (0 success, 2 user error)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # "--z-range -80:720": let a negative range follow its option like a number would.
    for i, a in enumerate(argv[:-1]):
        if a == "--z-range" and argv[i + 1].startswith("-"):
            argv[i : i + 2] = [f"--z-range={argv[i + 1]}"]
            break
    return run_main("recon", build_parser(), argv, loggers=("recon", "lfsim"))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


__all__ = ["CALIBRATION_FORMAT", "build_parser", "main"]
