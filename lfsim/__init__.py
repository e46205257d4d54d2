"""lfsim — a physically based light-field microscope simulator on Mitsuba 3 and Dr.Jit.

Public API (everything else is internal):

- :class:`Optics`, :func:`paper_optics`, :func:`small_optics` — the optical train.
- :func:`init_backend` — explicit Dr.Jit/Mitsuba variant, threads, kernel cache.
- :func:`load_scene`, :func:`write_scene` — Mitsuba scene files in ``scenes/``.
- :func:`render_particles`, :class:`RenderSettings` — trace particles to a light-field image.
- :class:`Particles` — particle tables (CSV ``x_um,y_um,z_um[,diameter_um,brightness]``).
- camera models, motions, seeding, experiments and datasets (see their modules).

Importing :mod:`lfsim` never sets a Mitsuba variant.
"""

from __future__ import annotations

import logging

from .backend import BackendInfo, find_libllvm, init_backend
from .dataset import generate_dataset
from .errors import BackendError, ConfigError, LfsimError, OutputError, SceneError
from .experiment import Experiment, load_experiment
from .io import read_tiff, write_tiff
from .optics import Optics, paper_optics, small_optics

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "BackendError",
    "BackendInfo",
    "ConfigError",
    "Experiment",
    "LfsimError",
    "Optics",
    "OutputError",
    "SceneError",
    "__version__",
    "find_libllvm",
    "generate_dataset",
    "init_backend",
    "load_experiment",
    "paper_optics",
    "read_tiff",
    "small_optics",
    "write_tiff",
]
