"""Alternative light-field projectors, kept to measure against the production one.

Three formulations of the projector, all exact adjoints, are measured per backend; the
production one (Dr.Jit gathers over the sparse PSF bank,
``recon.projector.LightFieldProjector``) is the fastest on the CPU; these are the two others,
run by ``benchmarks/bench_projectors.py`` and checked by
``tests/recon/test_projector_candidates.py``:

- :class:`ADTransposeProjector` — ``Hᵀ`` obtained by Dr.Jit's reverse-mode automatic
  differentiation of ``H`` (exact by construction; the gathers become scatter-adds).
- :class:`FFTProjector` — ``scipy.fft`` with frequency-domain accumulation: with the volume
  channel ``V_c`` placed as impulses at lenslet corners, ``H x = F⁻¹ Σ_c P̂_c · tile(F V_c)``
  (the spectrum of an array with zeros inserted between samples is the small spectrum
  tiled), and ``Hᵀ y`` folds ``conj(P̂_c) · F y`` back onto the lenslet grid. Patterns'
  spectra ``P̂_c`` are computed on the fly (storing all of them takes tens of GB at the
  paper's size).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from recon.projector import LightFieldProjector


class ADTransposeProjector(LightFieldProjector):
    """``H`` as in production; ``Hᵀ`` by reverse-mode AD of ``H``."""

    def backward_dr(self, polyphase):
        import drjit as dr
        import mitsuba as mi

        x = dr.opaque(mi.Float, 0.0, self.n_channels * self.nx * self.ny)
        dr.enable_grad(x)
        y = self.forward_dr(x)
        dr.backward(dr.sum(y * dr.detach(polyphase)))
        g = dr.grad(x)
        dr.eval(g)
        return dr.detach(g)


class FFTProjector:
    """``H`` and ``Hᵀ`` with FFTs on the padded image (see the module docstring)."""

    def __init__(self, bank, n_lenslets: tuple[int, int], workers: int = -1):
        self.bank = bank
        self.nx, self.ny = n_lenslets
        self.n, self.s = bank.n, bank.s
        self.nz = len(bank.depths_um)
        self.workers = workers
        qmax = max(int(np.abs(bank.dy).max()), int(np.abs(bank.dx).max())) // self.n + 2
        self.pad = qmax  # lenslets of padding on each side: no circular wrap-around
        self.gy, self.gx = self.ny + 2 * qmax, self.nx + 2 * qmax
        self.shape = (self.gy * self.n, self.gx * self.n)
        self._proj = LightFieldProjector.__new__(LightFieldProjector)
        self._proj.nx, self._proj.ny, self._proj.n, self._proj.s = self.nx, self.ny, self.n, self.s
        self._proj.nz = self.nz

    @property
    def volume_shape(self):
        return (self.nz, self.ny * self.s, self.nx * self.s)

    @property
    def image_shape(self):
        return (self.ny * self.n, self.nx * self.n)

    def _pattern_hat(self, c: int) -> np.ndarray:
        dy, dx, w = self.bank.pattern(c)
        img = np.zeros(self.shape, np.float64)
        img[dy % self.shape[0], dx % self.shape[1]] = w
        return sfft.rfft2(img, workers=self.workers)

    def _channels(self, vol: np.ndarray) -> np.ndarray:
        s = self.s
        v = vol.reshape(self.nz, self.ny, s, self.nx, s).transpose(0, 2, 4, 1, 3)
        return v.reshape(self.nz * s * s, self.ny, self.nx)

    def forward(self, volume: np.ndarray) -> np.ndarray:
        n, p = self.n, self.pad
        acc = np.zeros((self.shape[0], self.shape[1] // 2 + 1), np.complex128)
        small = np.zeros((self.gy, self.gx))
        for c, vc in enumerate(self._channels(np.asarray(volume, np.float64))):
            if not vc.any():
                continue
            small[p : p + self.ny, p : p + self.nx] = vc
            tiled = np.tile(sfft.fft2(small, workers=self.workers), (n, n))
            acc += self._pattern_hat(c) * tiled[:, : acc.shape[1]]
        img = sfft.irfft2(acc, s=self.shape, workers=self.workers)
        return img[p * n : (p + self.ny) * n, p * n : (p + self.nx) * n].astype(np.float32)

    def backward(self, image: np.ndarray) -> np.ndarray:
        n, p = self.n, self.pad
        big = np.zeros(self.shape)
        big[p * n : (p + self.ny) * n, p * n : (p + self.nx) * n] = image
        yhat = sfft.fft2(big, workers=self.workers)
        out = np.zeros((self.bank.n_channels, self.ny, self.nx))
        for c in range(self.bank.n_channels):
            ph = self._pattern_hat(c)
            full = np.empty(self.shape, np.complex128)
            full[:, : ph.shape[1]] = ph
            # Hermitian completion of the half spectrum of a real pattern.
            k = self.shape[1] - ph.shape[1]
            if k > 0:
                full[:, ph.shape[1] :] = np.conj(
                    ph[(-np.arange(self.shape[0])) % self.shape[0]][:, 1 : k + 1][:, ::-1]
                )
            prod = np.conj(full) * yhat
            folded = prod.reshape(n, self.gy, n, self.gx).sum(axis=(0, 2)) / (n * n)
            small = sfft.ifft2(folded, workers=self.workers).real
            out[c] = small[p : p + self.ny, p : p + self.nx]
        s = self.s
        vol = out.reshape(self.nz, s, s, self.ny, self.nx).transpose(0, 3, 1, 4, 2)
        return vol.reshape(self.volume_shape).astype(np.float32)
