"""Detection on several threads: the same numbers for any thread count, the deconvolution's
operator reused between the frames of a series, and ``HRVPTM_THREADS`` checked."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from track import deconvolve as dc
from track._threads import compute_threads, gaussian_filter, maximum_filter3
from track.errors import InputError


@pytest.mark.parametrize("shape", [(9, 21, 30), (1, 5, 40), (30, 2, 3)])
def test_threaded_filters_are_bit_identical_to_scipy(shape):
    rng = np.random.default_rng(3)
    a = rng.random(shape, dtype=np.float32)
    for sigma, mode in (
        ((2.5, 1.0, 0.7), "nearest"),
        (0.7, "reflect"),
        ((0.0, 3.0, 1.5), "nearest"),
    ):
        ref = ndimage.gaussian_filter(a, sigma, mode=mode)
        for threads in (1, 2, 3):
            got = gaussian_filter(a, sigma, mode=mode, threads=threads)
            assert got.dtype == a.dtype and np.array_equal(got, ref)
    b = a.astype(np.float64)
    for threads in (1, 2, 3):
        np.testing.assert_array_equal(
            maximum_filter3(b, mode="nearest", threads=threads),
            ndimage.maximum_filter(b, size=3, mode="nearest"),
        )


def test_deconvolution_same_for_any_thread_count_and_operator_reused(monkeypatch):
    rng = np.random.default_rng(4)
    vol = rng.random((24, 20, 18)).astype(np.float32)
    psf = np.exp(
        -0.5 * np.sum(np.mgrid[-4:5, -2:3, -2:3] ** 2 / [[[[4.0]]], [[[1.0]]], [[[1.0]]]], 0)
    )
    monkeypatch.setenv("HRVPTM_THREADS", "1")
    one = dc.deconvolve(vol, psf, dc.DeconvolveSettings(3))
    conv = dc._LAST["conv"]
    again = dc.deconvolve(vol * 2, psf, dc.DeconvolveSettings(3))
    assert dc._LAST["conv"] is conv  # same shape and PSF: the kernel's transform is reused
    monkeypatch.setenv("HRVPTM_THREADS", "2")
    two = dc.deconvolve(vol, psf, dc.DeconvolveSettings(3))
    np.testing.assert_array_equal(one, two)  # bit for bit
    np.testing.assert_allclose(again, 2 * one, rtol=1e-4, atol=1e-6)  # RL is scale-covariant
    other = dc.deconvolve(
        vol, psf[::-1].copy() + 0.01, dc.DeconvolveSettings(3)
    )  # another PSF: a new operator
    assert dc._LAST["conv"] is not conv and not np.array_equal(other, one)


def test_deconvolution_operator_matches_zero_padded_linear_convolution():
    """The circular transforms of the extended size are the linear convolution."""
    from scipy.signal import fftconvolve

    rng = np.random.default_rng(6)
    kernel = rng.random((5, 3, 7))
    conv = dc._Convolver((11, 8, 9), kernel, threads=1)
    x = rng.random(conv.ext_shape)
    full = fftconvolve(x, kernel, mode="same")
    np.testing.assert_allclose(conv.forward(x), full[conv.inner], rtol=1e-10, atol=1e-12)
    r = rng.random((11, 8, 9))
    ext = np.zeros(conv.ext_shape)
    ext[conv.inner] = r
    adj = fftconvolve(ext, kernel[::-1, ::-1, ::-1], mode="same")
    np.testing.assert_allclose(conv.adjoint(r), adj, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("value", ["0", "two", "-1"])
def test_bad_hrvptm_threads_is_named(monkeypatch, value):
    monkeypatch.setenv("HRVPTM_THREADS", value)
    with pytest.raises(InputError, match=f"HRVPTM_THREADS must be an integer >= 1, got '{value}'"):
        compute_threads()


def test_compute_threads_default_and_env(monkeypatch):
    monkeypatch.delenv("HRVPTM_THREADS", raising=False)
    assert compute_threads() >= 1
    monkeypatch.setenv("HRVPTM_THREADS", "3")
    assert compute_threads() == 3
