"""The calibration file of ``recon calibrate``: lenslet grid, optics and provenance.

A calibration records the optics it was made with, so that a reconstruction can refuse a
scene of another microscope (:func:`check_optics`). Functions here are the library behind
``recon calibrate`` and the calibration step of ``recon run`` and the study runner.
"""

from __future__ import annotations

import datetime as _dt
import logging
from pathlib import Path

import numpy as np

from .calibration import calibrate_white
from .errors import InputError, ReconError

log = logging.getLogger(__name__)

#: Relative difference between fitted and nominal lenslet pitch above which a calibration is
#: refused (``--allow-pitch-mismatch``: a warning).
PITCH_MISMATCH_FRACTION = 0.05

#: ``"format"`` entry of the calibration files ``recon calibrate`` writes.
CALIBRATION_FORMAT = "hrvptm.recon.calibration"


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


def calibrate_white_file(
    white: Path, optics, scene: Path, *, allow_pitch_mismatch: bool, allow_flag: str
):
    """Read a white image, check it against the scene's sensor and fit its lenslet grid.

    Returns
    -------
    image : ndarray, float32, shape (height, width)
    grid : LensletGrid
    deviation : float
        Fitted pitch / nominal pitch − 1.

    Raises
    ------
    InputError
        The white image's size differs from the scene's sensor.
    CalibrationError
        No lenslet grid, or a fitted pitch more than :data:`PITCH_MISMATCH_FRACTION` off the
        scene's (unless ``allow_pitch_mismatch``: then a warning).
    """
    from .errors import CalibrationError

    image = read_white(white)
    h, w = image.shape
    sw, sh = optics.sensor_xy_px
    if (w, h) != (sw, sh):
        raise InputError(
            f"white image {str(white)!r} is {w} × {h} px but the sensor of scene "
            f"{str(scene)!r} is {sw} × {sh} px; use a white image of this camera or the "
            "scene of the camera that took it"
        )
    nominal = optics.px_per_lenslet
    try:
        grid = calibrate_white(image, expected_pitch_px=nominal)
    except ReconError as exc:
        raise type(exc)(
            f"{white}: {exc} (the scene {scene} expects {nominal:.4g} px per lenslet)"
        ) from None
    deviation = grid.pitch_px / nominal - 1.0
    if abs(deviation) > PITCH_MISMATCH_FRACTION:
        msg = (
            f"fitted lenslet pitch {grid.pitch_px:.4f} px differs by {100 * deviation:+.1f} % "
            f"from the scene's optics ({nominal:.4f} px = mla_pitch_um / pixel_um); check that "
            f"{white} belongs to {scene}"
        )
        if not allow_pitch_mismatch:
            raise CalibrationError(f"{msg} (or pass {allow_flag} to accept it)")
        log.warning("%s", msg)
    return image, grid, deviation


def calibration_record(grid, optics, image, *, white: Path, scene: Path, deviation: float) -> dict:
    """The JSON record ``recon calibrate`` writes (grid, optics, inputs with checksums)."""
    from hrvbase.io import sha256_file

    from . import __version__

    h, w = image.shape
    return {
        "format": CALIBRATION_FORMAT,
        "format_version": 1,
        "grid": grid.to_dict(),
        "optics": optics.to_dict(),
        "nominal_pitch_px": optics.px_per_lenslet,
        "pitch_deviation": deviation,
        "white_image": {
            "path": str(Path(white).resolve()),
            "sha256": sha256_file(white),
            "shape": [h, w],
            "dtype": str(image.dtype),
        },
        "scene": {"path": str(Path(scene).resolve()), "sha256": sha256_file(scene)},
        "tool": {"name": "recon", "version": __version__, "command": "calibrate"},
        "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def read_calibration(path: Path):
    """A calibration file's lenslet grid, and the optics and scene file recorded with it.

    A bare grid file (:meth:`recon.calibration.LensletGrid.save`) records neither: None.

    Raises
    ------
    InputError
        Unreadable file, invalid grid or optics (names the file).
    """
    import json

    from lfsim.errors import ConfigError
    from lfsim.optics import Optics

    from .calibration import LensletGrid

    grid = LensletGrid.load(path)
    data = json.loads(Path(path).read_text(encoding="utf-8"))
    optics, scene = None, None
    if isinstance(data, dict) and data.get("optics") is not None:
        try:
            optics = Optics.from_dict(data["optics"])
        except (ConfigError, TypeError) as exc:
            raise InputError(f"{path}: invalid optics record: {exc}") from None
        scene = (data.get("scene") or {}).get("path")
    return grid, optics, scene


def check_optics(optics, grid, recorded, *, scene: Path, source: str, allow: bool) -> None:
    """Refuse a scene whose optics differ from those the calibration was made with.

    ``recorded`` are the calibration's optics (None for a bare grid file: only the image
    size is checked); ``source`` names the calibration in messages.
    """
    from .pipeline import optics_differences

    diffs = [] if recorded is None else optics_differences(optics, recorded)
    h, w = grid.image_shape
    sw, sh = optics.sensor_xy_px
    if (w, h) != (sw, sh) and not any(d.startswith("sensor_xy_px") for d in diffs):
        diffs.append(f"sensor {sw} × {sh} px (scene) vs {w} × {h} px images (calibration)")
    if recorded is None:
        log.info("%s records no optics; only its image size was checked against %s", source, scene)
    if not diffs:
        return
    msg = f"scene {str(scene)!r} does not match {source}: {'; '.join(diffs)}"
    if not allow:
        raise InputError(
            f"{msg}; use the scene the calibration was made with, or pass "
            "--allow-optics-mismatch to reconstruct with the scene's optics anyway"
        )
    log.warning("%s; reconstructing with the scene's optics (--allow-optics-mismatch)", msg)


def dataset_optics(dataset: Path):
    """The optics recorded in an lfsim dataset's ``dataset.json`` (None if absent)."""
    from hrvbase.io import read_json
    from lfsim.errors import ConfigError
    from lfsim.optics import Optics

    record = read_json(dataset / "dataset.json")
    if not isinstance(record, dict) or record.get("optics") is None:
        return None
    try:
        return Optics.from_dict(record["optics"])
    except (ConfigError, TypeError) as exc:
        raise InputError(f"{dataset / 'dataset.json'}: invalid optics record: {exc}") from None


__all__ = [
    "CALIBRATION_FORMAT",
    "PITCH_MISMATCH_FRACTION",
    "calibrate_white_file",
    "calibration_record",
    "check_optics",
    "dataset_optics",
    "read_calibration",
    "read_white",
]
