"""A dock widget that runs ``recon run`` or ``track run`` on a folder, in a worker thread.

The work is done by the library pipelines that the command lines call
(:func:`recon.pipeline.reconstruct_series`, :func:`track.pipeline.track_volumes`), in a
napari ``thread_worker``; the progress bar counts the output files written (one volume or one
particle table per frame). When the run ends, its output is opened in the viewer
(:func:`hrvptm_napari.layers.read_layers`); an error is shown in the widget's status line.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import napari.viewer
from magicgui.widgets import ComboBox, Container, FileEdit, Label, ProgressBar, PushButton

log = logging.getLogger(__name__)

#: Tasks of the widget.
TASKS = ("track run", "recon run")


def _numbered(folder: Path, suffix: str) -> int:
    from track.volumes import NUMBERED

    if not folder.is_dir():
        return 0
    return sum(1 for p in folder.iterdir() if NUMBERED.match(p.name) and p.suffix == suffix)


def reconstruct_folder(
    source: str | os.PathLike,
    out: str | os.PathLike,
    *,
    scene: str | os.PathLike | None = None,
    calib: str | os.PathLike | None = None,
    overwrite: bool = False,
):
    """Reconstruct a folder of light-field frames into numbered TIFF volumes, as ``recon run
    SOURCE -o OUT`` does with its defaults.

    ``source`` is an lfsim dataset (``dataset.json``, ``frames/``; its scene and white image
    are used unless ``scene`` / ``calib`` are given) or a folder of frames (then ``scene`` and
    ``calib`` are required). Returns :class:`recon.pipeline.SeriesResult`.

    Raises
    ------
    hrvbase.errors.InputError
        A missing scene, calibration or frame, or optics that do not match the calibration.
    """
    from hrvbase.errors import InputError
    from lfsim import init_backend
    from lfsim.scene import read_optics
    from recon.calibration_file import (
        calibrate_white_file,
        check_optics,
        dataset_optics,
        read_calibration,
    )
    from recon.frames import build_series, folder_frames
    from recon.pipeline import reconstruct_series
    from recon.preprocess import Preprocess

    source = Path(source)
    dataset = source if (source / "dataset.json").is_file() else None
    files = folder_frames(source / "frames" if dataset is not None else source)
    if scene is None and dataset is not None:
        record = read_json_dict(dataset / "dataset.json")
        named = record.get("scene")
        named = named.get("path") if isinstance(named, dict) else None
        if isinstance(named, str) and named:
            scene = Path(named) if Path(named).is_absolute() else (dataset / named).resolve()
    if scene is None:
        raise InputError(f"{source}: a scene file is needed (the optics of the microscope)")
    scene = Path(scene)
    optics = read_optics(scene)
    if calib is not None:
        grid, recorded, _ = read_calibration(Path(calib))
        where = f"calibration {str(calib)!r}"
    elif dataset is not None and (dataset / "white.tif").is_file():
        _, grid, _ = calibrate_white_file(
            dataset / "white.tif", optics, scene, allow_pitch_mismatch=False, allow_flag="calib"
        )
        recorded, where = dataset_optics(dataset), f"the optics of dataset {str(dataset)!r}"
    else:
        raise InputError(f"{source}: a lenslet calibration is needed (recon calibrate)")
    check_optics(optics, grid, recorded, scene=scene, source=where, allow=False)
    init_backend()
    return reconstruct_series(
        build_series(files),
        out,
        optics=optics,
        grid=grid,
        preprocess=Preprocess(background="auto"),
        overwrite=overwrite,
        progress=False,
        provenance={"scene": str(scene.resolve()), "command": "hrvptm napari"},
    )


def read_json_dict(path: Path) -> dict:
    """A JSON object file as a dict (an empty one when it holds something else)."""
    from hrvbase.io import read_json

    value = read_json(path)
    return value if isinstance(value, dict) else {}


def track_folder(source: str | os.PathLike, out: str | os.PathLike, *, overwrite: bool = False):
    """Detect, link and grid a volume series as ``track run SOURCE -o OUT`` does with its
    defaults (:func:`track.pipeline.track_volumes`). Returns its
    :class:`~track.pipeline.TrackResult`."""
    from track.detect import DetectSettings
    from track.pipeline import track_volumes
    from track.series import SeriesSettings

    return track_volumes(
        source,
        out,
        detect=DetectSettings(),
        series=SeriesSettings(),
        overwrite=overwrite,
        progress=False,
        provenance={"caller": "hrvptm napari"},
    )


def with_progress(
    job: Callable[[], Any], done: Callable[[], int], total: int, poll_s: float = 0.2
) -> Iterator[tuple[int, int]]:
    """Run ``job`` in a thread; yield ``(done(), total)`` every ``poll_s`` until it ends, then
    return its result (a generator for napari's ``thread_worker``; ``job``'s exception is
    raised again here)."""
    outcome: dict[str, Any] = {}

    def target():
        try:
            outcome["value"] = job()
        except BaseException as exc:  # handed to the caller below
            outcome["error"] = exc

    th = threading.Thread(target=target, daemon=True)
    th.start()
    while th.is_alive():
        yield min(done(), total), total
        th.join(poll_s)
    if "error" in outcome:
        raise outcome["error"]
    yield total, total
    return outcome.get("value")


class RunWidget(Container):
    """Run ``track run`` (a volume folder or OME-Zarr image) or ``recon run`` (an lfsim
    dataset, or frames with a scene and a calibration) into an output folder, then open it."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None):
        super().__init__(labels=True)
        self.viewer = napari_viewer
        self.task = ComboBox(label="task", choices=TASKS, value=TASKS[0])
        self.source = FileEdit(label="input", mode="d")
        self.scene = FileEdit(label="scene (recon)", mode="r", filter="*.xml")
        self.calib = FileEdit(label="calibration (recon)", mode="r", filter="*.json")
        self.output = FileEdit(label="output", mode="d")
        self.button = PushButton(text="Run")
        self.progress = ProgressBar(label="frames", min=0, max=1, value=0)
        self.status = Label(value="")
        self.extend([self.task, self.source, self.scene, self.calib, self.output, self.button,
                     self.progress, self.status])  # fmt: skip
        self.button.changed.connect(self.start)
        self.worker = None
        self.result = None
        self.error: BaseException | None = None

    @staticmethod
    def _path(edit: FileEdit) -> Path | None:
        v = str(edit.value or "")
        return None if v in ("", ".") else Path(v)

    def start(self, *_):
        """Start the selected task in a worker thread (returns the worker)."""
        from napari.qt.threading import thread_worker

        from track.volumes import scan_volumes

        src, out = self._path(self.source), self._path(self.output)
        self.result, self.error = None, None
        if src is None or out is None:
            self.status.value = "choose an input and an output folder"
            return None
        try:
            if self.task.value == "recon run":
                scene, calib = self._path(self.scene), self._path(self.calib)
                from recon.frames import folder_frames

                frames = src / "frames" if (src / "dataset.json").is_file() else src
                total = len(folder_frames(frames))

                def job():
                    return reconstruct_folder(src, out, scene=scene, calib=calib)

                def done():
                    return _numbered(out, ".tif")
            else:
                total = len(scan_volumes(src))

                def job():
                    return track_folder(src, out)

                def done():
                    return _numbered(out / "particles", ".csv")
        except Exception as exc:  # shown to the user, as the command line would print it
            self._failed(exc)
            return None
        self.progress.max = total
        self.progress.value = 0
        self.status.value = f"{self.task.value}: {src.name} → {out.name} …"
        self.button.enabled = False
        worker = thread_worker(with_progress, start_thread=False)(job, done, total)
        worker.yielded.connect(self._progress)
        worker.returned.connect(self._finished)
        worker.errored.connect(self._failed)
        worker.finished.connect(lambda: setattr(self.button, "enabled", True))
        self.worker = worker
        worker.start()
        return worker

    def _progress(self, value):
        done, total = value
        self.progress.value = done
        self.status.value = f"{self.task.value}: {done}/{total} frames"

    def _finished(self, result):
        from .layers import read_layers

        self.result = result
        out = self._path(self.output)
        self.status.value = f"{self.task.value}: done, {out}"
        if self.viewer is not None and out is not None:
            for data, kwargs, kind in read_layers(out):
                getattr(self.viewer, f"add_{kind}")(data, **kwargs)

    def _failed(self, exc):
        self.error = exc
        self.status.value = f"{self.task.value} failed: {exc}"
        log.warning("%s failed: %s", self.task.value, exc)
