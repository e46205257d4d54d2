"""The benchmark's alternative projectors compute the same H and Hᵀ as production."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "projector_candidates.py"


def _module():
    spec = importlib.util.spec_from_file_location("projector_candidates", PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_candidates_match_production(small_bank, small_projector, rng):
    mod = _module()
    fft = mod.FFTProjector(small_bank, (20, 20))
    ad = mod.ADTransposeProjector(small_bank, (20, 20))
    x = rng.random(small_projector.volume_shape).astype(np.float32)
    y = rng.random(small_projector.image_shape).astype(np.float32)
    hx, hty = small_projector.forward(x), small_projector.backward(y)
    np.testing.assert_allclose(fft.forward(x), hx, rtol=0, atol=1e-5 * hx.max())
    np.testing.assert_allclose(fft.backward(y), hty, rtol=0, atol=1e-5 * hty.max())
    np.testing.assert_allclose(ad.backward(y), hty, rtol=0, atol=1e-5 * hty.max())
    # and each is an exact adjoint on its own
    lhs = np.dot(fft.forward(x).ravel().astype(np.float64), y.ravel())
    rhs = np.dot(x.ravel().astype(np.float64), fft.backward(y).ravel())
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)
