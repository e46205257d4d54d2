"""docs/real_data.md end to end: camera files → lenslet calibration → pixel size → volumes →
tracks, on a synthetic "real" experiment laid out the way a camera exports it.

The "real" microscope is the small test scene with a tube lens that makes the magnification
5 % higher than the nominal scene says; the user only has the nominal scene. The frames are
named ``img_8.tif … img_11.tif``, which text order would take as 10, 11, 8, 9.
"""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from .helpers import experiment_toml

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "scenes" / "small.xml"
MAGNIFICATION_ERROR = 0.05
STEP_UM = (6.0, 0.0, 0.0)
FIRST = 8  # the camera's first frame number

RECON_FAST = ["--z-range", "120:400", "--z-step", "5", "--rays-per-pattern", "20000"]


def _hashes(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def camera_export(backend, tmp_path_factory):
    """``exp/`` as a camera and a microscope user would have it, and the true optics."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment
    from lfsim.noise import add_gaussian_noise
    from lfsim.render import render_micrometer
    from lfsim.scene import read_optics, write_scene

    base = tmp_path_factory.mktemp("walkthrough")
    nominal = read_optics(NOMINAL)
    true = replace(nominal, f_tube_um=nominal.f_tube_um * (1 + MAGNIFICATION_ERROR))
    true_scene = write_scene(true, base / "true_microscope.xml")
    toml = base / "exp.toml"
    toml.write_text(
        experiment_toml(
            experiment={
                "name": "walkthrough",
                "scene": true_scene.as_posix(),
                "seed": 11,
                "frames": 4,
            },
            particles={
                "kind": "box",
                "count": 18,
                "bounds_xyz_um": ((-180, 160), (-180, 160), (160, 340)),
                "min_spacing_um": 55,
            },
            motion={"type": "translation", "step_um": STEP_UM},
            render={"rays_per_particle": 30000, "tracer": "paraxial"},
            noise={"model": "gaussian", "snr": 30},
            white={"rays_per_lenslet": 3000},
        )
    )
    dataset = generate_dataset(load_experiment(toml), base / "rendered", progress=False)
    exp = base / "exp"
    (exp / "run1").mkdir(parents=True)
    shutil.copy(dataset / "white.tif", exp / "white.tif")
    for k in range(4):
        shutil.copy(dataset / "frames" / f"{k:06d}.tif", exp / "run1" / f"img_{FIRST + k}.tif")
    clean = render_micrometer(true, 10.0, rays_per_line=20_000, seed=3, tracer="paraxial")
    image, _ = add_gaussian_noise(clean.astype(np.float64), 50, 4, bit_depth=12)
    import tifffile

    tifffile.imwrite(exp / "micrometer.tif", image)
    return exp, dataset, true


def _run(main, capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert rc == 0, err
    return out, err


def test_camera_files_to_tracks(camera_export, tmp_path, capsys):
    import json

    from recon.cli import main as recon
    from track.cli import main as track
    from track.tables import read_tracks_csv

    exp, dataset, true = camera_export
    before = _hashes(exp)
    work = tmp_path / "work"

    # 1. Lenslet calibration from the white image (nominal scene).
    _run(
        recon, capsys, "calibrate", exp / "white.tif", "--scene", NOMINAL, "-o", work / "calib.json"
    )
    # 2. Pixel size from the stage micrometer, and the scene with the measured magnification.
    _run(
        recon,
        capsys,
        "pixel-size",
        exp / "micrometer.tif",
        "--division-um",
        10,
        "--scene",
        NOMINAL,
        "--calib",
        work / "calib.json",
        "-o",
        work / "pixel.json",
        "--write-scene",
        work / "measured.xml",
    )
    pixel = json.loads((work / "pixel.json").read_text())
    assert pixel["um_per_px"] == pytest.approx(true.object_pixel_um, rel=0.005)
    # 3. Volumes from the frames, by number, with the measured scene (magnification differs
    #    from the calibration's nominal optics: accepted).
    _, err = _run(
        recon,
        capsys,
        "run",
        str(exp / "run1" / "img_*.tif"),
        "--scene",
        work / "measured.xml",
        "--calib",
        work / "calib.json",
        "--fps",
        2500,
        *RECON_FAST,
        "-o",
        work / "volumes",
    )
    assert "does not match" not in err
    meta = json.loads((work / "volumes" / "recon.json").read_text())
    assert [Path(f["input"]).name for f in meta["frames"]] == [
        f"img_{FIRST + k}.tif" for k in range(4)
    ]
    assert [f["time_s"] for f in meta["frames"]] == pytest.approx(
        [(FIRST + k) / 2500 for k in range(4)]
    )
    # 4. Particles, tracks, displacement and strain.
    out, _ = _run(track, capsys, "run", work / "volumes", "-o", work / "tracks")
    assert out.startswith("RESULTS:")
    tracks = read_tracks_csv(work / "tracks" / "tracks.csv")
    truth0 = np.loadtxt(dataset / "truth" / "000000.csv", delimiter=",", skiprows=1)[:, 1:4]
    ids, counts = np.unique(tracks["track_id"], return_counts=True)
    full = ids[counts == 4]
    # Detection finds all 18 particles in every frame (its scales follow the volume); every
    # track found must be right. Some particles' long axial
    # images (FWHM ≈ 100 µm) overlap a neighbour's: one of them (42 µm off laterally, 84 µm
    # axially) steps 7.65 µm instead of 6 once; all others stay within 0.8 µm.
    assert len(full) >= 16
    xyz = np.stack([tracks["x_um"], tracks["y_um"], tracks["z_um"]], axis=1)
    within = 0
    steps_z = []
    for tid in full:
        sel = tracks["track_id"] == tid
        path = xyz[sel][np.argsort(tracks["frame"][sel])]
        step = np.diff(path, axis=0)
        np.testing.assert_allclose(step[:, :2], np.tile(STEP_UM[:2], (3, 1)), atol=2.0)
        within += bool(np.all(np.abs(step[:, :2] - STEP_UM[:2]) <= 1.0))
        steps_z.append(step[:, 2])
        # at the right lateral place: the measured magnification (the nominal one would put a
        # particle 100–200 µm from the axis 5–10 µm off)
        d = np.linalg.norm(truth0[:, :2] - path[0, :2], axis=1)
        assert d.min() < 2.0, (path[0], truth0[np.argmin(d)])
    assert within >= len(full) - 1
    # Axially the particles do not move (STEP_UM z = 0): every z step is localisation noise.
    # Its σ per step (two frames' σ_z in quadrature; robust: 1.4826 × the median |step|,
    # about 2.8 µm) is bounded by σ_z ≤ 3.5 µm a frame, and sets the tolerances: each step
    # within 3.5 σ, each track's mean step (3 steps: σ_step / 3) and the mean over the
    # tracks (σ_step / 3 / sqrt(n)) within 3.5 of their σ: a bias in z of about 1 µm a
    # frame fails.
    steps_z = np.asarray(steps_z)
    sigma_step = 1.4826 * float(np.median(np.abs(steps_z - STEP_UM[2])))
    assert sigma_step <= np.sqrt(2) * 3.5, sigma_step
    assert np.all(np.abs(steps_z - STEP_UM[2]) <= 3.5 * sigma_step), (steps_z, sigma_step)
    per_track = steps_z.mean(axis=1) - STEP_UM[2]
    assert np.all(np.abs(per_track) <= 3.5 * sigma_step / 3), (per_track, sigma_step)
    assert abs(per_track.mean()) <= 3.5 * sigma_step / 3 / np.sqrt(len(full)), per_track
    assert _hashes(exp) == before  # nothing the user gave changed
