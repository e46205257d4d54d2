"""The physical camera (lfsim.camera) against theory: shot and read noise, gain, offset,
quantisation, saturation, exposure from the frame rate. All random draws are seeded.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lfsim.camera import CameraModel, exposure_s, photons_per_frame, snr_vs_fps
from lfsim.errors import ConfigError
from lfsim.noise import NoiseSpec, apply_noise

from .shared import CAM, DTYPE, FULL


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


# -- bad input -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda c: CameraModel(quantum_efficiency=1.5), "quantum_efficiency"),
        (lambda c: CameraModel(quantum_efficiency=0.0), "quantum_efficiency"),
        (lambda c: CameraModel(read_noise_e=-1.0), "read_noise_e"),
        (lambda c: CameraModel(gain_dn_per_e=0.0), "gain_dn_per_e"),
        (lambda c: CameraModel(bit_depth=10), "bit_depth"),
        (lambda c: CameraModel(full_well_e=-5.0), "full_well_e"),
        (lambda c: CAM.expose(-c, 0), "photons"),
        (lambda c: exposure_s(0.0), "fps"),
        (lambda c: exposure_s(100.0, duty_cycle=1.2), "duty_cycle"),
    ],
)
def test_bad_input_names_parameter(call, name):
    with pytest.raises(ConfigError, match=name):
        call(np.ones((4, 4)))


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
