"""Shared helpers for the :mod:`track` tests: synthetic volumes of anisotropic Gaussian blobs.

Light-field reconstructions of small particles look like Gaussians elongated along z; the
blobs here use ``σ = (σz, σy, σx)`` in voxels, e.g. ``(2.5, 1.2, 1.2)``.
"""

from __future__ import annotations

import numpy as np
import pytest


def render_blobs(shape, centres_vox, sigma_vox, amplitudes=1.0, background=0.0):
    """Noise-free volume (float64) of Gaussian blobs at sub-voxel centres ``(z, y, x)``."""
    vol = np.full(shape, float(background))
    centres = np.atleast_2d(np.asarray(centres_vox, dtype=float))
    amps = np.broadcast_to(np.asarray(amplitudes, dtype=float), (centres.shape[0],))
    sig = np.asarray(sigma_vox, dtype=float)
    reach = np.ceil(5 * sig).astype(int)
    for c, a in zip(centres, amps, strict=True):
        lo = np.maximum(np.floor(c).astype(int) - reach, 0)
        hi = np.minimum(np.floor(c).astype(int) + reach + 1, shape)
        axes = [(np.arange(lo[i], hi[i]) - c[i]) / sig[i] for i in range(3)]
        g = [np.exp(-0.5 * t**2) for t in axes]
        vol[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] += (
            a * g[0][:, None, None] * g[1][None, :, None] * g[2][None, None, :]
        )
    return vol


def random_centres(rng, shape, n, min_sep_vox, margin_vox):
    """``n`` random sub-voxel centres with per-axis-scaled separation ≥ 1 and margins."""
    shape = np.asarray(shape, dtype=float)
    margin = np.asarray(margin_vox, dtype=float)
    sep = np.asarray(min_sep_vox, dtype=float)
    out = []
    for _ in range(100000):
        c = margin + rng.uniform(0, 1, 3) * (shape - 1 - 2 * margin)
        if all(np.max(np.abs(c - o) / sep) >= 1.0 for o in out):
            out.append(c)
            if len(out) == n:
                return np.array(out)
    raise RuntimeError("could not place the requested number of blobs")


@pytest.fixture
def rng():
    """A fresh seeded generator per test."""
    return np.random.default_rng(20240601)
