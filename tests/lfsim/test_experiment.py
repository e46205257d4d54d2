"""Experiment TOML files (lfsim.experiment): schema validation, examples, fingerprints."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from lfsim.errors import ConfigError
from lfsim.experiment import Experiment, load_experiment
from lfsim.motion import SimpleShear
from lfsim.noise import NoiseSpec

from ..helpers import BOX_UM, SHEAR_XZ, experiment_toml

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"
EXAMPLES = sorted((SCENES / "experiments").glob("*.toml"))

BASE = experiment_toml(
    experiment={"name": "t", "scene": "{scene}", "seed": 2, "frames": 3},
    particles={"kind": "box", "count": 4, "bounds_xyz_um": BOX_UM},
    motion=SHEAR_XZ,
    render={"rays_per_particle": 1000},
    noise={"model": "gaussian", "snr": (30, 20, 10)},
    white={"rays_per_lenslet": 100},
)


def write_toml(folder: Path, text: str = BASE, name: str = "exp.toml", scene=None) -> Path:
    path = folder / name
    path.write_text(text.replace("{scene}", str(scene or SCENES / "small.xml")))
    return path


def replace(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new)


def test_examples_exist_for_every_study():
    names = {p.stem for p in EXAMPLES}
    studies = [
        "fig4a_localization_snr",
        "fig4b_zero_displacement",
        "fig4c_frame_rate",
        "fig5a_translation_x",
        "fig5a_translation_y",
        "fig5b_axial_layer",
        "fig6a_uniaxial",
        "fig6b_rotation",
        "fig6c_simple_shear",
        "fig7_shear_impact",
    ]
    for s in studies:
        assert s in names and f"{s}_test" in names, s


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_loads(path):
    exp = load_experiment(path)
    assert exp.name == path.stem
    assert exp.scene.is_file()
    assert exp.frames >= 2
    assert len(exp.noise) == exp.frames
    d = exp.to_dict()
    json.dumps(d, allow_nan=False)
    assert Experiment.from_dict(json.loads(json.dumps(d))) == exp
    assert len(exp.fingerprint()) == 64
    if path.stem.startswith("water40x_") and path.stem.endswith("_test"):
        assert exp.optics.sensor_xy_px == (300, 300)  # scenes/water_40x_small*.xml
    elif path.stem.endswith("_test") or path.stem.startswith("demo_"):
        assert exp.optics.sensor_xy_px == (600, 450)  # scenes/medium*.xml
    else:
        assert exp.optics.sensor_xy_px == (1280, 800)
        assert exp.render.rays_per_particle == 100_000


def test_example_sweeps():
    a = load_experiment(SCENES / "experiments" / "fig4a_localization_snr.toml")
    assert [a.noise_for_frame(k).snr for k in range(a.frames)] == [90, 70, 50, 30, 17, 10, 5]
    b = load_experiment(SCENES / "experiments" / "fig4b_zero_displacement.toml")
    snrs = [b.noise_for_frame(k).snr for k in range(b.frames)]
    assert snrs[0::2] == snrs[1::2]
    c = load_experiment(SCENES / "experiments" / "fig4c_frame_rate.toml")
    fps = [c.noise_for_frame(k).fps for k in range(c.frames)]
    assert c.noise_for_frame(0).model == "camera" and min(fps) == 100 and max(fps) == 25000
    f7 = load_experiment(SCENES / "experiments" / "fig7_shear_impact.toml")
    assert isinstance(f7.motion, SimpleShear) and f7.motion.n_frames == f7.frames
    assert max(f7.motion.values) > 0.30 and f7.motion.values[-1] == pytest.approx(0.30, abs=0.01)


def test_load_values_and_defaults(tmp_path):
    exp = load_experiment(write_toml(tmp_path))
    assert exp.seed == 2 and exp.frames == 3 and exp.source == tmp_path / "exp.toml"
    assert [exp.noise_for_frame(k).snr for k in range(3)] == [30.0, 20.0, 10.0]
    assert exp.render.rays_per_particle == 1000 and exp.render.tracer == "mitsuba"
    assert exp.white.rays_per_lenslet == 100 and exp.white.snr == 50 and exp.white.enabled
    assert exp.to_dict()["noise"]["snr"] == [30.0, 20.0, 10.0]
    with pytest.raises(ConfigError, match="frame"):
        exp.noise_for_frame(3)
    # No [noise] and no [motion]: paper default noise, every frame the reference.
    text = BASE.split("[motion]")[0] + "[render]\nrays_per_particle = 1000\n"
    exp2 = load_experiment(write_toml(tmp_path, text, "b.toml"))
    assert exp2.motion is None
    assert exp2.noise_for_frame(2) == NoiseSpec(model="gaussian", snr=17.0)
    assert exp2.render.rays_per_particle == 1000 and exp2.white.rays_per_lenslet == 20000


def test_relative_scene_path(tmp_path):
    (tmp_path / "scenes").mkdir()
    shutil.copy(SCENES / "small.xml", tmp_path / "scenes" / "small.xml")
    (tmp_path / "exps").mkdir()
    path = write_toml(tmp_path / "exps", scene="../scenes/small.xml")
    exp = load_experiment(path)
    assert exp.scene == (tmp_path / "scenes" / "small.xml").resolve()


@pytest.mark.parametrize(
    ("old", "new", "key", "allowed"),
    [
        ("seed = 2", "seeed = 2", "seeed", "seed"),
        ("[particles]", "[partcles]", "partcles", "particles"),
        ("count = 4", "cout = 4", "cout", "count"),
        ("step_gamma = 0.05", "step_gama = 0.05", "step_gama", "step_gamma"),
        ("rays_per_particle = 1000", "rays = 1000", "rays", "rays_per_particle"),
        ('model = "gaussian"', 'modle = "gaussian"', "modle", "model"),
        ("rays_per_lenslet = 100", "rays_per_lenslets = 100", "rays_per_lenslets", "enabled"),
        ("[white]", "[whyte]", "whyte", "white"),
    ],
)
def test_unknown_keys_and_sections_name_key_file_and_allowed(tmp_path, old, new, key, allowed):
    path = write_toml(tmp_path, replace(BASE, old, new))
    with pytest.raises(ConfigError) as info:
        load_experiment(path)
    msg = str(info.value)
    assert repr(key) in msg or f"[{key}]" in msg
    assert allowed in msg
    assert str(path) in msg


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("center_xyz_um = [0, 0, 200]", "center_um = [0, 0, 200]"),
        ("center_xyz_um = [0, 0, 200]", "centre_um = [0, 0, 200]"),
        ("bounds_xyz_um = [[", "box_um = [["),
    ],
)
def test_keys_named_without_their_order_are_refused_naming_the_new_key(tmp_path, old, new):
    path = write_toml(tmp_path, replace(BASE, old, new))
    with pytest.raises(ConfigError) as info:
        load_experiment(path)
    msg = str(info.value)
    key, want = new.split(" =")[0], old.split(" =")[0]
    assert msg.startswith(f"{path}: [") and "\n" not in msg
    assert f"{key!r} is named {want!r}" in msg and "rename the key" in msg


def test_fingerprint_hashes_the_keys_under_fixed_names(tmp_path, monkeypatch):
    from hrvbase.io import rename_keys
    from lfsim.experiment import FINGERPRINT_KEYS

    d = rename_keys(load_experiment(write_toml(tmp_path)).to_dict(), FINGERPRINT_KEYS)
    assert d["motion"]["center_um"] == [0.0, 0.0, 200.0] and "center_xyz_um" not in d["motion"]
    assert d["particles"]["box_um"] == [[-150.0, 150.0], [-150.0, 150.0], [100.0, 300.0]]
    assert set(FINGERPRINT_KEYS) == {"center_xyz_um", "bounds_xyz_um"}
    # the fingerprint hashes those names: without them it would be another
    exp = load_experiment(write_toml(tmp_path))
    fixed = exp.fingerprint()
    monkeypatch.setattr("lfsim.experiment.FINGERPRINT_KEYS", {})
    assert exp.fingerprint() != fixed


def test_unknown_camera_key(tmp_path):
    text = replace(BASE, 'model = "gaussian"\nsnr = [30, 20, 10]', 'model = "camera"\n')
    text += "\n[noise.camera]\ngain = 1.0\n"
    path = write_toml(tmp_path, text)
    with pytest.raises(ConfigError, match="gain") as info:
        load_experiment(path)
    assert str(path) in str(info.value) and "gain_dn_per_e" in str(info.value)


def test_missing_scene_file_is_named(tmp_path):
    path = write_toml(tmp_path, scene=tmp_path / "no_such_scene.xml")
    with pytest.raises(ConfigError, match=r"no_such_scene\.xml") as info:
        load_experiment(path)
    assert str(path) in str(info.value)


def test_missing_experiment_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match=r"nothing\.toml"):
        load_experiment(tmp_path / "nothing.toml")
    path = write_toml(tmp_path, BASE + "\nthis is = = not toml\n")
    with pytest.raises(ConfigError, match=r"exp\.toml"):
        load_experiment(path)


def test_missing_required_keys(tmp_path):
    with pytest.raises(ConfigError, match="'name'"):
        load_experiment(write_toml(tmp_path, replace(BASE, 'name = "t"\n', "")))
    with pytest.raises(ConfigError, match=r"\[particles\]"):
        load_experiment(write_toml(tmp_path, BASE.replace("[particles]", "[motionx]"), "c.toml"))


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("snr = [30, 20, 10]", "snr = [30, 20]", r"snr has 2 values.*frames = 3"),
        ("frames = 3", "frames = 0", "frames"),
        ("seed = 2", "seed = -1", "seed"),
        ("rays_per_particle = 1000", "rays_per_particle = 0", "rays_per_particle"),
        ("rays_per_particle = 1000", 'tracer = "optix"', "tracer"),
        ("rays_per_lenslet = 100", "bit_depth = 10", "bit_depth"),
        ("snr = [30, 20, 10]", "snr = [30, -1, 10]", r"frame 1.*snr"),
        ('kind = "box"', 'kind = "sphere"', "kind"),
    ],
)
def test_invalid_values(tmp_path, old, new, match):
    path = write_toml(tmp_path, replace(BASE, old, new))
    with pytest.raises(ConfigError, match=match) as info:
        load_experiment(path)
    assert str(path) in str(info.value)


def test_fps_list_and_values_schedule_lengths(tmp_path):
    text = replace(
        BASE,
        'model = "gaussian"\nsnr = [30, 20, 10]',
        'model = "camera"\nphoton_rate_per_s = 6e5\nfps = [100, 1000]',
    )
    with pytest.raises(ConfigError, match=r"fps has 2 values.*frames = 3"):
        load_experiment(write_toml(tmp_path, text))
    ok = load_experiment(write_toml(tmp_path, text.replace("[100, 1000]", "[100, 1000, 4000]")))
    assert [ok.noise_for_frame(k).fps for k in range(3)] == [100.0, 1000.0, 4000.0]
    text = replace(BASE, "step_gamma = 0.05", "values = [0.0, 0.1]")
    with pytest.raises(ConfigError, match=r"values has 2 entries.*frames = 3"):
        load_experiment(write_toml(tmp_path, text, "v.toml"))


def test_paraxial_tracer_needs_ideal_lenslets(tmp_path):
    text = replace(
        BASE, "rays_per_particle = 1000", 'rays_per_particle = 1000\ntracer = "paraxial"'
    )
    assert load_experiment(write_toml(tmp_path, text)).render.tracer == "paraxial"
    with pytest.raises(ConfigError, match="paraxial"):
        load_experiment(write_toml(tmp_path, text, "g.toml", scene=SCENES / "small_glass.xml"))


def test_fingerprint(tmp_path):
    a = load_experiment(write_toml(tmp_path))
    assert a.fingerprint() == load_experiment(write_toml(tmp_path, name="copy.toml")).fingerprint()
    # Independent of where the files live, dependent on their contents.
    other = tmp_path / "elsewhere"
    other.mkdir()
    shutil.copy(SCENES / "small.xml", other / "small.xml")
    moved = load_experiment(write_toml(other, scene=other / "small.xml"))
    assert moved.fingerprint() == a.fingerprint()
    b = load_experiment(write_toml(tmp_path, replace(BASE, "seed = 2", "seed = 3"), "b.toml"))
    assert b.fingerprint() != a.fingerprint()
    with open(other / "small.xml", "a") as fh:
        fh.write("<!-- edited -->\n")
    assert load_experiment(other / "exp.toml").fingerprint() != a.fingerprint()
    # A list of equal values is the same experiment as the single value.
    c1 = load_experiment(write_toml(tmp_path, replace(BASE, "[30, 20, 10]", "17"), "c1.toml"))
    c2 = load_experiment(
        write_toml(tmp_path, replace(BASE, "[30, 20, 10]", "[17, 17, 17]"), "c2.toml")
    )
    assert c1.fingerprint() == c2.fingerprint()
