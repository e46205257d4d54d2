"""The ``recon calibrate`` command (and the parser around it)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import tifffile

from recon import LensletGrid, __version__
from recon.cli import CALIBRATION_FORMAT, main

from .synthetic import synthetic_white

SCENE = Path(__file__).resolve().parents[2] / "scenes" / "small.xml"

TRUTH = LensletGrid(15.0, 0.4, (157.3, 157.6), (300, 300))


def _white(path: Path, grid: LensletGrid = TRUTH) -> Path:
    img = synthetic_white((300, 300), grid, noise_sigma=0.02, vignetting=0.5, rng=1)
    tifffile.imwrite(path, np.clip(np.rint(100 + 3000 * img), 0, 65535).astype(np.uint16))
    return path


@pytest.fixture(scope="module")
def white_tif(tmp_path_factory) -> Path:
    return _white(tmp_path_factory.mktemp("white") / "white.tif")


def _run(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_calibrate_writes_calibration(tmp_path, capsys, white_tif):
    out = tmp_path / "calib.json"
    rc, stdout, err = _run(capsys, "calibrate", white_tif, "--scene", SCENE, "-o", out)
    assert rc == 0, err
    assert stdout.startswith(f"wrote {out}: pitch 1") and stdout.count("\n") == 1
    rec = json.loads(out.read_text())
    assert rec["format"] == CALIBRATION_FORMAT
    assert rec["tool"]["version"] == __version__
    assert rec["white_image"]["path"] == str(white_tif.resolve())
    assert rec["white_image"]["sha256"] == hashlib.sha256(white_tif.read_bytes()).hexdigest()
    assert rec["optics"]["sensor_xy_px"] == [300, 300]
    assert rec["nominal_pitch_px"] == pytest.approx(15.0)
    grid = LensletGrid.load(out)
    assert grid == LensletGrid.from_dict(rec["grid"])
    assert grid.pitch_px == pytest.approx(15.0, abs=0.002)
    assert grid.rotation_deg == pytest.approx(0.4, abs=0.01)
    idx = np.rint(grid.lenslet_index(TRUTH.all_centers()[1])).astype(int)
    assert np.abs(grid.centers(idx) - TRUTH.all_centers()[1]).max() < 0.05
    assert not list(tmp_path.glob(".*.tmp"))


def test_existing_output_is_kept(tmp_path, capsys, white_tif):
    out = tmp_path / "calib.json"
    out.write_text("precious\n")
    rc, _, err = _run(capsys, "calibrate", white_tif, "--scene", SCENE, "-o", out)
    assert rc == 2
    assert err.startswith("recon: error:") and "already exists" in err and "--overwrite" in err
    assert "Traceback" not in err
    assert out.read_text() == "precious\n"
    rc, _, err = _run(capsys, "calibrate", white_tif, "--scene", SCENE, "-o", out, "--overwrite")
    assert rc == 0, err
    assert json.loads(out.read_text())["format"] == CALIBRATION_FORMAT


def test_output_never_replaces_an_input(tmp_path, capsys):
    """`recon calibrate white.tif -o white.tif --overwrite` once replaced the white image."""
    white = _white(tmp_path / "white.tif")
    scene = tmp_path / "scene.xml"
    scene.write_bytes(SCENE.read_bytes())
    saved = {p: p.read_bytes() for p in (white, scene)}
    for out in (white, scene):
        rc, _, err = _run(capsys, "calibrate", white, "--scene", scene, "-o", out, "--overwrite")
        assert rc == 2 and "is an input" in err and err.count("\n") == 1, err
    assert {p: p.read_bytes() for p in saved} == saved


def test_missing_white(tmp_path, capsys):
    missing = tmp_path / "no_such_white.tif"
    out = tmp_path / "calib.json"
    rc, _, err = _run(capsys, "calibrate", missing, "--scene", SCENE, "-o", out)
    assert rc == 2
    assert "recon: error:" in err and "no_such_white.tif" in err and "does not exist" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_stack_is_refused(tmp_path, capsys):
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.zeros((3, 300, 300), np.uint16), photometric="minisblack")
    rc, _, err = _run(capsys, "calibrate", stack, "--scene", SCENE, "-o", tmp_path / "c.json")
    assert rc == 2
    assert "stack.tif" in err and "(3, 300, 300)" in err


def test_no_grid_and_missing_scene(tmp_path, capsys, white_tif):
    noise = tmp_path / "noise.tif"
    rng = np.random.default_rng(0)
    tifffile.imwrite(noise, rng.integers(0, 1000, (300, 300)).astype(np.uint16))
    rc, _, err = _run(capsys, "calibrate", noise, "--scene", SCENE, "-o", tmp_path / "c.json")
    assert rc == 2
    assert "noise.tif" in err and "no lenslet grid" in err and "Traceback" not in err
    rc, _, err = _run(
        capsys, "calibrate", white_tif, "--scene", tmp_path / "x.xml", "-o", tmp_path / "c.json"
    )
    assert rc == 2 and "x.xml" in err
    assert not (tmp_path / "c.json").exists()


def test_pitch_mismatch_is_refused_unless_allowed(tmp_path, capsys):
    other = _white(tmp_path / "w17.tif", LensletGrid(17.0, 0.0, (150.2, 150.7), (300, 300)))
    out = tmp_path / "c.json"
    rc, stdout, err = _run(capsys, "calibrate", other, "--scene", SCENE, "-o", out)
    assert rc == 2 and stdout == ""
    assert err.startswith("recon: error: ") and err.count("\n") == 1
    assert "differs by +13.3 %" in err and "w17.tif" in err and "--allow-pitch-mismatch" in err
    assert not out.exists()
    rc, _, err = _run(
        capsys, "calibrate", other, "--scene", SCENE, "-o", out, "--allow-pitch-mismatch"
    )
    assert rc == 0
    assert "recon: warning:" in err and "differs by +13.3 %" in err
    assert json.loads(out.read_text())["grid"]["pitch_px"] == pytest.approx(17.0, abs=0.01)


def test_white_of_another_sensor_size_is_refused(tmp_path, capsys):
    img = synthetic_white((280, 300), LensletGrid(15.0, 0.0, (150.0, 140.0), (280, 300)), rng=2)
    white = tmp_path / "white_300x280.tif"
    tifffile.imwrite(white, np.rint(100 + 3000 * img).astype(np.uint16))
    out = tmp_path / "c.json"
    for extra in ([], ["--allow-pitch-mismatch"]):
        rc, stdout, err = _run(capsys, "calibrate", white, "--scene", SCENE, "-o", out, *extra)
        assert rc == 2 and stdout == ""
        assert err.startswith("recon: error: ") and err.count("\n") == 1
        assert "white_300x280.tif" in err and "300 × 280 px" in err and "300 × 300 px" in err
        assert "small.xml" in err
        assert not out.exists()


def test_verbosity_options(tmp_path, capsys, white_tif):
    rc, out, err = _run(
        capsys, "-v", "calibrate", white_tif, "--scene", SCENE, "-o", tmp_path / "a.json"
    )
    assert rc == 0 and "recon: info: lenslet grid" in err
    rc, out, err = _run(
        capsys, "calibrate", white_tif, "--scene", SCENE, "-o", tmp_path / "b.json", "-q"
    )
    assert rc == 0 and out == "" and err == ""
    rc, _, _ = _run(
        capsys, "calibrate", white_tif, "--scene", SCENE, "-o", tmp_path / "c.json", "--threads=2"
    )
    assert rc == 0


def test_usage_errors(capsys):
    rc, _, err = _run(capsys)
    assert rc == 2 and "calibrate" in err
    assert main(["calibrate", "white.tif"]) == 2  # --scene and -o are required
    assert "--scene" in capsys.readouterr().err
    assert main(["--threads", "0", "calibrate"]) == 2
    assert capsys.readouterr().err.startswith("recon: error: argument --threads")
