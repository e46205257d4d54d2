"""recon — light-field reconstruction for hrvptm: lenslet calibration and rectification.

Public API (everything else is internal):

- :class:`LensletGrid` — the square lenslet grid on the sensor (pitch, rotation, origin, in
  continuous pixel coordinates: pixel ``(i, j)`` has its centre at ``(j + 0.5, i + 0.5)``,
  as in :mod:`lfsim`), with JSON ``save``/``load``.
- :func:`calibrate_white` — fit the grid of a white image (robust to vignetting, dark
  lenslets, noise and hot pixels).
- :func:`rectify`, :class:`RectifiedGeometry` — resample an image onto a whole number of
  pixels per lenslet, aligned with the array (the reconstruction works on rectified images).
- :mod:`recon.errors` — :class:`ReconError`, :class:`CalibrationError`, :class:`InputError`.
- the ``recon`` command line (:mod:`recon.cli`): ``recon calibrate WHITE.tif --scene
  SCENE.xml -o calib.json``.

Importing :mod:`recon` never sets a Mitsuba variant (DESIGN.md §2).
"""

from __future__ import annotations

import logging

from . import errors
from .calibration import LensletGrid, calibrate_white
from .errors import CalibrationError, InputError, ReconError
from .rectify import RectifiedGeometry, rectify

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "CalibrationError",
    "InputError",
    "LensletGrid",
    "ReconError",
    "RectifiedGeometry",
    "__version__",
    "calibrate_white",
    "errors",
    "rectify",
]
