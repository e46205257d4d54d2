"""hrvptm — validation studies of the HR-VPTM toolkit, end to end on synthetic light fields.

Sits above :mod:`lfsim`, :mod:`recon` and :mod:`track` (none of them imports it) and
rebuilds the paper's studies (Figs. 4–7): an experiment file is simulated, reconstructed,
tracked and compared frame by frame with its known truth.

Public API
----------
:func:`load_study`, :class:`Study`
    Study files: an lfsim experiment TOML with ``[study]``, ``[recon]``, ``[track]``
    sections (:mod:`hrvptm.config`).
:func:`run_study`
    Run or resume a study into a report folder (:mod:`hrvptm.study`).
:func:`analyse`, :class:`Analysis`
    The comparison with the truth (:mod:`hrvptm.analysis`, :mod:`hrvptm.compare`).
:func:`collect`
    Gather reports into one page (:mod:`hrvptm.collect`).
Errors
    :class:`StudyError` and its :class:`StudyConfigError`, :class:`ReportExistsError`,
    :class:`StageError`.
Command line
    ``hrvptm study | demo | collect`` (:mod:`hrvptm.cli`).
"""

from __future__ import annotations

from hrvbase import __version__, package_logger

from .analysis import Analysis, analyse
from .collect import collect
from .config import Study, load_study
from .errors import ReportExistsError, StageError, StudyConfigError, StudyError
from .study import run_study

package_logger(__name__)

__all__ = [
    "Analysis",
    "ReportExistsError",
    "StageError",
    "Study",
    "StudyConfigError",
    "StudyError",
    "__version__",
    "analyse",
    "collect",
    "load_study",
    "run_study",
]
