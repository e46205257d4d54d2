"""The ``lfsim`` command line (lfsim.cli.main, run in-process)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lfsim.cli import main
from lfsim.io import read_tiff
from lfsim.particles import Particles
from lfsim.scene import read_optics

from ..helpers import BOX_UM, experiment_toml

ROOT = Path(__file__).resolve().parents[2]
SMALL = str(ROOT / "scenes" / "small.xml")

TOML = experiment_toml(
    experiment={"name": "cli_tiny", "scene": SMALL, "seed": 1, "frames": 2},
    particles={"kind": "box", "count": 3, "bounds_xyz_um": BOX_UM},
    motion={"type": "translation", "step_um": (5, 0, 0)},
    render={"rays_per_particle": 2000},
    white={"rays_per_lenslet": 200},
)


def error_line(capsys) -> str:
    """The single stderr line of a failed command run with -q."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("lfsim: error: ")
    assert "Traceback" not in err
    return lines[0]


def render(particles, out, *options, scene=SMALL) -> int:
    """The exit status of ``lfsim -q render SCENE --particles PARTICLES -o OUT OPTIONS...``."""
    return main(
        ["-q", "render", str(scene), "--particles", str(particles), "-o", str(out), *options]
    )


def micrometer(out, axis: str, *options) -> int:
    """The exit status of ``lfsim -q micrometer`` with 20 µm divisions along ``axis``."""
    args = ["-o", str(out), "--division-um", "20", "--rays-per-line", "2000", "--axis", axis]
    return main(["-q", "micrometer", SMALL, *args, *options])


@pytest.fixture
def particles_csv(tmp_path):
    path = tmp_path / "p.csv"
    Particles(np.array([[0.0, 0.0, 150.0], [-80.0, 60.0, 250.0]])).to_csv(path)
    return path


def test_help_and_usage_errors(capsys):
    assert main(["--help"]) == 0
    assert "dataset" in capsys.readouterr().out
    assert main([]) == 2
    assert main(["render"]) == 2
    assert "lfsim: error:" in capsys.readouterr().err


def test_scene(tmp_path, capsys):
    out = tmp_path / "s.xml"
    assert main(["-q", "scene", "--preset", "small", "--set", "na=0.3", "-o", str(out)]) == 0
    optics = read_optics(out)
    assert optics.na == 0.3 and optics.sensor_xy_px == (300, 300) and optics.mla_kind == "ideal"
    args = ["scene", "--preset", "paper_4x", "--set", "sensor_xy_px=640,400", "-o", str(out)]
    before = out.read_bytes()
    assert main(["-q", *args]) == 2
    assert "s.xml" in error_line(capsys) and out.read_bytes() == before
    assert main(["-q", *args, "--overwrite"]) == 0
    assert read_optics(out).sensor_xy_px == (640, 400)
    assert (
        main(["-q", "scene", "--preset", "small", "--set", "nA=0.3", "-o", str(tmp_path / "t.xml")])
        == 2
    )
    line = error_line(capsys)
    assert "'nA'" in line and "na" in line
    assert not (tmp_path / "t.xml").exists()
    older = [
        "scene",
        "--preset",
        "small",
        "--set",
        "sensor_px=640,400",
        "-o",
        str(tmp_path / "u.xml"),
    ]
    assert main(["-q", *older]) == 2
    assert "'sensor_px' is named 'sensor_xy_px'" in error_line(capsys)
    assert not (tmp_path / "u.xml").exists()


def test_render(backend, tmp_path, particles_csv):
    out = tmp_path / "img.tif"
    assert render(particles_csv, out, "--rays", "3000", "--snr", "20", "--seed", "4") == 0
    img, meta = read_tiff(out)
    assert img.dtype == np.uint8 and img.shape == (300, 300)
    assert meta["noise"]["snr"] == 20 and meta["n_particles"] == 2 and meta["seed"] == 4
    assert meta["pixel_size_um"] == pytest.approx(read_optics(SMALL).object_pixel_um)
    again = tmp_path / "again.tif"
    assert render(particles_csv, again, "--rays", "3000", "--snr", "20", "--seed", "4") == 0
    assert again.read_bytes() == out.read_bytes()

    flt = tmp_path / "float.tif"
    assert render(particles_csv, flt, "--rays", "3000", "--float") == 0
    clean, meta = read_tiff(flt)
    assert clean.dtype == np.float32 and "noise" not in meta
    assert 0 < clean.sum() <= 2 * 3000

    cam = tmp_path / "cam.tif"
    assert render(particles_csv, cam, "--rays", "3000", "--noise", "camera") == 0
    img, meta = read_tiff(cam)
    assert img.dtype == np.uint16 and meta["noise"]["model"] == "camera"


def test_white_and_micrometer(backend, tmp_path):
    white = tmp_path / "w.tif"
    assert main(["-q", "white", SMALL, "-o", str(white), "--rays-per-lenslet", "200"]) == 0
    img, meta = read_tiff(white)
    assert img.dtype == np.uint16 and meta["kind"] == "white"
    m = tmp_path / "m.tif"
    assert micrometer(m, "y") == 0
    img, meta = read_tiff(m)
    assert img.shape == (300, 300) and meta["division_um"] == 20 and meta["axis"] == "y"
    mx = tmp_path / "mx.tif"
    assert micrometer(mx, "x") == 0
    assert not np.array_equal(read_tiff(mx)[0], img)
    # A rotated reticle out of focus: its rotation and depth are recorded with the image.
    mr = tmp_path / "mr.tif"
    assert micrometer(mr, "x", "--rotation-deg", "10", "--z-um", "15") == 0
    rot, meta = read_tiff(mr)
    assert meta["rotation_deg"] == 10 and meta["z_um"] == 15
    assert not np.array_equal(rot, read_tiff(mx)[0])


def test_dataset(backend, tmp_path, capsys):
    toml = tmp_path / "e.toml"
    toml.write_text(TOML)
    out = tmp_path / "ds"
    assert main(["dataset", str(toml), "-o", str(out), "--quiet"]) == 0
    rec = json.loads((out / "dataset.json").read_text())
    assert rec["status"] == "complete" and rec["frames"] == 2
    assert (out / "frames" / "000001.tif").is_file() and (out / "truth" / "000001.csv").is_file()
    before = (out / "dataset.json").read_bytes()
    assert main(["-q", "dataset", str(toml), "-o", str(out)]) == 0  # complete: nothing to do
    assert (out / "dataset.json").read_bytes() == before

    # Another experiment into the same folder: refused without --overwrite.
    toml2 = tmp_path / "e2.toml"
    toml2.write_text(TOML.replace("seed = 1", "seed = 2"))
    assert main(["-q", "dataset", str(toml2), "-o", str(out)]) == 2
    assert str(out) in error_line(capsys) and (out / "dataset.json").read_bytes() == before
    assert main(["-q", "dataset", str(toml2), "-o", str(out), "--overwrite"]) == 0
    assert json.loads((out / "dataset.json").read_text())["experiment"]["experiment"]["seed"] == 2


def test_bad_input_gives_one_line_and_exit_2(backend, tmp_path, particles_csv, capsys):
    # Missing scene file.
    out = tmp_path / "img.tif"
    missing = tmp_path / "nowhere.xml"
    assert render(particles_csv, out, scene=missing) == 2
    assert "nowhere.xml" in error_line(capsys) and not out.exists()
    # Missing particle table.
    assert render(tmp_path / "none.csv", out) == 2
    assert "none.csv" in error_line(capsys) and not out.exists()
    # Unknown TOML key.
    toml = tmp_path / "bad.toml"
    toml.write_text(TOML.replace("rays_per_particle", "rays_per_partcle"))
    assert main(["-q", "dataset", str(toml), "-o", str(tmp_path / "ds")]) == 2
    line = error_line(capsys)
    assert "rays_per_partcle" in line and "bad.toml" in line
    assert not (tmp_path / "ds").exists()
    # Existing outputs are never replaced without --overwrite.
    for cmd in (
        ["render", SMALL, "--particles", str(particles_csv), "--rays", "1000"],
        ["white", SMALL, "--rays-per-lenslet", "100"],
        ["micrometer", SMALL, "--rays-per-line", "1000"],
    ):
        out.write_bytes(b"precious")
        assert main(["-q", *cmd, "-o", str(out)]) == 2
        assert "img.tif" in error_line(capsys)
        assert out.read_bytes() == b"precious"
    assert render(particles_csv, out, "--rays", "1000", "--overwrite") == 0
    assert read_tiff(out)[0].shape == (300, 300)
    # Particles outside the field of view, a non-dataset output folder, conflicting options.
    far = tmp_path / "far.csv"
    Particles(np.array([[900.0, 0.0, 100.0]])).to_csv(far)
    assert render(far, tmp_path / "f.tif") == 2
    assert "field of view" in error_line(capsys)
    toml.write_text(TOML)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "x.txt").write_text("x")
    assert main(["-q", "dataset", str(toml), "-o", str(tmp_path / "busy")]) == 2
    assert "busy" in error_line(capsys)
    assert render(particles_csv, tmp_path / "n.tif", "--noise", "none", "--snr", "5") == 2
    assert "--snr" in error_line(capsys)


def test_outputs_never_land_on_inputs_even_with_overwrite(backend, tmp_path, capsys):
    """`lfsim render --particles p.csv -o p.csv --overwrite` once replaced the CSV by a TIFF."""
    csv = tmp_path / "p.csv"
    Particles(np.array([[0.0, 0.0, 150.0]])).to_csv(csv)
    scene = tmp_path / "s.xml"
    assert main(["-q", "scene", "--preset", "small", "-o", str(scene)]) == 0
    saved = {p: p.read_bytes() for p in (csv, scene)}
    for cmd in (
        ["render", str(scene), "--particles", str(csv), "-o", str(csv)],
        ["render", str(scene), "--particles", str(csv), "-o", str(scene)],
        ["white", str(scene), "-o", str(scene)],
        ["micrometer", str(scene), "-o", str(scene)],
    ):
        assert main(["-q", *cmd, "--overwrite"]) == 2
        assert "is an input" in error_line(capsys)
    assert {p: p.read_bytes() for p in saved} == saved
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.csv", "s.xml"]


def test_render_warns_of_coincident_and_overlapping_particles(backend, tmp_path, capsys):
    """Three identical rows (almost surely a table mistake) and two overlapping beads are
    rendered, with a warning naming the rows and positions."""
    table = tmp_path / "p.csv"
    table.write_text(
        "x_um,y_um,z_um\n0,0,150\n0,0,150\n0,0,150\n-80,60,250\n-75,60,250\n", encoding="utf-8"
    )
    out = tmp_path / "img.tif"
    assert main(["render", SMALL, "--particles", str(table), "-o", str(out), "--rays", "1000"]) == 0
    err = capsys.readouterr().err
    warnings = [ln for ln in err.splitlines() if ln.startswith("lfsim: warning: ")]
    assert len(warnings) == 1, err
    line = warnings[0]
    assert "rows 1, 2, 3" in line and "(0, 0, 150)" in line and "coincide" in line, line
    assert "rows 4 and 5" in line and "5 µm apart" in line and "p.csv" in line, line
    assert out.is_file()


@pytest.mark.parametrize("command", ["render", "white"])
def test_paraxial_tracer_on_a_glass_scene_speaks_the_users_language(
    backend, tmp_path, particles_csv, capsys, command
):
    glass = ROOT / "scenes" / "small_glass.xml"
    out = tmp_path / "img.tif"
    extra = ["--particles", str(particles_csv)] if command == "render" else []
    argv = ["-q", command, str(glass), *extra, "-o", str(out), "--tracer", "paraxial"]
    assert main(argv) == 2
    line = error_line(capsys)
    assert "--tracer paraxial" in line and "'glass'" in line and "small_glass.xml" in line
    assert "--tracer mitsuba" in line and "trace_paraxial" not in line, line
    assert not out.exists()
