"""Fixtures of the napari plugin's tests: a virtual X display, one viewer for the session, and
a small study report with known truth (volumes, track results, truth tables).

napari draws with OpenGL, which Qt's ``offscreen`` platform does not provide; the viewer runs
on the ``xcb`` platform against an Xvfb display started here (``setup.sh`` installs Xvfb).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

#: Voxel size (dz, dy, dx) µm and object-space (x, y, z) of the centre of voxel (0, 0, 0):
#: an origin far from 0 and no multiple of the voxel size, so that a layer placed by the
#: voxel corner or without its origin is caught.
VOXEL_UM = (4.0, 2.0, 2.0)
ORIGIN_XYZ_UM = (-101.0, -63.0, 117.0)
SHAPE = (24, 40, 56)
N_FRAMES = 3
STEP_X_UM = 2.0  # one voxel along x per frame: the truth stays on voxel centres
#: Voxel indices (k, j, i) of the particles in frame 0: a lateral grid 12 voxels apart, on
#: three z planes (four particles each).
PARTICLES_KJI = [
    ((6, 12, 17)[n % 3], j, i) for n, (j, i) in enumerate((j, i) for j in (7, 19, 31)
                                                      for i in (8, 20, 32, 44))
]  # fmt: skip


def voxel_centre_xyz(kji) -> np.ndarray:
    """Object-space (x, y, z) µm of the centre of voxel (k, j, i) (docs/conventions.md §2)."""
    k, j, i = np.asarray(kji, dtype=float).T
    x0, y0, z0 = ORIGIN_XYZ_UM
    dz, dy, dx = VOXEL_UM
    return np.column_stack([x0 + i * dx, y0 + j * dy, z0 + k * dz])


def truth_xyz(frame: int) -> np.ndarray:
    return voxel_centre_xyz(PARTICLES_KJI) + np.array([STEP_X_UM * frame, 0.0, 0.0])


def _blobs(centres_xyz: np.ndarray, rng) -> np.ndarray:
    x0, y0, z0 = ORIGIN_XYZ_UM
    dz, dy, dx = VOXEL_UM
    kk, jj, ii = np.indices(SHAPE, dtype=float)
    vol = np.zeros(SHAPE)
    for x, y, z in centres_xyz:
        k, j, i = (z - z0) / dz, (y - y0) / dy, (x - x0) / dx
        vol += 100.0 * np.exp(
            -0.5 * (((kk - k) / 1.5) ** 2 + ((jj - j) / 1.2) ** 2 + ((ii - i) / 1.2) ** 2)
        )
    return (vol + 1.0 + rng.normal(0, 0.3, SHAPE)).astype(np.float32)


def write_study(base: Path) -> Path:
    """``base/report``: an ``hrvptm study`` report of one variant (``mismatched``) with the
    dataset's truth, the volumes (TIFF, as ``recon run`` writes them) and ``track run``'s
    results (the library pipeline)."""
    from hrvbase.tables import write_table
    from lfsim.io import write_tiff
    from track.detect import DetectSettings
    from track.fields import GridSettings
    from track.pipeline import track_volumes
    from track.series import SeriesSettings

    report = base / "report"
    variant = report / "mismatched"
    (variant / "dataset" / "truth").mkdir(parents=True)
    (variant / "volumes").mkdir()
    rng = np.random.default_rng(7)
    for f in range(N_FRAMES):
        xyz = truth_xyz(f)
        n = len(xyz)
        write_table(
            variant / "dataset" / "truth" / f"{f:06d}.csv",
            {
                "id": np.arange(n),
                "x_um": xyz[:, 0],
                "y_um": xyz[:, 1],
                "z_um": xyz[:, 2],
                "diameter_um": np.full(n, 5.0),
                "brightness": np.ones(n),
            },
        )
        write_tiff(
            variant / "volumes" / f"{f:06d}.tif",
            _blobs(xyz, rng),
            metadata={"frame": f, "number": f, "time_s": None},
            pixel_size_um=VOXEL_UM,
            origin_xyz_um=ORIGIN_XYZ_UM,
        )
    track_volumes(
        variant / "volumes",
        variant / "track",
        detect=DetectSettings(deconvolution_iterations=0),
        series=SeriesSettings(grid=GridSettings(spacing_um=12.0)),
    )
    (report / "study.json").write_text(
        json.dumps({"tool": "hrvptm", "name": "napari_test", "runs": []}), encoding="utf-8"
    )
    return report


@pytest.fixture(scope="session")
def study_report(tmp_path_factory) -> Path:
    return write_study(tmp_path_factory.mktemp("napari_study"))


@pytest.fixture(scope="session")
def display():
    """An Xvfb display for the session (``DISPLAY`` and ``QT_QPA_PLATFORM=xcb`` set)."""
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.fail("Xvfb is not installed (setup.sh installs Debian's xvfb)")
    read, write = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(write), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
        pass_fds=(write,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write)
    with os.fdopen(read) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        pytest.fail("Xvfb did not start")
    old = {k: os.environ.get(k) for k in ("DISPLAY", "QT_QPA_PLATFORM")}
    os.environ["DISPLAY"] = f":{number}"
    os.environ["QT_QPA_PLATFORM"] = "xcb"
    yield os.environ["DISPLAY"]
    proc.terminate()
    proc.wait(10)
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@pytest.fixture(scope="session")
def session_viewer(display):
    import napari

    viewer = napari.Viewer(show=True, title="hrvptm tests")
    viewer.window._qt_window.resize(1000, 800)
    yield viewer
    viewer.close()


@pytest.fixture
def viewer(session_viewer):
    """The session's viewer, emptied and in 2D, for one test."""
    session_viewer.layers.clear()
    session_viewer.dims.ndisplay = 2
    return session_viewer


@pytest.fixture(scope="module")
def study_in_viewer(session_viewer, study_report):
    """The session's viewer with the test study opened by the plugin (once per module), as
    ``(viewer, layers)``."""
    session_viewer.layers.clear()
    session_viewer.dims.ndisplay = 2
    return session_viewer, session_viewer.open(study_report, plugin="hrvptm")
