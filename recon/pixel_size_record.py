"""The result of a pixel-size measurement and what it gives the rest of the project: the
scene's optics with the measured magnification, the record ``recon pixel-size`` writes and
reads, and the corrected scene."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import InputError
from .pixel_size_defaults import PIXEL_SIZE_FORMAT

log = logging.getLogger(__name__)


def _positive(value: Any, name: str) -> float:
    """``value`` as a finite float > 0, or :class:`recon.errors.InputError` naming ``name``."""
    from hrvbase.errors import InputError as BaseInputError
    from hrvbase.validate import positive_float as check

    try:
        return check(value, name)
    except BaseInputError as exc:
        raise InputError(str(exc)) from None


@dataclass(frozen=True)
class PixelSizeResult:
    """The measured object-space pixel size (see :func:`~recon.pixel_size.measure_pixel_size`).

    Attributes
    ----------
    um_per_px, um_per_px_std : float
        Object-space size of one sensor pixel and its standard uncertainty (µm / pixel).
    magnification : float
        Implied lateral magnification, ``M_nominal · um_per_px_nominal / um_per_px``.
    nominal_um_per_px, nominal_magnification : float
        The scene's values (``Optics.object_pixel_um``, ``Optics.magnification``).
    axis : {"x", "y"}
        Image axis along which the divisions run.
    angle_deg, angle_std_deg : float
        Direction of the scale (normal to the lines) in the image, from +x towards +y
        (degrees): near 0 for ``axis="x"``, near 90 for ``axis="y"``.
    rotation_deg : float
        ``angle_deg`` minus the nominal direction of ``axis`` (0° or 90°).
    division_um : float
    divisions_per_lenslet : float
        Fitted ``q = P / D`` (object-space lenslet pitch over the division).
    lenslet_pitch_px : float
        Lenslet pitch used (pixels).
    line_fraction : float
        Fitted width of a line over the division (blur included).
    explained : float
        Fraction of the variation of the lenslet sums the ruling model explains.
    n_lenslets, n_rows, n_columns : int
        Lenslets used; rows of lenslets and lenslets along the scale in the ruled region.
    alternatives : list of dict
        Other scales that fit, with their cost excess in noise variances (``chi2``).
    """

    um_per_px: float
    um_per_px_std: float
    magnification: float
    nominal_um_per_px: float
    nominal_magnification: float
    axis: str
    angle_deg: float
    angle_std_deg: float
    rotation_deg: float
    division_um: float
    divisions_per_lenslet: float
    lenslet_pitch_px: float
    line_fraction: float
    explained: float
    n_lenslets: int
    n_rows: int
    n_columns: int
    alternatives: list = field(default_factory=list)

    @property
    def relative_deviation(self) -> float:
        """``um_per_px / nominal_um_per_px − 1``."""
        return self.um_per_px / self.nominal_um_per_px - 1.0

    def to_dict(self) -> dict:
        """Plain-JSON representation (lengths in µm, angles in degrees)."""
        return {
            "um_per_px": self.um_per_px,
            "um_per_px_std": self.um_per_px_std,
            "magnification": self.magnification,
            "nominal": {
                "um_per_px": self.nominal_um_per_px,
                "magnification": self.nominal_magnification,
            },
            "relative_deviation": self.relative_deviation,
            "axis": self.axis,
            "angle_deg": self.angle_deg,
            "angle_std_deg": self.angle_std_deg,
            "rotation_deg": self.rotation_deg,
            "division_um": self.division_um,
            "divisions_per_lenslet": self.divisions_per_lenslet,
            "lenslet_pitch_px": self.lenslet_pitch_px,
            "line_fraction": self.line_fraction,
            "explained_variance": self.explained,
            "n_lenslets": self.n_lenslets,
            "n_rows": self.n_rows,
            "n_columns": self.n_columns,
            "alternatives": self.alternatives,
        }


def nominal_grid(optics, image_shape: tuple[int, int]):
    """The lenslet grid the scene's optics imply: pitch ``px_per_lenslet``, no rotation, a
    lenslet centred on the optical axis ``axis_xy_px``."""
    from .calibration import LensletGrid

    return LensletGrid(
        pitch_px=optics.px_per_lenslet,
        rotation_deg=0.0,
        origin_xy_px=tuple(optics.axis_xy_px),
        image_shape=tuple(image_shape),
    )


def apply_pixel_size(optics, record) -> Any:
    """The optics with the measured magnification: ``object_pixel_um`` becomes the measured
    ``um_per_px``.

    The magnification error of a real microscope sits in the objective/tube-lens pair (and
    any relay before the lenslet array), not in the camera: the lenslet pitch on the sensor
    (``px_per_lenslet``, measured by ``recon calibrate``) is unchanged. So the tube lens's
    focal length is scaled, ``f_tube ← f_objective · pixel_um / um_per_px``; the objective,
    its NA and aperture stop, the array and the camera keep their values.

    Parameters
    ----------
    optics : lfsim.optics.Optics
        The nominal optics (the scene the measurement used).
    record : PixelSizeResult or dict
        A result, or the JSON record ``recon pixel-size`` writes (``um_per_px`` and, when
        present, ``optics.pixel_um`` are read).

    Returns
    -------
    lfsim.optics.Optics

    Raises
    ------
    InputError
        A record without a positive ``um_per_px``, or one made for another camera pixel.
    """
    if isinstance(record, PixelSizeResult):
        um = record.um_per_px
    elif isinstance(record, dict):
        if record.get("format") not in (None, PIXEL_SIZE_FORMAT):
            raise InputError(
                f"not a pixel-size record (format {record.get('format')!r}, expected "
                f"{PIXEL_SIZE_FORMAT!r})"
            )
        um = record.get("um_per_px")
        rec_optics = record.get("optics")
        if isinstance(rec_optics, dict) and "pixel_um" in rec_optics:
            rec_px = rec_optics["pixel_um"]
            if not isinstance(rec_px, int | float) or not math.isclose(
                rec_px, optics.pixel_um, rel_tol=1e-9
            ):
                raise InputError(
                    f"the pixel-size record was measured with pixel_um = {rec_px!r}, but these "
                    f"optics have pixel_um = {optics.pixel_um!r} (another camera?)"
                )
    else:
        raise InputError(f"record must be a PixelSizeResult or a dict, got {type(record).__name__}")
    um = _positive(um, "um_per_px")
    f_tube = optics.f_objective_um * optics.pixel_um / um
    return replace(optics, f_tube_um=f_tube)


def image_metadata(path) -> dict:
    """The JSON metadata of a TIFF written by :mod:`lfsim` (``{}`` if it has none or cannot be
    read: the caller then needs ``--scene``)."""
    from hrvbase.errors import HrvError
    from hrvbase.formats.tiff_layout import read_tiff

    try:
        _, meta = read_tiff(path)
    except HrvError:
        return {}
    return meta if isinstance(meta, dict) else {}


def build_record(
    result: PixelSizeResult,
    optics,
    *,
    image: np.ndarray,
    image_path,
    scene_path,
    calib_path=None,
    grid=None,
    settings: dict | None = None,
    written_scene=None,
    version: str = "",
    elapsed_s: float | None = None,
) -> dict:
    """The JSON record ``recon pixel-size`` writes (format
    :data:`~recon.pixel_size_defaults.PIXEL_SIZE_FORMAT`).

    Holds the result (:meth:`PixelSizeResult.to_dict`: ``um_per_px`` and ``um_per_px_std``
    in µm per pixel, ``magnification``, ``nominal``, ``relative_deviation``, ``axis``,
    ``angle_deg``, ``rotation_deg``, ``division_um`` ...), the nominal optics, the lenslet
    grid used and where it came from, the settings, and the path and SHA-256 of the image,
    the scene, the calibration and the written scene.
    """
    import datetime as dt
    from pathlib import Path

    from hrvbase.io import sha256_file

    def ref(path):
        if path is None:
            return None
        return {"path": str(Path(path).resolve()), "sha256": sha256_file(path)}

    used = grid if grid is not None else nominal_grid(optics, image.shape)
    return {
        "format": PIXEL_SIZE_FORMAT,
        "format_version": 1,
        **result.to_dict(),
        "optics": optics.to_dict(),
        "lenslet_grid": {
            "source": "calibration" if grid is not None else "scene",
            **used.to_dict(),
        },
        "settings": dict(settings or {}),
        "input": {
            **ref(image_path),
            "shape": list(image.shape),
        },
        "scene": ref(scene_path),
        "calibration": ref(calib_path),
        "measured_scene": ref(written_scene),
        "tool": {"name": "recon", "version": version, "command": "pixel-size"},
        "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "elapsed_s": None if elapsed_s is None else round(elapsed_s, 3),
    }


def load_pixel_record(path) -> dict:
    """Read a record written by ``recon pixel-size`` (for :func:`apply_pixel_size`).

    Raises
    ------
    InputError
        Missing or invalid file, or not a pixel-size record (names the file).
    """
    from hrvbase.io import read_json

    data = read_json(path)
    if not isinstance(data, dict) or data.get("format") != PIXEL_SIZE_FORMAT:
        raise InputError(
            f'{path} is not a pixel-size record (expected "format": {PIXEL_SIZE_FORMAT!r}; '
            "make one with `recon pixel-size`)"
        )
    return data


def write_measured_scene(optics, path, *, overwrite: bool = False, source=None, result=None):
    """Write ``optics`` (from :func:`apply_pixel_size`) as a scene file, atomically.

    Parameters
    ----------
    optics : lfsim.optics.Optics
    path : path
        Output ``.xml`` (an existing file is replaced only with ``overwrite``).
    source : path, optional
        The nominal scene, named in the file's description.
    result : PixelSizeResult, optional
        The measurement, quoted in the description.

    Returns
    -------
    Path
    """
    from pathlib import Path

    from hrvbase.io import atomic_path
    from lfsim.scene import write_scene

    text = "Scene with the measured magnification (recon pixel-size)"
    if source is not None:
        text += f" from {Path(source).name}"
    if result is not None:
        text += (
            f": {result.um_per_px:.6g} +- {result.um_per_px_std:.2g} um/px, "
            f"M = {result.magnification:.6g} (nominal {result.nominal_magnification:.6g})"
        )
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        write_scene(optics, tmp, description=text)
    return path
