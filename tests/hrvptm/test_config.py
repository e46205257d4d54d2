"""Study files (hrvptm.config) and lfsim's handling of the downstream sections."""

from __future__ import annotations

from pathlib import Path

import pytest

from hrvptm.config import load_study
from hrvptm.errors import StudyConfigError
from lfsim.errors import ConfigError
from lfsim.experiment import load_experiment

from ..helpers import experiment_toml

EXPERIMENTS = Path(__file__).resolve().parents[2] / "scenes" / "experiments"
STUDIES = sorted(EXPERIMENTS.glob("*.toml"))

BASE = experiment_toml(
    experiment={"name": "x", "scene": "{scene}", "frames": 4},
    particles={"kind": "box", "count": 10, "bounds_xyz_um": ((-100, 100), (-100, 100), (150, 300))},
)


def _write(tmp_path: Path, extra: str) -> Path:
    p = tmp_path / "study.toml"
    scene = (EXPERIMENTS.parent / "medium.xml").as_posix()
    p.write_text(BASE.format(scene=scene) + extra, encoding="utf-8")
    return p


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: p.stem)
def test_every_example_is_a_valid_study_and_experiment(path):
    study = load_study(path)
    assert study.study.figure or path.stem.startswith(
        ("demo", "shear_nonuniform", "inclusion_stretch")
    )
    exp = load_experiment(path)  # lfsim reads the same file, skipping the study sections
    assert exp == study.experiment
    if "glass" in study.experiment.scene.name:
        assert study.is_crime_free  # rendered with glass lenslets, reconstructed with ideal ones
        assert study.recon_scene.name == study.experiment.scene.name.replace("_glass", "")
        names = list(study.variants())
        assert names[0] == "mismatched"
        assert ("matched" in names) == study.study.matched
        assert ("as_air" in names) == study.study.specimen_as_air


def test_matched_variant_renders_through_the_reconstruction_model():
    study = load_study(EXPERIMENTS / "fig6c_simple_shear_test.toml")
    v = study.variants()
    assert v["mismatched"].optics.mla_kind == "glass"
    assert v["matched"].optics.mla_kind == "ideal"
    assert v["matched"].scene == study.recon_scene
    assert v["matched"].fingerprint() != v["mismatched"].fingerprint()


def test_specimen_as_air_reconstructs_the_first_variants_frames_without_the_specimen(tmp_path):
    from hrvptm.stages import VariantPaths, recon_optics

    study = load_study(EXPERIMENTS / "fig5b_axial_layer_gel_test.toml")
    assert list(study.variants()) == ["mismatched", "as_air"]
    assert study.variants()["as_air"] == study.experiment  # the same frames, not rendered again
    paths = VariantPaths.of(study, tmp_path, "as_air")
    assert paths.root == tmp_path / "as_air"
    assert paths.dataset == tmp_path / "mismatched" / "dataset"
    assert paths.volumes == tmp_path / "as_air" / "volumes"
    assert VariantPaths.of(study, tmp_path, "mismatched").dataset == paths.dataset
    gel, air = recon_optics(study, "mismatched"), recon_optics(study, "as_air")
    assert gel.medium_ior == 1.35 and gel.coverslip_thickness_um == 170
    assert air.medium_ior == air.immersion_ior == 1.0 and air.coverslip_thickness_um == 0
    assert not air.has_interfaces and air.axial_scale == 1.0
    # everything else is the same microscope
    for f in ("na", "mla_pitch_um", "pixel_um", "sensor_xy_px", "axis_xy_px", "mla_kind"):
        assert getattr(air, f) == getattr(gel, f), f


def test_specimen_as_air_needs_a_specimen(tmp_path):
    with pytest.raises(StudyConfigError, match="specimen_as_air = true, but recon_scene"):
        load_study(_write(tmp_path, "\n[study]\nspecimen_as_air = true\n"))
    with pytest.raises(StudyConfigError, match="specimen_as_air must be true or false"):
        load_study(_write(tmp_path, "\n[study]\nspecimen_as_air = 1\n"))


def test_defaults_when_no_study_sections(tmp_path):
    s = load_study(_write(tmp_path, ""))
    assert s.study.kind == "localization"  # no motion
    assert not s.is_crime_free and list(s.variants()) == ["matched"]
    from recon.settings import ReconSettings
    from track.detect import DetectSettings

    assert s.recon == ReconSettings()  # the library's defaults: depths from the optics
    assert s.track.detect == DetectSettings()


@pytest.mark.parametrize(
    "extra, match",
    [
        ("[study]\nkindd = 'series'\n", r"\[study\] unknown key 'kindd' \(did you mean 'kind'\?\)"),
        ("[study]\nkind = 'movie'\n", "kind must be one of"),
        ("[study]\nkind = 'pairs'\ngroup_size = 3\n", "multiple of group_size = 3"),
        ("[study]\nrecon_scene = 'nope.xml'\n", "recon_scene .*nope.xml.* does not exist"),
        ("[recon]\nz_min_um = 400\nz_max_um = 100\n", r"\[recon\] z range 400.0:100.0 is empty"),
        ("[recon]\nz_range_um = [1, 2]\n", r"\[recon\] unknown key 'z_range_um'"),
        ("[recon]\ns = 0\n", r"\[recon\] s must be an integer in 1..64"),
        ("[recon]\nlanczos_a = -1\n", r"\[recon\] lanczos_a must be >= 0"),
        ("[recon]\nstop_rel_change = -0.1\n", r"\[recon\] stop_rel_change must be >= 0"),
        ("[recon]\nthreads = 0\n", r"\[recon\] threads must be an integer >= 1"),
        ("[track.detect]\nthreshold = 1.5\n", r"\[track.detect\] threshold must be"),
        ("[track]\nmode = 'batch'\n", r"\[track\] mode must be"),
        ("[track]\nthreshold = 0.3\n", r"\[track\] unknown key 'threshold'"),
        ("[track.grid]\nsmoothing = -1\n", r"\[track.grid\] smoothing"),
        ("[track.link]\ndescriptor_ratio = 2\n", r"\[track.link\] descriptor_ratio"),
        (
            "[stdy]\nkind = 'series'\n",
            r"unknown section or key \[stdy\] \(did you mean \[study\]\?\)",
        ),
    ],
)
def test_bad_study_values_name_the_file_section_and_expectation(tmp_path, extra, match):
    with pytest.raises(StudyConfigError, match=match) as info:
        load_study(_write(tmp_path, extra))
    assert "study.toml" in str(info.value)


def test_lfsim_still_rejects_misspelt_sections(tmp_path):
    with pytest.raises(ConfigError, match=r"did you mean \[study\]"):
        load_experiment(_write(tmp_path, "[stdy]\nkind = 'series'\n"))


def test_missing_and_invalid_files(tmp_path):
    with pytest.raises(StudyConfigError, match="does not exist"):
        load_study(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[experiment\n", encoding="utf-8")
    with pytest.raises(StudyConfigError, match="not valid TOML"):
        load_study(bad)


def test_track_options_become_track_settings(tmp_path):
    from track.detect import DetectSettings
    from track.fields import GridSettings
    from track.series import SeriesSettings

    s = load_study(_write(tmp_path, "[track.grid]\nsmoothing = 10000\ntarget_nodes = 900\n"))
    series = s.track.series
    assert isinstance(series, SeriesSettings) and series.mode == "incremental"
    assert series.grid.smoothing == 1e4
    assert series.grid.target_nodes == 900 and series.grid.spacing_um is None
    assert s.track.detect == DetectSettings()  # every default is track's own
    t = load_study(
        _write(tmp_path, "[track.detect]\nthreshold = 'auto'\ndeconvolution_iterations = 0\n")
    )
    assert t.track.detect.threshold == "auto" and t.track.detect.deconvolution_iterations == 0
    default = load_study(_write(tmp_path, "")).track
    assert default.series.grid == GridSettings()  # GCV smoothing, the particle-density grid
    assert default.series.mode == SeriesSettings().mode
    # track's own limits reach the study file, named
    with pytest.raises(StudyConfigError, match="target_nodes must be at most 2000000"):
        load_study(_write(tmp_path, "[track.grid]\ntarget_nodes = 3000000\n"))


def test_every_section_key_is_a_settings_field():
    """The study file's [recon] and [track.*] keys are the settings dataclasses' fields: one
    source for every default and check (no copy in hrvptm)."""
    import dataclasses

    from hrvptm import config

    assert not hasattr(config, "ReconSpec")
    assert {f.name for f in dataclasses.fields(config.TrackSpec)} == {"detect", "series", "axial"}


@pytest.mark.parametrize(
    ("top", "extra", "needle"),
    [
        ('study = "series"\n', "", "[study] must be a table"),
        ('study = ["series"]\n', "", "[study] must be a table"),
        ("", '[[study]]\nkind = "series"\n', "[study] must be a table"),
        ("recon = 3\n", "", "[recon] must be a table"),
        ("track = [1, 2]\n", "", "[track] must be a table"),
        ("", "[track]\ndetect = 3\n", "[track.detect] must be a table"),
        ("", "[[track.axial]]\nmethod = 'simulated'\n", "[track.axial] must be a table"),
        ("", "[track]\naxial = 'simulated'\n", "[track.axial] must be a table"),
        ("", "[study.kind]\nname = 'series'\n", "[study] kind must be a string"),
        ("", "[track.mode]\nname = 'incremental'\n", "[track] mode must be a string"),
    ],
)
def test_wrong_type_sections_and_keys_are_one_line_errors(tmp_path, top, extra, needle):
    p = _write(tmp_path, extra)
    p.write_text(top + p.read_text(encoding="utf-8"), encoding="utf-8")
    with pytest.raises(StudyConfigError) as info:
        load_study(p)
    msg = str(info.value)
    assert needle in msg and "study.toml" in msg and "\n" not in msg, msg


def test_a_study_kind_given_as_the_section_says_how_to_write_it(tmp_path):
    p = _write(tmp_path, "")
    p.write_text('study = "series"\n' + p.read_text(encoding="utf-8"), encoding="utf-8")
    with pytest.raises(StudyConfigError, match=r"write \[study\] with kind = 'series'"):
        load_study(p)
