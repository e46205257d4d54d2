"""Noise and camera models (lfsim.camera) against theory.

SNR throughout is the paper's ``P99.9(clean image) / sigma_noise`` (P99.9 = 99.9th percentile of
the noise-free image). All random draws are seeded.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from lfsim.camera import (
    NOISE_MODELS,
    CameraModel,
    NoiseSpec,
    add_gaussian_noise,
    apply_noise,
    exposure_s,
    measure_snr,
    photons_per_frame,
    scale_to_dn,
    snr_vs_fps,
)
from lfsim.errors import ConfigError

FULL = {8: 255, 12: 4095, 16: 65535}
DTYPE = {8: np.uint8, 12: np.uint16, 16: np.uint16}


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
    with caplog.at_level(logging.WARNING, logger="lfsim.camera"):
        _, info = add_gaussian_noise(clean, 1000.0, 0, bit_depth=8)
    assert info["sigma_dn"] < 0.5
    assert any("quantisation" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="lfsim.camera"):
        add_gaussian_noise(clean, 1000.0, 0, bit_depth=16)
    assert not caplog.records


def test_scale_to_dn_no_noise(clean):
    img, info = scale_to_dn(clean, bit_depth=12)
    assert img.dtype == np.uint16
    assert info["sigma_dn"] == 0.0 and info["offset_dn"] == 0.0
    np.testing.assert_array_equal(img, np.rint(info["scale_dn_per_unit"] * clean))
    assert img.max() == round(0.7 * 4095)


# -- the physical camera -------------------------------------------------------------------
CAM = CameraModel(
    quantum_efficiency=0.8,
    read_noise_e=2.0,
    gain_dn_per_e=0.5,
    offset_dn=100.0,
    bit_depth=12,
    full_well_e=10_000.0,
)


@pytest.mark.parametrize("n_photons", [0.0, 10.0, 100.0, 1000.0])
def test_camera_flat_field_statistics(n_photons):
    n = 200 * 200
    img = CAM.expose(np.full((200, 200), n_photons), np.random.default_rng(int(n_photons) + 5))
    assert img.dtype == np.uint16 and img.shape == (200, 200)
    x = img.astype(np.float64)
    # analytic: electrons ~ Poisson(QE·N), + N(0, σ_read²), × gain, + offset, rounded
    electrons = 0.8 * n_photons
    mean_th = 0.5 * electrons + 100.0
    var_th = 0.5**2 * (electrons + 2.0**2) + 1 / 12  # shot + read noise + rounding
    assert abs(x.mean() - mean_th) < 4 * math.sqrt(var_th / n)
    assert abs(x.var(ddof=1) - var_th) < 4 * var_th * math.sqrt(2 / (n - 1))
    # the model's formulas are these
    assert CAM.mean_dn(n_photons) == pytest.approx(mean_th, rel=1e-12)
    assert CAM.variance_dn(n_photons) == pytest.approx(var_th, rel=1e-12)
    # the measured SNR of the flat field is the analytic one
    if n_photons > 0:
        snr = (x.mean() - CAM.offset_dn) / x.std()
        snr_th = 0.5 * electrons / math.sqrt(var_th)
        assert snr == pytest.approx(snr_th, rel=0.02)
        assert CAM.snr(n_photons) == pytest.approx(snr_th, rel=1e-12)


def test_camera_quantisation_term_matters():
    """1/12 DN² is resolved: at low read noise the measured variance needs it."""
    cam = CameraModel(read_noise_e=1.0, gain_dn_per_e=1.0, offset_dn=20.0, bit_depth=8)
    x = cam.expose(np.zeros((300, 300)), 3).astype(np.float64)
    n = x.size
    var_th = 1.0**2 * 1.0**2 + 1 / 12  # (gain · read noise)² + rounding
    assert abs(x.var(ddof=1) - var_th) < 4 * var_th * math.sqrt(2 / (n - 1))
    assert abs(x.var(ddof=1) - 1.0) > 0.04  # without the 1/12 DN² the variance is off
    assert cam.variance_dn(0.0) == pytest.approx(var_th, rel=1e-12)
    assert cam.variance_dn(0.0, quantisation=False) == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("bit_depth", [8, 12, 16])
def test_camera_saturation_and_dtype(bit_depth):
    cam = CameraModel(bit_depth=bit_depth, full_well_e=None, gain_dn_per_e=1.0, offset_dn=10.0)
    photons = np.array([[0.0, 1e9], [1e12, 50.0]])
    img = cam.expose(photons, 0)
    assert img.dtype == DTYPE[bit_depth]
    assert img[0, 1] == FULL[bit_depth] and img[1, 0] == FULL[bit_depth]
    assert img[0, 0] < FULL[bit_depth] and img[1, 1] < FULL[bit_depth]


def test_camera_full_well_clips_electrons():
    cam = CameraModel(read_noise_e=0.0, gain_dn_per_e=0.1, offset_dn=0.0, full_well_e=1000.0)
    img = cam.expose(np.full((50, 50), 1e6), 0)
    np.testing.assert_array_equal(img, 100)  # 1000 e- x 0.1 DN/e-, below ADC saturation


def test_camera_seeding():
    ph = np.full((64, 64), 30.0)
    np.testing.assert_array_equal(CAM.expose(ph, 9), CAM.expose(ph, np.random.default_rng(9)))
    assert np.any(CAM.expose(ph, 9) != CAM.expose(ph, 10))


# -- exposure and frame rate ---------------------------------------------------------------
def test_exposure_follows_frame_rate():
    assert exposure_s(1000.0) == pytest.approx(1e-3)
    assert exposure_s(1000.0, duty_cycle=0.5) == pytest.approx(5e-4)
    assert photons_per_frame(1e6, 200.0) == pytest.approx(2 * photons_per_frame(1e6, 400.0))
    assert photons_per_frame(1e6, 1000.0, 0.25) == pytest.approx(250.0)


def test_snr_falls_as_fps_rises():
    fps = np.array([100, 250, 500, 1000, 2500, 5000, 10_000, 25_000], dtype=float)
    snr = snr_vs_fps(CAM, 2e6, fps)
    assert snr.shape == fps.shape
    assert np.all(np.diff(snr) < 0)
    # analytic: QE·N electrons over the shot, read (2 e-) and rounding (1/12 DN² at 0.5 DN/e-)
    # noise, with N = rate / fps photons per frame
    e = 0.8 * 2e6 / fps
    np.testing.assert_allclose(snr, e / np.sqrt(e + 2.0**2 + (1 / 12) / 0.5**2), rtol=1e-12)
    # shot-noise limit at low fps: SNR ≈ sqrt(QE · photons)
    assert snr[0] == pytest.approx(math.sqrt(0.8 * 2e4), rel=0.01)
    # at 25 kfps 80 photons, 64 e- against 2 e- read noise
    assert snr[-1] == pytest.approx(64 / math.sqrt(64 + 4 + (1 / 12) / 0.25), rel=1e-9)


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
        (lambda c: CameraModel(quantum_efficiency=1.5), "quantum_efficiency"),
        (lambda c: CameraModel(quantum_efficiency=0.0), "quantum_efficiency"),
        (lambda c: CameraModel(read_noise_e=-1.0), "read_noise_e"),
        (lambda c: CameraModel(gain_dn_per_e=0.0), "gain_dn_per_e"),
        (lambda c: CameraModel(bit_depth=10), "bit_depth"),
        (lambda c: CameraModel(full_well_e=-5.0), "full_well_e"),
        (lambda c: CAM.expose(-c, 0), "photons"),
        (lambda c: exposure_s(0.0), "fps"),
        (lambda c: exposure_s(100.0, duty_cycle=1.2), "duty_cycle"),
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


def test_tracer_counts_are_thinned_not_shot_noised_twice():
    """Integer photon counts already carry shot noise: the camera thins them (binomial)."""
    cam = CameraModel(
        quantum_efficiency=0.8, read_noise_e=0.0, gain_dn_per_e=1.0, offset_dn=0.0, bit_depth=16
    )
    rng = np.random.default_rng(5)
    lam = 200.0
    counts = rng.poisson(lam, size=(300, 300)).astype(np.uint32)  # a tracer's photon counts
    ppc = 0.5  # each traced ray stands for half a real photon
    dn = cam.expose_counts(counts, ppc, rng).astype(np.float64)
    mean = 0.8 * ppc * lam
    assert dn.mean() == pytest.approx(mean, rel=0.005)
    # Poisson statistics (+ 1/12 DN² of rounding), not the doubled variance of re-sampling.
    assert dn.var() == pytest.approx(mean + 1 / 12, rel=0.03)
    doubled = cam.expose(ppc * counts.astype(np.float64), rng).astype(np.float64)
    assert doubled.var() > 1.3 * dn.var()
    # apply_noise routes integer images through the thinning path.
    spec = NoiseSpec(model="camera", camera=cam)
    img, info = apply_noise(counts, spec, 1)
    assert info["shot_noise"].startswith("binomial")
    assert img.astype(float).var() == pytest.approx(0.8 * lam + 1 / 12, rel=0.03)
    with pytest.raises(ConfigError, match="counts"):
        cam.expose_counts(counts.astype(float), 1.0, rng)
