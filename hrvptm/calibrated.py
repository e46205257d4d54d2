"""Track a series with the simulator self-calibration of the reconstruction's position bias.

It needs the three lower packages (lfsim renders, recon reconstructs, track detects and
links), so it lives here, above them; ``hrvptm axial`` is its command line and ``hrvptm
study`` its ``[track.axial]`` stage. The reconstruction places each particle with a fixed
bias that depends on its depth and on its position under its lenslet
(:mod:`track.axial_bias`). :func:`track_volumes_calibrated`
measures it on the user's own microscope model and subtracts it, in three steps under one
folder ``ROOT``:

1. ``ROOT/detect/``: the particles of every volume (:func:`track.pipeline.track_volumes`,
   detection only);
2. ``ROOT/axial/``: for every frame, noise-free spheres rendered at the detected positions
   through the model's ideal lenslets and reconstructed as the frame was
   (:func:`recon.reference.reference_volumes`, in ``frames/`` and ``volumes/``), the corrected
   tables (``particles/NNNNNN.csv``) and what was subtracted (``axial_calibration.json``);
3. ``ROOT/track/``: the corrected tables linked and gridded
   (:func:`track.pipeline.track_clouds`).

The reconstruction's model (:class:`ReconModel`) comes from the volumes' ``recon.json``
(``recon run`` records the optics, the lenslet calibration and the settings there), or from
the caller (``hrvptm study``). A rerun resumes every step: detections of unchanged volumes
are kept, references of unchanged positions are neither rendered nor reconstructed again.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hrvbase.errors import InputError
from track.axial_bias import AxialCalibration, apply_bias, correct_table, reference_bias

log = logging.getLogger(__name__)

#: Sub-folders of ``ROOT`` (module docstring).
DETECT_DIR, AXIAL_DIR, TRACK_DIR = "detect", "axial", "track"
_LAYOUT = (DETECT_DIR, AXIAL_DIR, TRACK_DIR)
#: What :func:`track_volumes_calibrated` writes in ``axial/``.
AXIAL_RECORD = "axial_calibration.json"
#: A reference sphere wider than this many times the particles' lateral FWHM measured in the
#: volumes (plus half a voxel for its count of voxels) is refused: a reconstructed sphere is
#: never narrower than 0.87 of its diameter (its projection's width at half height), so such
#: spheres are not the particles, and their offsets are of another size and sign.
SPHERE_MAX_FWHM = 1.5
#: A reference sphere narrower than the particles' lateral FWHM over this factor is warned of
#: (small particles are widened by the resolution, so it may be right).
SPHERE_MIN_FWHM = 4.0


@dataclass(frozen=True)
class ReconModel:
    """What the volumes were reconstructed with: the references are reconstructed alike.

    Attributes
    ----------
    optics : lfsim.optics.Optics
        The reconstruction's microscope (its lenslets are rendered as ideal ones).
    grid : recon.lenslet_grid.LensletGrid
        The lenslet calibration of the frames.
    settings : recon.settings.ReconSettings
        Depths, super-resolution, iterations, filter.
    """

    optics: Any
    grid: Any
    settings: Any

    @classmethod
    def from_record(cls, volumes: str | os.PathLike) -> ReconModel:
        """The model recorded in ``VOLUMES/recon.json`` by ``recon run`` (a TIFF folder or an
        OME-Zarr image).

        Raises
        ------
        InputError
            No such folder, no ``recon.json`` (volumes that ``recon`` did not make), or one
            that lacks the optics, the calibration or the settings; the message names the
            file.
        """
        from dataclasses import fields

        from hrvbase.errors import HrvError
        from hrvbase.io import read_json
        from lfsim.optics import Optics
        from recon.lenslet_grid import LensletGrid
        from recon.settings import ReconSettings

        if not Path(volumes).is_dir():
            what = "is a file" if Path(volumes).exists() else "does not exist"
            raise InputError(
                f"volumes {volumes} {what}; expected the folder (or OME-Zarr image) that "
                "`recon run` wrote"
            )
        path = Path(volumes) / "recon.json"
        if not path.is_file():
            raise InputError(
                f"{path} does not exist: the axial self-calibration reconstructs references "
                "as the volumes were, and needs the record that `recon run` writes with them"
            )
        rec = read_json(path)
        missing = [k for k in ("optics", "calibration", "settings") if k not in rec]
        if not isinstance(rec, Mapping) or missing:
            raise InputError(f"{path} lacks {missing or 'a JSON object'} (not a recon record)")
        try:
            known = {f.name for f in fields(ReconSettings)}
            # a record of the older layout names the region roi_px
            older = {"roi_px": "roi_xy_px"}
            st = {older.get(k, k): v for k, v in rec["settings"].items()}
            st = {k: v for k, v in st.items() if k in known}
            if st.get("roi_xy_px") is not None:
                st["roi_xy_px"] = tuple(st["roi_xy_px"])
            return cls(
                optics=Optics.from_dict(rec["optics"]),
                grid=LensletGrid.from_dict(rec["calibration"]),
                settings=ReconSettings(**st),
            )
        except (HrvError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: {exc}") from None


def reference_settings(axial: AxialCalibration):
    """The :class:`recon.reference.ReferenceSettings` of ``axial`` (the values it gives, the
    others at their defaults: the one place they are defined)."""
    from recon.reference import ReferenceSettings

    given = {"sphere_diameter_um": axial.sphere_diameter_um}
    given["rays_per_particle"] = axial.rays_per_particle
    return ReferenceSettings(**{k: v for k, v in given.items() if v is not None})


def particle_size_um(volumes: str | os.PathLike) -> tuple[float, float, str] | None:
    """Lateral size of the particles of a series as the detector measures it: the median
    full width at half maximum across x and y (:func:`track.psf_estimate.particle_fwhm_vox`)
    of its first volume.

    Returns
    -------
    (fwhm_um, voxel_um, source) or None
        The mean of the y and x widths and of the y and x voxel sizes (µm), and the volume
        measured; None when the volume has no clear particle maximum.
    """
    from track.psf_estimate import particle_fwhm_vox
    from track.volumes import read_volume, scan_volumes

    first = scan_volumes(volumes)[0]
    fwhm = particle_fwhm_vox(read_volume(first))
    if fwhm is None:
        return None
    _dz, dy, dx = first.voxel_size_um
    size = (fwhm[1] * dy + fwhm[2] * dx) / 2.0
    return float(size), float((dy + dx) / 2.0), first.source()


def check_sphere_diameter(
    volumes: str | os.PathLike,
    axial: AxialCalibration,
    name: str = "[track.axial] sphere_diameter_um",
) -> None:
    """Refuse reference spheres far wider than the particles the volumes hold, and warn of
    far narrower ones (:data:`SPHERE_MAX_FWHM`, :data:`SPHERE_MIN_FWHM`).

    Parameters
    ----------
    volumes : path
        The series (its first volume is measured, :func:`particle_size_um`).
    axial : AxialCalibration
        Its ``sphere_diameter_um`` (None: the default of
        :class:`recon.reference.ReferenceSettings`) is checked.
    name : str
        How the message names the diameter (the option or the table key that set it).

    Raises
    ------
    InputError
        A diameter above :data:`SPHERE_MAX_FWHM` × (FWHM + half a voxel).
    """
    diameter = reference_settings(axial).sphere_diameter_um
    if axial.sphere_diameter_um is None:
        name = f"the default {name}"
    measured = particle_size_um(volumes)
    if measured is None:
        log.warning(
            "%s: no clear particle maximum; %s %g µm is not checked", volumes, name, diameter
        )
        return
    fwhm, voxel, source = measured
    limit = SPHERE_MAX_FWHM * (fwhm + voxel / 2.0)
    said = (
        f"{name} {diameter:g} µm, particles measured in {source}: lateral FWHM {fwhm:.3g} µm "
        f"on {voxel:.3g} µm voxels"
    )
    if diameter > limit:
        raise InputError(
            f"{said}; reference spheres wider than {limit:.3g} µm are not these particles (their "
            "offsets have another size and sign): give the particles' diameter"
        )
    if diameter < fwhm / SPHERE_MIN_FWHM:
        log.warning(
            "%s; spheres narrower than %.3g µm (1/%g of it) may not show the particles' bias: "
            "check that it is the particles' diameter",
            said,
            fwhm / SPHERE_MIN_FWHM,
            SPHERE_MIN_FWHM,
        )


def _half_boxes(frames: list, detect) -> list:
    out = []
    for k, entry in enumerate(frames):
        half = (entry.get("report") or {}).get("half_box_vox")
        if half is None:
            half = detect.half_box_vox
        if half is None:
            raise InputError(f"detections of frame {k} record no half_box_vox")
        out.append(half)
    return out


def correct_series(
    detect_dir: str | os.PathLike,
    axial_dir: str | os.PathLike,
    *,
    model: ReconModel,
    detect,
    axial: AxialCalibration,
    progress: bool = False,
    parallel=None,
) -> list[Path]:
    """Step 2 of the module docstring: references of every frame of a ``track detect``
    folder, and its tables corrected by their bias.

    Returns
    -------
    list of Path
        ``axial_dir/particles/NNNNNN.csv``, one per frame (frames whose detection failed: an
        empty table).
    """
    from hrvbase.io import read_json, write_json
    from recon.reference import reference_volumes
    from track.pipeline import SUMMARY
    from track.tables import read_points_csv, write_points_csv
    from track.volumes import read_volume, scan_volumes

    detect_dir, axial_dir = Path(detect_dir), Path(axial_dir)
    frames = read_json(detect_dir / SUMMARY)["frames"]
    tables, positions = [], []
    for k, entry in enumerate(frames):
        src = detect_dir / entry["particles"] if entry.get("particles") else None
        if src is None or not src.is_file():  # a failed frame: no particles
            src = axial_dir / "detected" / f"{k:06d}.csv"
            write_points_csv(src, np.zeros((0, 3)), overwrite=True)
        tables.append(src)
        positions.append(read_points_csv(src))
    halves = _half_boxes(frames, detect)
    # Step 1 measures the bias at the detections; step k at the positions step k - 1
    # corrected them to (AxialCalibration.steps), in its own work folder.
    at, biases = positions, None
    for step in range(1, axial.steps + 1):
        if biases is not None:
            at = [
                apply_bias(p, b, lateral=axial.lateral)
                for p, b in zip(positions, biases, strict=True)
            ]
        refs = reference_volumes(
            at,
            axial_dir if step == 1 else axial_dir / f"step{step}",
            optics=model.optics,
            grid=model.grid,
            recon_settings=model.settings,
            settings=reference_settings(axial),
            progress=progress,
            parallel=parallel,
        )
        infos = scan_volumes(refs[0].parent)
        biases = [
            reference_bias(read_volume(info), info.voxel_size_um, info.origin_xyz_um, p, half)
            for p, info, half in zip(at, infos, halves, strict=True)
        ]
    corrected, record = [], []
    for k, (src, bias) in enumerate(zip(tables, biases, strict=True)):
        dst = axial_dir / "particles" / f"{k:06d}.csv"
        record.append({"frame": k, **correct_table(src, dst, bias, lateral=axial.lateral)})
        corrected.append(dst)
    write_json(
        axial_dir / AXIAL_RECORD,
        {"settings": dataclasses.asdict(axial), "frames": record},
        overwrite=True,
    )
    return corrected


def track_volumes_calibrated(
    volumes: str | os.PathLike,
    root: str | os.PathLike,
    *,
    model: ReconModel | None = None,
    detect=None,
    series=None,
    axial: AxialCalibration | None = None,
    overwrite: bool = False,
    allow_partial: bool = False,
    progress: bool = False,
    vti_encoding: str = "binary",
    provenance: Mapping[str, Any] | None = None,
    parallel=None,
    own_folder: bool = True,
    diameter_name: str = "[track.axial] sphere_diameter_um",
):
    """Detect, calibrate and track a series of volumes (module docstring).

    Parameters
    ----------
    volumes : path
        As :func:`track.pipeline.track_volumes`.
    root : path
        Receives ``detect/``, ``axial/`` and ``track/``.
    model : ReconModel, optional
        Default: :meth:`ReconModel.from_record` of ``volumes``.
    detect : track.detect.DetectSettings, optional
    series : track.series.SeriesSettings, optional
    axial : AxialCalibration, optional
        Default ``AxialCalibration(method="simulated")``.
    overwrite, allow_partial, progress, vti_encoding, provenance, parallel
        As :func:`track.pipeline.track_volumes` (``overwrite`` and ``allow_partial`` apply to
        every step).
    own_folder : bool
        ``root`` holds nothing but these three folders: one with other contents is refused
        (default). ``False``: ``root`` is shared (a study's variant folder).
    diameter_name : str
        How messages name the reference spheres' diameter (:func:`check_sphere_diameter`,
        before any work).

    Returns
    -------
    result : track.pipeline.TrackResult
        Of the linking (``root/track``).
    seconds : dict
        ``detect``, ``axial_calibration`` and ``link`` (s).
    """
    from track.pipeline import track_clouds

    shared = {
        "overwrite": overwrite,
        "allow_partial": allow_partial,
        "progress": progress,
        "parallel": parallel,
    }
    detect, corrected, secs = detect_volumes_calibrated(
        volumes,
        root,
        model=model,
        detect=detect,
        axial=axial,
        provenance=provenance,
        own_folder=own_folder,
        diameter_name=diameter_name,
        **shared,
    )
    prov = dict(provenance or {})
    t2 = time.perf_counter()
    result = track_clouds(
        corrected,
        root / TRACK_DIR,
        series=series,
        vti_encoding=vti_encoding,
        provenance={**prov, "axial_calibration": str(root / AXIAL_DIR / AXIAL_RECORD)},
        # as track_volumes links its own detections: the shared σ cancels
        common_sigma_xyz_um=detect.sigma_systematic_um[::-1],
        **shared,
    )
    return result, {**secs, "link": time.perf_counter() - t2}


def detect_volumes_calibrated(
    volumes: str | os.PathLike,
    root: str | os.PathLike,
    *,
    model: ReconModel | None = None,
    detect=None,
    axial: AxialCalibration | None = None,
    overwrite: bool = False,
    allow_partial: bool = False,
    progress: bool = False,
    provenance: Mapping[str, Any] | None = None,
    parallel=None,
    own_folder: bool = True,
    diameter_name: str = "[track.axial] sphere_diameter_um",
):
    """Steps 1 and 2 of the module docstring: detect the particles of every volume and
    correct them by the bias of their reference (what :func:`track_volumes_calibrated` links;
    a localization or pairs study's tables).

    Parameters are those of :func:`track_volumes_calibrated`.

    Returns
    -------
    detect : track.detect.DetectSettings
        The detection settings used (``detect`` or the default).
    tables : list of Path
        ``root/axial/particles/NNNNNN.csv``, one per volume (a frame whose detection
        failed: an empty table).
    seconds : dict
        ``detect`` and ``axial_calibration`` (s).
    """
    from track.detect import DetectSettings
    from track.pipeline import track_volumes

    root = Path(root)
    if root.exists() and not root.is_dir():
        raise InputError(f"results folder {root} is a file")
    if root.is_dir() and own_folder:
        other = sorted(p.name for p in root.iterdir() if p.name not in _LAYOUT)
        if other:
            raise InputError(
                f"results folder {root} holds {', '.join(other[:3])}, not only the "
                f"{'/, '.join(_LAYOUT)}/ of a calibrated run: use a new folder"
            )
    axial = axial or AxialCalibration(method="simulated")
    if not axial.enabled:
        raise InputError("the axial calibration method is 'none': nothing to calibrate")
    detect = detect or DetectSettings()
    model = model or ReconModel.from_record(volumes)
    check_sphere_diameter(volumes, axial, diameter_name)
    prov = dict(provenance or {})
    t0 = time.perf_counter()
    track_volumes(
        volumes,
        root / DETECT_DIR,
        detect=detect,
        series=None,
        overwrite=overwrite,
        allow_partial=allow_partial,
        progress=progress,
        provenance={**prov, "axial_calibration": axial.method},
        parallel=parallel,
    )
    t1 = time.perf_counter()
    corrected = correct_series(
        root / DETECT_DIR,
        root / AXIAL_DIR,
        model=model,
        detect=detect,
        axial=axial,
        progress=progress,
        parallel=parallel,
    )
    secs = {"detect": t1 - t0, "axial_calibration": time.perf_counter() - t1}
    return detect, corrected, secs


__all__ = [
    "AXIAL_DIR",
    "AXIAL_RECORD",
    "DETECT_DIR",
    "SPHERE_MAX_FWHM",
    "SPHERE_MIN_FWHM",
    "TRACK_DIR",
    "ReconModel",
    "check_sphere_diameter",
    "correct_series",
    "detect_volumes_calibrated",
    "particle_size_um",
    "reference_settings",
    "track_volumes_calibrated",
]
