"""The pipeline stages of a study, each run through the library of the tool a user would run.

For each variant (``mismatched``: rendered with the experiment's scene — glass lenslets —
and reconstructed with ``recon_scene``; ``matched``: rendered with ``recon_scene`` itself;
``as_air``: the first variant's frames reconstructed with ``recon_scene`` as if its specimen
were air, :func:`recon_optics`, its ``dataset/`` that variant's)::

    REPORT/<variant>/dataset/   lfsim.generate_dataset       (white.tif, frames/, truth/)
    REPORT/<variant>/calib.json recon.calibrate_white of white.tif
    REPORT/<variant>/volumes/   recon.pipeline.reconstruct_series
    REPORT/<variant>/track/     track.pipeline.track_volumes (detection only for localization
                                and pairs; detect → link → fields for a series)

A series with ``[track.axial] method = "simulated"`` is detected into ``REPORT/<variant>/
detect/`` (``track_volumes`` without linking), its frames' references rendered and
reconstructed into ``REPORT/<variant>/axial/`` (:func:`recon.reference.reference_volumes`),
the corrected particle tables written to ``axial/particles/`` (with ``axial/
axial_calibration.json``: what was subtracted) and those linked and gridded into ``track/``
(:func:`track.pipeline.track_clouds`), the layout the analysis reads.

Every stage resumes by itself: lfsim and recon keep per-frame records and fingerprints, and
``track`` skips volumes whose checksum it has seen. A stage whose inputs or settings changed
is redone (each tool replaces only the files it wrote).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .calibrated import AXIAL_DIR, DETECT_DIR, TRACK_DIR
from .config import AS_AIR
from .errors import StageError

log = logging.getLogger(__name__)


@contextmanager
def _stage_errors(what: str) -> Iterator[None]:
    """Run a stage's library calls: an :class:`hrvbase.errors.HrvError` they raise becomes a
    one-line :class:`StageError` ``"{what}: {message}"`` (``what``: the stage and its folder)."""
    from hrvbase.errors import HrvError

    try:
        yield
    except HrvError as exc:
        raise StageError(f"{what}: {exc}") from None


@dataclass(frozen=True)
class VariantPaths:
    """Folders of one variant of a study inside the report folder.

    ``dataset_root``: the variant folder whose ``dataset/`` it reconstructs (default: its
    own; the ``as_air`` variant reconstructs the first variant's frames)."""

    root: Path
    dataset_root: Path | None = None

    @classmethod
    def of(cls, study, report: Path, variant: str) -> VariantPaths:
        """The folders of ``variant`` of ``study`` in the report folder ``report``."""
        source = study.dataset_variant(variant)
        return cls(report / variant, None if source == variant else report / source)

    @property
    def variant(self) -> str:
        return self.root.name

    @property
    def dataset(self) -> Path:
        return (self.dataset_root or self.root) / "dataset"

    @property
    def calib(self) -> Path:
        return self.root / "calib.json"

    @property
    def volumes(self) -> Path:
        return self.root / "volumes"

    @property
    def track(self) -> Path:
        return self.root / TRACK_DIR

    @property
    def detect(self) -> Path:
        """Detections before the axial self-calibration (``[track.axial]`` on only)."""
        return self.root / DETECT_DIR

    @property
    def axial(self) -> Path:
        """References and corrected tables of the axial self-calibration."""
        return self.root / AXIAL_DIR


def recon_optics(study, variant: str):
    """The optics ``variant`` reconstructs with: ``recon_scene``'s, or for ``"as_air"`` the
    same microscope with the specimen left out (the specimen of the immersion medium's index,
    the cover glass the objective is corrected for), what a user who describes a gel as air
    reconstructs with."""
    import dataclasses

    from lfsim.scene import read_optics

    optics = read_optics(study.recon_scene)
    if variant != AS_AIR:
        return optics
    return dataclasses.replace(
        optics,
        medium_ior=optics.immersion_ior,
        coverslip_thickness_um=optics.coverslip_corrected_um,
    )


def frame_preprocess(experiment=None):
    """The preprocessing of every frame a study reconstructs: the black level is estimated
    (median) and modelled, as ``recon run`` does (the axial references are prepared alike,
    :func:`recon.reference.reference_preprocess`). A simulated camera's conversion gain
    (``[noise.camera]``, what its data sheet gives a user) enters each frame's SNR as
    ``recon run --gain-dn-per-e`` does."""
    from lfsim.camera import CameraModel
    from recon.preprocess import Preprocess

    gain = 0.0
    if experiment is not None:
        spec = experiment.noise_for_frame(0)
        if spec.model == "camera":
            gain = (spec.camera or CameraModel()).gain_dn_per_e
    return Preprocess(background="auto", gain_dn_per_e=gain)


def simulate(experiment, paths: VariantPaths, *, progress: bool = True, parallel=None) -> float:
    """Render the dataset (resumes a finished or interrupted one) on ``parallel``
    (:class:`hrvbase.parallel.Parallel`; default: in process). Returns seconds spent."""
    from hrvbase.errors import HrvError
    from hrvbase.io import read_json
    from lfsim import generate_dataset

    t0 = time.perf_counter()
    record = paths.dataset / "dataset.json"
    overwrite = False
    if record.is_file():
        try:
            overwrite = read_json(record).get("fingerprint") != experiment.fingerprint()
        except HrvError:
            overwrite = True
        if overwrite:
            log.info("%s: the experiment changed; the dataset is rendered again", paths.dataset)
    with _stage_errors(f"simulation into {paths.dataset}"):
        generate_dataset(
            experiment, paths.dataset, overwrite=overwrite, progress=progress, parallel=parallel
        )
    return time.perf_counter() - t0


def reconstruct(study, paths: VariantPaths, *, progress: bool = True, parallel=None) -> float:
    """Calibrate the white image and reconstruct every frame with the study's forward model
    (``recon_scene``), the frames on ``parallel`` (default: in process). Returns seconds
    spent."""
    from recon.calibration import calibrate_white
    from recon.calibration_file import read_white
    from recon.pipeline import reconstruct_series

    t0 = time.perf_counter()
    frames = sorted((paths.dataset / "frames").glob("[0-9]*.tif"))
    if len(frames) != study.experiment.frames:
        raise StageError(
            f"{paths.dataset}: expected {study.experiment.frames} frames, found {len(frames)}"
        )
    with _stage_errors(f"reconstruction into {paths.volumes}"):
        optics = recon_optics(study, paths.variant)
        white = read_white(paths.dataset / "white.tif")
        grid = calibrate_white(white, expected_pitch_px=optics.px_per_lenslet)
        grid.save(paths.calib, overwrite=True)
        reconstruct_series(
            frames,
            paths.volumes,
            optics=optics,
            grid=grid,
            settings=study.recon,
            preprocess=frame_preprocess(study.experiment),
            overwrite=True,  # inside the report: replace only an outdated run of this study
            progress=progress,
            provenance={
                "scene": str(Path(study.recon_scene).resolve()),
                "command": "hrvptm",
                **({"specimen": "left out (as air)"} if paths.variant == AS_AIR else {}),
            },
            parallel=parallel,
        )
    return time.perf_counter() - t0


def track_stage(
    study, paths: VariantPaths, *, progress: bool = True, parallel=None
) -> float | dict[str, float]:
    """Detect (and, for a series, link and grid) with :func:`track.pipeline.track_volumes`,
    as ``track detect`` / ``track run`` would, the detection on ``parallel``. Failed frames
    are kept (partial results allowed): the analysis counts them and fails the study. Returns
    seconds spent; with ``[track.axial]`` on (:func:`track_calibrated`), seconds per stage
    (``track``, ``axial_calibration``)."""
    from track.pipeline import track_volumes

    if study.track.axial.enabled:
        return track_calibrated(study, paths, progress=progress, parallel=parallel)
    t0 = time.perf_counter()
    series = study.track.series if study.study.kind == "series" else None
    with _stage_errors(f"tracking {paths.volumes}"):
        track_volumes(
            paths.volumes,
            paths.track,
            detect=study.track.detect,
            series=series,
            overwrite=True,  # inside the report: replace only an outdated run of this study
            allow_partial=True,
            progress=progress,
            provenance={"caller": "hrvptm"},
            parallel=parallel,
        )
    return time.perf_counter() - t0


def track_calibrated(
    study, paths: VariantPaths, *, progress: bool = True, parallel=None
) -> dict[str, float]:
    """Particles corrected by the simulator self-calibration of the reconstruction's bias
    (:mod:`hrvptm.calibrated`, as ``hrvptm axial``): ``detect/`` and ``axial/`` of the
    variant, and for a series ``track/`` (the corrected tables linked and gridded); the
    tables a study analyses are :func:`particle_tables`. Returns seconds spent: ``track``
    (detection, linking, fields) and ``axial_calibration`` (references and correction)."""
    from recon.lenslet_grid import LensletGrid

    from .calibrated import ReconModel, detect_volumes_calibrated, track_volumes_calibrated

    common = {
        "detect": study.track.detect,
        "axial": study.track.axial,
        "overwrite": True,  # inside the report: replace only an outdated run of this study
        "allow_partial": True,
        "progress": progress,
        "provenance": {"caller": "hrvptm"},
        "parallel": parallel,
        "own_folder": False,  # the variant's folder: dataset, volumes, ...
    }
    with _stage_errors(f"tracking {paths.volumes} with the axial calibration"):
        model = ReconModel(
            recon_optics(study, paths.variant), LensletGrid.load(paths.calib), study.recon
        )
        if study.study.kind == "series":
            _, secs = track_volumes_calibrated(
                paths.volumes, paths.root, model=model, series=study.track.series, **common
            )
        else:
            _, _, secs = detect_volumes_calibrated(paths.volumes, paths.root, model=model, **common)
    track_s = secs["detect"] + secs.get("link", 0.0)
    return {"track": track_s, "axial_calibration": secs["axial_calibration"]}


def particle_tables(study, paths: VariantPaths) -> Path:
    """The folder of the particle tables (``NNNNNN.csv``) a study analyses: ``track/
    particles`` (what ``track`` detected, or for a series linked), or ``axial/particles``
    for a localization or pairs study with ``[track.axial]`` on (corrected, not linked)."""
    if study.track.axial.enabled and study.study.kind != "series":
        return paths.axial / "particles"
    return paths.track / "particles"
