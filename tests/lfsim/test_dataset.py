"""Dataset generation (lfsim.dataset): layout, ground truth, determinism, resume, overwrite."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from lfsim.dataset import frame_path, generate_dataset, truth_path
from lfsim.errors import ConfigError, OutputError
from lfsim.experiment import load_experiment
from lfsim.io import read_tiff
from lfsim.particles import Particles

from ..helpers import BOX_UM, SHEAR_XZ, experiment_toml

ROOT = Path(__file__).resolve().parents[2]
SMALL = ROOT / "scenes" / "small.xml"

TINY = experiment_toml(
    experiment={"name": "tiny", "scene": SMALL, "seed": 5, "frames": 3},
    particles={"kind": "box", "count": 3, "bounds_xyz_um": BOX_UM, "min_spacing_um": 40},
    motion=SHEAR_XZ,
    render={"rays_per_particle": 3000},
    noise={"model": "gaussian", "snr": (40, 20, 10)},
    white={"rays_per_lenslet": 300},
)


def tiny(tmp_path: Path, text: str = TINY, name: str = "tiny.toml"):
    path = tmp_path / name
    path.write_text(text)
    return load_experiment(path)


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file of the dataset except the record (which holds timings)."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "dataset.json"
    }


def mtimes(folder: Path) -> dict[str, int]:
    return {
        p.relative_to(folder).as_posix(): p.stat().st_mtime_ns
        for p in folder.rglob("*")
        if p.is_file()
    }


@pytest.fixture(scope="module")
def made(tmp_path_factory, backend):
    """One tiny dataset shared by the read-only tests."""
    base = tmp_path_factory.mktemp("made")
    exp = tiny(base)
    out = generate_dataset(exp, base / "ds", progress=False)
    return exp, out


def test_layout_and_record(made):
    exp, out = made
    assert sorted(snapshot(out)) == [
        "frames/000000.tif",
        "frames/000001.tif",
        "frames/000002.tif",
        "truth/000000.csv",
        "truth/000001.csv",
        "truth/000002.csv",
        "white.tif",
    ]
    rec = json.loads((out / "dataset.json").read_text())
    assert rec["status"] == "complete" and rec["fingerprint"] == exp.fingerprint()
    assert rec["experiment"] == exp.to_dict() and rec["seed"] == 5 and rec["frames"] == 3
    assert rec["scene"]["path"] == str(SMALL) and len(rec["scene"]["sha256"]) == 64
    assert rec["optics"] == exp.optics.to_dict()
    assert rec["lfsim_version"] and rec["created"] and rec["finished"]
    assert [r["noise"]["snr"] for r in rec["frame_records"]] == [40.0, 20.0, 10.0]
    assert all(r["seconds"] > 0 for r in rec["frame_records"])
    for k in range(3):
        img, meta = read_tiff(frame_path(out, k))
        assert img.dtype == np.uint8 and img.shape == (300, 300)
        assert meta["frame"] == k and meta["noise"]["snr"] == [40.0, 20.0, 10.0][k]
        assert meta["pixel_size_um"] == pytest.approx(exp.optics.object_pixel_um)
        assert meta["noise"]["sigma_dn"] > 0
    white, wmeta = read_tiff(out / "white.tif")
    assert white.dtype == np.uint16 and white.shape == (300, 300)
    assert wmeta["kind"] == "white" and wmeta["noise"]["snr"] == 50.0
    assert white.mean() > 10 * read_tiff(frame_path(out, 0))[0].mean()


def test_truth_is_the_motion_of_the_seeded_reference(made):
    exp, out = made
    ref = exp.particles.make(np.random.default_rng(exp.seed))
    for k in range(exp.frames):
        truth = Particles.from_csv(truth_path(out, k))
        assert np.array_equal(truth.ids, ref.ids)
        assert np.array_equal(truth.positions_um, exp.motion.positions(ref.positions_um, k))
        assert np.array_equal(truth.diameter_um, ref.diameter_um)
        assert np.array_equal(truth.brightness, ref.brightness)
    moved = Particles.from_csv(truth_path(out, 2)).positions_um
    assert np.allclose(moved[:, 0] - ref.positions_um[:, 0], 0.1 * (ref.positions_um[:, 2] - 200))


def test_same_seed_gives_byte_identical_files(made, tmp_path):
    exp, out = made
    again = generate_dataset(exp, tmp_path / "again", progress=False)
    assert snapshot(again) == snapshot(out)


def test_resume_regenerates_only_missing_frames(made, tmp_path, caplog):
    exp, out = made
    reference = snapshot(out)
    ds = generate_dataset(exp, tmp_path / "ds", progress=False)
    frame_path(ds, 1).unlink()  # an interrupted run: frame 1 incomplete
    truth_path(ds, 1).unlink()
    record = json.loads((ds / "dataset.json").read_text())
    record["status"] = "incomplete"
    (ds / "dataset.json").write_text(json.dumps(record))
    before = mtimes(ds)
    with caplog.at_level(logging.INFO, logger="lfsim"):
        generate_dataset(exp, ds, progress=False)
    assert "2 of 3 frames already present and verified, skipped" in caplog.text
    after = mtimes(ds)
    changed = sorted(k for k in after if before.get(k) != after[k])
    assert changed == ["dataset.json", "frames/000001.tif", "truth/000001.csv"]
    assert snapshot(ds) == reference
    rec = json.loads((ds / "dataset.json").read_text())
    assert rec["status"] == "complete" and all(r is not None for r in rec["frame_records"])
    assert len(rec["runs"]) == 2 and rec["runs"][-1]["frames_rendered"] == 1

    # A complete dataset is left alone.
    before = mtimes(ds)
    generate_dataset(exp, ds, progress=False)
    assert mtimes(ds) == before

    # Resume verifies what it keeps: a truncated frame and an edited truth table are redone,
    # exactly those, and come back byte-identical.
    with open(frame_path(ds, 2), "r+b") as fh:
        fh.truncate(100)
    t0 = truth_path(ds, 0)
    t0.write_text(t0.read_text().replace("1", "7", 1))
    before = mtimes(ds)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="lfsim"):
        generate_dataset(exp, ds, progress=False)
    assert "frame(s) 0, 2 changed on disk" in caplog.text
    after = mtimes(ds)
    changed = sorted(k for k in after if before.get(k) != after[k])
    assert changed == [
        "dataset.json",
        "frames/000000.tif",
        "frames/000002.tif",
        "truth/000000.csv",
        "truth/000002.csv",
    ]
    assert snapshot(ds) == reference


def test_different_experiment_refused_then_overwritten(made, tmp_path):
    exp, _ = made
    ds = generate_dataset(exp, tmp_path / "ds", progress=False)
    (ds / "notes.txt").write_text("mine")
    (ds / "frames" / "user.tif").write_bytes(b"mine too")
    before = {**snapshot(ds), "dataset.json": (ds / "dataset.json").read_bytes()}
    other = tiny(
        tmp_path,
        TINY.replace("seed = 5", "seed = 6")
        .replace("frames = 3", "frames = 2")
        .replace("snr = [40, 20, 10]", "snr = 17"),
        "other.toml",
    )
    with pytest.raises(OutputError, match="different experiment") as info:
        generate_dataset(other, ds, progress=False)
    assert str(ds) in str(info.value)
    assert {**snapshot(ds), "dataset.json": (ds / "dataset.json").read_bytes()} == before

    generate_dataset(other, ds, overwrite=True, progress=False)
    assert (ds / "notes.txt").read_text() == "mine"
    assert (ds / "frames" / "user.tif").read_bytes() == b"mine too"
    assert not frame_path(ds, 2).exists() and not truth_path(ds, 2).exists()
    rec = json.loads((ds / "dataset.json").read_text())
    assert rec["fingerprint"] == other.fingerprint() and rec["status"] == "complete"
    assert frame_path(ds, 1).read_bytes() != before["frames/000001.tif"]


def test_non_dataset_folder_refused(made, tmp_path):
    exp, _ = made
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"jpeg")
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="photos"):
            generate_dataset(exp, folder, overwrite=overwrite, progress=False)
    assert sorted(p.name for p in folder.iterdir()) == ["holiday.jpg"]
    # An empty existing folder is fine.
    (tmp_path / "empty").mkdir()
    generate_dataset(exp, tmp_path / "empty", progress=False)
    assert (tmp_path / "empty" / "dataset.json").is_file()


def test_particles_outside_field_rejected(backend, tmp_path):
    text = TINY.replace("bounds_xyz_um = [[-150, 150]", "bounds_xyz_um = [[300, 400]")
    exp = tiny(tmp_path, text)
    with pytest.raises(ConfigError, match="outside the field of view"):
        generate_dataset(exp, tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()


def test_static_experiment_without_white(backend, tmp_path):
    text = (
        TINY.split("[motion]")[0] + "[render]\nrays_per_particle = 2000\n[white]\nenabled = false\n"
    )
    exp = tiny(tmp_path, text)
    ds = generate_dataset(exp, tmp_path / "ds", progress=False)
    assert not (ds / "white.tif").exists()
    t0 = Particles.from_csv(truth_path(ds, 0))
    t2 = Particles.from_csv(truth_path(ds, 2))
    assert np.array_equal(t0.positions_um, t2.positions_um)
    # Same particles, independent noise and rays per frame.
    assert frame_path(ds, 0).read_bytes() != frame_path(ds, 2).read_bytes()
    rec = json.loads((ds / "dataset.json").read_text())
    assert rec["white"] is None and rec["layout"]["white"] is None


def test_interrupted_run_resumes_to_the_same_files(made, tmp_path, monkeypatch):
    import lfsim.render

    exp, out = made
    real = lfsim.render.render_particles
    calls = {"n": 0}

    def dies_on_second_frame(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(lfsim.render, "render_particles", dies_on_second_frame)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(exp, tmp_path / "ds", progress=False)
    rec = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert rec["status"] == "incomplete"
    assert frame_path(tmp_path / "ds", 0).is_file() and not frame_path(tmp_path / "ds", 1).exists()
    assert not [p for p in (tmp_path / "ds").rglob("*.tmp")]
    monkeypatch.setattr(lfsim.render, "render_particles", real)
    generate_dataset(exp, tmp_path / "ds", progress=False)
    assert snapshot(tmp_path / "ds") == snapshot(out)
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text())["status"] == "complete"


@pytest.mark.parametrize(
    ("box", "motion", "why"),
    [
        # Every particle 55 mm from the focal plane: once written as a "complete" dataset.
        ("[[-100, 100], [-100, 100], [55000, 55100]]", "", "imaged depth range"),
        ("[[-100, 100], [-100, 100], [-60000, -59900]]", "", "behind the objective"),
        # In range at frame 0, carried out of it by the motion at frame 2.
        ("[[-100, 100], [-100, 100], [100, 200]]", "translation", "frame 2"),
    ],
)
def test_particles_outside_the_imaged_volume_are_refused(backend, tmp_path, box, motion, why):
    text = TINY.replace("[[-150, 150], [-150, 150], [100, 300]]", box)
    if motion:
        shear = (
            'type = "simple_shear"\nplane = "xz"\nstep_gamma = 0.05\ncenter_xyz_um = [0, 0, 200]'
        )
        assert shear in text
        text = text.replace(shear, 'type = "translation"\nstep_um = [0, 0, 900]')
    assert text != TINY
    exp = tiny(tmp_path, text)
    with pytest.raises(ConfigError, match=why):
        generate_dataset(exp, tmp_path / "ds", progress=False)
    assert not (tmp_path / "ds").exists()
