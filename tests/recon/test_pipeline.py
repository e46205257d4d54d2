"""End to end: an lfsim dataset through `recon run`, resume, refusals, bad input."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from recon.cli import main

from ..helpers import experiment_toml

ROOT = Path(__file__).resolve().parents[2]

EXPERIMENT = experiment_toml(
    experiment={"name": "recon_test", "scene": "{scene}", "seed": 3, "frames": 3},
    particles={
        "kind": "box",
        "count": 6,
        "bounds_xyz_um": ((-180, 160), (-180, 160), (150, 350)),
        "min_spacing_um": 60,
        "diameter_um": 15,
    },
    motion={"type": "translation", "step_um": (5.0, 0.0, 0.0)},
    render={"rays_per_particle": 30000},
    noise={"model": "gaussian", "snr": 30},
    white={"rays_per_lenslet": 3000},
)

FAST = ["--z-range", "-40:400", "--z-step", "20", "-s", "3", "--rays-per-pattern", "20000"]


def make_dataset(tmp_path_factory, frames: int = 3) -> Path:
    """The lfsim dataset of :data:`EXPERIMENT` with ``frames`` frames, in a new folder."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment

    d = tmp_path_factory.mktemp(f"ds{frames}")
    toml = d / "exp.toml"
    text = EXPERIMENT.replace("frames = 3", f"frames = {frames}")
    toml.write_text(text.format(scene=(ROOT / "scenes" / "small.xml").as_posix()))
    out = d / "dataset"
    generate_dataset(load_experiment(toml), out, progress=False)
    return out


@pytest.fixture(scope="module")
def dataset(backend, tmp_path_factory):
    return make_dataset(tmp_path_factory)


def run(capsys, *args):
    """``recon -q ARGS``: the exit code, stdout and stderr."""
    rc = main(["-q", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_dataset_folder_reconstructs_and_finds_particles(dataset, tmp_path, capsys):
    from lfsim.io import read_json, read_tiff

    vol_dir = tmp_path / "vol"
    rc, _, err = run(capsys, "run", dataset, *FAST, "--iterations", "4", "-o", vol_dir)
    assert rc == 0, err
    meta = read_json(vol_dir / "recon.json")
    assert meta["status"] == "complete"
    assert len(meta["frames"]) == 3
    assert all(len(f["input_sha256"]) == 64 for f in meta["frames"])
    vol, vmeta = read_tiff(vol_dir / "000000.tif")
    assert vol.dtype == np.float32
    assert vol.shape == tuple(meta["volume_shape"])
    assert vmeta["voxel_size_um"] == pytest.approx([20.0, 25 / 3, 25 / 3])
    # Every particle has a bright voxel within 1.5 lateral voxels and 2 z-steps of it.
    g = meta["grid"]
    depths = np.asarray(g["depths_um"])
    vox = g["lenslet_object_um"] / g["s"]
    truth = np.loadtxt(dataset / "truth" / "000000.csv", delimiter=",", skiprows=1)[:, 1:4]
    for x, y, z in truth:
        i = int((x - g["origin_xy_um"][0]) / vox)
        j = int((y - g["origin_xy_um"][1]) / vox)
        k = int(np.argmin(np.abs(depths - z)))
        near = vol[max(k - 2, 0) : k + 3, max(j - 2, 0) : j + 3, max(i - 2, 0) : i + 3]
        assert near.max() > 0.3 * vol.max(), (x, y, z)
    # the lenslet grid travels in each TIFF: copied without recon.json, the volumes keep
    # the lenslet period that track's detection uses
    from track.volumes import scan_volumes

    assert vmeta["grid"] == g
    bare = tmp_path / "copied"
    bare.mkdir()
    for f in vol_dir.glob("*.tif"):
        shutil.copy(f, bare / f.name)
    for folder in (vol_dir, bare):
        vols = scan_volumes(folder)
        assert [v.lenslet_period_vox for v in vols] == [3] * 3, folder
        assert vols[0].lenslet_phase_vox == (0, 0)
        # ... and so does each frame's measured SNR
        assert [v.snr for v in vols] == [f["preprocess"]["snr"] for f in meta["frames"]]
        # ... and the specimen's surface: none in air
        assert [v.surface_z_um for v in vols] == [None] * 3
    assert meta["surface_z_um"] is None and vmeta["surface_z_um"] is None
    # the SNR recon measures on each raw frame is the simulator's (its definition, paper
    # §4.1), within the spread of the 99.9th percentile of this small image (90 000 px)
    truth_snr = [r["noise"]["snr"] for r in read_json(dataset / "dataset.json")["frame_records"]]
    got = [f["preprocess"]["snr"] for f in meta["frames"]]
    assert got == pytest.approx(truth_snr, rel=0.15), (got, truth_snr)


def test_resume_and_refusal(dataset, tmp_path, capsys):
    vol_dir = tmp_path / "vol"
    args = ["run", dataset, *FAST, "--iterations", "1", "-o", vol_dir]
    assert run(capsys, *args)[0] == 0
    before = {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")}
    (vol_dir / "000001.tif").unlink()
    rc, out, _ = main_verbose(capsys, *args)
    assert rc == 0
    assert "1 volume(s) reconstructed, 2 already done" in out
    after = {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")}
    assert after == before  # the resumed frame is byte-identical
    # Resume verifies what it keeps: a truncated volume is redone, exactly that one.
    with open(vol_dir / "000002.tif", "r+b") as fh:
        fh.truncate(1000)
    mtimes = {p.name: p.stat().st_mtime_ns for p in vol_dir.glob("*.tif")}
    rc, out, err = main_verbose(capsys, *args)
    assert rc == 0 and "1 volume(s) reconstructed, 2 already done" in out
    assert "000002.tif changed on disk" in err
    assert {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")} == before
    changed = [p.name for p in vol_dir.glob("*.tif") if p.stat().st_mtime_ns != mtimes[p.name]]
    assert changed == ["000002.tif"]
    # A folder of a version that did not measure the SNR gains it on resume, nothing redone.
    from hrvbase.io import read_json, write_json

    meta = read_json(vol_dir / "recon.json")
    snrs = [f["preprocess"].pop("snr") for f in meta["frames"]]
    write_json(vol_dir / "recon.json", meta, overwrite=True)
    rc, out, _ = main_verbose(capsys, *args)
    assert rc == 0 and "0 volume(s) reconstructed, 3 already done" in out
    assert [f["preprocess"]["snr"] for f in read_json(vol_dir / "recon.json")["frames"]] == snrs
    assert {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")} == before
    # The camera gain changes the SNR (shot noise), not the volumes: resumed, SNR measured anew.
    rc, out, _ = main_verbose(capsys, *args, "--gain-dn-per-e", "0.5")
    assert rc == 0 and "0 volume(s) reconstructed, 3 already done" in out
    shot = [f["preprocess"]["snr"] for f in read_json(vol_dir / "recon.json")["frames"]]
    assert all(a < b for a, b in zip(shot, snrs, strict=True)), (shot, snrs)
    assert {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")} == before
    # Other settings into the same folder: refused, nothing touched.
    rc, _, err = run(capsys, "run", dataset, *FAST, "--iterations", "2", "-o", vol_dir)
    assert rc == 2 and "other inputs or settings" in err and err.count("\n") == 1
    assert {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")} == before
    # A folder that is not ours: refused.
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    rc, _, err = run(capsys, "run", dataset, *FAST, "-o", foreign)
    assert rc == 2 and "not empty" in err
    assert (foreign / "notes.txt").read_text() == "mine"


def test_threads_setting_does_not_change_the_volumes(dataset, tmp_path, capsys):
    """--threads sets ReconSettings.threads (recorded, and the projector's pool); a folder made
    with 2 threads resumes with 1 (not part of the fingerprint), to the same bytes."""
    from lfsim.io import read_json

    vol_dir = tmp_path / "vol"
    args = ["run", dataset, *FAST, "--iterations", "2", "--frames", "0:2", "-o", vol_dir]
    assert run(capsys, "--threads", "2", *args)[0] == 0
    meta = read_json(vol_dir / "recon.json")
    assert meta["settings"]["threads"] == 2 and meta["projector_threads"] == 2
    before = {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")}
    assert len(before) == 2
    (vol_dir / "000001.tif").unlink()
    rc, out, err = main_verbose(capsys, *args, "--threads", "1")
    assert rc == 0, err
    assert "1 volume(s) reconstructed, 1 already done" in out
    meta = read_json(vol_dir / "recon.json")
    assert meta["settings"]["threads"] == 1 and meta["projector_threads"] == 1
    assert {p.name: p.read_bytes() for p in vol_dir.glob("*.tif")} == before
    from recon.errors import InputError
    from recon.settings import ReconSettings

    assert ReconSettings(threads=3).result_dict() == ReconSettings().result_dict()
    assert ReconSettings(threads=3).to_dict()["threads"] == 3
    for bad in (0, 1.5, True):
        with pytest.raises(InputError, match="threads must be an integer"):
            ReconSettings(threads=bad)


def main_verbose(capsys, *args):
    rc = main([*map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_bad_inputs(dataset, tmp_path, capsys):
    import tifffile

    # Frame size different from the calibration's.
    small = tmp_path / "small.tif"
    tifffile.imwrite(small, np.zeros((100, 120), np.uint8))
    calib = tmp_path / "calib.json"
    assert (
        run(
            capsys,
            "calibrate",
            dataset / "white.tif",
            "--scene",
            ROOT / "scenes" / "small.xml",
            "-o",
            calib,
        )[0]
        == 0
    )
    rc, _, err = run(
        capsys,
        "run",
        small,
        "--scene",
        ROOT / "scenes/small.xml",
        "--calib",
        calib,
        *FAST,
        "-o",
        tmp_path / "v1",
    )
    assert rc == 2 and "calibration" in err and "small.tif" in err
    # Non-finite pixels.
    nan = tmp_path / "nan.tif"
    a = np.ones((300, 300), np.float32)
    a[5, 5] = np.nan
    tifffile.imwrite(nan, a)
    rc, _, err = run(
        capsys,
        "run",
        nan,
        "--scene",
        ROOT / "scenes/small.xml",
        "--calib",
        calib,
        *FAST,
        "-o",
        tmp_path / "v2",
    )
    assert rc == 2 and "non-finite" in err
    # A depth range these optics cannot resolve on a 20 x 20-lenslet image.
    rc, _, err = run(
        capsys, "run", dataset, "--z-range", "0:3000", "--z-step", "50", "-o", tmp_path / "v3"
    )
    assert rc == 2 and "cannot be resolved" in err
    # Missing frames, bad z step.
    rc, _, err = run(
        capsys,
        "run",
        tmp_path / "missing.tif",
        "--scene",
        ROOT / "scenes/small.xml",
        "--calib",
        calib,
        "-o",
        tmp_path / "v4",
    )
    assert rc == 2 and "missing.tif" in err
    rc, _, err = run(capsys, "run", dataset, "--z-step", "0", "-o", tmp_path / "v5")
    assert rc == 2 and "--z-step must be > 0" in err
    for d in ("v1", "v2", "v3", "v4", "v5"):
        assert not (tmp_path / d).exists() or not any((tmp_path / d).iterdir())


def test_roi_reconstructs_a_sub_field(dataset, tmp_path, capsys):
    from lfsim.io import read_json

    vol_dir = tmp_path / "roi"
    rc, _, err = run(
        capsys, "run", dataset, *FAST, "--iterations", "1", "--roi", "30:240,45:255", "-o", vol_dir
    )
    assert rc == 0, err
    meta = read_json(vol_dir / "recon.json")
    nx, ny = meta["grid"]["n_lenslets_xy"]
    # 14 whole lenslets lie in the region; rectification keeps those whose samples all lie
    # inside the region's pixel centres (the border lenslets may drop out).
    assert 12 <= nx <= 14 and 12 <= ny <= 14
    shutil.rmtree(vol_dir)


def test_background_model_is_a_setting_of_its_own(dataset, tmp_path, capsys):
    """Both ways of handling the black level run; they are different settings (a folder made
    with one is not resumed with the other) and both find the same bright voxels."""
    import tifffile

    vols = {}
    for mode in ("subtract", "model"):
        out = tmp_path / mode
        args = ["run", dataset, *FAST, "--iterations", "2", "--background-model", mode, "-o", out]
        assert run(capsys, *args)[0] == 0
        vols[mode] = tifffile.imread(out / "000000.tif")
    top = {m: set(np.argsort(v.ravel())[-30:]) for m, v in vols.items()}
    assert len(top["subtract"] & top["model"]) >= 22  # measured 26 of 30
    rc, _, err = run(capsys, "run", dataset, *FAST, "--iterations", "2", "-o", tmp_path / "model")
    assert rc == 2 and "other inputs or settings" in err
    from recon.errors import InputError
    from recon.pipeline import ReconSettings

    with pytest.raises(InputError, match="background_model"):
        ReconSettings(background_model="clip")


def test_dataset_with_a_scene_of_other_optics_is_refused(dataset, tmp_path, capsys):
    from lfsim import small_optics
    from lfsim.scene import write_scene

    other = write_scene(small_optics(na=0.25), tmp_path / "na025.xml")
    out = tmp_path / "v"
    rc, stdout, err = run(capsys, "run", dataset, "--scene", other, *FAST, "-o", out)
    assert rc == 2 and stdout == "" and err.count("\n") == 1
    assert "na025.xml" in err and str(dataset) in err and "na 0.25 (scene) vs 0.2" in err
    assert not out.exists()


def test_dataset_rendered_through_glass_lenslets(dataset, tmp_path, capsys):
    """The README quick start on a dataset whose scene has the glass lenslet mesh: it is
    reconstructed with the ideal lenslets of the same optics (a warning says so)."""
    import json

    from lfsim.io import read_json

    glass = tmp_path / "dataset_glass"
    shutil.copytree(dataset, glass)
    record = json.loads((glass / "dataset.json").read_text())
    record["scene"]["path"] = str(ROOT / "scenes" / "small_glass.xml")
    record["optics"]["mla_kind"] = "glass"
    (glass / "dataset.json").write_text(json.dumps(record))
    out = tmp_path / "vol"
    rc, _, err = main_verbose(capsys, "run", glass, *FAST, "--iterations", "1", "-o", out)
    assert rc == 0, err
    assert "recon: warning:" in err and "glass mesh" in err and "ideal lenslets" in err
    meta = read_json(out / "recon.json")
    assert meta["status"] == "complete" and meta["scene_mla_kind"] == "glass"
    assert meta["scene"].endswith("small_glass.xml")
