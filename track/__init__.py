"""track — particle detection, linking, and displacement/strain fields from volumes.

Consumes reconstructed volumes (float32 ``(z, y, x)``, voxel size in µm) or point clouds
from any source and produces particle tables, matches, Lagrangian trajectories and gridded
displacement/strain fields (docs/conventions.md conventions: µm, x/y/z order, tensors
``(..., 3, 3)``, ``F = I + ∂u/∂X``, ``E = (FᵀF − I)/2``, ``e = sym(∂u/∂X)``,
``γ = 2 e_xz``, ``F_total = F_inc · F_prev``).

Public API
----------
Pipeline (:mod:`track.pipeline`)
    :func:`track_volumes` (detect → link → fields from a folder of volumes, resumable),
    :func:`track_clouds` (link point clouds), returning a :class:`TrackResult`
    (:class:`FrameDetections`, :class:`PairOutcome`) and writing the results folder;
    :class:`FailedFramesError` when frames fail and partial results are not allowed; its
    stages in :mod:`track.detections` and :mod:`track.link_outputs`, the results folder in
    :mod:`track.results`.
Detection (:mod:`track.detect`, :mod:`track.psf_estimate`)
    :class:`DetectSettings`, :class:`Detection`, :func:`detect_particles`,
    :func:`estimate_psf`.
Linking (:mod:`track.matching`)
    :class:`LinkSettings`, :class:`LinkResult`, :func:`link_pair`.
Strain (:mod:`track.strain`)
    :func:`particle_deformation_gradient` (local least-squares ``F`` per particle, settings
    :class:`LocalFitSettings`, result :class:`ParticleStrain`), :func:`green_lagrange`,
    :func:`infinitesimal`, :func:`engineering_shear`.
Fields (:mod:`track.fields`)
    :class:`GridSettings`, :class:`GridField`, :func:`gridded_field`,
    :func:`fit_displacement`, :func:`grid_axes`, :func:`gcv_smoothing` (the default smoothing,
    chosen by generalised cross-validation); grids in :mod:`track.grid`, the thin-plate
    spline in :mod:`track.thin_plate` and :mod:`track.thin_plate_fit`.
Series (:mod:`track.series`)
    :class:`SeriesSettings`, :func:`track_series` (returns a :class:`SeriesResult`;
    incremental / cumulative modes,
    trajectories, Eulerian cumulation), :func:`link_tracks`, :func:`cumulate_eulerian`; the
    settings in :mod:`track.series_settings`, pairwise linking in :mod:`track.pairs`,
    trajectories in :mod:`track.tracks`, the per-match σ in :mod:`track.sigma_model`, the
    increments' fields in :mod:`track.increments`, the cumulation in :mod:`track.eulerian`.
Files (:mod:`track.tables`, :mod:`track.field_files`, :mod:`track.volumes`)
    point/match/track CSV tables; ``.npz`` and ParaView ``.vti`` fields; volume series
    (TIFF volumes placed in object space from their metadata or ``recon.json``).
    :mod:`track.io` re-exports all three for backward compatibility.
DataFrames (:mod:`track.dataframes`)
    :func:`read_particles`, :func:`read_matches`, :func:`read_tracks`, :func:`read_fields`,
    :func:`read_results` (a results folder as :class:`ResultsTables`); :func:`to_trackpy` /
    :func:`from_trackpy` (trackpy's column names); :func:`write_particles`,
    :func:`write_tracks`.
Errors (:mod:`track.errors`)
    :class:`TrackError` and its :class:`InputError`, :class:`TrackingError`,
    :class:`FailedFramesError`.
Command line (:mod:`track.cli`)
    ``track run | detect | link``, a thin layer over the pipeline.

Detection, linking, the pipeline and the DataFrames are imported on first use
(``track.detect_particles``, ``track.track_volumes``, ``track.read_tracks`` etc.), so
``import track`` stays light (and imports pandas only for the DataFrames).
"""

from __future__ import annotations

import importlib
from typing import Any

from hrvbase import __version__

from .errors import FailedFramesError, InputError, TrackError, TrackingError
from .eulerian import cumulate_eulerian
from .fields import fit_displacement, gridded_field
from .grid import GridField, GridSettings, grid_axes
from .series import SeriesResult, track_series
from .series_settings import SeriesSettings
from .strain import (
    LocalFitSettings,
    ParticleStrain,
    engineering_shear,
    green_lagrange,
    infinitesimal,
    particle_deformation_gradient,
)
from .thin_plate import gcv_smoothing
from .tracks import link_tracks

#: Names imported lazily from the detection and matching modules.
_LAZY = {
    "DetectSettings": "detect",
    "Detection": "detect",
    "detect_particles": "detect",
    "estimate_psf": "psf_estimate",
    "LinkSettings": "matching",
    "LinkResult": "matching",
    "link_pair": "matching",
    "FrameDetections": "pipeline",
    "PairOutcome": "pipeline",
    "TrackResult": "pipeline",
    "track_clouds": "pipeline",
    "track_volumes": "pipeline",
    "ResultsTables": "dataframes",
    "from_trackpy": "dataframes",
    "read_fields": "dataframes",
    "read_matches": "dataframes",
    "read_particles": "dataframes",
    "read_results": "dataframes",
    "read_tracks": "dataframes",
    "to_trackpy": "dataframes",
    "write_particles": "dataframes",
    "write_tracks": "dataframes",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'track' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "FailedFramesError",
    "GridField",
    "GridSettings",
    "InputError",
    "LocalFitSettings",
    "ParticleStrain",
    "SeriesResult",
    "SeriesSettings",
    "TrackError",
    "TrackingError",
    "__version__",
    "cumulate_eulerian",
    "engineering_shear",
    "fit_displacement",
    "gcv_smoothing",
    "green_lagrange",
    "grid_axes",
    "gridded_field",
    "infinitesimal",
    "link_tracks",
    "particle_deformation_gradient",
    "track_series",
    *_LAZY,
]
