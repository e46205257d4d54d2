"""``hrvptm axial`` (hrvptm.calibrated) on volumes that ``recon run`` made from a glass-lenslet
rendering with an ideal-lenslet model: the layout, the correction against the truth, resume,
and the refusals."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from hrvptm.cli import main
from track.tables import read_points_csv

from ..recon.test_pipeline import EXPERIMENT as _RECON_EXPERIMENT

ROOT = Path(__file__).resolve().parents[2]
# The recon tests' scene, with 8 particles over 2 frames.
EXPERIMENT = _RECON_EXPERIMENT.replace("count = 6", "count = 8").replace("frames = 3", "frames = 2")
RECON = ["--z-range", "100:400", "--z-step", "10", "-s", "3", "--iterations", "5"]


@pytest.fixture(scope="module")
def volumes(backend, tmp_path_factory):
    """Rendered through the glass lenslets, reconstructed with the ideal model (no inverse
    crime: the calibration renders through the model's ideal lenslets)."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment
    from recon.cli import main as recon

    d = tmp_path_factory.mktemp("axial_cli")
    toml = d / "exp.toml"
    assert "count = 8" in EXPERIMENT and "frames = 2" in EXPERIMENT
    toml.write_text(EXPERIMENT.format(scene=(ROOT / "scenes" / "small_glass.xml").as_posix()))
    generate_dataset(load_experiment(toml), d / "ds", progress=False)
    scene = str(ROOT / "scenes" / "small.xml")
    assert recon(["-q", "run", str(d / "ds"), "--scene", scene, *RECON, "-o", str(d / "vol")]) == 0
    return d


def run(capsys, *args):
    rc = main(["-q", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _errors(truth_dir: Path, tables: list[Path]) -> np.ndarray:
    """Detected − true positions of the particles found (µm; x, y, z), all frames."""
    out = []
    for k, table in enumerate(tables):
        truth = read_points_csv(truth_dir / f"{k:06d}.csv")
        found = read_points_csv(table)
        dist, idx = cKDTree(truth).query(found)
        out.append(found[dist < 20] - truth[idx[dist < 20]])
    return np.concatenate(out)


def test_calibrated_run_lowers_the_position_bias(volumes, tmp_path, capsys):
    out = tmp_path / "res"
    rc, _, err = run(capsys, "axial", volumes / "vol", "-o", out)
    assert rc == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["axial", "detect", "track"]
    raw = sorted((out / "detect" / "particles").glob("*.csv"))
    fixed = sorted((out / "axial" / "particles").glob("*.csv"))
    assert len(raw) == len(fixed) == 2
    truth = volumes / "ds" / "truth"
    e_raw, e_fixed = _errors(truth, raw), _errors(truth, fixed)
    assert len(e_raw) == len(e_fixed) >= 10
    rms_raw, rms_fixed = np.sqrt(np.mean(e_raw**2, 0)), np.sqrt(np.mean(e_fixed**2, 0))
    # Measured (2 frames, the default two steps): z 2.54 -> 1.28 µm, x 0.19 -> 0.10, y 0.18
    # -> 0.10 µm (one step: z 1.24 µm).
    assert rms_raw[2] > 1.5  # the reconstruction's bias is there
    assert rms_fixed[2] < 0.75 * rms_raw[2]
    assert np.all(rms_fixed[:2] < 1.1 * rms_raw[:2])
    record = json.loads((out / "axial" / "axial_calibration.json").read_text("utf-8"))
    assert record["settings"]["method"] == "simulated"
    assert [f["applied_axes"] for f in record["frames"]] == ["xyz", "xyz"]
    summary = json.loads((out / "track" / "summary.json").read_text("utf-8"))
    assert summary["status"] == "complete"
    assert summary["axial_calibration"].endswith("axial_calibration.json")
    # Resume: nothing is rendered again; the corrected tables are the same.
    stamps = {p: p.stat().st_mtime_ns for p in (out / "axial" / "frames").glob("*.tif")}
    before = [p.read_bytes() for p in fixed]
    rc, _, err = run(capsys, "axial", volumes / "vol", "-o", out)
    assert rc == 0, err
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert [p.read_bytes() for p in fixed] == before
    # z only: x and y as detected (and a track config: no fields).
    cfg = tmp_path / "track.toml"
    cfg.write_text("[track.grid]\ntarget_nodes = 500\n", "utf-8")
    rc, _, err = run(
        capsys, "axial", volumes / "vol", "--z-only", "-o", tmp_path / "z",
        "--track-config", cfg,
    )  # fmt: skip
    assert rc == 0, err
    z_only = sorted((tmp_path / "z" / "axial" / "particles").glob("*.csv"))
    for a, b in zip(raw, z_only, strict=True):
        pa, pb = read_points_csv(a), read_points_csv(b)
        assert np.array_equal(pa[:, :2], pb[:, :2]) and not np.array_equal(pa[:, 2], pb[:, 2])


def test_a_second_fixed_point_step_measures_the_bias_where_the_first_put_the_particles(
    volumes, tmp_path, capsys
):
    """``[track.axial] steps = 2`` (the default): the second references are rendered at the
    positions the first step corrected (in ``axial/step2``), and the corrected positions are
    no worse than with ``steps = 1``."""
    one, two = tmp_path / "one", tmp_path / "two"
    cfg = tmp_path / "track.toml"
    cfg.write_text("[track.axial]\nsteps = 1\n", "utf-8")
    assert run(capsys, "axial", volumes / "vol", "-o", one, "--track-config", cfg)[0] == 0
    assert not (one / "axial" / "step2").exists()
    rc, _, err = run(capsys, "axial", volumes / "vol", "-o", two)
    assert rc == 0, err
    record = json.loads((two / "axial" / "axial_calibration.json").read_text("utf-8"))
    assert record["settings"]["steps"] == 2
    # step 1 is the one-step run: the same references
    for f in sorted((one / "axial" / "frames").glob("*.tif")):
        assert f.read_bytes() == (two / "axial" / "frames" / f.name).read_bytes()
    assert len(list((two / "axial" / "step2" / "volumes").glob("*.tif"))) == 2
    truth = volumes / "ds" / "truth"
    e = {}
    for name, out in (("detected", one / "detect"), ("one", one / "axial"), ("two", two / "axial")):
        e[name] = _errors(truth, sorted((out / "particles").glob("*.csv")))
    # the second step moves the positions, by less than the first
    move1 = np.abs(e["one"][:, 2] - e["detected"][:, 2])
    move2 = np.abs(e["two"][:, 2] - e["one"][:, 2])
    assert 0 < np.median(move2) < np.median(move1)
    rms = {k: np.sqrt(np.mean(v[:, 2] ** 2)) for k, v in e.items()}
    assert rms["two"] < 1.05 * rms["one"] < rms["detected"], rms
    cfg.write_text("[track.axial]\nsteps = 0\n", "utf-8")
    rc, _, err = run(capsys, "axial", volumes / "vol", "-o", tmp_path / "x", "--track-config", cfg)
    assert rc == 2 and "steps must be an integer in 1..5" in err


def test_calibrated_run_refusals(volumes, tmp_path, capsys):
    vol = volumes / "vol"
    # volumes without their recon record
    bare = tmp_path / "bare"
    bare.mkdir()
    for p in vol.glob("*.tif"):
        shutil.copy(p, bare / p.name)
    rc, _, err = run(capsys, "axial", bare, "-o", tmp_path / "b")
    assert rc == 2 and "recon.json does not exist" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()
    # a results folder of something else: refused, untouched
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    rc, _, err = run(capsys, "axial", vol, "-o", mine)
    assert rc == 2 and "holds notes.txt" in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    # bad values name the option or the file
    rc, _, err = run(capsys, "axial", vol, "--reference-rays", "10", "-o", tmp_path / "c")
    assert rc == 2 and "--reference-rays must be an integer >= 1000" in err
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[track.detect]\nthreshold = 3\n[recon]\ns = 3\n", "utf-8")
    rc, _, err = run(capsys, "axial", vol, "--track-config", cfg, "-o", tmp_path / "d")
    assert rc == 2 and "bad.toml" in err and "[track] tables" in err
    assert not (tmp_path / "d").exists()


def test_sphere_diameter_is_checked_against_the_particles_measured(volumes, tmp_path, capsys):
    """Reference spheres far larger than the particles the detector measures in the volumes
    (15 µm particles: a lateral FWHM of 33 µm on these 8.3 µm voxels) are refused before any
    work, with the numbers; the same value from [track.axial] of --track-config too."""
    vol = volumes / "vol"
    for d in ("5000", "60"):
        rc, _, err = run(capsys, "axial", vol, "--sphere-diameter-um", d, "-o", tmp_path / "r")
        lines = err.strip().splitlines()
        assert rc == 2 and len(lines) == 1, err
        assert f"--sphere-diameter-um {float(d):g} µm" in lines[0] and "lateral FWHM" in lines[0]
        assert not (tmp_path / "r").exists()
    cfg = tmp_path / "track.toml"
    cfg.write_text("[track.axial]\nsphere_diameter_um = 200\n", "utf-8")
    rc, _, err = run(capsys, "axial", vol, "--track-config", cfg, "-o", tmp_path / "r")
    assert rc == 2 and "[track.axial] sphere_diameter_um of " in err and " 200 µm" in err, err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("kind", ["missing", "a-file"])
def test_voldir_missing_or_a_file_is_named_as_such(tmp_path, capsys, kind):
    vol = tmp_path / "vol"
    if kind == "a-file":
        vol.write_bytes(b"II*\x00")
    rc, _, err = run(capsys, "axial", vol, "-o", tmp_path / "res")
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    what = "does not exist" if kind == "missing" else "is a file"
    assert f"volumes {vol} {what}" in lines[0] and "recon.json" not in lines[0], lines[0]
    assert not (tmp_path / "res").exists()


def test_a_recon_record_of_the_older_layout_gives_the_same_model(tmp_path):
    from hrvbase.io import rename_keys
    from hrvptm.calibrated import ReconModel
    from lfsim.optics import small_optics
    from recon.lenslet_grid import LensletGrid
    from recon.settings import ReconSettings

    optics = small_optics(na=0.25)
    grid = LensletGrid(15.0, 0.2, (157.5, 152.0), (300, 300))
    settings = ReconSettings(
        z_min_um=-40.0, z_max_um=40.0, z_step_um=10.0, roi_xy_px=(0, 90, 15, 80)
    )
    record = {
        "optics": optics.to_dict(),
        "calibration": grid.to_dict(),
        "settings": settings.to_dict(),
    }
    (tmp_path / "new").mkdir()
    (tmp_path / "new" / "recon.json").write_text(json.dumps(record))
    older = rename_keys(record, {"sensor_xy_px": "sensor_px", "axis_xy_px": "axis_px"})
    older = rename_keys(older, {"origin_xy_px": "origin_px", "roi_xy_px": "roi_px"})
    assert "roi_px" in older["settings"] and "origin_px" in older["calibration"]
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "recon.json").write_text(json.dumps(older))
    new = ReconModel.from_record(tmp_path / "new")
    assert new == ReconModel(optics, grid, settings)
    assert ReconModel.from_record(tmp_path / "old") == new
