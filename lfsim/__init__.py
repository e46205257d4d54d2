"""lfsim — a physically based light-field microscope simulator on Mitsuba 3 and Dr.Jit.

Public API (everything else is internal):

- :class:`Optics`, :func:`paper_optics`, :func:`small_optics` — the optical train.
- :func:`init_backend` — explicit Dr.Jit/Mitsuba variant, threads, kernel cache.
- :func:`load_scene`, :func:`write_scene` — Mitsuba scene files in ``scenes/``.
- :func:`render_particles`, :class:`RenderSettings` — trace particles to a light-field image.
- :class:`Particles` — particle tables (CSV ``x_um,y_um,z_um[,diameter_um,brightness]``).
- :class:`NoiseSpec`, :func:`apply_noise`, :func:`add_gaussian_noise`, :func:`measure_snr`,
  :func:`signal_reference` — noise models (:mod:`lfsim.noise`; SNR = S / sigma_noise);
  :class:`CameraModel` — the physical camera (:mod:`lfsim.camera`).
- :class:`Experiment`, :func:`load_experiment` — experiment files;
  :func:`generate_dataset` — a dataset with ground truth, resumable.
- :func:`read_tiff`, :func:`write_tiff` — images and volumes with their scale (:mod:`lfsim.io`).
- :class:`BackendInfo`, :func:`find_libllvm` — what :func:`init_backend` chose and found.
- Errors: :class:`LfsimError` and its :class:`BackendError`, :class:`ConfigError`,
  :class:`SceneError`; :class:`OutputError` (the shared :mod:`hrvbase` one).
- motions and seeding (see their modules).

Importing :mod:`lfsim` never sets a Mitsuba variant.
"""

from __future__ import annotations

from hrvbase import __version__, package_logger

from .backend import BackendInfo, find_libllvm, init_backend
from .camera import CameraModel
from .dataset import generate_dataset
from .errors import BackendError, ConfigError, LfsimError, OutputError, SceneError
from .experiment import Experiment, load_experiment
from .io import read_tiff, write_tiff
from .noise import NoiseSpec, add_gaussian_noise, apply_noise, measure_snr, signal_reference
from .optics import Optics, paper_optics, small_optics

package_logger(__name__)

__all__ = [
    "BackendError",
    "BackendInfo",
    "CameraModel",
    "ConfigError",
    "Experiment",
    "LfsimError",
    "NoiseSpec",
    "Optics",
    "OutputError",
    "SceneError",
    "__version__",
    "add_gaussian_noise",
    "apply_noise",
    "find_libllvm",
    "generate_dataset",
    "init_backend",
    "load_experiment",
    "measure_snr",
    "paper_optics",
    "read_tiff",
    "signal_reference",
    "small_optics",
    "write_tiff",
]
