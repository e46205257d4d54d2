"""recon — light-field reconstruction for hrvptm: lenslet calibration, rectification, and
Richardson–Lucy deconvolution of time series into volumes.

Public API (everything else is internal):

Calibration and rectification
    :class:`LensletGrid` — the square lenslet grid on the sensor (pitch, rotation, origin, in
    continuous pixel coordinates: pixel ``(i, j)`` has its centre at ``(j + 0.5, i + 0.5)``,
    as in :mod:`lfsim`), with JSON ``save``/``load`` (:mod:`recon.lenslet_grid`);
    :func:`calibrate_white` — fit the grid of a white image (robust to vignetting, dark
    lenslets, noise and hot pixels); :func:`rectify`, :class:`RectifiedGeometry` — resample
    an image onto a whole number of pixels per lenslet, aligned with the array (the
    reconstruction works on rectified images).
Reconstruction
    :func:`compute_psf_bank`, :class:`PSFBank` — the light-field PSF of every depth and
    sub-lenslet position, traced with :mod:`lfsim` and cached; :func:`compute_wave_psf_bank`
    — the same bank from wave optics (:mod:`recon.psf_wave`; ``ReconSettings.psf_model``
    chooses); :func:`make_projector`,
    :class:`LightFieldProjector` (Dr.Jit gathers, the GPU path), :class:`SparseProjector`
    (scipy.sparse, the CPU path) — the forward model ``H`` and its transpose;
    :func:`richardson_lucy`, :class:`RLResult` — the deconvolution, in the projector's array
    world; :class:`DepthFilter` — the depth-adaptive anti-aliasing filter; :class:`ReconGrid`
    — depths, voxels and object-space coordinates of the volume.
Series
    :class:`ReconSettings`, :func:`reconstruct_series`, :class:`SeriesResult` — a time series
    of frames into volumes, resumable, with provenance (what ``recon run`` does);
    :mod:`recon.volume_store` — where the volumes go: numbered TIFF files or one OME-Zarr
    image (``recon run --format zarr``), one writer per format, frames written independently.
Errors
    :mod:`recon.errors` — :class:`ReconError`, :class:`CalibrationError`, :class:`InputError`.
Command line
    :mod:`recon.cli`: ``recon calibrate WHITE.tif --scene SCENE.xml -o calib.json``,
    ``recon run``.

Importing :mod:`recon` never sets a Mitsuba variant (docs/conventions.md) and imports neither
Dr.Jit nor Mitsuba: they load when a PSF bank is traced or a Dr.Jit projector is built.
"""

from __future__ import annotations

from hrvbase import __version__, package_logger

from . import errors
from .calibration import LensletGrid, calibrate_white
from .deconvolve import RLResult, richardson_lucy
from .errors import CalibrationError, InputError, ReconError
from .filters import DepthFilter
from .geometry import ReconGrid
from .pipeline import SeriesResult, reconstruct_series
from .projector import LightFieldProjector, SparseProjector, make_projector
from .psf import PSFBank, compute_psf_bank
from .psf_wave import compute_wave_psf_bank
from .rectify import RectifiedGeometry, rectify
from .settings import ReconSettings

package_logger(__name__)

__all__ = [
    "CalibrationError",
    "DepthFilter",
    "InputError",
    "LensletGrid",
    "LightFieldProjector",
    "PSFBank",
    "RLResult",
    "ReconError",
    "ReconGrid",
    "ReconSettings",
    "RectifiedGeometry",
    "SeriesResult",
    "SparseProjector",
    "__version__",
    "calibrate_white",
    "compute_psf_bank",
    "compute_wave_psf_bank",
    "errors",
    "make_projector",
    "reconstruct_series",
    "rectify",
    "richardson_lucy",
]
