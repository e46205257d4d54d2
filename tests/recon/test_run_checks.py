"""`recon run` checks: scene optics against the calibration's, glass-lenslet scenes, and a
failed start that must not block the corrected command."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import tifffile

from recon.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "small.xml"
FAST = "--z-range 100:200 --z-step 50 -s 1 --iterations 1 --rays-per-pattern 20000".split()


def run(capsys, *args, quiet=True):
    argv = list(map(str, args))
    rc = main(["-q", *argv] if quiet else argv)
    out = capsys.readouterr()
    return rc, out.out, out.err


def refused(rc, out, err, *names):
    """Exit status 2 and one line on stderr naming every one of ``names``."""
    assert rc == 2 and out == "", err
    assert err.startswith("recon: error: ") and err.count("\n") == 1, err
    for name in names:
        assert name in err, (name, err)


@pytest.fixture(scope="module")
def frame(base_frame, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("frame") / "img_1.tif"
    tifffile.imwrite(path, base_frame)
    return path


def scene_with(tmp_path: Path, name: str, **changes) -> Path:
    from lfsim import small_optics
    from lfsim.scene import write_scene

    return write_scene(small_optics(**changes), tmp_path / name)


@pytest.mark.parametrize(
    ("changes", "what"),
    [
        ({"na": 0.25}, "na 0.25 (scene) vs 0.2 (calibration)"),
        ({"mla_focal_um": 1100.0}, "mla_focal_um 1100 (scene) vs 1000 (calibration)"),
        ({"pixel_um": 100 / 15 * (1 + 1e-4)}, "pixel_um"),
        (
            {"sensor_xy_px": (330, 300)},
            "sensor_xy_px [330, 300] (scene) vs [300, 300] (calibration)",
        ),
        ({"axis_xy_px": (142.5, 157.5)}, "axis_xy_px [142.5, 157.5] (scene)"),
    ],
)
def test_scene_other_than_the_calibrations_is_refused(
    calib, frame, tmp_path, capsys, changes, what
):
    other = scene_with(tmp_path, "other.xml", **changes)
    out = tmp_path / "v"
    rc, stdout, err = run(
        capsys, "run", frame, "--scene", other, "--calib", calib, *FAST, "-o", out
    )
    refused(rc, stdout, err, "other.xml", str(calib), what, "--allow-optics-mismatch")
    assert not out.exists()


def test_optics_mismatch_can_be_allowed(calib, frame, tmp_path, capsys):
    from lfsim.io import read_json

    other = scene_with(tmp_path, "na025.xml", na=0.25)
    out = tmp_path / "v"
    args = ["run", frame, "--scene", other, "--calib", calib, *FAST, "-o", out]
    rc, _, err = run(capsys, *args, "--allow-optics-mismatch", quiet=False)
    assert rc == 0, err
    assert "recon: warning: scene" in err and "na 0.25 (scene) vs 0.2 (calibration)" in err
    assert read_json(out / "recon.json")["optics"]["na"] == 0.25


def test_tiny_differences_are_accepted(calib, frame, tmp_path, capsys):
    """A difference of 1e-9 in the pixel size is rounding: no error, no optics warning (not
    even without -q), the volume written, and nothing written anywhere else (the scene,
    calibration and frame unchanged, no other file beside the output folder)."""
    import hashlib

    from lfsim.io import read_json

    scene = scene_with(tmp_path, "same.xml", pixel_um=100 / 15 * (1 + 1e-9))
    inputs = [scene, Path(calib), Path(frame)]
    before = [hashlib.sha256(p.read_bytes()).hexdigest() for p in inputs]
    listing = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "v"
    rc, stdout, err = run(
        capsys, "run", frame, "--scene", scene, "--calib", calib, *FAST, "-o", out, quiet=False
    )
    assert rc == 0, err
    assert "error" not in err and "warning" not in err and "calibration)" not in err, err
    assert "mismatch" not in stdout + err, (stdout, err)
    record = read_json(out / "recon.json")
    assert record["status"] == "complete" and [f["index"] for f in record["frames"]] == [0]
    assert (out / "000000.tif").is_file()
    assert [hashlib.sha256(p.read_bytes()).hexdigest() for p in inputs] == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*listing, "v"])


def test_calibration_of_another_sensor_is_refused(base_frame, backend, tmp_path, capsys):
    """A calibration of the paper's 1280 × 800 px camera used with the small scene (whose
    axis lies 250 µm away in object space) was accepted before."""
    from lfsim import paper_optics
    from recon.calibration import LensletGrid

    calib = tmp_path / "paper_calib.json"
    grid = LensletGrid(15.0, 0.0, (637.5, 397.5), (800, 1280))
    calib.write_text(json.dumps({"grid": grid.to_dict(), "optics": paper_optics().to_dict()}))
    big = tmp_path / "big.tif"
    tifffile.imwrite(big, base_frame.repeat(3, axis=0)[:800].repeat(5, axis=1)[:, :1280])
    out = tmp_path / "v"
    rc, stdout, err = run(capsys, "run", big, "--scene", SCENE, "--calib", calib, *FAST, "-o", out)
    refused(rc, stdout, err, "sensor_xy_px [300, 300] (scene) vs [1280, 800] (calibration)")
    assert not out.exists()
    # A bare grid file (no optics): its image size is still checked against the sensor.
    bare = tmp_path / "grid.json"
    grid.save(bare)
    rc, stdout, err = run(capsys, "run", big, "--scene", SCENE, "--calib", bare, *FAST, "-o", out)
    refused(rc, stdout, err, "grid.json", "sensor 300 × 300 px (scene) vs 1280 × 800 px images")
    assert not out.exists()


# -- glass lenslets, failed starts ----------------------------------------------------------
def test_glass_scene_is_reconstructed_with_ideal_lenslets(calib, frame, tmp_path, capsys):
    """A scene with the glass lenslet mesh is reconstructed with the ideal lenslets of the
    same optics: the same volumes as with the ideal scene, and a warning."""
    import numpy as np

    from lfsim.io import read_json, read_tiff

    glass = ROOT / "scenes" / "small_glass.xml"
    out_glass, out_ideal = tmp_path / "glass", tmp_path / "ideal"
    args = [frame, "--calib", calib, *FAST]
    rc, _, err = run(capsys, "run", *args, "--scene", glass, "-o", out_glass, quiet=False)
    assert rc == 0, err
    assert err.count("recon: warning:") == 1 and "glass mesh" in err and "ideal lenslets" in err
    meta = read_json(out_glass / "recon.json")
    assert meta["optics"]["mla_kind"] == "ideal" and meta["scene_mla_kind"] == "glass"
    rc, _, err = run(capsys, "run", *args, "--scene", SCENE, "-o", out_ideal)
    assert rc == 0, err
    assert read_json(out_ideal / "recon.json")["scene_mla_kind"] == "ideal"
    a, b = read_tiff(out_glass / "000000.tif")[0], read_tiff(out_ideal / "000000.tif")[0]
    assert a.max() > 0 and np.array_equal(a, b)
    # Same model, same settings: the ideal scene resumes the glass scene's folder.
    rc, stdout, err = run(capsys, "run", *args, "--scene", SCENE, "-o", out_glass, quiet=False)
    assert rc == 0 and "0 volume(s) reconstructed, 1 already done" in stdout, err


def test_failed_start_leaves_nothing_in_the_way(calib, frame, tmp_path, capsys, monkeypatch):
    import recon.pipeline
    from lfsim.errors import ConfigError

    def broken(*a, **k):
        raise ConfigError("PSF model failed")

    out = tmp_path / "new" / "v"
    args = ["run", frame, "--scene", SCENE, "--calib", calib, *FAST, "-o", out]
    with monkeypatch.context() as m:
        m.setattr(recon.pipeline, "compute_psf_bank", broken)
        refused(*run(capsys, *args), "PSF model failed")
        assert not out.exists()
        # A folder the user made is kept, empty.
        out.mkdir(parents=True)
        refused(*run(capsys, *args), "PSF model failed")
        assert out.is_dir() and not any(out.iterdir())

        def interrupted(*a, **k):
            raise KeyboardInterrupt

        m.setattr(recon.pipeline, "compute_psf_bank", interrupted)
        assert run(capsys, *args)[0] == 130
        assert out.is_dir() and not any(out.iterdir())
    # The same command, now working, needs no --overwrite.
    rc, _, err = run(capsys, *args)
    assert rc == 0, err
    assert (out / "000000.tif").is_file()


def test_record_without_volumes_does_not_block(calib, frame, tmp_path, capsys):
    """A recon.json left by a run that wrote no volume (e.g. by an older version that failed
    in the PSF model) is replaced, even with other settings, without --overwrite."""
    out = tmp_path / "v"
    out.mkdir()
    (out / "recon.json").write_text(json.dumps({"fingerprint": "0" * 64, "status": "incomplete"}))
    rc, _, err = run(capsys, "run", frame, "--scene", SCENE, "--calib", calib, *FAST, "-o", out)
    assert rc == 0, err
    assert json.loads((out / "recon.json").read_text())["status"] == "complete"


# -- dark frame and background ------------------------------------------------------------
def test_dark_frame_brighter_than_the_frames_is_refused(calib, frame, base_frame, tmp_path, capsys):
    """A "dark" frame brighter than the frames (e.g. the white image) made a background of
    about −21 000 DN and volumes 1000 times too bright."""
    import numpy as np

    from lfsim.io import read_json

    args = ["run", frame, "--scene", SCENE, "--calib", calib, *FAST]
    bright = tmp_path / "white.tif"
    tifffile.imwrite(bright, np.full(base_frame.shape, 21000, np.uint16))
    out = tmp_path / "v"
    rc, stdout, err = run(capsys, *args, "--dark", bright, "-o", out)
    median = float(np.median(base_frame))
    refused(
        rc, stdout, err, "--dark", "white.tif", "brighter than", "21000.0 DN", f"{median:.1f} DN"
    )
    assert not out.exists()
    # A dark frame at the camera's black level is accepted, and so is one a few grey levels
    # (its noise) above the frame's median.
    for level in (40, median + 2):
        dark = tmp_path / f"dark_{level:g}.tif"
        tifffile.imwrite(dark, np.full(base_frame.shape, level, np.float32))
        rc, _, err = run(capsys, *args, "--dark", dark, "-o", tmp_path / f"ok_{level:g}")
        assert rc == 0, err
        record = read_json(tmp_path / f"ok_{level:g}" / "recon.json")["frames"][0]
        assert abs(record["preprocess"]["background"] - (median - level)) < 1e-3
    # A negative constant background is refused too.
    rc, stdout, err = run(capsys, *args, "--background", "-20", "-o", out)
    refused(rc, stdout, err, "--background", ">= 0", "-20")
    assert not out.exists()


def test_dataset_without_its_white_image_names_the_missing_file(frame, tmp_path, capsys):
    ds = tmp_path / "ds"
    (ds / "frames").mkdir(parents=True)
    (ds / "dataset.json").write_text(json.dumps({"scene": {"path": str(SCENE)}}))
    tifffile.imwrite(ds / "frames" / "000000.tif", tifffile.imread(frame))
    out = tmp_path / "v"
    rc, stdout, err = run(capsys, "run", ds, *FAST, "-o", out)
    refused(rc, stdout, err, str(ds / "white.tif"), "does not exist", "--calib")
    assert not out.exists()


def test_stop_rel_change_accepts_none_as_its_help_says(calib, frame, tmp_path, capsys):
    from lfsim.io import read_json

    assert main(["run", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "'none' (the default): run all iterations" in text
    args = ["run", frame, "--scene", SCENE, "--calib", calib, *FAST]
    for value, recorded in (("none", None), ("0.01", 0.01)):
        out = tmp_path / f"v_{value}"
        rc, _, err = run(capsys, *args, "--stop-rel-change", value, "-o", out)
        assert rc == 0, err
        assert read_json(out / "recon.json")["settings"]["stop_rel_change"] == recorded
    for bad in ("never", "-0.1", "nan"):
        rc, stdout, err = run(capsys, *args, "--stop-rel-change", bad, "-o", tmp_path / "x")
        refused(rc, stdout, err, "--stop-rel-change", "'none' or a number >= 0", repr(bad))
    assert not (tmp_path / "x").exists()


def test_dark_frame_that_is_a_folder_is_named_as_such(calib, frame, tmp_path, capsys):
    (tmp_path / "dark").mkdir()
    out = tmp_path / "v"
    args = ["run", frame, "--scene", SCENE, "--calib", calib, *FAST, "-o", out]
    rc, stdout, err = run(capsys, *args, "--dark", tmp_path / "dark")
    refused(rc, stdout, err, f"dark frame {str(tmp_path / 'dark')!r} is a folder, not a TIFF file")
    assert not out.exists()


@pytest.mark.parametrize(
    "record", ["{}", "[1, 2]", '{"scene": "small.xml"}', '{"scene": {"path": 3}}']
)
def test_dataset_record_naming_no_scene_is_refused(calib, frame, tmp_path, capsys, record):
    ds = tmp_path / "ds"
    (ds / "frames").mkdir(parents=True)
    (ds / "dataset.json").write_text(record)
    tifffile.imwrite(ds / "frames" / "000000.tif", tifffile.imread(frame))
    out = tmp_path / "v"
    rc, stdout, err = run(capsys, "run", ds, "--calib", calib, *FAST, "-o", out)
    refused(rc, stdout, err, str(ds / "dataset.json"), "names no scene", "--scene")
    assert not out.exists()


def test_a_resume_with_other_settings_says_which(calib, frame, base_frame, tmp_path, capsys):
    import numpy as np

    out = tmp_path / "v"
    args = ["run", frame, "--scene", SCENE, "--calib", calib, *FAST, "-o", out]
    rc, _, err = run(capsys, *args)
    assert rc == 0, err
    rc, stdout, err = run(capsys, *args, "--iterations", "2", "--lanczos", "3")
    refused(rc, stdout, err, "iterations 1 then, 2 now", "lanczos_a 2 then, 3 now", "--overwrite")
    dark = tmp_path / "dark.tif"
    tifffile.imwrite(dark, np.zeros(base_frame.shape, np.uint16))
    refused(*run(capsys, *args, "--dark", dark), "dark frame none then, given now")
    refused(*run(capsys, *args, "--hot-pixels"), "hot_pixels False then, True now")
    # Another dark frame than the one a run used.
    rc, _, err = run(capsys, *args, "--dark", dark, "--overwrite")
    assert rc == 0, err
    tifffile.imwrite(dark, np.ones(base_frame.shape, np.uint16))
    refused(*run(capsys, *args, "--dark", dark), "another dark frame (SHA-256")
