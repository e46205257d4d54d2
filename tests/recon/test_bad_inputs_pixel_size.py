"""Bad inputs of ``recon pixel-size`` and ``lfsim micrometer`` (the corpus rules of
``tests/corpus.py``): each is refused with one line naming its cause, exit 2, the inputs
unchanged and nothing written.

The micrometer the ``recon pixel-size`` cases measure is an lfsim micrometer of 10 µm
divisions through the corpus scene (a copy of ``scenes/small.xml``), rendered once per module
with the paraxial tracer (50 000 rays per line, SNR 30, 12 bit).
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from tests.corpus import BLOCKED, Base, Case, Env, case_adder, params, run_case

CASES: list[Case] = []
case = case_adder(CASES)


@functools.cache
def _micrometer(rotation_deg: float = 0.0, z_um: float = 0.0, magnification: float = 1.03):
    """A noisy 12-bit lfsim micrometer (uint16) of 10 µm divisions through ``scenes/small.xml``
    with its magnification ``magnification`` × the scene's."""
    from dataclasses import replace

    from lfsim.noise import add_gaussian_noise
    from lfsim.render import render_micrometer
    from lfsim.scene import read_optics
    from tests.corpus import SMALL

    nominal = read_optics(SMALL)
    true = replace(nominal, f_tube_um=nominal.f_tube_um * magnification)
    clean = render_micrometer(
        true, 10.0, rotation_deg=rotation_deg, z_um=z_um, seed=3, tracer="paraxial"
    )
    img, _ = add_gaussian_noise(
        clean.astype(np.float64), 30.0, np.random.default_rng(3), bit_depth=12
    )
    return img.astype(np.uint16)


def mic(e: Env, name: str = "mic.tif", **kw):
    """The micrometer as a TIFF among the case's inputs."""
    return e.tif(name, _micrometer(**kw))


def pix_argv(e: Env, *extra, image=None, division="10", scene=None, out=None) -> list:
    return [
        "pixel-size",
        image if image is not None else mic(e),
        "--division-um",
        division,
        "--scene",
        scene or e.b.scene,
        "-o",
        out or e.o("pixel.json"),
        *extra,
    ]


# ---- recon pixel-size: option values ----
for cid, division, needle in [
    ("division-nan", "nan", "--division-um"),
    ("division-inf", "inf", "--division-um"),
    ("division-finer-than-resolved", "0.5", "finer than the objective resolves"),
    ("division-beyond-the-field", "1000", "fewer than 3 lines"),
    ("division-ten-times-too-coarse", "100", "fits a ruling of 10 µm divisions"),
]:
    case(
        f"recon-pixel-size-{cid}",
        "recon",
        lambda e, d=division: pix_argv(e, division=d),
        needle,
    )
for cid, extra, needle in [
    ("tolerance-nan", ["--tolerance", "nan"], "--tolerance"),
    ("tolerance-half", ["--tolerance", "0.5"], "--tolerance"),
    ("tolerance-negative", ["--tolerance", "-0.1"], "--tolerance"),
    ("axis-z", ["--axis", "z"], "--axis"),
    ("polarity-grey", ["--polarity", "grey"], "--polarity"),
    ("wrong-axis", ["--axis", "y"], "divisions run along x, not along axis 'y'"),
    ("wrong-polarity", ["--polarity", "dark"], "give polarity 'bright'"),
]:
    case(f"recon-pixel-size-{cid}", "recon", lambda e, x=extra: pix_argv(e, *x), needle)

# ---- recon pixel-size: images that are no (measurable) micrometer ----
for cid, make, needle in [
    ("particle-image", lambda e: e.b.frames[0], "no ruled band"),
    ("white-image", lambda e: e.b.white, "no ruled band"),
    ("blank-image", lambda e: e.tif("blank.tif", np.zeros((300, 300), np.uint16)), "no ruled band"),
    (
        "saturated-image",
        lambda e: e.tif("sat.tif", np.full((300, 300), 4095, np.uint16)),
        "no ruled band",
    ),
    (
        "inverted-micrometer",
        lambda e: e.tif("inv.tif", (4095 - _micrometer()).astype(np.uint16)),
        "give polarity 'dark'",
    ),
    (
        "defocused-300um",
        lambda e: mic(e, "defocused.tif", z_um=300.0),
        "out of focus by about",
    ),
    (
        "wrong-size-image",
        lambda e: e.tif("small.tif", _micrometer()[:200, :200]),
        "sensor is 300 × 300 px",
    ),
    (
        "nan-pixels",
        lambda e: e.tif("nan.tif", np.where(_micrometer() > 2000, np.nan, 1.0).astype(np.float32)),
        "nan.tif",
    ),
    ("stack", lambda e: e.tif("stack.tif", np.stack([_micrometer()] * 2)), "2-D"),
    ("missing", lambda e: e.inp / "nope.tif", "nope.tif"),
    ("empty-file", lambda e: e.w("empty.tif", b""), "empty.tif"),
    ("truncated", lambda e: e.trunc(mic(e), "cut.tif", 0.3), "cut.tif"),
    ("not-a-tiff", lambda e: e.w("text.tif", "a text file\n"), "text.tif"),
]:
    case(f"recon-pixel-size-{cid}", "recon", lambda e, m=make: pix_argv(e, image=m(e)), needle)

# ---- recon pixel-size: scene and calibration ----
case(
    "recon-pixel-size-scene-missing",
    "recon",
    lambda e: pix_argv(e, scene=e.inp / "nope.xml"),
    "nope.xml",
)
case(
    "recon-pixel-size-no-scene-named",
    "recon",
    lambda e: ["pixel-size", mic(e), "--division-um", "10", "-o", e.o("p.json")],
    "--scene is required",
)
case(
    "recon-pixel-size-calib-na-mismatch",
    "recon",
    lambda e: pix_argv(e, "--calib", e.b.calib, scene=e.b.scene_na025),
    "na 0.25 (scene) vs 0.2 (calibration)",
)
case(
    "recon-pixel-size-calib-of-another-sensor",
    "recon",
    lambda e: pix_argv(e, "--calib", e.b.calib, scene=e.b.scene_200),
    "does not match calibration",
)
case(
    "recon-pixel-size-calib-missing",
    "recon",
    lambda e: pix_argv(e, "--calib", e.inp / "nope.json"),
    "nope.json",
)
case(
    "recon-pixel-size-calib-not-json",
    "recon",
    lambda e: pix_argv(e, "--calib", e.w("calib.json", "{not json")),
    "calib.json",
)
case(
    "recon-pixel-size-calib-other-image-size",
    "recon",
    lambda e: pix_argv(
        e,
        "--calib",
        e.calib(lambda d: d.update(optics=None) or d["grid"].update(image_shape=[200, 200])),
    ),
    "calibrated on 200 × 200 px",
)

# ---- recon pixel-size: outputs ----
case(
    "recon-pixel-size-output-exists",
    "recon",
    lambda e: pix_argv(e, out=e.existing()),
    "already exists",
)
case(
    "recon-pixel-size-output-is-the-image",
    "recon",
    lambda e: (lambda m: pix_argv(e, "--overwrite", image=m, out=m))(mic(e)),
    "input",
)
case(
    "recon-pixel-size-output-below-the-image",
    "recon",
    lambda e: (lambda m: pix_argv(e, image=m, out=m / "pixel.json"))(mic(e)),
    "not a folder",
)
case(
    "recon-pixel-size-output-below-a-file",
    "recon",
    lambda e: pix_argv(e, out=e.blocker() / "pixel.json"),
    BLOCKED,
)
case(
    "recon-pixel-size-write-scene-onto-the-scene",
    "recon",
    lambda e: (lambda s: pix_argv(e, "--write-scene", s, "--overwrite", scene=s))(
        e.w("scene.xml", e.b.scene.read_text())
    ),
    "input",
)
case(
    "recon-pixel-size-write-scene-exists",
    "recon",
    lambda e: pix_argv(e, "--write-scene", e.existing("measured.xml")),
    "already exists",
)


# ---- lfsim micrometer ----
def micro_argv(e: Env, *extra, out=None, scene=None) -> list:
    return ["micrometer", scene or e.b.scene, "-o", out or e.o("m.tif"), *extra]


for cid, extra, needle in [
    ("rotation-inf", ["--rotation-deg", "inf"], "--rotation-deg"),
    ("rotation-below-minus-90", ["--rotation-deg", "-90.5"], "--rotation-deg"),
    ("z-inf", ["--z-um", "inf"], "--z-um"),
    ("z-beyond-the-depth-range", ["--z-um", "1e5"], "--z-um"),
    ("line-width-nan", ["--line-width-um", "nan"], "--line-width-um"),
    ("division-inf", ["--division-um", "inf"], "--division-um"),
    ("rays-per-line-negative", ["--rays-per-line", "-5"], "--rays-per-line"),
    ("snr-zero", ["--snr", "0"], "--snr"),
    ("seed-negative", ["--seed", "-1"], "--seed"),
]:
    case(f"lfsim-micrometer-{cid}", "lfsim", lambda e, x=extra: micro_argv(e, *x), needle)
case(
    "lfsim-micrometer-output-below-a-file",
    "lfsim",
    lambda e: micro_argv(e, out=e.blocker() / "m.tif"),
    BLOCKED,
)
case(
    "lfsim-micrometer-scene-not-xml",
    "lfsim",
    lambda e: micro_argv(e, scene=e.w("scene.xml", "not a scene\n")),
    "scene.xml",
)
case(
    "lfsim-micrometer-scene-truncated",
    "lfsim",
    lambda e: micro_argv(e, scene=e.trunc(e.b.scene, "cut.xml", 0.5)),
    "cut.xml",
)


@pytest.mark.parametrize("c", params(CASES))
def test_bad_input(c: Case, corpus_base: Base, tmp_path, capsys) -> None:
    run_case(c, corpus_base, tmp_path, capsys)


def test_ids_are_new() -> None:
    """Every id is unique here and absent from the other corpus modules."""
    from pathlib import Path

    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) >= 30
    root = Path(__file__).resolve().parents[1]
    others = [
        p for p in root.rglob("test_bad_inputs*.py") if p.resolve() != Path(__file__).resolve()
    ]
    text = "\n".join(p.read_text(encoding="utf-8") for p in others)
    assert not [i for i in ids if json.dumps(i) in text]
