"""The bad-input corpus: every command of the four command lines against bad input.

Each case runs one command in-process (its ``main(argv)``) on small valid inputs built once
(:func:`base`: a tiny lfsim dataset of ``scenes/small.xml``, its calibration, a reconstructed
volume folder, track results, point clouds, a study file and a finished report) or on a bad
file the case writes itself, and checks the rules of docs/conventions.md §7-8:

- the exit status is the expected one (2: an error the user can cause; 3: ``track`` frames
  failed) and never 0, unless the case is a warning only (e.g. a gap in frame numbers: exit 0
  and a warning line naming it);
- stderr holds exactly one line ``PROG: error: ...`` (warnings may come before it), no
  traceback and no ``internal error``, and that line contains what identifies the fault (the
  file, option or parameter the user typed);
- no input changed: the SHA-256 of every file, and the set of files and folders, of the
  shared inputs, of the repository's ``scenes/`` and of the case's own folder are the same
  after the run (so an output that was refused was not created, and one that existed before
  is unchanged), except the outputs of a run that legitimately wrote (warning-only cases and
  ``track`` failed frames, whose inputs are still checked).

Categories: missing, empty, truncated, wrong-type and wrong-size files; NaN, text and empty
tables; misspelt and ill-typed keys; non-physical values; unwritable, conflicting and
pre-existing outputs; mismatched optics; broken series.
"""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import tifffile

from tests.corpus import (  # noqa: F401
    BLOCKED,
    DROP,
    EXPERIMENT,
    FAST,
    RESULTS,
    ROOT,
    SMALL,
    STUDY,
    Base,
    Case,
    Env,
    case_adder,
    collect_argv,
    mutate,
    params,
    run_case,
    snapshot,
    study_argv,
    toml_text,
    write_cloud,
)

CASES: list[Case] = []
case = case_adder(CASES)


def _cuda_present() -> bool:
    from lfsim.backend import _cuda_available

    return _cuda_available()


NO_CUDA = (pytest.mark.skipif(_cuda_present(), reason="this machine has a CUDA driver"),)


def zeros_u16(shape=(300, 300)) -> np.ndarray:
    return np.zeros(shape, np.uint16)


def frame_u16(seed=0, shape=(300, 300)) -> np.ndarray:
    return np.random.default_rng(seed).integers(50, 1000, shape).astype(np.uint16)


# ---- lfsim (global options) ----
def white_argv(e: Env, *extra, out: Path | None = None) -> list:
    return ["white", e.b.scene, "-o", out or e.o("w.tif"), *extra]


case("lfsim-threads-zero", "lfsim", lambda e: ["--threads", "0", *white_argv(e)], "--threads")
case("lfsim-threads-text", "lfsim", lambda e: ["--threads", "many", *white_argv(e)], "--threads")
case(
    "lfsim-device-cuda-without-gpu",
    "lfsim",
    lambda e: ["--device", "cuda", *white_argv(e)],
    "no CUDA",
    marks=NO_CUDA,
)
case("lfsim-device-unknown", "lfsim", lambda e: ["--device", "gpu", *white_argv(e)], "--device")
case("lfsim-command-unknown", "lfsim", lambda e: ["draw"], "draw")
case("recon-command-unknown", "recon", lambda e: ["rectify"], "rectify")
case("track-command-unknown", "track", lambda e: ["follow"], "follow")
case("hrvptm-command-unknown", "hrvptm", lambda e: ["report"], "report")


# ---- lfsim scene ----
def scene_argv(e: Env, *extra, out: Path | None = None) -> list:
    return ["scene", "--preset", "small", "-o", out or e.o("s.xml"), *extra]


for cid, item, needle in [
    ("misspelt-key", "nae=0.3", "'nae'"),
    ("ill-typed-value", "na=abc", "na"),
    ("no-equals", "na", "KEY=VALUE"),
    ("empty-key", "=0.3", "KEY=VALUE"),
    ("negative-na", "na=-0.2", "na"),
    ("na-above-one", "na=1.5", "na"),
    ("nan-na", "na=nan", "na"),
    ("zero-pitch", "mla_pitch_um=0", "mla_pitch_um"),
    ("negative-pixel", "pixel_um=-6.6", "pixel_um"),
    ("inf-tube-focal", "f_tube_um=inf", "f_tube_um"),
    ("nan-objective-focal", "f_objective_um=nan", "f_objective_um"),
    ("huge-sensor", "sensor_xy_px=100000,100000", "sensor_xy_px"),
    ("zero-sensor", "sensor_xy_px=0,0", "sensor_xy_px"),
    ("sensor-one-value", "sensor_xy_px=300", "sensor_xy_px"),
    ("sensor-fractional", "sensor_xy_px=300.5,300", "sensor_xy_px"),
    ("bad-mla-kind", "mla_kind=plastic", "mla_kind"),
    ("bad-mla-ior", "mla_ior=0.5", "mla_ior"),
    ("axis-nan", "axis_xy_px=nan,150", "axis_xy_px"),
    ("wavelength-negative", "wavelength_um=-0.6", "wavelength_um"),
]:
    case(f"scene-set-{cid}", "lfsim", lambda e, i=item: scene_argv(e, "--set", i), needle)
case(
    "scene-mla-conflicts-with-set",
    "lfsim",
    lambda e: scene_argv(e, "--mla", "glass", "--set", "mla_kind=ideal"),
    "--mla",
)
case("scene-preset-unknown", "lfsim", lambda e: ["scene", "--preset", "big", "-o", e.o()], "big")
case("scene-output-missing", "lfsim", lambda e: ["scene", "--preset", "small"], "--output")
case(
    "scene-output-exists",
    "lfsim",
    lambda e: scene_argv(e, out=e.existing("s.xml")),
    "already exists",
)
case("scene-output-is-folder", "lfsim", lambda e: scene_argv(e, out=e.inp), "is a folder")
case(
    "scene-output-below-a-file",
    "lfsim",
    lambda e: scene_argv(e, out=e.blocker() / "s.xml"),
    BLOCKED,
)


# ---- lfsim render ----
def render_argv(e: Env, *extra, scene=None, particles=None, out=None) -> list:
    return [
        "render",
        scene or e.b.scene,
        "--particles",
        particles or e.b.particles,
        "-o",
        out or e.o("r.tif"),
        *extra,
    ]


XML_HALF = "half.xml"
for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.xml", "nope.xml"),
    ("empty", lambda e: e.w("empty.xml", ""), "empty.xml"),
    ("truncated", lambda e: e.trunc(e.b.scene, XML_HALF), XML_HALF),
    ("binary", lambda e: e.w("binary.xml", bytes(range(256)) * 4), "binary.xml"),
    ("a-tiff", lambda e: e.tif("scene.xml", zeros_u16((4, 4))), "scene.xml"),
    ("a-folder", lambda e: e.dir("scene_dir"), "scene_dir"),
    ("not-an-lfsim-scene", lambda e: e.w("bare.xml", '<scene version="3.0.0"/>\n'), "bare.xml"),
    (
        "misspelt-optics-key",
        lambda e: e.w("typo.xml", e.b.scene.read_text().replace('name="na"', 'name="nae"')),
        "typo.xml",
    ),
    (
        "ill-typed-optics-value",
        lambda e: e.w("text.xml", e.b.scene.read_text().replace('value="0.2"', 'value="wide"', 1)),
        "text.xml",
    ),
    (
        "huge-sensor",
        lambda e: e.w(
            "huge.xml",
            e.b.scene.read_text().replace(
                'name="sensor_width_px" value="300"', 'name="sensor_width_px" value="3000000"'
            ),
        ),
        "huge.xml",
    ),
]:
    case(f"render-scene-{cid}", "lfsim", lambda e, m=make: render_argv(e, scene=m(e)), needle)

CSV_CASES = [
    ("missing", None, "nope.csv"),
    ("empty", "", "empty"),
    ("blank-lines", "\n\n\n", "empty"),
    ("nan-value", "x_um,y_um,z_um\n0,0,nan\n", "line 2"),
    ("inf-value", "x_um,y_um,z_um\n0,inf,150\n", "line 2"),
    ("text-value", "x_um,y_um,z_um\n0,zero,150\n", "'zero'"),
    ("misspelt-header", "x_um,y_um,zum\n0,0,150\n", "z_um"),
    ("short-row", "x_um,y_um,z_um\n0,0\n", "line 2"),
    ("long-row", "x_um,y_um,z_um\n0,0,150,4\n", "line 2"),
    ("duplicated-column", "x_um,y_um,z_um,z_um\n0,0,150,150\n", "z_um"),
    ("binary", bytes(range(256)) * 4, "particles.csv"),
    ("semicolons", "x_um;y_um;z_um\n0;0;150\n", "x_um"),
]
for cid, content, needle in CSV_CASES:

    def _p(e, c=content, cid=cid):
        return e.inp / "nope.csv" if c is None else e.w("particles.csv", c)

    case(f"render-particles-{cid}", "lfsim", lambda e, p=_p: render_argv(e, particles=p(e)), needle)

for cid, content, needle in [
    ("header-only", "x_um,y_um,z_um\n", "particles.csv"),
    ("unknown-column", "x_um,y_um,z_um,colour\n0,0,150,3\n", "colour"),
    ("negative-diameter", "x_um,y_um,z_um,diameter_um\n0,0,150,-15\n", "diameter_um"),
    ("zero-diameter", "x_um,y_um,z_um,diameter_um\n0,0,150,0\n", "diameter_um"),
    ("negative-brightness", "x_um,y_um,z_um,brightness\n0,0,150,-1\n", "brightness"),
    ("fractional-id", "id,x_um,y_um,z_um\n1.5,0,0,150\n", "id"),
    ("behind-the-objective", "x_um,y_um,z_um\n0,0,-60000\n", "objective"),
    ("far-outside-the-field", "x_um,y_um,z_um\n100000,0,150\n", "outside the field of view"),
    ("all-dark", "x_um,y_um,z_um,brightness\n0,0,150,0\n", "no particles in the field of view"),
]:
    case(
        f"render-particles-{cid}",
        "lfsim",
        lambda e, c=content: render_argv(e, particles=e.w("particles.csv", c)),
        needle,
    )

for cid, extra, needle in [
    ("rays-zero", ["--rays", "0"], "--rays"),
    ("rays-negative", ["--rays", "-5"], "--rays"),
    ("rays-text", ["--rays", "many"], "--rays"),
    ("snr-zero", ["--snr", "0"], "--snr"),
    ("snr-negative", ["--snr", "-3"], "--snr"),
    ("snr-nan", ["--snr", "nan"], "--snr"),
    ("snr-inf", ["--snr", "inf"], "--snr"),
    ("float-with-snr", ["--float", "--snr", "10"], "--float"),
    ("snr-with-camera-noise", ["--noise", "camera", "--snr", "10"], "--snr"),
    ("bit-depth-unsupported", ["--bit-depth", "10"], "--bit-depth"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("tracer-unknown", ["--tracer", "optix"], "--tracer"),
]:
    case(f"render-{cid}", "lfsim", lambda e, x=extra: render_argv(e, *x), needle)

case(
    "render-output-is-the-scene",
    "lfsim",
    lambda e: render_argv(e, "--overwrite", out=e.b.scene),
    "is an input",
)
case(
    "render-output-is-the-particles",
    "lfsim",
    lambda e: render_argv(e, "--overwrite", out=e.b.particles),
    "is an input",
)
case("render-output-exists", "lfsim", lambda e: render_argv(e, out=e.existing()), "already exists")
case("render-output-is-folder", "lfsim", lambda e: render_argv(e, out=e.inp), "is a folder")
case(
    "render-output-below-a-file",
    "lfsim",
    lambda e: render_argv(e, out=e.blocker() / "r.tif"),
    BLOCKED,
)
case(
    "render-device-cuda-without-gpu",
    "lfsim",
    lambda e: ["--device", "cuda", *render_argv(e)],
    "no CUDA",
    marks=NO_CUDA,
)

# ---- lfsim white ----
for cid, extra, needle in [
    ("rays-per-lenslet-zero", ["--rays-per-lenslet", "0"], "--rays-per-lenslet"),
    ("rays-per-lenslet-negative", ["--rays-per-lenslet", "-100"], "--rays-per-lenslet"),
    ("rays-per-lenslet-text", ["--rays-per-lenslet", "1e4x"], "--rays-per-lenslet"),
    ("snr-zero", ["--snr", "0"], "--snr"),
    ("snr-nan", ["--snr", "nan"], "--snr"),
    ("snr-negative", ["--snr", "-50"], "--snr"),
    ("seed-negative", ["--seed", "-2"], "--seed"),
]:
    case(f"white-{cid}", "lfsim", lambda e, x=extra: white_argv(e, *x), needle)
for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.xml", "nope.xml"),
    ("empty", lambda e: e.w("empty.xml", ""), "empty.xml"),
    ("truncated", lambda e: e.trunc(e.b.scene, XML_HALF), XML_HALF),
]:
    case(
        f"white-scene-{cid}",
        "lfsim",
        lambda e, m=make: ["white", m(e), "-o", e.o("w.tif")],
        needle,
    )
case(
    "white-output-is-the-scene",
    "lfsim",
    lambda e: white_argv(e, "--overwrite", out=e.b.scene),
    "is an input",
)
case("white-output-exists", "lfsim", lambda e: white_argv(e, out=e.existing()), "already exists")
case(
    "white-output-below-a-file",
    "lfsim",
    lambda e: white_argv(e, out=e.blocker() / "w.tif"),
    BLOCKED,
)


# ---- lfsim micrometer ----
def micro_argv(e: Env, *extra, out=None, scene=None) -> list:
    return ["micrometer", scene or e.b.scene, "-o", out or e.o("m.tif"), *extra]


for cid, extra, needle in [
    ("division-zero", ["--division-um", "0"], "--division-um"),
    ("division-negative", ["--division-um", "-10"], "--division-um"),
    ("division-nan", ["--division-um", "nan"], "--division-um"),
    ("division-beyond-the-field", ["--division-um", "1e9"], "--division-um"),
    ("line-width-negative", ["--line-width-um", "-2"], "--line-width-um"),
    ("line-width-zero", ["--line-width-um", "0"], "--line-width-um"),
    ("line-wider-than-division", ["--line-width-um", "20"], "--line-width-um"),
    ("rays-per-line-zero", ["--rays-per-line", "0"], "--rays-per-line"),
    ("axis-z", ["--axis", "z"], "--axis"),
    ("rotation-beyond-90", ["--rotation-deg", "91"], "--rotation-deg"),
    ("rotation-nan", ["--rotation-deg", "nan"], "--rotation-deg"),
    ("z-nan", ["--z-um", "nan"], "--z-um"),
    ("z-behind-the-objective", ["--z-um", "-1e6"], "--z-um"),
    ("snr-inf", ["--snr", "inf"], "--snr"),
]:
    case(f"micrometer-{cid}", "lfsim", lambda e, x=extra: micro_argv(e, *x), needle)
case(
    "micrometer-output-is-the-scene",
    "lfsim",
    lambda e: micro_argv(e, "--overwrite", out=e.b.scene),
    "is an input",
)
case(
    "micrometer-output-exists", "lfsim", lambda e: micro_argv(e, out=e.existing()), "already exists"
)
case(
    "micrometer-scene-missing",
    "lfsim",
    lambda e: micro_argv(e, scene=e.inp / "nope.xml"),
    "nope.xml",
)
case("micrometer-output-is-folder", "lfsim", lambda e: micro_argv(e, out=e.inp), "is a folder")


# ---- lfsim dataset ----
def dataset_argv(e: Env, toml: Path, out=None, *extra) -> list:
    return ["dataset", toml, "-o", out or e.o("ds"), *extra]


for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.toml", "nope.toml"),
    ("empty", lambda e: e.w("empty.toml", ""), "[experiment]"),
    ("truncated", lambda e: e.trunc(e.b.exp, "half.toml", 0.3), "half.toml"),
    ("binary", lambda e: e.w("bin.toml", bytes(range(256)) * 4), "bin.toml"),
    ("a-folder", lambda e: e.dir("toml_dir"), "toml_dir"),
    ("not-toml", lambda e: e.w("exp.toml", "name: corpus\nframes: 3\n"), "exp.toml"),
]:
    case(f"dataset-file-{cid}", "lfsim", lambda e, m=make: dataset_argv(e, m(e)), needle)

EXPERIMENT_ERRORS = [
    ("unknown-section", {"partcles.count": 6}, "partcles"),
    ("misspelt-particles-key", {"particles.cout": 6}, "cout"),
    ("misspelt-experiment-key", {"experiment.frame": 3}, "'frame'"),
    ("missing-name", {"experiment.name": DROP}, "name"),
    ("empty-name", {"experiment.name": " "}, "name"),
    ("frames-text", {"experiment.frames": "three"}, "frames"),
    ("frames-zero", {"experiment.frames": 0}, "frames"),
    ("frames-fractional", {"experiment.frames": 2.5}, "frames"),
    ("seed-negative", {"experiment.seed": -1}, "seed"),
    ("seed-text", {"experiment.seed": "x"}, "seed"),
    ("scene-missing", {"experiment.scene": "/nonexistent/scene.xml"}, "scene.xml"),
    ("scene-not-a-path", {"experiment.scene": 3}, "scene"),
    ("count-zero", {"particles.count": 0}, "count"),
    ("count-negative", {"particles.count": -6}, "count"),
    ("count-text", {"particles.count": "six"}, "count"),
    ("kind-unknown", {"particles.kind": "sphere"}, "kind"),
    (
        "box-inverted",
        {"particles.bounds_xyz_um": [[160, -180], [-180, 160], [150, 350]]},
        "bounds_xyz_um",
    ),
    ("box-wrong-shape", {"particles.bounds_xyz_um": [1, 2, 3]}, "bounds_xyz_um"),
    (
        "box-nan",
        {"particles.bounds_xyz_um": [[-180, 160], [-180, float("nan")], [150, 350]]},
        "bounds_xyz_um",
    ),
    (
        "box-behind-the-objective",
        {"particles.bounds_xyz_um": [[-180, 160], [-180, 160], [-70000, -60000]]},
        "objective",
    ),
    (
        "box-far-outside-the-field",
        {"particles.bounds_xyz_um": [[1e5, 1.1e5], [-180, 160], [150, 350]]},
        "field",
    ),
    ("diameter-negative", {"particles.diameter_um": -15}, "diameter_um"),
    ("diameter-zero", {"particles.diameter_um": 0}, "diameter_um"),
    ("spacing-impossible", {"particles.min_spacing_um": 5000}, "min_spacing_um"),
    ("spacing-negative", {"particles.min_spacing_um": -1}, "min_spacing_um"),
    ("brightness-inf", {"particles.brightness": float("inf")}, "brightness"),
    ("motion-type-unknown", {"motion.type": "wobble"}, "wobble"),
    ("motion-step-wrong-length", {"motion.step_um": [5.0, 0.0]}, "step_um"),
    ("motion-step-nan", {"motion.step_um": [float("nan"), 0.0, 0.0]}, "step_um"),
    ("motion-misspelt-key", {"motion.stepum": [5.0, 0.0, 0.0]}, "stepum"),
    ("render-rays-zero", {"render.rays_per_particle": 0}, "rays_per_particle"),
    ("render-rays-text", {"render.rays_per_particle": "many"}, "rays_per_particle"),
    ("render-rays-fractional", {"render.rays_per_particle": 3000.5}, "rays_per_particle"),
    ("render-tracer-unknown", {"render.tracer": "optix"}, "tracer"),
    ("render-diffraction-text", {"render.diffraction": "yes"}, "diffraction"),
    ("noise-snr-nan", {"noise.snr": float("nan")}, "snr"),
    ("noise-snr-inf", {"noise.snr": float("inf")}, "snr"),
    ("noise-snr-negative", {"noise.snr": -30}, "snr"),
    ("noise-snr-text", {"noise.snr": "high"}, "snr"),
    ("noise-snr-list-wrong-length", {"noise.snr": [30, 20]}, "snr"),
    ("noise-model-unknown", {"noise.model": "poisson"}, "poisson"),
    ("noise-misspelt-key", {"noise.snrr": 30}, "snrr"),
    ("white-bit-depth", {"white.bit_depth": 10}, "bit_depth"),
    ("white-rays-zero", {"white.rays_per_lenslet": 0}, "rays_per_lenslet"),
    ("white-snr-zero", {"white.snr": 0}, "snr"),
    ("csv-particles-without-a-table", {"particles.kind": "csv"}, "csv"),
]
for cid, changes, needle in EXPERIMENT_ERRORS:
    case(
        f"dataset-{cid}",
        "lfsim",
        lambda e, c=changes: dataset_argv(e, e.exp_toml(c)),
        needle,
    )


def _csv_particles(e: Env, content: str | None) -> Path:
    table = e.inp / "gone.csv" if content is None else e.w("table.csv", content)
    return e.exp_toml(
        {
            "particles.kind": "csv",
            "particles.csv": str(table),
            "particles.count": DROP,
            "particles.bounds_xyz_um": DROP,
            "particles.min_spacing_um": DROP,
        }
    )


case(
    "dataset-csv-particles-nan",
    "lfsim",
    lambda e: dataset_argv(e, _csv_particles(e, "x_um,y_um,z_um\n0,0,nan\n")),
    "table.csv",
)
case(
    "dataset-csv-particles-empty",
    "lfsim",
    lambda e: dataset_argv(e, _csv_particles(e, "")),
    "table.csv",
)
case(
    "dataset-csv-particles-file-missing",
    "lfsim",
    lambda e: dataset_argv(e, _csv_particles(e, None)),
    "gone.csv",
)
case(
    "dataset-output-is-the-experiment",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.b.exp, "--overwrite"),
    "is an input",
)
case(
    "dataset-output-contains-the-experiment",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.b.exp.parent, "--overwrite"),
    "contains the input",
)
case(
    "dataset-output-inside-the-scene-folder",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.b.scene.parent, "--overwrite"),
    "contains the input",
)
case(
    "dataset-output-is-a-file",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.existing()),
    "existing.out",
)
case(
    "dataset-output-below-a-file",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.blocker() / "ds"),
    BLOCKED,
)
case(
    "dataset-output-foreign-folder",
    "lfsim",
    lambda e: dataset_argv(e, e.b.exp, e.foreign()),
    "foreign",
)
case(
    "dataset-output-of-another-experiment",
    "lfsim",
    lambda e: dataset_argv(e, e.exp_toml({"experiment.seed": 4}), e.b.ds),
    "--overwrite",
)


# ---- recon calibrate ----
def cal_argv(e: Env, white=None, scene=None, out=None, *extra) -> list:
    return [
        "calibrate",
        white or e.b.white,
        "--scene",
        scene or e.b.scene,
        "-o",
        out or e.o("calib.json"),
        *extra,
    ]


for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.tif", "nope.tif"),
    ("empty", lambda e: e.w("empty.tif", b""), "empty.tif"),
    ("truncated", lambda e: e.trunc(e.b.white, "half.tif"), "half.tif"),
    ("text", lambda e: e.w("text.tif", "not an image\n"), "text.tif"),
    ("a-folder", lambda e: e.dir("white_dir"), "white_dir"),
    (
        "stack",
        lambda e: e.tif("stack.tif", np.stack([frame_u16()] * 3), photometric="minisblack"),
        "stack.tif",
    ),
    ("rgb", lambda e: e.tif("rgb.tif", np.zeros((300, 300, 3), np.uint8)), "rgb.tif"),
    ("wrong-size", lambda e: e.tif("small.tif", zeros_u16((100, 120))), "small.tif"),
    (
        "nan-pixels",
        lambda e: e.tif("nan.tif", np.full((300, 300), np.nan, np.float32)),
        "nan.tif",
    ),
    ("all-zero", lambda e: e.tif("zero.tif", zeros_u16()), "zero.tif"),
    ("noise-only", lambda e: e.tif("noise.tif", frame_u16()), "noise.tif"),
]:
    case(f"calibrate-white-{cid}", "recon", lambda e, m=make: cal_argv(e, white=m(e)), needle)
for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.xml", "nope.xml"),
    ("empty", lambda e: e.w("empty.xml", ""), "empty.xml"),
    ("truncated", lambda e: e.trunc(e.b.scene, XML_HALF), XML_HALF),
    ("a-tiff", lambda e: e.tif("scene.xml", zeros_u16((4, 4))), "scene.xml"),
    ("other-sensor-size", lambda e: e.b.scene_200, "s200.xml"),
    (
        "other-lenslet-pitch",
        lambda e: e.b.scene_pitch,
        "p125.xml",
    ),
]:
    case(f"calibrate-scene-{cid}", "recon", lambda e, m=make: cal_argv(e, scene=m(e)), needle)
case(
    "calibrate-output-is-the-white",
    "recon",
    lambda e: cal_argv(e, None, None, e.b.white, "--overwrite"),
    "is an input",
)
case(
    "calibrate-output-is-the-scene",
    "recon",
    lambda e: cal_argv(e, None, None, e.b.scene, "--overwrite"),
    "is an input",
)
case(
    "calibrate-output-exists",
    "recon",
    lambda e: cal_argv(e, None, None, e.existing()),
    "already exists",
)
case("calibrate-output-is-folder", "recon", lambda e: cal_argv(e, None, None, e.inp), "folder")
case(
    "calibrate-output-below-a-file",
    "recon",
    lambda e: cal_argv(e, None, None, e.blocker() / "c.json"),
    BLOCKED,
)
case("calibrate-scene-option-missing", "recon", lambda e: ["calibrate", e.b.white], "--scene")


# ---- recon run ----
def run_argv(e: Env, *frames, scene=True, calib=True, out=None, extra=()) -> list:
    argv = ["run", *frames]
    if scene:
        argv += ["--scene", e.b.scene if scene is True else scene]
    if calib:
        argv += ["--calib", e.b.calib if calib is True else calib]
    return [*argv, *FAST, "--iterations", "1", *extra, "-o", out or e.o("v")]


def ds_argv(e: Env, *extra, out=None) -> list:
    return ["run", e.b.ds, *FAST, "--iterations", "1", *extra, "-o", out or e.o("v")]


for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.tif", "nope.tif"),
    ("empty", lambda e: e.w("empty.tif", b""), "empty.tif"),
    ("truncated", lambda e: e.trunc(e.b.frames[0], "half.tif"), "half.tif"),
    ("text-as-tiff", lambda e: e.w("text.tif", "hello\n"), "text.tif"),
    (
        "nan-pixels",
        lambda e: e.tif("nan.tif", np.where(frame_u16() > 500, np.nan, 1).astype(np.float32)),
        "nan.tif",
    ),
    ("wrong-size", lambda e: e.tif("small.tif", zeros_u16((100, 120))), "small.tif"),
    ("rgb", lambda e: e.tif("rgb.tif", np.zeros((300, 300, 3), np.uint8)), "rgb.tif"),
    ("complex", lambda e: e.tif("cplx.tif", np.zeros((300, 300), np.complex64)), "cplx.tif"),
    ("empty-folder", lambda e: e.dir("nothing"), "nothing"),
    ("glob-matches-nothing", lambda e: str(e.inp / "img_*.tif"), "img_*.tif"),
    ("list-naming-a-missing-frame", lambda e: e.w("list.txt", "gone.tif\n"), "gone.tif"),
    ("empty-list", lambda e: e.w("list.txt", "# nothing\n"), "list.txt"),
    ("binary-list", lambda e: e.w("list.txt", bytes(range(256))), "list.txt"),
]:
    case(f"run-frame-{cid}", "recon", lambda e, m=make: run_argv(e, m(e)), needle)

case(
    "run-series-mixed-sizes",
    "recon",
    lambda e: run_argv(
        e,
        e.frames_dir(
            {
                "img_0.tif": frame_u16(0),
                "img_1.tif": frame_u16(1, (300, 280)),
                "img_2.tif": frame_u16(2),
            }
        ),
    ),
    "img_1.tif",
)
case(
    "run-series-mixed-dtypes",
    "recon",
    lambda e: run_argv(
        e,
        e.frames_dir(
            {
                "img_0.tif": frame_u16(0),
                "img_1.tif": frame_u16(1).astype(np.float32),
                "img_2.tif": frame_u16(2),
            }
        ),
    ),
    "img_1.tif",
)
case(
    "run-series-ambiguous-names",
    "recon",
    lambda e: run_argv(e, e.frames_dir({"img_1.tif": frame_u16(0), "img_01.tif": frame_u16(1)})),
    "img_",
)
case(
    "run-series-names-without-numbers",
    "recon",
    lambda e: run_argv(e, e.frames_dir({"left.tif": frame_u16(0), "right.tif": frame_u16(1)})),
    "left.tif",
)
case(
    "run-series-gap-is-a-warning",
    "recon",
    lambda e: run_argv(
        e,
        e.frames_dir(
            {
                "img_0.tif": tifffile.imread(e.b.frames[0]),
                "img_1.tif": tifffile.imread(e.b.frames[1]),
                "img_3.tif": tifffile.imread(e.b.frames[2]),
            }
        ),
    ),
    "missing frames 2",
    kind="warning",
    writes=True,
)
case(
    "run-frames-past-the-end-is-a-warning",
    "recon",
    lambda e: run_argv(e, e.b.ds / "frames", extra=["--frames", "1:10"]),
    "--frames 1:10",
    kind="warning",
    writes=True,
)
case(
    "run-scene-missing",
    "recon",
    lambda e: run_argv(e, e.b.frames[0], scene=e.inp / "no.xml"),
    "no.xml",
)
case("run-scene-required", "recon", lambda e: run_argv(e, e.b.frames[0], scene=False), "--scene")
case("run-calib-required", "recon", lambda e: run_argv(e, e.b.frames[0], calib=False), "--calib")
for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.json", "nope.json"),
    ("empty", lambda e: e.w("calib.json", ""), "calib.json"),
    ("truncated", lambda e: e.trunc(e.b.calib, "calib.json"), "calib.json"),
    ("a-tiff", lambda e: e.tif("calib.json", zeros_u16((4, 4))), "calib.json"),
    ("a-list", lambda e: e.w("calib.json", "[1, 2, 3]"), "calib.json"),
    ("a-folder", lambda e: e.dir("calib_dir"), "calib_dir"),
    (
        "misspelt-key",
        lambda e: e.calib(lambda d: d["grid"].update(pich_px=d["grid"].pop("pitch_px"))),
        "pitch_px",
    ),
    ("text-pitch", lambda e: e.calib(lambda d: d["grid"].update(pitch_px="fifteen")), "pitch_px"),
    ("nan-pitch", lambda e: e.calib(lambda d: d["grid"].update(pitch_px=float("nan"))), "pitch_px"),
    ("negative-pitch", lambda e: e.calib(lambda d: d["grid"].update(pitch_px=-15.0)), "pitch_px"),
    (
        "origin-wrong-length",
        lambda e: e.calib(lambda d: d["grid"].update(origin_xy_px=[1.0])),
        "origin_xy_px",
    ),
    (
        "image-shape-text",
        lambda e: e.calib(lambda d: d["grid"].update(image_shape="300x300")),
        "image_shape",
    ),
    (
        "optics-misspelt",
        lambda e: e.calib(lambda d: d["optics"].update(nae=d["optics"].pop("na"))),
        "nae",
    ),
    ("optics-ill-typed", lambda e: e.calib(lambda d: d["optics"].update(na="0.2x")), "na"),
    ("other-sensor", lambda e: e.calib(lambda d: d["grid"].update(image_shape=[200, 200])), "200"),
]:
    case(
        f"run-calib-{cid}",
        "recon",
        lambda e, m=make: run_argv(e, e.b.frames[0], calib=m(e)),
        needle,
    )

case(
    "run-scene-other-optics-than-calibration",
    "recon",
    lambda e: run_argv(e, e.b.frames[0], scene=e.b.scene_na025),
    "na025.xml",
)
case(
    "run-scene-other-sensor-than-calibration",
    "recon",
    lambda e: run_argv(e, e.b.frames[0], scene=e.b.scene_200),
    "s200.xml",
)
case(
    "run-dataset-with-a-scene-of-other-optics",
    "recon",
    lambda e: ["run", e.b.ds, "--scene", e.b.scene_na025, *FAST, "-o", e.o("v")],
    "na 0.25",
)
for cid, extra, needle in [
    ("z-range-text", ["--z-range=abc"], "--z-range"),
    ("z-range-one-plane", ["--z-range=100:100"], "z range 100:100"),
    ("z-range-reversed", ["--z-range=400:-40"], "z range 400"),
    ("z-range-nan", ["--z-range=nan:100"], "--z-range"),
    ("z-range-inf", ["--z-range=-40:inf"], "--z-range"),
    ("z-range-unresolvable", ["--z-range=0:3000", "--z-step", "50"], "cannot be resolved"),
    ("z-step-zero", ["--z-step", "0"], "--z-step"),
    ("z-step-negative", ["--z-step", "-20"], "--z-step"),
    ("z-step-nan", ["--z-step", "nan"], "--z-step"),
    ("z-step-inf", ["--z-step", "inf"], "--z-step"),
    ("z-step-larger-than-range", ["--z-step", "1000"], "steps of 1000"),
    ("iterations-zero", ["--iterations", "0"], "--iterations"),
    ("iterations-negative", ["--iterations", "-3"], "--iterations"),
    ("iterations-text", ["--iterations", "few"], "--iterations"),
    ("s-zero", ["-s", "0"], "--super-resolution"),
    ("s-negative", ["-s", "-3"], "--super-resolution"),
    ("lanczos-negative", ["--lanczos", "-1"], "--lanczos"),
    ("lanczos-nan", ["--lanczos", "nan"], "--lanczos"),
    ("stop-tolerance-negative", ["--stop-rel-change", "-0.1"], "--stop-rel-change"),
    ("stop-tolerance-nan", ["--stop-rel-change", "nan"], "--stop-rel-change"),
    ("rays-per-pattern-zero", ["--rays-per-pattern", "0"], "--rays-per-pattern"),
    ("projector-unknown", ["--projector", "magic"], "--projector"),
    ("background-text", ["--background", "dark"], "--background"),
    ("background-nan", ["--background", "nan"], "--background"),
    ("background-negative-inf", ["--background", "-inf"], "--background"),
    ("roi-text", ["--roi", "left"], "--roi"),
    ("roi-inverted", ["--roi", "200:100,0:100"], "--roi"),
    ("roi-outside-the-image", ["--roi", "5000:6000,0:100"], "(5000, 6000, 0, 100)"),
    ("fps-zero", ["--fps", "0"], "--fps"),
    ("fps-negative", ["--fps", "-10"], "--fps"),
    ("fps-nan", ["--fps", "nan"], "--fps"),
    ("frames-text", ["--frames", "first"], "--frames"),
    ("frames-reversed", ["--frames", "5:2"], "--frames"),
    ("frames-beyond-the-series", ["--frames", "10:20"], "--frames"),
    ("frames-step-zero", ["--frames", "0:3:0"], "--frames"),
    ("threads-zero", ["--threads", "0"], "--threads"),
    ("gain-negative", ["--gain-dn-per-e", "-0.5"], "--gain-dn-per-e"),
    ("gain-nan", ["--gain-dn-per-e", "nan"], "--gain-dn-per-e"),
    ("gain-text", ["--gain-dn-per-e", "high"], "--gain-dn-per-e"),
]:
    case(f"run-{cid}", "recon", lambda e, x=extra: ds_argv(e, *x), needle)
case(
    "run-device-cuda-without-gpu",
    "recon",
    lambda e: ds_argv(e, "--device", "cuda"),
    "no CUDA",
    marks=NO_CUDA,
)
for cid, make, needle in [
    ("missing", lambda e: e.inp / "dark.tif", "dark.tif"),
    ("wrong-size", lambda e: e.tif("dark.tif", zeros_u16((100, 100))), "dark.tif"),
    (
        "nan",
        lambda e: e.tif("dark.tif", np.full((300, 300), np.nan, np.float32)),
        "dark.tif",
    ),
    ("truncated", lambda e: e.trunc(e.b.frames[0], "dark.tif"), "dark.tif"),
]:
    case(f"run-dark-{cid}", "recon", lambda e, m=make: ds_argv(e, "--dark", m(e)), needle)
case(
    "run-output-is-a-frame",
    "recon",
    lambda e: run_argv(e, e.b.frames[0], out=e.b.frames[0], extra=["--overwrite"]),
    "is an input",
)
case(
    "run-output-inside-the-dataset",
    "recon",
    lambda e: ds_argv(e, "--overwrite", out=e.b.ds / "volumes"),
    "inside the input folder",
)
case(
    "run-output-contains-the-dataset",
    "recon",
    lambda e: ds_argv(e, "--overwrite", out=e.b.root),
    "contains the input",
)
case(
    "run-output-is-the-calibration",
    "recon",
    lambda e: run_argv(e, e.b.frames[0], out=e.b.calib, extra=["--overwrite"]),
    "is an input",
)
case(
    "run-output-inside-the-frame-folder",
    "recon",
    lambda e: run_argv(e, e.b.ds / "frames", out=e.b.ds / "frames" / "v"),
    "inside the input folder",
)
case("run-output-is-a-file", "recon", lambda e: ds_argv(e, out=e.existing()), "existing.out")
case("run-output-below-a-file", "recon", lambda e: ds_argv(e, out=e.blocker() / "v"), BLOCKED)
case("run-output-foreign-folder", "recon", lambda e: ds_argv(e, out=e.foreign()), "foreign")
case(
    "run-output-of-other-settings",
    "recon",
    lambda e: ["run", e.b.ds, *FAST, "--iterations", "2", "-o", e.voldir()],
    "other inputs or settings",
)
case("run-frames-missing", "recon", lambda e: ["run", "-o", e.o("v")], "FRAMES")


# ---- track run / detect ----
def _vol_array(e: Env) -> np.ndarray:
    return tifffile.imread(e.b.vol / "000000.tif")


def _truncate(d: Path) -> None:
    p = d / "000001.tif"
    p.write_bytes(p.read_bytes()[:1000])


def _replace(name: str, array: np.ndarray):
    def edit(d: Path) -> None:
        (d / name).unlink()
        tifffile.imwrite(d / name, array)

    return edit


def _nan_volume(d: Path) -> None:
    arr = tifffile.imread(d / "000001.tif")
    arr[arr.shape[0] // 2, 10, 10] = np.nan
    _replace("000001.tif", arr)(d)


def _no_metadata(d: Path) -> None:
    for p in sorted(d.glob("*.tif")):
        a = tifffile.imread(p)
        p.unlink()
        tifffile.imwrite(p, a)
    (d / "recon.json").unlink()


TRACK_VOLDIR = [
    ("missing", lambda e: e.inp / "novol", "novol"),
    ("empty", lambda e: e.dir("empty_vol"), "empty_vol"),
    ("a-file", lambda e: e.w("vol.tif", "x"), "vol.tif"),
    ("truncated-volume", lambda e: e.voldir(_truncate), "000001.tif"),
    (
        "text-as-volume",
        lambda e: e.voldir(lambda d: (d / "000001.tif").write_text("x")),
        "000001.tif",
    ),
    (
        "2d-volume",
        lambda e: e.voldir(_replace("000001.tif", zeros_u16((60, 60)).astype(np.float32))),
        "000001.tif",
    ),
    ("nan-volume", lambda e: e.voldir(_nan_volume), "000001.tif", True),
    (
        "mixed-shapes",
        lambda e: e.voldir(_replace("000001.tif", np.zeros((5, 60, 60), np.float32))),
        "000001.tif",
    ),
    (
        "mixed-dtypes",
        lambda e: e.voldir(_replace("000001.tif", _vol_array(e).astype(np.float64))),
        "000001.tif",
    ),
    ("gap-in-numbers", lambda e: e.voldir(lambda d: (d / "000001.tif").unlink()), "000001"),
    ("no-voxel-size", lambda e: e.voldir(_no_metadata), "voxel"),
    (
        "recon-json-truncated",
        lambda e: e.voldir(lambda d: (d / "recon.json").write_text("{")),
        "recon.json",
    ),
    (
        "recon-json-a-list",
        lambda e: e.voldir(lambda d: (d / "recon.json").write_text("[]")),
        "recon.json",
    ),
]
for cmd in ("run", "detect"):
    for cid, make, needle, *after_work in TRACK_VOLDIR:
        if cmd == "detect" and cid not in (
            "missing",
            "truncated-volume",
            "nan-volume",
            "mixed-shapes",
            "2d-volume",
        ):
            continue
        case(
            f"track-{cmd}-{cid}",
            "track",
            lambda e, m=make, c=cmd: [c, m(e), "-o", e.o("res")],
            needle,
            writes=bool(after_work),  # found while reading, after earlier volumes were done
        )
case(
    "track-run-single-volume",
    "track",
    lambda e: [
        "run",
        e.voldir(lambda d: [(d / f"00000{k}.tif").unlink() for k in (1, 2)]),
        "-o",
        e.o("res"),
    ],
    "volume",
)


def trk_argv(e: Env, *extra, cmd="run", out=None) -> list:
    return [cmd, e.b.vol, "-o", out or e.o("res"), *extra]


for cid, extra, needle in [
    ("threshold-zero", ["--threshold", "0"], "--threshold"),
    ("threshold-above-one", ["--threshold", "1.5"], "--threshold"),
    ("threshold-text", ["--threshold", "high"], "--threshold"),
    ("threshold-nan", ["--threshold", "nan"], "--threshold"),
    ("blob-min-negative", ["--blob-min-vox", "-1"], "--blob-min-vox"),
    ("blob-min-above-max", ["--blob-min-vox", "100", "--blob-max-vox", "10"], "--blob-"),
    ("edge-margin-negative", ["--edge-margin-um", "-5"], "--edge-margin-um"),
    ("edge-margin-nan", ["--edge-margin-um", "nan"], "--edge-margin-um"),
    ("edge-margin-beyond-the-volume", ["--edge-margin-um", "1e6"], "--edge-margin-um"),
    ("deconvolution-iterations-negative", ["--deconvolution-iterations", "-1"], "--deconvolution"),
    ("method-unknown", ["--method", "gauss"], "--method"),
    ("grid-spacing-too-fine", ["--grid-spacing-um", "0.01"], "--grid-spacing-um"),
    ("grid-spacing-zero", ["--grid-spacing-um", "0"], "--grid-spacing-um"),
    ("grid-spacing-negative", ["--grid-spacing-um", "-20"], "--grid-spacing-um"),
    ("grid-spacing-nan", ["--grid-spacing-um", "nan"], "--grid-spacing-um"),
    ("grid-spacing-one-cell", ["--grid-spacing-um", "1e6"], "--grid-spacing-um"),
    ("target-nodes-zero", ["--target-nodes", "0"], "--target-nodes"),
    ("target-nodes-one", ["--target-nodes", "1"], "--target-nodes"),
    ("target-nodes-1e12", ["--target-nodes", "1000000000000"], "--target-nodes"),
    ("smoothing-negative", ["--smoothing", "-1"], "--smoothing"),
    ("smoothing-text", ["--smoothing", "auto"], "--smoothing"),
    ("mode-unknown", ["--mode", "lagrangian"], "--mode"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
    ("interpolation-unknown", ["--interpolation", "cubic"], "--interpolation"),
    ("vti-encoding-unknown", ["--vti-encoding", "zip"], "--vti-encoding"),
]:
    case(f"track-run-{cid}", "track", lambda e, x=extra: trk_argv(e, *x), needle)
for cid, extra, needle in [
    ("threshold-zero", ["--threshold", "0"], "--threshold"),
    ("blob-min-above-max", ["--blob-min-vox", "100", "--blob-max-vox", "10"], "--blob-"),
    ("grid-option-not-taken", ["--grid-spacing-um", "20"], "--grid-spacing-um"),
]:
    case(f"track-detect-{cid}", "track", lambda e, x=extra: trk_argv(e, *x, cmd="detect"), needle)

for cmd in ("run", "detect"):
    case(
        f"track-{cmd}-output-is-the-volumes",
        "track",
        lambda e, c=cmd: trk_argv(e, "--overwrite", cmd=c, out=e.b.vol),
        "is an input",
    )
    case(
        f"track-{cmd}-output-inside-the-volumes",
        "track",
        lambda e, c=cmd: trk_argv(e, cmd=c, out=e.b.vol / "res"),
        "inside the input folder",
    )
case(
    "track-run-output-contains-the-volumes",
    "track",
    lambda e: trk_argv(e, "--overwrite", out=e.b.root),
    "contains the input",
)
case("track-run-output-is-a-file", "track", lambda e: trk_argv(e, out=e.existing()), "existing.out")
case(
    "track-run-output-below-a-file",
    "track",
    lambda e: trk_argv(e, out=e.blocker() / "res"),
    BLOCKED,
)
case("track-run-output-foreign-folder", "track", lambda e: trk_argv(e, out=e.foreign()), "foreign")


def _copy_trk(e: Env) -> Path:
    d = e.tmp / "res"
    shutil.copytree(e.b.trk, d)
    return d


case(
    "track-run-output-of-other-settings",
    "track",
    lambda e: trk_argv(e, "--threshold", "0.3", out=_copy_trk(e)),
    "--overwrite",
)
case(
    "track-detect-output-of-other-settings",
    "track",
    lambda e: trk_argv(e, "--threshold", "0.3", cmd="detect", out=_copy_trk(e)),
    "--overwrite",
)
case(
    "track-link-output-of-other-inputs",
    "track",
    lambda e: link_argv(e, out=_copy_trk(e)),
    "--overwrite",
)
case(
    "track-detect-volumes-without-particles",
    "track",
    lambda e: [
        "detect",
        e.voldir(
            lambda d: [
                _replace(p.name, np.zeros_like(_vol_array(e)))(d) for p in sorted(d.glob("*.tif"))
            ]
        ),
        "-o",
        e.o("res"),
    ],
    "000000",
    status=3,
    writes=True,
)


# ---- track link ----
def link_argv(e: Env, *clouds, out=None, extra=()) -> list:
    return ["link", *(clouds or e.b.clouds), "-o", out or e.o("res"), *extra]


LINK_CSV = [
    ("missing", None, "nope.csv"),
    ("empty", "", "cloud.csv"),
    ("nan-value", "x_um,y_um,z_um\n1,2,nan\n", "cloud.csv"),
    ("inf-value", "x_um,y_um,z_um\n1,inf,3\n", "cloud.csv"),
    ("text-value", "x_um,y_um,z_um\n1,two,3\n", "cloud.csv"),
    ("misspelt-header", "x_um,y_um,zum\n1,2,3\n", "z_um"),
    ("short-row", "x_um,y_um,z_um\n1,2\n", "cloud.csv"),
    ("binary", bytes(range(256)) * 4, "cloud.csv"),
]
for cid, content, needle in LINK_CSV:

    def _c(e, c=content):
        return e.inp / "nope.csv" if c is None else e.w("cloud.csv", c)

    case(
        f"track-link-second-cloud-{cid}",
        "track",
        lambda e, c=_c: link_argv(e, e.b.clouds[0], c(e)),
        needle,
    )
    case(
        f"track-link-first-cloud-{cid}",
        "track",
        lambda e, c=_c: link_argv(e, c(e), e.b.clouds[1]),
        needle,
    )
for i, pair in enumerate(("first", "second")):
    case(
        f"track-link-{pair}-cloud-header-only",
        "track",
        lambda e, i=i: link_argv(
            e, *([e.w("cloud.csv", "x_um,y_um,z_um\n"), e.b.clouds[1]][:: 1 - 2 * i])
        ),
        "0 found",
        status=3,
        writes=True,
    )
case("track-link-a-folder", "track", lambda e: link_argv(e, e.b.clouds[0], e.dir("d")), "d")
case("track-link-one-cloud", "track", lambda e: link_argv(e, e.b.clouds[0]), "2")
case(
    "track-link-too-few-particles",
    "track",
    lambda e: link_argv(e, e.b.clouds[0], e.w("few.csv", "x_um,y_um,z_um\n1,2,3\n4,5,6\n")),
    "fewer than 4",
    status=3,
    writes=True,
)
for cid, extra, needle in [
    ("grid-spacing-too-fine", ["--grid-spacing-um", "0.01"], "--grid-spacing-um"),
    ("grid-spacing-one-cell", ["--grid-spacing-um", "1e6"], "--grid-spacing-um"),
    ("target-nodes-1e12", ["--target-nodes", "1000000000000"], "--target-nodes"),
    ("target-nodes-one", ["--target-nodes", "1"], "--target-nodes"),
    ("smoothing-nan", ["--smoothing", "nan"], "--smoothing"),
    ("detect-option-not-taken", ["--threshold", "0.3"], "--threshold"),
]:
    case(f"track-link-{cid}", "track", lambda e, x=extra: link_argv(e, extra=x), needle)
case(
    "track-link-output-is-a-cloud",
    "track",
    lambda e: link_argv(e, out=e.b.clouds[1], extra=["--overwrite"]),
    "is an input",
)
case(
    "track-link-output-contains-the-clouds",
    "track",
    lambda e: link_argv(e, out=e.b.clouds[0].parent, extra=["--overwrite"]),
    "contains the input",
)
case(
    "track-link-output-is-a-file", "track", lambda e: link_argv(e, out=e.existing()), "existing.out"
)
case(
    "track-link-output-below-a-file",
    "track",
    lambda e: link_argv(e, out=e.blocker() / "res"),
    BLOCKED,
)
case(
    "track-link-output-foreign-folder", "track", lambda e: link_argv(e, out=e.foreign()), "foreign"
)
for prog in ("lfsim", "recon", "track", "hrvptm"):
    case(f"{prog}-command-missing", prog, lambda e: ["-v"], "COMMAND")


# ---- hrvptm study ----
for cid, make, needle in [
    ("missing", lambda e: e.inp / "nope.toml", "nope.toml"),
    ("empty", lambda e: e.w("empty.toml", ""), "[experiment]"),
    ("truncated", lambda e: e.trunc(e.b.study, "half.toml", 0.3), "half.toml"),
    ("binary", lambda e: e.w("bin.toml", bytes(range(256)) * 4), "bin.toml"),
    ("a-folder", lambda e: e.dir("study_dir"), "study_dir"),
]:
    case(f"study-file-{cid}", "hrvptm", lambda e, m=make: study_argv(e, m(e)), needle)

STUDY_ERRORS = [
    ("unknown-section", {"recno.s": 3}, "recno"),
    ("study-misspelt-key", {"study.kindd": "series"}, "kindd"),
    ("study-kind-unknown", {"study.kind": "movie"}, "movie"),
    ("study-figure-unknown", {"study.figure": "9z"}, "figure"),
    ("study-recon-scene-missing", {"study.recon_scene": "gone.xml"}, "gone.xml"),
    ("study-match-radius-negative", {"study.match_radius_um": -30}, "match_radius_um"),
    ("study-match-radius-nan", {"study.match_radius_um": float("nan")}, "match_radius_um"),
    ("study-time-step-zero", {"study.time_step_s": 0}, "time_step_s"),
    ("study-group-size-one", {"study.group_size": 1}, "group_size"),
    ("study-matched-text", {"study.matched": "yes"}, "matched"),
    ("pairs-with-odd-frames", {"study.kind": "pairs"}, "group_size"),
    ("series-with-one-frame", {"experiment.frames": 1}, "frames"),
    ("recon-misspelt-key", {"recon.z_stepum": 20}, "z_stepum"),
    ("recon-s-text", {"recon.s": "five"}, "[recon]"),
    ("recon-s-zero", {"recon.s": 0}, "s"),
    ("recon-iterations-fractional", {"recon.iterations": 2.5}, "iterations"),
    ("recon-lanczos-negative", {"recon.lanczos_a": -1}, "lanczos_a"),
    ("recon-stop-tolerance-negative", {"recon.stop_rel_change": -0.1}, "stop_rel_change"),
    ("recon-one-plane", {"recon.z_min_um": 100, "recon.z_max_um": 100}, "z range 100:100"),
    ("recon-z-step-zero", {"recon.z_step_um": 0}, "z_step_um"),
    ("recon-z-step-nan", {"recon.z_step_um": float("nan")}, "z_step_um"),
    ("recon-rays-per-pattern-zero", {"recon.rays_per_pattern": 0}, "rays_per_pattern"),
    ("recon-projector-unknown", {"recon.projector": "magic"}, "projector"),
    ("track-mode-unknown", {"track.mode": "lagrangian"}, "mode"),
    ("track-misspelt-key", {"track.mdoe": "incremental"}, "mdoe"),
    ("track-unknown-subtable", {"track.linkk.seed": 1}, "linkk"),
    ("track-grid-target-zero", {"track.grid.target_nodes": 0}, "target_nodes"),
    ("track-grid-target-one", {"track.grid.target_nodes": 1}, "target_nodes"),
    ("track-grid-target-1e12", {"track.grid.target_nodes": 10**12}, "target_nodes"),
    ("track-grid-spacing-tiny", {"track.grid.spacing_um": 0.01}, "spacing_um"),
    ("track-grid-spacing-negative", {"track.grid.spacing_um": -5.0}, "spacing_um"),
    ("track-grid-smoothing-text", {"track.grid.smoothing": "auto"}, "smoothing"),
    ("track-detect-threshold-two", {"track.detect.threshold": 2.0}, "threshold"),
    ("track-detect-misspelt", {"track.detect.treshold": 0.25}, "treshold"),
    ("track-detect-blob-text", {"track.detect.blob_min_vox": "few"}, "blob_min_vox"),
    ("track-grid-target-text", {"track.grid.target_nodes": "many"}, "target_nodes"),
    ("track-grid-spacing-text", {"track.grid.spacing_um": "fine"}, "spacing_um"),
    ("track-detect-threshold-text", {"track.detect.threshold": "high"}, "threshold"),
    ("track-detect-edge-margin-text", {"track.detect.edge_margin_um": "wide"}, "edge_margin_um"),
    ("track-link-seed-text", {"track.link.seed": "x"}, "seed"),
    ("track-link-ratio-text", {"track.link.descriptor_ratio": "x"}, "descriptor_ratio"),
    ("track-min-particles-text", {"track.min_particles": "few"}, "min_particles"),
    ("recon-z-min-text", {"recon.z_min_um": "top"}, "z_min_um"),
    ("recon-lanczos-text", {"recon.lanczos_a": "wide"}, "lanczos_a"),
    ("recon-roi-wrong-length", {"recon.roi_xy_px": [1, 2]}, "roi_xy_px"),
    ("recon-roi-older-name", {"recon.roi_px": [0, 90, 0, 80]}, "'roi_px' is named 'roi_xy_px'"),
    (
        "particles-box-older-name",
        {"particles.box_um": [[-180, 160], [-180, 160], [150, 350]]},
        "'box_um' is named 'bounds_xyz_um'",
    ),
    ("recon-z-max-missing", {"recon.z_max_um": DROP}, "z_max_um"),
    ("experiment-name-missing", {"experiment.name": DROP}, "name"),
    ("noise-snr-nan", {"noise.snr": float("nan")}, "snr"),
    ("particles-count-zero", {"particles.count": 0}, "count"),
    ("scene-missing", {"experiment.scene": "gone.xml"}, "gone.xml"),
]
for cid, changes, needle in STUDY_ERRORS:
    case(f"study-{cid}", "hrvptm", lambda e, c=changes: study_argv(e, e.study_toml(c)), needle)
case(
    "study-recon-scene-of-other-sensor",
    "hrvptm",
    lambda e: study_argv(e, e.study_toml({"study.recon_scene": str(e.b.scene_200)})),
    "s200.xml",
)
case(
    "study-output-is-the-study-file",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, e.b.study, "--overwrite"),
    "is an input",
)
case(
    "study-output-contains-the-study-file",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, e.b.study.parent, "--overwrite"),
    "contains the input",
)
case(
    "study-output-is-a-file",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, e.existing()),
    "existing.out",
)
case(
    "study-output-below-a-file",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, e.blocker() / "rep"),
    BLOCKED,
)
case(
    "study-output-foreign-folder",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, e.foreign()),
    "study.json",
)


def _other_study(e: Env, state: str | None = None) -> Path:
    d = e.tmp / "rep"
    d.mkdir()
    text = state or json.dumps({"tool": "hrvptm", "name": "other", "runs": [], "seconds_total": {}})
    (d / "study.json").write_text(text, encoding="utf-8")
    return d


case(
    "study-output-of-another-study",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, _other_study(e)),
    "'other'",
)
case(
    "study-output-state-not-from-hrvptm",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, _other_study(e, '{"tool": "track"}')),
    "study.json",
)
case(
    "study-output-state-truncated",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, _other_study(e, '{"tool": "hrv')),
    "study.json",
)
case(
    "study-until-unknown",
    "hrvptm",
    lambda e: study_argv(e, e.b.study, None, "--until", "plot"),
    "plot",
)

# ---- hrvptm demo (every case is refused before the study starts) ----
case("demo-output-is-a-file", "hrvptm", lambda e: ["demo", "-o", e.existing()], "existing.out")
case("demo-output-below-a-file", "hrvptm", lambda e: ["demo", "-o", e.blocker() / "d"], BLOCKED)
case("demo-output-foreign-folder", "hrvptm", lambda e: ["demo", "-o", e.foreign()], "study.json")
case("demo-output-of-another-study", "hrvptm", lambda e: ["demo", "-o", _other_study(e)], "'other'")
case(
    "demo-output-state-not-from-hrvptm",
    "hrvptm",
    lambda e: ["demo", "-o", _other_study(e, '{"tool": "lfsim"}')],
    "study.json",
)
case(
    "demo-output-state-truncated",
    "hrvptm",
    lambda e: ["demo", "-o", _other_study(e, "{")],
    "study.json",
)
case(
    "demo-output-contains-the-demo-file",
    "hrvptm",
    lambda e: ["demo", "-o", ROOT / "scenes" / "experiments", "--overwrite"],
    "contains the input",
)
case("demo-output-missing", "hrvptm", lambda e: ["demo"], "--output")


# ---- hrvptm collect ----
def _summary(text: str | bytes):
    def edit(d: Path) -> None:
        p = d / "summary.json"
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text, encoding="utf-8")

    return edit


for cid, make, needle in [
    ("missing", lambda e: e.inp / "norep", "norep"),
    ("empty-folder", lambda e: e.dir("emptyrep"), "emptyrep"),
    ("a-file", lambda e: e.w("rep.md", "# x\n"), "rep.md"),
    ("summary-json-truncated", lambda e: e.report(_summary('{"study": ')), "summary.json"),
    ("summary-json-empty", lambda e: e.report(_summary("")), "summary.json"),
    ("summary-json-a-list", lambda e: e.report(_summary("[]")), "summary.json"),
    ("summary-json-without-keys", lambda e: e.report(_summary("{}")), "summary.json"),
    (
        "summary-json-ill-typed",
        lambda e: e.report(
            _summary(
                json.dumps(
                    {
                        "study": {"experiment": {"experiment": {"name": "s", "frames": 2}}},
                        "variants": 3,
                        "comparison": "none",
                        "plots": [],
                    }
                )
            )
        ),
        "summary.json",
    ),
    (
        "summary-json-comparison-ill-typed",
        lambda e: e.report(
            _summary(
                json.dumps(
                    {
                        "study": {"experiment": {"experiment": {"name": "s", "frames": 2}}},
                        "variants": {},
                        "comparison": [{"label": "strain", "paper": "high", "unit": "strain"}],
                        "plots": [],
                    }
                )
            )
        ),
        "summary.json",
    ),
    ("summary-json-binary", lambda e: e.report(_summary(bytes(range(256)))), "summary.json"),
    (
        "summary-md-binary",
        lambda e: e.report(lambda d: (d / "summary.md").write_bytes(b"\xff\xfe\x00bad")),
        "summary.md",
    ),
    ("summary-md-missing", lambda e: e.report(lambda d: (d / "summary.md").unlink()), "summary.md"),
]:
    case(f"collect-report-{cid}", "hrvptm", lambda e, m=make: collect_argv(e, m(e)), needle)


def _collected_page(e: Env) -> Path:
    from hrvptm.cli import main

    page = e.tmp / "page.md"
    assert main(["-q", "collect", str(e.b.report), "-o", str(page)]) == 0
    return page


case(
    "collect-output-is-the-reports-summary",
    "hrvptm",
    lambda e: collect_argv(e, out=e.b.report / "summary.md", extra=["--overwrite"]),
    "summary.md",
)
case(
    "collect-output-inside-the-report",
    "hrvptm",
    lambda e: collect_argv(e, out=e.b.report / "page.md"),
    "inside the input folder",
)
case(
    "collect-output-contains-the-report",
    "hrvptm",
    lambda e: collect_argv(e, out=e.b.root, extra=["--overwrite"]),
    "contains the input",
)
case(
    "collect-output-page-not-written-by-collect",
    "hrvptm",
    lambda e: collect_argv(e, out=e.existing("page.md"), extra=["--overwrite"]),
    "not written by hrvptm collect",
)
case(
    "collect-output-page-exists",
    "hrvptm",
    lambda e: collect_argv(e, out=_collected_page(e)),
    "already exists",
)
case("collect-output-is-folder", "hrvptm", lambda e: collect_argv(e, out=e.inp), "folder")
case(
    "collect-output-below-a-file",
    "hrvptm",
    lambda e: collect_argv(e, out=e.blocker() / "page.md"),
    BLOCKED,
)
case(
    "collect-preamble-missing",
    "hrvptm",
    lambda e: collect_argv(e, extra=["--preamble", e.inp / "intro.md"]),
    "intro.md",
)
case(
    "collect-preamble-is-the-output",
    "hrvptm",
    lambda e: collect_argv(
        e, out=_collected_page(e), extra=["--preamble", e.tmp / "page.md", "--overwrite"]
    ),
    "is an input",
)
case(
    "collect-preamble-binary",
    "hrvptm",
    lambda e: collect_argv(e, extra=["--preamble", e.w("intro.md", b"\xff\xfe\x00bad")]),
    "intro.md",
)
case(
    "collect-preamble-a-folder",
    "hrvptm",
    lambda e: collect_argv(e, extra=["--preamble", e.dir("intro")]),
    "intro",
)
case("collect-reports-missing", "hrvptm", lambda e: ["collect", "-o", e.o("page.md")], "REPORT")


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path: Path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)


def test_corpus_size_and_coverage() -> None:
    """At least 150 cases, covering every command of the four command lines."""
    assert len(CASES) >= 150
    assert len({c.id for c in CASES}) == len(CASES)
    prefixes = Counter(c.id.split("-")[0] for c in CASES)
    commands = {
        "lfsim": ["scene", "render", "white", "micrometer", "dataset"],
        "recon": ["calibrate", "run"],
        "track": ["track-run", "track-detect", "track-link"],
        "hrvptm": ["study", "demo", "collect"],
    }
    for names in commands.values():
        for name in names:
            assert any(c.id.startswith(name + "-") for c in CASES), name
    assert prefixes  # printed in the summary below
    if RESULTS:
        n = len(RESULTS)
        tb = sum(r["traceback"] for r in RESULTS)
        silent = sum(r["silent"] for r in RESULTS)
        changed = sum(r["changed_inputs"] for r in RESULTS)
        left = sum(r["left_outputs"] for r in RESULTS)
        print(
            f"\nbad-input corpus: {n} cases run, tracebacks {tb}, silent {silent}, "
            f"changed inputs {changed}, outputs left by refused runs {left}"
        )


#: The corpus modules of the frame-series, pixel-size, parallel, axial-calibration, report
#: and study-file features, beside each package's tests.
FEATURE_CORPORA = (
    "tests.recon.test_bad_inputs_series",
    "tests.recon.test_bad_inputs_pixel_size",
    "tests.track.test_bad_inputs_series",
    "tests.hrvptm.test_bad_inputs_newer",
    "tests.hrvbase.test_bad_inputs_parallel",
)


def test_feature_corpora_size_and_distinct_ids() -> None:
    """At least 150 cases on those features, every id distinct across the whole corpus."""
    import importlib

    feature = [c for m in FEATURE_CORPORA for c in importlib.import_module(m).CASES]
    assert len(feature) >= 150
    ids = [c.id for c in [*CASES, *feature]]
    assert len(set(ids)) == len(ids), [i for i, n in Counter(ids).items() if n > 1]
