"""Noise models (lfsim.noise) against theory: the paper's Gaussian noise at a given SNR, the
signal reference of sparse images, the choice of model.

SNR throughout is ``S / sigma_noise`` with ``S`` the paper's P99.9 (99.9th percentile of the
noise-free image), or for sparse images half the P99.9 of the lit pixels
(``signal_reference``). All random draws are seeded.
"""

from __future__ import annotations

import hashlib
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from lfsim.errors import ConfigError
from lfsim.noise import (
    NOISE_MODELS,
    NoiseSpec,
    add_gaussian_noise,
    apply_noise,
    measure_snr,
    scale_to_dn,
    signal_reference,
)

from .shared import CAM, DTYPE, FULL


def spot_image(shape=(400, 400), n_spots=300, sigma_px=1.5, seed=1) -> np.ndarray:
    """Gaussian spots of random brightness on a black background (float, arbitrary units)."""
    rng = np.random.default_rng(seed)
    ny, nx = shape
    img = np.zeros(shape)
    yy, xx = np.mgrid[-6:7, -6:7]
    for _ in range(n_spots):
        cy, cx = rng.uniform(6, ny - 7), rng.uniform(6, nx - 7)
        iy, ix = int(cy), int(cx)
        amp = rng.uniform(0.3, 1.0)
        dy, dx = yy - (cy - iy), xx - (cx - ix)
        img[iy - 6 : iy + 7, ix - 6 : ix + 7] += amp * np.exp(-(dx**2 + dy**2) / (2 * sigma_px**2))
    return img


@pytest.fixture(scope="module")
def clean() -> np.ndarray:
    img = spot_image()
    # the test image must make P99.9 a real signal level, not background
    assert np.percentile(img, 99.9) > 0.3 * img.max()
    return img


# -- the paper's Gaussian model ------------------------------------------------------------
@pytest.mark.parametrize("bit_depth", [8, 12, 16])
@pytest.mark.parametrize("snr", [90.0, 17.0, 5.0])
def test_gaussian_measured_snr_matches_request(clean, snr, bit_depth):
    noisy, info = add_gaussian_noise(clean, snr, 123, bit_depth=bit_depth)
    assert noisy.dtype == DTYPE[bit_depth]
    assert noisy.shape == clean.shape
    assert info["model"] == "gaussian" and info["bit_depth"] == bit_depth
    assert info["snr"] == snr
    clean_dn = info["scale_dn_per_unit"] * clean
    # the documented relations between the returned numbers
    assert info["sigma_dn"] == pytest.approx(np.percentile(clean_dn, 99.9) / snr, rel=1e-12)
    assert info["offset_dn"] == pytest.approx(4.0 * info["sigma_dn"], rel=1e-12)
    assert clean_dn.max() == pytest.approx(0.7 * (FULL[bit_depth] - info["offset_dn"]), rel=1e-12)
    measured = measure_snr(noisy, clean_dn, info["offset_dn"])
    assert measured == pytest.approx(snr, rel=0.05)
    # the black level keeps the noise unbiased (clipping at 0 would shift the mean up)
    resid = noisy.astype(np.float64) - info["offset_dn"] - clean_dn
    assert abs(resid.mean()) < 0.02 * info["sigma_dn"] + 0.01
    # 4 sigma black level: ~3e-5 of the background clipped (~2e-4 at 8 bit, where rounding
    # eats 0.5 DN of a 5.6 DN offset); without it half of it would be
    assert np.mean(noisy == 0) < 5e-4


def test_gaussian_without_offset_would_bias(clean):
    """Regression guard for the black level: with offset_sigmas=0 the background is clipped."""
    noisy, info = add_gaussian_noise(clean, 5.0, 7, offset_sigmas=0.0)
    assert info["offset_dn"] == 0.0
    clean_dn = info["scale_dn_per_unit"] * clean
    assert measure_snr(noisy, clean_dn) > 1.3 * 5.0
    noisy4, info4 = add_gaussian_noise(clean, 5.0, 7)
    assert measure_snr(noisy4, info4["scale_dn_per_unit"] * clean, info4["offset_dn"]) == (
        pytest.approx(5.0, rel=0.05)
    )


def test_gaussian_seeding(clean):
    a, _ = add_gaussian_noise(clean, 17.0, 42)
    b, _ = add_gaussian_noise(clean, 17.0, np.random.default_rng(42))
    c, _ = add_gaussian_noise(clean, 17.0, 43)
    np.testing.assert_array_equal(a, b)
    assert np.count_nonzero(a != c) > 0.5 * a.size


def test_gaussian_warns_when_quantisation_dominates(clean, caplog):
    with caplog.at_level(logging.WARNING, logger="lfsim.noise"):
        _, info = add_gaussian_noise(clean, 1000.0, 0, bit_depth=8)
    assert info["sigma_dn"] < 0.5
    assert any("quantisation" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="lfsim.noise"):
        add_gaussian_noise(clean, 1000.0, 0, bit_depth=16)
    assert not caplog.records


def test_scale_to_dn_no_noise(clean):
    img, info = scale_to_dn(clean, bit_depth=12)
    assert img.dtype == np.uint16
    assert info["sigma_dn"] == 0.0 and info["offset_dn"] == 0.0
    np.testing.assert_array_equal(img, np.rint(info["scale_dn_per_unit"] * clean))
    assert img.max() == round(0.7 * 4095)


# -- the signal reference: dense images keep the paper's P99.9, sparse images work --------
def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


#: Outputs of the code before the sparse-image reference (commit 2fdc2a8) on ``spot_image()``.
OLD_OUTPUTS = {
    ("gaussian", 8): "b3dd4c2bcd58cf0930cfa8282db4ac03711465331afaa5dafa60ec983e3aecb1",
    ("gaussian", 12): "ada4d69f1eca9dc2ed3b2b8372287009963f34b331a74de4281099ab5125c164",
    ("gaussian", 16): "11cebcf4ee044a990be4ae8aa880b1e8bf3ec3ad18e613b5ab382c488d3a7800",
    ("none", 12): "98e9ec6bba11f935720b6b958f76a18c67e26ed9da859223f6adde1143565c91",
    ("camera", 12): "796a3beb79c7bb6eec4544e26493e7fab47fb8d6f8d4c38789344e4975eabf39",
}


def test_dense_images_are_unchanged_bit_for_bit(clean):
    assert signal_reference(clean) == np.percentile(clean, 99.9)
    for bd in (8, 12, 16):
        noisy, info = add_gaussian_noise(clean, 17.0, 123, bit_depth=bd)
        assert _sha(noisy) == OLD_OUTPUTS[("gaussian", bd)]
    assert info["sigma_dn"] == 1822.5011669124733 and info["offset_dn"] == 7290.004667649893
    assert _sha(scale_to_dn(clean, bit_depth=12)[0]) == OLD_OUTPUTS[("none", 12)]
    spec = NoiseSpec(model="camera", camera=CAM, fps=2000.0, photon_rate_per_s=4e5)
    img, info = apply_noise(clean, spec, 8)
    assert _sha(img) == OLD_OUTPUTS[("camera", 12)]
    assert info["photons_per_unit"] == 243.4377837943001
    noisy, info = add_gaussian_noise(clean, 17.0, 123, bit_depth=12)
    clean_dn = info["scale_dn_per_unit"] * clean
    assert measure_snr(noisy, clean_dn, info["offset_dn"]) == 17.000073061774945


def one_spot(shape=(500, 500), n_spots=1, seed=4) -> np.ndarray:
    """A sparse image: fewer than 0.1 % of the pixels lit, so its P99.9 is 0."""
    return spot_image(shape, n_spots=n_spots, seed=seed)


def test_sparse_reference_is_half_the_lit_pixels_p999():
    img = one_spot()
    lit = img[img > 0]
    assert lit.size < 0.001 * img.size and np.percentile(img, 99.9) == 0
    assert signal_reference(img) == 0.5 * np.percentile(lit, 99.9)
    # Adding particles moves the reference smoothly (no jump where P99.9 leaves zero).
    refs = [signal_reference(spot_image((300, 300), n_spots=n, seed=9)) for n in range(1, 40)]
    peaks = [spot_image((300, 300), n_spots=n, seed=9).max() for n in range(1, 40)]
    ratios = np.array(refs) / np.array(peaks)
    assert np.all((ratios > 0.2) & (ratios <= 1.0)), ratios


@pytest.mark.parametrize("bit_depth", [8, 12])
def test_sparse_image_gets_the_requested_snr(bit_depth):
    img = one_spot()
    noisy, info = add_gaussian_noise(img, 17.0, 5, bit_depth=bit_depth)
    clean_dn = info["scale_dn_per_unit"] * img
    assert info["sigma_dn"] == pytest.approx(signal_reference(clean_dn) / 17.0, rel=1e-12)
    assert measure_snr(noisy, clean_dn, info["offset_dn"]) == pytest.approx(17.0, rel=0.05)
    quiet, qinfo = scale_to_dn(img, bit_depth=bit_depth)
    assert quiet.max() == round(0.7 * FULL[bit_depth]) and qinfo["sigma_dn"] == 0.0
    spec = NoiseSpec(model="camera", camera=CAM, fps=1000.0, photon_rate_per_s=1e5)
    _, cinfo = apply_noise(img, spec, 3)
    assert cinfo["photons_p999"] == pytest.approx(100.0)


@pytest.mark.parametrize(
    "call",
    [
        lambda z: add_gaussian_noise(z, 17.0, 0),
        lambda z: scale_to_dn(z),
        lambda z: signal_reference(z),
        lambda z: apply_noise(z, NoiseSpec(model="camera"), 0),
        lambda z: measure_snr(z, z),
    ],
)
def test_all_zero_image_means_no_particles(call):
    with pytest.raises(ConfigError, match=r"^no particles in the field of view"):
        call(np.zeros((20, 30)))


def test_one_particle_renders_with_noise_and_without(backend, tmp_path, capsys):
    """Through the command line: a single particle, Gaussian noise at SNR 17 and --noise none."""
    from lfsim.cli import main
    from lfsim.io import read_tiff
    from lfsim.particles import Particles
    from lfsim.render import render_particles
    from lfsim.scene import load_scene
    from lfsim.tracer import RenderSettings

    small = str(Path(__file__).resolve().parents[2] / "scenes" / "small.xml")
    one = Particles(np.array([[10.0, -20.0, 150.0]]))
    settings = RenderSettings(rays_per_particle=80, seed=3)  # few rays: < 90 of 90 000 px lit
    clean = render_particles(load_scene(small), one, settings).astype(np.float64)
    assert 0 < np.count_nonzero(clean) < 0.001 * clean.size and np.percentile(clean, 99.9) == 0
    noisy, info = add_gaussian_noise(clean, 17.0, 2, bit_depth=12)
    measured = measure_snr(noisy, info["scale_dn_per_unit"] * clean, info["offset_dn"])
    assert measured == pytest.approx(17.0, rel=0.1)

    csv = tmp_path / "one.csv"
    one.to_csv(csv)
    base = ["-q", "render", small, "--particles", str(csv), "--rays", "80", "--seed", "3"]
    assert main([*base, "--snr", "17", "-o", str(tmp_path / "g.tif")]) == 0, capsys.readouterr()
    img, meta = read_tiff(tmp_path / "g.tif")
    assert meta["noise"]["model"] == "gaussian" and meta["noise"]["snr"] == 17.0
    assert img.dtype == np.uint8 and img.max() > 100
    assert main([*base, "--noise", "none", "-o", str(tmp_path / "n.tif")]) == 0
    img, meta = read_tiff(tmp_path / "n.tif")
    assert meta["noise"]["model"] == "none" and img.max() == round(0.7 * 255)
    assert 0 < np.count_nonzero(img) < 0.001 * img.size


# -- NoiseSpec / apply_noise ---------------------------------------------------------------
def test_noise_spec_round_trip():
    spec = NoiseSpec.from_dict(
        {"model": "camera", "camera": {"read_noise_e": 1.5}, "fps": 1000, "photon_rate_per_s": 1e5}
    )
    assert spec.camera.read_noise_e == 1.5 and spec.bit_depth == spec.camera.bit_depth
    assert NoiseSpec.from_dict(spec.to_dict()) == spec
    g = NoiseSpec.from_dict({"model": "gaussian", "snr": 17})
    assert g.bit_depth == 8 and NoiseSpec.from_dict(g.to_dict()) == g
    assert set(NOISE_MODELS) == {"none", "gaussian", "camera"}


def test_apply_noise_dispatch(clean):
    img, info = apply_noise(clean, NoiseSpec(model="none", bit_depth=16), 0)
    assert img.dtype == np.uint16 and info["model"] == "none"
    np.testing.assert_array_equal(img, scale_to_dn(clean, bit_depth=16)[0])

    spec = NoiseSpec(model="gaussian", snr=17.0, bit_depth=12)
    img, info = apply_noise(clean, spec, 5)
    np.testing.assert_array_equal(img, add_gaussian_noise(clean, 17.0, 5, bit_depth=12)[0])

    # camera, absolute photons
    cam_spec = NoiseSpec(model="camera", camera=CAM)
    img, info = apply_noise(clean * 500.0, cam_spec, 8)
    np.testing.assert_array_equal(img, CAM.expose(clean * 500.0, 8))
    assert info["photons_per_unit"] == 1.0 and info["exposure_s"] is None

    # camera, relative image scaled by photon rate and frame rate
    spec = NoiseSpec(model="camera", camera=CAM, fps=2000.0, photon_rate_per_s=4e5)
    img, info = apply_noise(clean, spec, 8)
    assert info["photons_per_unit"] * np.percentile(clean, 99.9) == pytest.approx(200.0)
    assert info["photons_p999"] == pytest.approx(200.0)
    assert info["exposure_s"] == pytest.approx(5e-4)
    assert info["snr"] == pytest.approx(0.5 * 160 / math.sqrt(0.25 * (160 + 4) + 1 / 12))
    clean_dn = info["scale_dn_per_unit"] * clean + info["offset_dn"]
    np.testing.assert_allclose(img.mean(), clean_dn.mean(), atol=0.02)
    # doubling the frame rate halves the photons (and lowers the SNR)
    _, info2 = apply_noise(clean, NoiseSpec(**{**spec.__dict__, "fps": 4000.0}), 8)
    assert info2["photons_p999"] == pytest.approx(100.0)
    assert info2["snr"] < info["snr"]


# -- bad input -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda c: add_gaussian_noise(c, 0.0, 0), "snr"),
        (lambda c: add_gaussian_noise(c, -3.0, 0), "snr"),
        (lambda c: add_gaussian_noise(c, math.nan, 0), "snr"),
        (lambda c: add_gaussian_noise(c, math.inf, 0), "snr"),
        (lambda c: add_gaussian_noise(c, 10.0, 0, bit_depth=10), "bit_depth"),
        (lambda c: add_gaussian_noise(c, 10.0, 0, fill=1.5), "fill"),
        (lambda c: add_gaussian_noise(c, 10.0, None), "rng"),
        (lambda c: add_gaussian_noise(np.where(c > 0.5, np.nan, c), 10.0, 0), "clean"),
        (lambda c: add_gaussian_noise(-c, 10.0, 0), "clean"),
        (lambda c: add_gaussian_noise(np.zeros_like(c), 10.0, 0), "clean"),
        (lambda c: add_gaussian_noise(c[None], 10.0, 0), "clean"),
        (lambda c: NoiseSpec(model="poisson"), "model"),
        (lambda c: NoiseSpec(model="gaussian"), "snr"),
        (lambda c: NoiseSpec(model="camera", fps=100.0), "photon_rate_per_s"),
        (lambda c: NoiseSpec(model="camera", bit_depth=8), "bit_depth"),
        (lambda c: NoiseSpec.from_dict({"model": "gaussian", "snr": 5, "sigma": 2}), "sigma"),
        (lambda c: NoiseSpec.from_dict({"model": "camera", "camera": {"qe": 0.5}}), "qe"),
    ],
)
def test_bad_input_names_parameter(clean, call, name):
    with pytest.raises(ConfigError, match=name):
        call(clean)
