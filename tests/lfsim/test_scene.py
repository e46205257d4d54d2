"""Scene files: written, read back into the same optics, checked, loaded by Mitsuba."""

from __future__ import annotations

from pathlib import Path

import pytest

from lfsim import SceneError, paper_optics, small_optics
from lfsim.scene import load_scene, read_optics, write_scene

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.mark.parametrize("name", ["paper_4x", "paper_4x_glass", "small", "small_glass"])
def test_shipped_scenes_read_back_and_match_presets(name):
    o = read_optics(SCENES / f"{name}.xml")
    preset = paper_optics if name.startswith("paper") else small_optics
    kind = "glass" if name.endswith("glass") else "ideal"
    assert o == preset(mla_kind=kind)


def test_shipped_scenes_are_up_to_date(tmp_path):
    # The committed XML is exactly what write_scene produces today.
    for name, optics in [("small", small_optics()), ("paper_4x", paper_optics())]:
        shipped = (SCENES / f"{name}.xml").read_text()
        fresh = write_scene(optics, tmp_path / f"{name}.xml").read_text()
        body = lambda t: t[t.index("<default") :]  # noqa: E731 - skip the description comment
        assert body(fresh) == body(shipped)


def test_write_read_round_trip(tmp_path):
    o = small_optics(na=0.3, mla_pitch_um=150.0, mla_focal_um=1500.0, pixel_um=10.0)
    path = write_scene(o, tmp_path / "custom.xml")
    assert read_optics(path) == o
    g = small_optics(mla_kind="glass", mla_ior=1.46)
    assert read_optics(write_scene(g, tmp_path / "g.xml")) == g


def test_loads_in_mitsuba_with_plugins(backend):
    import mitsuba as mi

    scene = mi.load_file(str(SCENES / "small.xml"))
    ids = {s.id() for s in scene.shapes()}
    assert {"objective", "aperture_stop", "tube_lens", "mla", "sensor"} <= ids
    glass = load_scene(SCENES / "small_glass.xml")
    ids = {s.id() for s in glass.mi_scene.shapes()}
    assert {"mla", "mla_caps", "mla_back", "sensor"} <= ids


def test_glass_mesh_regenerated_when_missing(backend, tmp_path):
    path = write_scene(small_optics(mla_kind="glass"), tmp_path / "g.xml")
    for ply in (tmp_path / "meshes").glob("*.ply"):
        ply.unlink()
    scene = load_scene(path)
    assert any((tmp_path / "meshes").glob("*.ply"))
    assert scene.optics.mla_kind == "glass"


def test_missing_scene_file_named():
    with pytest.raises(SceneError, match=r"nope\.xml"):
        read_optics("nope.xml")


def test_hand_edited_element_is_caught(tmp_path):
    path = write_scene(small_optics(), tmp_path / "s.xml")
    text = path.read_text().replace('name="focal_mm" value="50.0"', 'name="focal_mm" value="40.0"')
    path.write_text(text)
    with pytest.raises(SceneError, match="objective"):
        read_optics(path)


def test_non_physical_default_is_caught(tmp_path):
    path = write_scene(small_optics(), tmp_path / "s.xml")
    path.write_text(path.read_text().replace('name="na" value="0.2"', 'name="na" value="-0.2"'))
    with pytest.raises(SceneError, match="na"):
        read_optics(path)


def test_not_an_lfsim_scene(tmp_path):
    p = tmp_path / "plain.xml"
    p.write_text('<scene version="3.0.0"><shape type="sphere"/></scene>')
    with pytest.raises(SceneError, match="optics"):
        read_optics(p)
    p.write_text("<scene")
    with pytest.raises(SceneError, match=r"not valid XML"):
        read_optics(p)
