"""``[track.axial]``: the simulator self-calibration of the reconstruction's axial bias in a
study (hrvptm.stages.track_calibrated)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from hrvptm.cli import main
from hrvptm.config import load_study
from hrvptm.errors import StudyConfigError

from ..helpers import experiment_toml

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = ROOT / "scenes" / "experiments"

BASE = experiment_toml(
    experiment={"name": "x", "scene": "{scene}", "frames": 3},
    particles={"kind": "box", "count": 10, "bounds_xyz_um": ((-100, 100), (-100, 100), (150, 300))},
)
MOTION = "[motion]\ntype = 'translation'\nstep_um = [5, 0, 0]\n"


def _write(tmp_path: Path, extra: str) -> Path:
    p = tmp_path / "study.toml"
    p.write_text(BASE.format(scene=(ROOT / "scenes" / "medium.xml").as_posix()) + extra, "utf-8")
    return p


def test_axial_option_is_read_and_checked(tmp_path):
    assert not load_study(_write(tmp_path, MOTION)).track.axial.enabled
    on = load_study(_write(tmp_path, MOTION + "[track.axial]\nmethod = 'simulated'\n"))
    assert on.track.axial.enabled and on.track.axial.lateral
    for extra, match in (
        ("[track.axial]\nmethod = 'fit'\n", r"\[track.axial\] method must be one of"),
        ("[track.axial]\nsphere_diameter_um = -1\n", r"\[track.axial\] sphere_diameter_um"),
        ("[track.axial]\nlateral = 1\n", r"\[track.axial\] lateral must be"),
        ("[track.axial]\nmetod = 'simulated'\n", r"did you mean"),
    ):
        with pytest.raises(StudyConfigError, match=match) as info:
            load_study(_write(tmp_path, MOTION + extra))
        assert "study.toml" in str(info.value) and "\n" not in str(info.value)
    # a localization study (no motion) corrects its tables without linking them
    loc = load_study(_write(tmp_path, "[track.axial]\nmethod = 'simulated'\n"))
    assert loc.study.kind == "localization" and loc.track.axial.enabled


def test_the_tables_a_study_analyses(tmp_path):
    """With the calibration a series analyses the linked corrected tables (track/), a
    localization or pairs study the corrected ones (axial/, not linked); without it, what
    track detected (track/)."""
    from hrvptm.stages import VariantPaths, particle_tables

    paths = VariantPaths(tmp_path)
    on = "[track.axial]\nmethod = 'simulated'\n"
    pairs = "[study]\nkind = 'pairs'\ngroup_size = 3\n"
    for extra, tables in (
        (MOTION, paths.track),
        (MOTION + on, paths.track),
        ("", paths.track),
        (on, paths.axial),
        (pairs, paths.track),
        (pairs + on, paths.axial),
    ):
        study = load_study(_write(tmp_path, extra))
        assert particle_tables(study, paths) == tables / "particles", extra


def _off_and_on(tmp_path: Path, name: str, edit=lambda t: t) -> tuple[Path, Path]:
    """The test-size study ``name`` run without, then (on a copy of that report: the same
    dataset and volumes) with the calibration; the two report folders."""
    text = edit((EXPERIMENTS / f"{name}.toml").read_text("utf-8"))
    text = text.replace('"../medium', f'"{(ROOT / "scenes").as_posix()}/medium')
    off_toml, on_toml = tmp_path / "off.toml", tmp_path / "on.toml"
    off_toml.write_text(text, "utf-8")
    on_toml.write_text(text + "\n[track.axial]\nmethod = 'simulated'\n", "utf-8")
    off, on = tmp_path / "off", tmp_path / "on"
    assert main(["study", str(off_toml), "-o", str(off), "-q"]) == 0
    shutil.copytree(off, on)  # only tracking differs
    assert main(["study", str(on_toml), "-o", str(on), "-q", "--overwrite"]) == 0
    return off, on


@pytest.mark.slow
@pytest.mark.studies
def test_self_calibration_lowers_the_z_displacement_error(tmp_path):
    """fig5a_x at test size, 3 frames: the same dataset tracked without and with the
    calibration. Measured (seed 1): worst-frame z displacement RMSD 2.48 → 0.95 µm, pooled
    2.35 → 0.90 µm; x (the axis of the motion) 0.243 → 0.181 µm, y 0.157 → 0.163 µm."""
    off, on = _off_and_on(
        tmp_path, "fig5a_translation_x_test", lambda t: t.replace("frames = 5", "frames = 3")
    )
    on_toml = tmp_path / "on.toml"
    s_off, s_on = (
        json.loads((r / "summary.json").read_text("utf-8"))["variants"]["mismatched"]
        for r in (off, on)
    )
    a, b = s_off["summary"], s_on["summary"]
    assert a["worst_u_rmsd_z"] > 2.0  # the bias is there without the calibration
    assert b["worst_u_rmsd_z"] < 1.3 and b["worst_u_rmsd_z"] < 0.6 * a["worst_u_rmsd_z"]
    assert b["pooled_u_rmsd_z"] < 1.2
    assert b["pooled_u_rmsd_x"] < 0.85 * a["pooled_u_rmsd_x"]  # the lenslet-phase bias
    assert b["pooled_u_rmsd_y"] < 1.15 * a["pooled_u_rmsd_y"]  # a little scatter added
    assert s_on["summary"]["wrong_tracks"] == 0
    assert s_on["seconds"]["axial_calibration"] > 0
    assert "axial calibration" in (on / "summary.md").read_text("utf-8")
    record = json.loads((on / "mismatched" / "axial" / "axial_calibration.json").read_text())
    assert [f["applied_axes"] for f in record["frames"]] == ["xyz"] * 3
    # resume: unchanged detections are neither rendered nor reconstructed again
    assert main(["study", str(on_toml), "-o", str(on), "-q"]) == 0
    again = json.loads((on / "summary.json").read_text("utf-8"))["variants"]["mismatched"]
    assert again["summary"]["worst_u_rmsd_z"] == pytest.approx(b["worst_u_rmsd_z"], rel=1e-12)
    assert again["seconds"]["axial_calibration"] < 0.5 * s_on["seconds"]["axial_calibration"]


@pytest.mark.slow
@pytest.mark.studies
def test_self_calibration_on_a_heterogeneous_motion(tmp_path):
    """inclusion_stretch at test size (a stiff sphere in a matrix stretched to 20 %, 5
    frames): the same dataset without and with the calibration. Measured (seed 1): z
    displacement RMSD worst frame 3.43 -> 1.30 µm, pooled 3.08 -> 1.19; x 0.222 -> 0.159,
    y 0.207 -> 0.184 µm; strain RMSD E_zz 2.37 -> 1.96 %, E_xz 1.41 -> 0.95 %, E_yz 1.23 ->
    0.85 % (the ideal of the detected particles: 1.64 / 0.98 / 0.78 %), E_xx, E_yy, E_xy
    unchanged; every particle tracked, none wrongly."""
    off, on = _off_and_on(tmp_path, "inclusion_stretch_test")
    a, b = (
        json.loads((r / "summary.json").read_text("utf-8"))["variants"]["mismatched"]["summary"]
        for r in (off, on)
    )
    assert a["worst_u_rmsd_z"] > 2.5
    assert b["worst_u_rmsd_z"] < 1.7 and b["worst_u_rmsd_z"] < 0.5 * a["worst_u_rmsd_z"]
    assert b["pooled_u_rmsd_x"] < a["pooled_u_rmsd_x"]
    assert b["pooled_u_rmsd_y"] < 1.1 * a["pooled_u_rmsd_y"]
    for c in ("zz", "xz", "yz"):  # the components the axial bias spoils
        assert b[f"pooled_E_rmsd_{c}"] < 0.9 * a[f"pooled_E_rmsd_{c}"], c
    for c in ("xx", "yy", "xy"):
        assert b[f"pooled_E_rmsd_{c}"] < 1.1 * a[f"pooled_E_rmsd_{c}"], c
    assert b["min_tracking_ratio"] >= 0.99 and b["wrong_tracks"] == 0


@pytest.mark.slow
@pytest.mark.studies
def test_self_calibration_in_a_localization_study(tmp_path):
    """fig4a at test size (static particles, one frame per SNR): the same dataset without and
    with the calibration; the corrected tables are analysed, not linked. Measured (seed 1):
    worst-SNR absolute mean z error 3.36 -> 1.39 µm, pooled z RMSD 3.47 -> 1.49 µm, x 0.182
    -> 0.176, y 0.185 -> 0.182 µm; every frame's particles detected as before."""
    off, on = _off_and_on(tmp_path, "fig4a_localization_snr_test")
    a, b = (
        json.loads((r / "summary.json").read_text("utf-8"))["variants"]["mismatched"]["summary"]
        for r in (off, on)
    )
    assert a["worst_abs_mean_z"] > 2.5  # the bias is there without the calibration
    assert b["worst_abs_mean_z"] < 0.6 * a["worst_abs_mean_z"]
    assert b["pooled_rmsd_z"] < 0.6 * a["pooled_rmsd_z"]
    for ax in "xy":
        assert b[f"pooled_rmsd_{ax}"] < 1.1 * a[f"pooled_rmsd_{ax}"], ax
    assert b["mean_recall"] == a["mean_recall"]
    record = json.loads((on / "mismatched" / "axial" / "axial_calibration.json").read_text())
    assert len(record["frames"]) == load_study(tmp_path / "on.toml").experiment.frames
    assert all(f["corrected"] == f["particles"] for f in record["frames"])
    assert not (on / "mismatched" / "track" / "tracks.csv").exists()  # nothing linked


#: A 10×/0.3 microscope (150 µm f/16.7 lenslets, 11 px per lenslet; the second optics of
#: tests/track/test_detect_settings.py) on a 30 × 24-lenslet sensor.
TEN_X = (
    "na=0.3",
    "f_objective_um=20000",
    "f_tube_um=200000",
    "mla_pitch_um=150",
    "mla_focal_um=2500",
    "pixel_um=13.636363636",
    "sensor_xy_px=330,264",
)
TEN_X_STUDY = """
[experiment]
name = "loc10x"
scene = "ten_glass.xml"
seed = 3
frames = 3

[particles]
kind = "box"
count = 12
bounds_xyz_um = [[-150, 150], [-120, 120], [50, 120]]
min_spacing_um = 45
diameter_um = 6

[render]
rays_per_particle = 50000
diffraction = true

[noise]
model = "gaussian"
snr = [50, 17, 5]

[white]
rays_per_lenslet = 2000
snr = 50

[study]
kind = "localization"
recon_scene = "ten.xml"

[recon]
z_min_um = 20
z_max_um = 150
z_step_um = 2
s = 3
iterations = 8
"""


@pytest.mark.slow
@pytest.mark.studies
def test_self_calibration_on_another_microscope(tmp_path):
    """Off the tuned path: another microscope (10×/0.3, 6 µm particles), other
    reconstruction settings (8 iterations, s = 3, 2 µm planes), a localization study.
    Measured (seed 3): pooled z RMSD 1.72 -> 0.72 µm, worst absolute mean z 1.09 -> 0.34 µm,
    x 0.200 -> 0.144, y 0.194 -> 0.146 µm; all 12 particles detected in each frame."""
    from lfsim.cli import main as lfsim_main

    sets = [a for s in TEN_X for a in ("--set", s)]
    for name, mla in (("ten.xml", "ideal"), ("ten_glass.xml", "glass")):
        argv = ["scene", "--preset", "small", "--mla", mla, *sets, "-o", str(tmp_path / name)]
        assert lfsim_main([*argv, "-q"]) == 0
    off_toml, on_toml = tmp_path / "off.toml", tmp_path / "on.toml"
    off_toml.write_text(TEN_X_STUDY, "utf-8")
    on_toml.write_text(
        TEN_X_STUDY + "\n[track.axial]\nmethod = 'simulated'\nsphere_diameter_um = 6\n", "utf-8"
    )
    off, on = tmp_path / "off", tmp_path / "on"
    assert main(["study", str(off_toml), "-o", str(off), "-q"]) == 0
    shutil.copytree(off, on)  # only the detection differs
    assert main(["study", str(on_toml), "-o", str(on), "-q", "--overwrite"]) == 0
    a, b = (
        json.loads((r / "summary.json").read_text("utf-8"))["variants"]["mismatched"]["summary"]
        for r in (off, on)
    )
    assert a["mean_recall"] == b["mean_recall"] == 1.0
    assert a["pooled_rmsd_z"] > 1.3
    assert b["pooled_rmsd_z"] < 0.6 * a["pooled_rmsd_z"]
    assert b["worst_abs_mean_z"] < 0.6 * a["worst_abs_mean_z"]
    for ax in "xy":
        assert b[f"pooled_rmsd_{ax}"] < 1.1 * a[f"pooled_rmsd_{ax}"], ax


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ("sphere_diameter_um = 60\n", "sphere_diameter_um = 60 µm"),
        ("sphere_diameter_um = 5000\n", "sphere_diameter_um = 5000 µm"),
        ("sphere_diameter_um = 2\n", "sphere_diameter_um = 2 µm"),
    ],
)
def test_sphere_diameter_is_the_particles(tmp_path, extra, needle):
    """[track.axial] sphere_diameter_um far from the study's particles (15 µm) is refused
    when the study file is read, naming both."""
    text = MOTION + "[track.axial]\nmethod = 'simulated'\n" + extra
    with pytest.raises(StudyConfigError, match="diameter_um = 15 µm") as info:
        load_study(_write(tmp_path, text))
    msg = str(info.value)
    assert needle in msg and "study.toml" in msg and "\n" not in msg
    ok = load_study(_write(tmp_path, MOTION + "[track.axial]\nmethod = 'simulated'\n"))
    assert ok.track.axial.sphere_diameter_um is None
