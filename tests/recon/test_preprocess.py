"""recon.preprocess: the SNR of a camera frame."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.preprocess import Preprocess


def test_frame_snr_follows_the_simulator_definition():
    """SNR = S / σ with S the 99.9th percentile above the median and σ the noise at S:
    additive noise measured on the frame, the shot noise of S from the camera gain."""
    from recon.preprocess import frame_snr

    rng = np.random.default_rng(4)
    clean = np.zeros((400, 400))
    clean[rng.integers(0, 400, 300), rng.integers(0, 400, 300)] = 200.0  # sparse spots
    clean = np.maximum(clean, np.roll(clean, 1, 0))  # 2-px spots: > 0.1 % of the pixels
    img = 100.0 + clean + rng.normal(0.0, 4.0, clean.shape)  # black level + read noise
    got = frame_snr(img)
    assert got["signal_dn"] == pytest.approx(200.0, rel=0.05)
    assert got["noise_dn"] == pytest.approx(4.0, rel=0.05)
    assert got["snr"] == pytest.approx(50.0, rel=0.08)
    with_shot = frame_snr(img, gain_dn_per_e=0.5)  # σ² = 16 + 0.5 × 200
    assert with_shot["noise_dn"] == pytest.approx(np.sqrt(16 + 100), rel=0.05)
    assert frame_snr(100.0 + clean)["snr"] is None  # a noise-free rendering


def test_gain_is_checked_and_recorded_only_when_set():
    assert "gain_dn_per_e" not in Preprocess().to_dict()  # earlier runs' records resume
    assert Preprocess(gain_dn_per_e=0.25).to_dict()["gain_dn_per_e"] == 0.25
    for bad in (-1.0, float("nan"), "0.3", True):
        with pytest.raises(InputError, match="gain_dn_per_e must be a finite number >= 0"):
            Preprocess(gain_dn_per_e=bad)
