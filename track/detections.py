"""Detection stage of :func:`track.pipeline.track_volumes`: the PSF of the first volume, one
volume detected and its table written (:func:`_detect_frame`, in any process), and the
detections of a series as they arrive (:class:`_Detections`), read by the linking while the
other frames are still being detected.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hrvbase.io import file_record, verify_record, write_json

from .errors import InputError, TrackingError
from .results import SUMMARY, FrameDetections
from .tables import read_point_sigmas, read_points_csv, write_points_csv
from .volumes import VolumeInfo, numbered, read_volume

log = logging.getLogger(__name__)


def _detect(detect):
    from .detect import DetectSettings

    detect = DetectSettings() if detect is None else detect
    if not isinstance(detect, DetectSettings):
        raise InputError(f"detect must be a DetectSettings, got {type(detect).__name__}")
    return detect


def frame_times(vols: Sequence[VolumeInfo]) -> list[float] | None:
    """The recorded times (s) of the volumes' frames; None unless every one has one."""
    times = [v.time_s for v in vols]
    return None if any(t is None for t in times) else times


def volume_extent_um(volume: VolumeInfo) -> np.ndarray:
    """Size ``(x, y, z)`` (µm) spanned by the voxel centres of a volume."""
    shape = np.asarray(volume.shape, dtype=float)  # (nz, ny, nx)
    vs = np.asarray(volume.voxel_size_um, dtype=float)  # (dz, dy, dx)
    return ((shape - 1) * vs)[::-1]


def _first_psf(vol, info, settings):
    """PSF of the first volume, used for the whole sequence (paper §3.2)."""
    from .psf_estimate import estimate_psf

    if settings.deconvolution_iterations == 0:
        return None, "not used (deconvolution off)"
    if info.lenslet_period_vox is not None:
        # the volume detect_particles deconvolves: its lenslet phases equalised
        from .lenslet_phases import equalize_lenslet_phases

        vol, _ = equalize_lenslet_phases(vol, info.lenslet_period_vox, info.lenslet_phase_vox)
    try:
        psf = estimate_psf(
            vol, info.voxel_size_um, n_particles=settings.psf_particles, box_um=settings.psf_box_um
        )
    except (TrackingError, InputError) as exc:
        log.warning("no PSF from the first volume (%s); each volume estimates its own", exc)
        return None, f"not available from the first volume: {exc}"
    return psf, f"estimated from {info.name}, shape {list(psf.shape)}"


def _known_sigmas(sigma_xyz_um: np.ndarray) -> np.ndarray | None:
    """A table's uncertainties, or None when it has none (all NaN: an older table)."""
    return None if sigma_xyz_um.size == 0 or np.all(np.isnan(sigma_xyz_um)) else sigma_xyz_um


def _detect_frame(job, ctx) -> dict:
    """Detect the particles of one volume and write its table (atomically); any process.

    ``job`` is ``(i, VolumeInfo)``, ``ctx`` ``(DetectSettings, psf or None, results folder)``.
    Returns the positions ``(N, 3)``, their uncertainties ``(N, 3)`` (µm), the detection
    report and the frame's summary entries.
    """
    from .detect import detect_particles

    _, v = job
    settings, psf, out = ctx
    t0 = time.perf_counter()
    vol = read_volume(v)
    det = detect_particles(
        vol,
        v.voxel_size_um,
        settings,
        psf,
        origin_xyz_um=v.origin_xyz_um,
        lenslet_period_vox=v.lenslet_period_vox,
        lenslet_phase_vox=v.lenslet_phase_vox,
        snr=v.snr,
        surface_z_um=v.surface_z_um,
    )
    part = numbered(out / "particles", v.frame, ".csv")
    write_points_csv(
        part, det.positions_um, det.intensities, sigma_xyz_um=det.sigma_xyz_um, overwrite=True
    )
    positions = np.asarray(det.positions_um, dtype=float).reshape(-1, 3)
    sigma = None
    if det.sigma_xyz_um is not None:
        sigma = np.asarray(det.sigma_xyz_um, dtype=float).reshape(-1, 3)
    entry = {
        "particles": str(part.relative_to(out)),
        "n_particles": int(positions.shape[0]),
        "voxel_size_um": list(v.voxel_size_um),
        "origin_xyz_um": list(v.origin_xyz_um),
        "seconds": time.perf_counter() - t0,
        "report": det.report,
        "particles_file": file_record(part),
    }
    return {"positions": positions, "sigma": sigma, "report": det.report, "entry": entry}


def _psf_context(settings, psf, out):
    return settings, psf, out


class _Detections:
    """The detections of a series as they arrive (:mod:`hrvbase.parallel`).

    A sequence of the frames' clouds (positions ``(N, 3)``, µm): item ``i`` waits until frame
    ``i`` is detected, so that linking starts on the first frames while the others are still
    being detected. :meth:`finish` waits for all and returns the :class:`FrameDetections`.
    """

    def __init__(
        self, vols, checksums, settings, out: Path, summary: dict, prev, progress, parallel
    ):
        from hrvbase.parallel import WorkerContext, frame_map

        self.vols, self.out, self.summary = vols, out, summary
        prev_frames = {e.get("index"): e for e in (prev or {}).get("frames", [])}
        frames = [
            {
                "index": v.index,
                "frame": v.frame,
                "time_s": v.time_s,
                "input": v.source(),
                "input_sha256": sha,
            }
            for v, sha in zip(vols, checksums, strict=True)
        ]
        summary["frames"] = frames
        summary["inputs"] = [{"path": f["input"], "sha256": f["input_sha256"]} for f in frames]
        self.frames = frames
        self.clouds: list[np.ndarray | None] = [None] * len(vols)
        self._sigmas: list[np.ndarray | None] = [None] * len(vols)
        self.reports: list[dict] = [{} for _ in vols]
        for i, (v, f) in enumerate(zip(vols, frames, strict=True)):
            old = prev_frames.get(v.index)
            part = numbered(out / "particles", v.frame, ".csv")
            same = old and old.get("frame", old.get("index")) == v.frame
            if same and old.get("input_sha256") == f["input_sha256"]:
                if verify_record(part, old.get("particles_file")):
                    self.clouds[i] = read_points_csv(part)
                    self._sigmas[i] = _known_sigmas(read_point_sigmas(part))
                    frames[i] = {**old, **f, "reused": True}
                elif part.is_file():
                    log.warning(
                        "%s changed on disk since it was written (truncated or edited); "
                        "detecting volume %s again",
                        part,
                        v.name,
                    )
        todo = [i for i in range(len(vols)) if self.clouds[i] is None]
        if prev is not None:  # the earlier results stay unless the volumes to detect are sound
            for i in todo:
                if vols[i].dataset is None:  # (a Zarr frame was read for its checksum)
                    read_volume(vols[i])
        if todo:
            log.info("detecting particles in %d of %d volumes", len(todo), len(vols))
        else:
            log.info("all %d volumes already detected; detection skipped", len(vols))
        self.psf_note = (prev or {}).get("psf", "")
        self.t0 = time.perf_counter()
        self._map = None
        self._results = iter(())
        if todo:
            psf, self.psf_note = _first_psf(read_volume(vols[0]), vols[0], settings)
            here = out.resolve()  # workers may run in another folder
            self._map = frame_map(
                _detect_frame,
                [(i, dataclasses.replace(vols[i], path=vols[i].path.resolve())) for i in todo],
                parallel=parallel,
                context=WorkerContext(_psf_context, (settings, psf, here)),
                progress=progress,
                desc="detect",
                unit="volume",
            )
            self._results = iter(self._map)

    def _take(self, job, result) -> None:
        i, v = job
        self.clouds[i] = result["positions"]
        self._sigmas[i] = result["sigma"]
        self.reports[i] = result["report"]
        self.frames[i].update(result["entry"])
        if self.clouds[i].shape[0] == 0:
            log.info("volume %s: no particle found", v.name)
        self.summary["psf"] = self.psf_note
        write_json(self.out / SUMMARY, self.summary, overwrite=True)  # resumable after each

    def __len__(self) -> int:
        return len(self.vols)

    def __getitem__(self, i: int) -> np.ndarray:
        while self.clouds[i] is None:
            self._take(*next(self._results))
        return self.clouds[i]

    @property
    def sigmas(self) -> _SigmaView:
        """The frames' position uncertainties ``(N, 3)`` (µm; None: unknown), as they arrive."""
        return _SigmaView(self)

    def close(self) -> None:
        if self._map is not None:
            self._map.close()

    def release(self) -> None:
        """Once every frame has arrived (linking read them all): end the detection's map (its
        client; the workers stay for the fields when the cluster is shared)."""
        if all(c is not None for c in self.clouds):
            for job, result in self._results:  # nothing left: the map ends
                self._take(job, result)
            self.close()

    def finish(self) -> list[FrameDetections]:
        """Wait for every detection; record the detection's summary entries."""
        try:
            for job, result in self._results:
                self._take(job, result)
        finally:
            self.close()
        summary = self.summary
        summary["psf"] = self.psf_note
        summary["timings"]["detect_s"] = time.perf_counter() - self.t0
        summary["frame_ids"] = [v.frame for v in self.vols]
        summary["frame_times_s"] = frame_times(self.vols)
        return [
            FrameDetections(
                v.frame,
                v.source(),
                c,
                numbered(self.out / "particles", v.frame, ".csv"),
                bool(f.get("reused", False)),
                r,
                sg,
                v.time_s,
            )
            for v, c, f, r, sg in zip(
                self.vols, self.clouds, self.frames, self.reports, self._sigmas, strict=True
            )
        ]


class _SigmaView:
    """``detections.sigmas[i]``: frame ``i``'s uncertainties, waiting for its detection."""

    def __init__(self, detections: _Detections) -> None:
        self._d = detections

    def __len__(self) -> int:
        return len(self._d)

    def __getitem__(self, i: int) -> np.ndarray | None:
        self._d[i]  # waits until frame i is detected
        return self._d._sigmas[i]


__all__ = ["frame_times", "volume_extent_um"]
