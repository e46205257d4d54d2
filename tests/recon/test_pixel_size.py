"""Pixel-size calibration from a stage micrometer (recon.pixel_size, ``recon pixel-size``).

Micrometers are rendered with ``lfsim`` (paraxial tracer, Gaussian noise at SNR 50, 12 bit)
through a "true" microscope whose tube lens makes the magnification 4 % lower or 5 % higher
than the scene's, rotated by up to 2°, and measured with the nominal scene. Measured when this
file was written (relative error of ``um_per_px``; standard uncertainty in brackets):

- 10 µm divisions, 300 × 300 px scene (20 lenslets): −4 %/+2°: −0.020 % (0.014 %), +5 %/−1.5°:
  −0.011 % (0.013 %); over −4 %/+5 % × 0°/+2°/−1.5° at SNR 17 and 50 all within 0.09 %.
- 100 µm divisions, 1200 × 300 px (80 lenslets): −4 %/−1.5°: +0.003 %, +5 %/+2°: −0.007 %;
  on the 300 × 300 px scene (5 lines) the scale is undetermined and refused.
- Five particles 170–184 µm from the axis at z = 150 µm, reconstructed with the scene
  corrected by the measurement: distances from the axis within 0.24 % (0.2–0.6 µm); with the
  nominal scene +4.8 … +5.3 %, the magnification error.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tifffile

from lfsim.errors import ConfigError
from recon.cli import main
from recon.errors import InputError
from recon.pixel_size import (
    PIXEL_SIZE_FORMAT,
    PixelSizeError,
    apply_pixel_size,
    load_pixel_record,
    measure_pixel_size,
    nominal_grid,
    ruling_coverage,
)

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "small.xml"


@pytest.fixture(scope="module")
def nominal():
    from lfsim.scene import read_optics

    return read_optics(SCENE)


def true_optics(optics, error: float):
    """The microscope with its magnification off by ``error`` (tube lens)."""
    return replace(optics, f_tube_um=optics.f_tube_um * (1.0 + error))


def micrometer(optics, division_um, rotation_deg, *, axis="x", snr=50.0, seed=1):
    """A noisy lfsim micrometer image (12-bit counts) through ``optics``."""
    from lfsim.noise import add_gaussian_noise
    from lfsim.render import render_micrometer

    clean = render_micrometer(
        optics,
        division_um,
        axis=axis,
        rays_per_line=20_000,
        seed=seed,
        tracer="paraxial",
        rotation_deg=rotation_deg,
    )
    img, _ = add_gaussian_noise(
        clean.astype(np.float64), snr, np.random.default_rng(seed + 100), bit_depth=12
    )
    return img


# -- the model ------------------------------------------------------------------------------
def _coverage_by_sampling(c, r, q, theta, phi, rho, sigma, n=500):
    from scipy.special import ndtr

    t = (np.arange(n) + 0.5) / n - 0.5
    xx, yy = np.meshgrid(c + t, r + t)
    psi = q * (xx * math.cos(theta) + yy * math.sin(theta)) + phi
    f = psi - np.round(psi)
    return sum(
        ndtr((f + m + rho / 2) / sigma) - ndtr((f + m - rho / 2) / sigma) for m in range(-4, 5)
    ).mean()


def test_ruling_coverage_is_the_cell_average():
    rng = np.random.default_rng(7)
    for k in range(12):
        c, r = rng.uniform(-20, 20), rng.uniform(-8, 8)
        q, phi = rng.uniform(0.2, 3.2), rng.uniform(-1, 1)
        theta = 0.0 if k % 4 == 0 else rng.uniform(-0.2, 0.2)
        rho, sigma = rng.uniform(0.01, 0.5), rng.uniform(0.003, 0.2 if k % 3 == 0 else 0.03)
        got = ruling_coverage(np.array([c]), np.array([r]), q, theta, phi, rho, sigma)[0]
        assert got == pytest.approx(
            _coverage_by_sampling(c, r, q, theta, phi, rho, sigma), abs=1e-4
        )


# -- measurements ---------------------------------------------------------------------------
@pytest.mark.parametrize(("error", "rotation"), [(-0.04, 2.0), (0.05, -1.5)])
def test_fine_divisions(backend, nominal, error, rotation):
    """10 µm divisions, finer than the 25 µm lenslets: measured from their moiré."""
    true = true_optics(nominal, error)
    res = measure_pixel_size(micrometer(true, 10.0, rotation), nominal, 10.0)
    assert res.um_per_px == pytest.approx(true.object_pixel_um, rel=0.005)
    assert abs(res.um_per_px / true.object_pixel_um - 1) < 4 * res.um_per_px_std / res.um_per_px
    assert res.magnification == pytest.approx(true.magnification, rel=0.005)
    assert res.relative_deviation == pytest.approx(1 / (1 + error) - 1, abs=0.005)
    assert res.axis == "x" and res.rotation_deg == pytest.approx(rotation, abs=0.3)
    assert 0 < res.um_per_px_std < 0.002 * res.um_per_px


@pytest.mark.parametrize(("error", "rotation"), [(-0.04, -1.5), (0.05, 2.0)])
def test_coarse_divisions_over_a_wide_field(backend, nominal, error, rotation):
    """100 µm divisions (4 lenslets): each line lights one column of lenslets; the scale comes
    from the vernier of 16 lines against the lenslets."""
    wide = replace(nominal, sensor_xy_px=(1200, 300), axis_xy_px=None)
    true = true_optics(wide, error)
    res = measure_pixel_size(micrometer(true, 100.0, rotation), wide, 100.0)
    assert res.um_per_px == pytest.approx(true.object_pixel_um, rel=0.005)
    assert res.rotation_deg == pytest.approx(rotation, abs=0.3)


def test_coarse_divisions_in_a_small_field_are_refused(backend, nominal):
    """Five lines that all stay inside their lenslets cannot give the scale to 1 %."""
    img = micrometer(true_optics(nominal, -0.04), 100.0, 0.0)
    with pytest.raises(PixelSizeError, match="uncertainty on the scale"):
        measure_pixel_size(img, nominal, 100.0)


def test_dark_lines_along_y(backend, nominal):
    true = true_optics(nominal, 0.05)
    img = micrometer(true, 10.0, 1.0, axis="y")
    dark = img.max() - img
    res = measure_pixel_size(dark, nominal, 10.0, polarity="dark")
    assert res.axis == "y" and res.angle_deg == pytest.approx(91.0, abs=0.3)
    assert res.um_per_px == pytest.approx(true.object_pixel_um, rel=0.005)


def test_near_a_half_integer_the_mirror_scale_is_not_hidden(backend, nominal):
    """P/D = 2.525: the mirror-image unfolding (2.475) fits almost as well; the measurement
    says so rather than picking one."""
    img = micrometer(true_optics(nominal, -0.01), 10.0, 0.0)
    with pytest.raises(PixelSizeError, match="two scales alike"):
        measure_pixel_size(img, nominal, 10.0)


def test_no_ruling(backend, nominal):
    from lfsim.render import render_white

    rng = np.random.default_rng(3)
    with pytest.raises(PixelSizeError):
        measure_pixel_size(rng.normal(100, 5, (300, 300)), nominal, 10.0)
    white = render_white(nominal, rays_per_lenslet=2000, tracer="paraxial").astype(float)
    with pytest.raises(PixelSizeError):
        measure_pixel_size(white + rng.normal(0, 2, white.shape), nominal, 10.0)


def test_bad_arguments(nominal):
    img = np.zeros((300, 300))
    for kwargs, what in (
        ({"division_um": 0.0}, "division_um"),
        ({"division_um": -10.0}, "division_um"),
        ({"division_um": 10.0, "axis": "z"}, "axis"),
        ({"division_um": 10.0, "polarity": "grey"}, "polarity"),
        ({"division_um": 10.0, "tolerance": 0.7}, "tolerance"),
    ):
        with pytest.raises(InputError, match=what):
            measure_pixel_size(img, nominal, **kwargs)
    with pytest.raises(InputError):
        measure_pixel_size(np.zeros((2, 300, 300)), nominal, 10.0)
    with pytest.raises(InputError, match="sensor is 300 × 300 px"):
        measure_pixel_size(np.zeros((200, 300)), nominal, 10.0)
    grid = nominal_grid(nominal, (200, 200))
    with pytest.raises(InputError, match="calibrated on"):
        measure_pixel_size(img, nominal, 10.0, grid=grid)


def test_apply_pixel_size(nominal):
    record = {"format": PIXEL_SIZE_FORMAT, "um_per_px": 1.7, "optics": nominal.to_dict()}
    out = apply_pixel_size(nominal, record)
    assert out.object_pixel_um == pytest.approx(1.7, rel=1e-12)
    assert out.magnification == pytest.approx(nominal.pixel_um / 1.7, rel=1e-12)
    same = ("f_objective_um", "na", "pixel_um", "mla_pitch_um", "mla_focal_um", "axis_xy_px")
    assert all(getattr(out, k) == getattr(nominal, k) for k in same)
    assert out.px_per_lenslet == nominal.px_per_lenslet
    with pytest.raises(InputError, match="another camera"):
        apply_pixel_size(replace(nominal, pixel_um=5.0), record)
    with pytest.raises(InputError, match="not a pixel-size record"):
        apply_pixel_size(nominal, {"format": "something else", "um_per_px": 1.7})
    with pytest.raises(InputError, match="um_per_px"):
        apply_pixel_size(nominal, {"format": PIXEL_SIZE_FORMAT, "um_per_px": -1})


# -- the measurement puts reconstructed particles where they are -----------------------------
def _lateral_centroids(vol_dir: Path, positions_um) -> np.ndarray:
    """(x, y) in µm of the reconstructed blob nearest to each expected position."""
    from scipy import ndimage

    from lfsim.io import read_json, read_tiff

    vol, _ = read_tiff(vol_dir / "000000.tif")
    g = read_json(vol_dir / "recon.json")["grid"]
    vox = g["lenslet_object_um"] / g["s"]
    ox, oy = g["origin_xy_um"]
    out = []
    for x, y, _ in positions_um:
        i0, j0 = int((x - ox) / vox), int((y - oy) / vox)
        w = math.ceil(30 / vox)  # search ±30 µm: covers a 5 % scale error at 200 µm
        sub = vol[:, max(j0 - w, 0) : j0 + w + 1, max(i0 - w, 0) : i0 + w + 1]
        k, j, i = np.unravel_index(np.argmax(sub), sub.shape)
        j, i = j + max(j0 - w, 0), i + max(i0 - w, 0)
        h = 3
        patch = vol[max(k - 1, 0) : k + 2, j - h : j + h + 1, i - h : i + h + 1].sum(axis=0)
        rim = np.r_[patch[0], patch[-1], patch[:, 0], patch[:, -1]]
        cj, ci = ndimage.center_of_mass(np.clip(patch - np.median(rim), 0, None))
        out.append((ox + (i - h + ci + 0.5) * vox, oy + (j - h + cj + 0.5) * vox))
    return np.array(out)


def test_reconstruction_with_the_measured_scale(backend, nominal, tmp_path):
    from lfsim.io import write_tiff
    from lfsim.noise import add_gaussian_noise
    from lfsim.particles import Particles
    from lfsim.render import render_particles
    from lfsim.tracer import RenderSettings
    from recon.pipeline import ReconSettings, reconstruct_series

    error = 0.05
    true = true_optics(nominal, error)
    measured = measure_pixel_size(micrometer(true, 10.0, 1.0), nominal, 10.0)
    corrected = apply_pixel_size(nominal, measured)
    pos = np.array(
        [[-180.0, 30, 150], [160, -90, 150], [40, 170, 150], [-60, -170, 150], [120, 120, 150]]
    )
    img = render_particles(
        true, Particles(pos), RenderSettings(rays_per_particle=40_000, seed=3), tracer="paraxial"
    )
    img, _ = add_gaussian_noise(img.astype(np.float64), 40, np.random.default_rng(4), bit_depth=12)
    frame = write_tiff(tmp_path / "frame.tif", img.astype(np.uint16), metadata={})
    grid = nominal_grid(nominal, img.shape)  # the sensor side is unchanged
    settings = ReconSettings(
        z_min_um=100, z_max_um=220, z_step_um=10, s=5, iterations=3, rays_per_pattern=20_000
    )
    r_true = np.hypot(pos[:, 0], pos[:, 1])
    ratio = {}
    for name, optics in (("corrected", corrected), ("nominal", nominal)):
        reconstruct_series(
            [frame], tmp_path / name, optics=optics, grid=grid, settings=settings, progress=False
        )
        xy = _lateral_centroids(tmp_path / name, pos)
        ratio[name] = np.hypot(xy[:, 0], xy[:, 1]) / r_true - 1
    # Corrected: every distance from the axis within 0.5 % (measured: within 0.25 %).
    assert np.all(np.abs(ratio["corrected"]) < 0.005), ratio
    # Nominal: off by the magnification error, as expected.
    assert np.all(np.abs(ratio["nominal"] - error) < 0.01), ratio


# -- command line ---------------------------------------------------------------------------
def _run(capsys, *argv):
    rc = main(["-q", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def _lfsim(*argv):
    from lfsim.cli import main as lfsim_main

    assert lfsim_main(["-q", *map(str, argv)]) == 0


@pytest.fixture(scope="module")
def true_micrometer(backend, tmp_path_factory):
    """An lfsim micrometer through a microscope with 4 % less magnification than small.xml."""
    d = tmp_path_factory.mktemp("mic")
    _lfsim("scene", "--preset", "small", "--set", "f_tube_um=192000", "-o", d / "true.xml")
    _lfsim(
        "micrometer", d / "true.xml", "-o", d / "mic.tif", "--tracer", "paraxial",
        "--rays-per-line", "20000", "--bit-depth", "12",
    )  # fmt: skip
    return d / "mic.tif"


def test_cli_writes_record_and_scene(true_micrometer, nominal, tmp_path, capsys):
    from hrvbase.io import sha256_file
    from lfsim.scene import read_optics

    out, scene_out = tmp_path / "pixel.json", tmp_path / "measured.xml"
    rc, _, err = _run(
        capsys, "pixel-size", true_micrometer, "--division-um", "10", "--scene", SCENE,
        "-o", out, "--write-scene", scene_out,
    )  # fmt: skip
    assert rc == 0, err
    rec = json.loads(out.read_text())
    truth = nominal.object_pixel_um / 0.96
    assert rec["format"] == PIXEL_SIZE_FORMAT
    assert rec["um_per_px"] == pytest.approx(truth, rel=0.005)
    assert 0 < rec["um_per_px_std"] < 0.01 * rec["um_per_px"]
    assert rec["magnification"] == pytest.approx(0.96 * nominal.magnification, rel=0.005)
    assert rec["nominal"]["um_per_px"] == pytest.approx(nominal.object_pixel_um)
    assert rec["nominal"]["magnification"] == pytest.approx(nominal.magnification)
    assert rec["relative_deviation"] == pytest.approx(1 / 0.96 - 1, abs=0.005)
    assert rec["axis"] == "x" and abs(rec["angle_deg"]) < 0.3 and rec["division_um"] == 10
    assert rec["input"]["sha256"] == sha256_file(true_micrometer)
    assert rec["scene"] == {"path": str(SCENE.resolve()), "sha256": sha256_file(SCENE)}
    assert rec["tool"]["name"] == "recon" and rec["tool"]["version"]
    assert rec["lenslet_grid"]["source"] == "scene"
    assert rec["measured_scene"]["sha256"] == sha256_file(scene_out)
    measured = read_optics(scene_out)
    assert measured.object_pixel_um == pytest.approx(rec["um_per_px"], rel=1e-9)
    assert apply_pixel_size(nominal, load_pixel_record(out)) == measured
    # Nothing is replaced without --overwrite.
    before = out.read_bytes()
    rc, _, err = _run(
        capsys, "pixel-size", true_micrometer, "--division-um", "10", "--scene", SCENE, "-o", out
    )
    assert rc == 2 and "already exists" in err and err.count("\n") == 1
    assert out.read_bytes() == before


def test_cli_takes_the_scene_from_the_image(backend, nominal, tmp_path, capsys):
    """An lfsim image names its scene; 9 µm divisions through the nominal microscope."""
    mic = tmp_path / "mic9.tif"
    _lfsim(
        "micrometer", SCENE, "-o", mic, "--division-um", "9", "--tracer", "paraxial",
        "--rays-per-line", "20000", "--bit-depth", "12",
    )  # fmt: skip
    out = tmp_path / "p.json"
    rc, _, err = _run(capsys, "pixel-size", mic, "--division-um", "9", "-o", out)
    assert rc == 0, err
    rec = json.loads(out.read_text())
    assert rec["um_per_px"] == pytest.approx(nominal.object_pixel_um, rel=0.005)
    assert rec["scene"]["path"] == str(SCENE.resolve())


def test_cli_bad_inputs(true_micrometer, tmp_path, capsys):
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.zeros((2, 30, 30), np.uint16))
    noise = tmp_path / "noise.tif"
    rng = np.random.default_rng(0)
    tifffile.imwrite(noise, rng.integers(90, 110, (300, 300)).astype(np.uint16))
    out = tmp_path / "p.json"
    cases = [
        ((tmp_path / "missing.tif", "--division-um", "10"), "does not exist"),
        ((stack, "--division-um", "10"), "2-D"),
        ((true_micrometer, "--division-um", "0"), "--division-um must be > 0"),
        ((true_micrometer, "--division-um", "-10"), "--division-um must be > 0"),
        ((noise, "--division-um", "10"), "noise.tif"),
    ]
    for args, message in cases:
        rc, _, err = _run(capsys, "pixel-size", *args, "--scene", SCENE, "-o", out)
        assert rc == 2 and message in err and err.count("\n") == 1, err
        assert err.startswith("recon: error: ")
        assert not out.exists()
    # An output onto an input is refused, even with --overwrite; nothing is touched.
    before = true_micrometer.read_bytes()
    for extra in (["-o", true_micrometer], ["-o", out, "--write-scene", SCENE]):
        rc, _, err = _run(
            capsys, "pixel-size", true_micrometer, "--division-um", "10", "--scene", SCENE,
            *extra, "--overwrite",
        )  # fmt: skip
        assert rc == 2 and "input" in err and err.count("\n") == 1, err
    assert true_micrometer.read_bytes() == before
    assert not out.exists()


# -- rotated and defocused micrometers ------------------------------------------------------
@pytest.mark.parametrize(("axis", "rotation"), [("x", 60.0), ("x", -90.0), ("y", 80.0)])
def test_micrometer_sources_at_any_rotation(nominal, axis, rotation):
    """Beyond ±45° the reticle's lines still lie every division along its rotated scale."""
    from lfsim.render import micrometer_sources

    src = micrometer_sources(nominal, 10.0, 2.0, axis, rotation_deg=rotation)
    t = math.radians(rotation + (90.0 if axis == "y" else 0.0))
    along = src.centers_um[:, :2] @ np.array([math.cos(t), math.sin(t)])
    assert np.allclose(along / 10.0, np.round(along / 10.0), atol=1e-6)
    assert len(np.unique(np.round(along / 10.0))) >= 25
    # Each box is one line width across the scale's nearest image axis.
    assert np.all(np.min(src.sizes_um[:, :2], axis=1) <= 2.0 + 1e-9)


def test_lfsim_micrometer_rotation_and_depth(backend, tmp_path):
    from lfsim.io import read_tiff

    out = tmp_path / "m60.tif"
    _lfsim(
        "micrometer", SCENE, "-o", out, "--rotation-deg", "60", "--z-um", "50",
        "--tracer", "paraxial", "--rays-per-line", "2000",
    )  # fmt: skip
    _, meta = read_tiff(out)
    assert meta["rotation_deg"] == 60 and meta["z_um"] == 50


def _rendered(true, rotation, *, z_um=0.0, snr=50.0, seed=1):
    """An lfsim micrometer (10 µm divisions, 50 000 rays per line) rotated by ``rotation``° and
    ``z_um`` out of focus, 12-bit counts at ``snr``."""
    from lfsim.noise import add_gaussian_noise
    from lfsim.render import render_micrometer

    clean = render_micrometer(
        true, 10.0, rotation_deg=rotation, z_um=z_um, seed=seed, tracer="paraxial"
    )
    img, _ = add_gaussian_noise(
        clean.astype(np.float64), snr, np.random.default_rng(seed + 100), bit_depth=12
    )
    return img


@pytest.mark.parametrize(
    ("rotation", "error", "snr"),
    [(40.0, 0.0, 50.0), (40.0, 0.1, 15.0), (25.0, -0.1, 50.0), (60.0, 0.0, 15.0)],
)
def test_a_rotated_ruling_is_measured_within_its_uncertainty_or_refused(
    backend, nominal, rotation, error, snr
):
    """At any angle: the result is within 2σ of the truth, or refused — never 2.03 ± 0.001
    µm/px for 1.667 (a 40° ruling fitted near 0°)."""
    true = true_optics(nominal, error)
    try:
        res = measure_pixel_size(_rendered(true, rotation, snr=snr), nominal, 10.0)
    except PixelSizeError as exc:
        assert "lenslet" in str(exc)
        return
    assert abs(res.um_per_px - true.object_pixel_um) <= 2 * res.um_per_px_std
    assert res.rotation_deg == pytest.approx(rotation if rotation <= 45 else rotation - 90, abs=1)


@pytest.mark.parametrize(("rotation", "error"), [(10.0, 0.0), (90.0, 0.05), (80.0, -0.1)])
def test_a_ruling_near_a_lenslet_axis_is_measured(backend, nominal, rotation, error):
    true = true_optics(nominal, error)
    res = measure_pixel_size(_rendered(true, rotation), nominal, 10.0)
    assert abs(res.um_per_px - true.object_pixel_um) <= 2 * res.um_per_px_std
    assert res.um_per_px == pytest.approx(true.object_pixel_um, rel=0.005)
    assert res.angle_deg == pytest.approx(rotation, abs=0.5)
    assert res.axis == ("x" if rotation < 45 else "y")


@pytest.mark.parametrize("z_um", [300.0, 50.0, -150.0])
def test_a_defocused_micrometer_is_refused(backend, nominal, z_um):
    """300 µm out of focus gave +18.6 % silently; the parallax between the lenslets' views
    measures the defocus."""
    img = _rendered(true_optics(nominal, 0.03), 0.0, z_um=z_um, snr=15.0)
    with pytest.raises(PixelSizeError, match="out of focus by about") as info:
        measure_pixel_size(img, nominal, 10.0)
    z = float(str(info.value).split("about ")[1].split(" ")[0])
    assert np.sign(z) == np.sign(z_um) and abs(z) > 0.3 * abs(z_um)


def test_defocus_of_an_in_focus_micrometer_is_small(backend, nominal):
    from recon.pixel_size import defocus_um

    for rotation, snr in ((0.0, 5.0), (40.0, 50.0), (90.0, 5.0)):
        z, z_std = defocus_um(
            _rendered(nominal, rotation, snr=snr), nominal_grid(nominal, (300, 300)), nominal
        )
        assert abs(z) < 8.0 and 0 < z_std < 5.0, (rotation, z, z_std)


# -- each cause of a refusal named --------------------------------------------------------------
@pytest.fixture(scope="module")
def in_focus(backend, nominal):
    """A 10 µm micrometer through a microscope 3 % above the scene's magnification."""
    return _rendered(true_optics(nominal, 0.03), 0.0, snr=20.0, seed=3)


def test_a_wrong_division_is_named(backend, nominal, in_focus):
    with pytest.raises(PixelSizeError, match=r"fits a ruling of 10 µm divisions .* not of the 100"):
        measure_pixel_size(in_focus, nominal, 100.0)
    with pytest.raises(InputError, match="finer than the objective resolves"):
        measure_pixel_size(in_focus, nominal, 1.0)


def test_a_wrong_polarity_is_named(backend, nominal, in_focus):
    with pytest.raises(PixelSizeError, match=r"lines are bright, not dark .* polarity 'bright'"):
        measure_pixel_size(in_focus, nominal, 10.0, polarity="dark")
    with pytest.raises(PixelSizeError, match=r"lines are dark, not bright .* polarity 'dark'"):
        measure_pixel_size(in_focus.max() - in_focus, nominal, 10.0)


def test_a_wrong_axis_is_named(backend, nominal, in_focus):
    with pytest.raises(PixelSizeError, match="divisions run along x, not along axis 'y'"):
        measure_pixel_size(in_focus, nominal, 10.0, axis="y")


def test_a_particle_image_is_named(backend, nominal):
    from lfsim.particles import Particles
    from lfsim.render import render_particles
    from lfsim.tracer import RenderSettings

    rng = np.random.default_rng(5)
    pos = np.c_[rng.uniform(-220, 220, (20, 2)), rng.uniform(0, 150, 20)]
    img = render_particles(
        nominal, Particles(pos), RenderSettings(rays_per_particle=20_000, seed=1), tracer="paraxial"
    )
    with pytest.raises(PixelSizeError, match=r"no ruled band .* not a particle"):
        measure_pixel_size(img.astype(float), nominal, 10.0)


def test_cli_names_a_scene_calibration_mismatch(true_micrometer, tmp_path, capsys):
    from recon.calibration_file import read_calibration

    white = tmp_path / "white.tif"
    _lfsim("white", SCENE, "-o", white, "--tracer", "paraxial", "--rays-per-lenslet", "2000")
    calib = tmp_path / "calib.json"
    assert main(["-q", "calibrate", str(white), "--scene", str(SCENE), "-o", str(calib)]) == 0
    rec = json.loads(calib.read_text())
    rec["optics"]["na"] = 0.25
    calib.write_text(json.dumps(rec))
    assert read_calibration(calib)[1].na == 0.25
    out = tmp_path / "p.json"
    rc, _, err = _run(
        capsys, "pixel-size", true_micrometer, "--division-um", "10", "--scene", SCENE,
        "--calib", calib, "-o", out,
    )  # fmt: skip
    assert rc == 2 and err.count("\n") == 1 and not out.exists()
    assert "does not match calibration" in err and "na 0.2 (scene) vs 0.25 (calibration)" in err


def test_a_rotated_ruling_that_is_not_found_names_its_angle(backend, nominal):
    """40° at SNR 5: no ruling fits; the message names the angle as the cause."""
    with pytest.raises(PixelSizeError, match="40° from the lenslet x axis"):
        measure_pixel_size(_rendered(nominal, 40.0, snr=5.0, seed=2), nominal, 10.0)


def test_a_micrometer_on_the_cover_glass_of_a_specimen_gives_the_specimens_pixel_size(
    backend, nominal
):
    """In a microscope with a gel (n = 1.35) behind 170 µm of glass the reticle lies on the
    cover glass in air, in focus, and measures the lateral scale of the specimen (planar
    interfaces leave a focused plane's magnification unchanged)."""
    from lfsim.render import micrometer_optics

    gel = replace(
        true_optics(nominal, 0.05),
        medium_ior=1.35,
        coverslip_thickness_um=170.0,
        coverslip_ior=1.523,
        focus_depth_um=200.0,
    )
    slide = micrometer_optics(gel)
    assert slide.medium_ior == 1.0 and slide.coverslip_thickness_um == 170.0
    assert abs(slide.surface_z_um) < 2.0  # the focus on the cover glass (rays of full NA)
    assert micrometer_optics(nominal) is nominal  # no specimen: the scene itself
    res = measure_pixel_size(micrometer(gel, 10.0, 1.0), replace(nominal), 10.0)
    assert abs(res.um_per_px / gel.object_pixel_um - 1) < 4 * res.um_per_px_std / res.um_per_px
    assert res.magnification == pytest.approx(gel.magnification, rel=0.002)
    from lfsim.render import render_micrometer

    with pytest.raises(ConfigError, match="inside the cover glass"):
        render_micrometer(gel, 10.0, tracer="paraxial", z_um=-5.0)
