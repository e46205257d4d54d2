"""hrvbase: the small shared base of the toolkit (numpy only at import; file readers load theirs).

What every package needs, defined once:

- :mod:`hrvbase.errors`: :class:`HrvError` and the common :class:`InputError`,
  :class:`OutputError`;
- :mod:`hrvbase.io`: atomic writes, JSON, checksums, output records that resume verifies,
  and the guard that keeps outputs off the user's inputs;
- :mod:`hrvbase.validate`: number and array validators (e.g. ``(N, 3)`` point arrays);
- :mod:`hrvbase.cli`: logging, ``-q``/``-v``/``--version``, ``--workers``/``--scheduler`` and
  the error handling of every command line;
- :mod:`hrvbase.known_fields`: analytic heterogeneous displacement fields (Gaussian
  indentation, stiff inclusion) that ``lfsim`` prescribes and ``track``'s tests link;
- :mod:`hrvbase.parallel`: frames of a series in parallel, in process or on Dask (imported
  only when a command runs frames on more than one process).
- :mod:`hrvbase.formats`: every file format in one place: the readers of camera frames
  (TIFF, Phantom ``.cine``) and volume series (numbered TIFF volumes, OME-Zarr) chosen by
  content or name, the TIFF layout of our images and volumes, and the volume geometry
  (tifffile, zarr and pims are imported only by the readers that use them).

- :func:`package_logger`: the silent logger of each package, and ``__version__``, the
  toolkit's version that every package reports.

``lfsim``, ``recon``, ``track`` and ``hrvptm`` import it; it imports none of them.
"""

from __future__ import annotations

import logging

from .errors import HrvError, InputError, OutputError

#: The version of the toolkit, which every package reports as its own.
__version__ = "0.1.0"


def package_logger(name: str) -> logging.Logger:
    """The logger of package ``name``, silent until an application configures logging.

    Parameters
    ----------
    name : str
        The package's ``__name__``.

    Returns
    -------
    logging.Logger
        The logger, with a :class:`logging.NullHandler` so that a library user who has not set
        up logging sees no messages.
    """
    logger = logging.getLogger(name)
    logger.addHandler(logging.NullHandler())
    return logger


__all__ = ["HrvError", "InputError", "OutputError", "package_logger"]
