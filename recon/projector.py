"""Forward and backward light-field projection on Dr.Jit, exploiting lenslet periodicity.

With the image in *polyphase* layout ``Y[r, v, u]`` (pixel ``(v·n + ry, u·n + rx)`` of
lenslet ``(u, v)``, residue ``r = ry·n + rx``) and the volume as channels ``V[c, v, u]``
(channel ``c`` = depth and sub-lenslet position, see :class:`recon.psf.PSFBank`), a pattern
entry ``(c, dy, dx, w)`` with ``dy = qy·n + ry`` and ``dx = qx·n + rx`` links voxel
``(c, v, u)`` to pixel ``(r, v + qy, u + qx)``. Then

- forward ``H``:  ``Y[r, v, u] = Σ_{e ∈ E_r} w_e · V[c_e, v − qy_e, u − qx_e]``
- backward ``Hᵀ``: ``V[c, v, u] = Σ_{e ∈ E_c} w_e · Y[r_e, v + qy_e, u + qx_e]``

over the same set of terms (a term exists when both the voxel and the pixel are inside the
grid), so ``Hᵀ`` is the exact transpose of ``H``. Both are pure gathers — one Dr.Jit thread
per output element looping over its entry list — with no atomics: deterministic, and the same
code runs on the LLVM (CPU) and CUDA (GPU) backends. The operation count is
``nnz(bank) × n_lenslets`` multiply-adds per projection, the minimum for this model.

Entries are packed as ``c | (qy + 128) << 16 | (qx + 128) << 24`` in one 32-bit word
(``c < 65 536`` channels, shifts within ±127 lenslets).
"""

from __future__ import annotations

import logging

import numpy as np

from .errors import InputError
from .psf import PSFBank

log = logging.getLogger(__name__)


def _dr_types():
    import drjit as dr
    import mitsuba as mi

    from lfsim.backend import backend_info, init_backend

    if backend_info() is None:
        init_backend()
    return dr, mi.Float, mi.UInt32, mi.Int32


class LightFieldProjector:
    """``H`` and ``Hᵀ`` of a PSF bank over a grid of ``(nx, ny)`` lenslets.

    Parameters
    ----------
    bank : PSFBank
    n_lenslets : tuple of int
        ``(nx, ny)`` lenslets of the rectified image (image ``(ny·n, nx·n)`` pixels).

    Notes
    -----
    Volumes are ``(nz, ny·s, nx·s)`` float32 and images ``(ny·n, nx·n)`` float32 numpy
    arrays at the interface; :meth:`forward_dr` / :meth:`backward_dr` work on flat Dr.Jit
    arrays in the internal layouts and are what the iterative solvers call.
    """

    def __init__(self, bank: PSFBank, n_lenslets: tuple[int, int]):
        self.bank = bank
        self.nx, self.ny = (int(v) for v in n_lenslets)
        if self.nx < 1 or self.ny < 1:
            raise InputError(f"n_lenslets must be positive, got {n_lenslets!r}")
        self.n, self.s = bank.n, bank.s
        self.nz = len(bank.depths_um)
        self.n_channels = bank.n_channels
        self.n_res = self.n * self.n
        if self.n_channels >= 1 << 16 or self.n_res >= 1 << 16:
            raise InputError("PSF bank too large for the packed projector (>= 65 536 channels)")
        dr, Float, UInt32, _ = _dr_types()
        self._dr = dr
        c = np.repeat(np.arange(self.n_channels, dtype=np.int64), np.diff(bank.offsets))
        qy, ry = np.divmod(bank.dy.astype(np.int64), self.n)
        qx, rx = np.divmod(bank.dx.astype(np.int64), self.n)
        if max(np.abs(qy).max(initial=0), np.abs(qx).max(initial=0)) > 127:
            raise InputError("PSF patterns wider than ±127 lenslets are not supported")
        r = ry * self.n + rx
        shift = ((qy + 128) << 16) | ((qx + 128) << 24)
        # Forward table: entries grouped by output residue r.
        order = np.argsort(r, kind="stable")
        self._f_word = UInt32((c[order] | shift[order]).astype(np.uint32))
        self._f_w = Float(bank.w[order].astype(np.float32))
        self._f_off = UInt32(np.searchsorted(r[order], np.arange(self.n_res + 1)).astype(np.uint32))
        # Backward table: entries grouped by channel c (the bank's own order).
        self._b_word = UInt32((r | shift).astype(np.uint32))
        self._b_w = Float(bank.w.astype(np.float32))
        self._b_off = UInt32(bank.offsets.astype(np.uint32))
        self.macs_per_projection = int(bank.nnz) * self.nx * self.ny

    # -- shapes ---------------------------------------------------------------------------
    @property
    def volume_shape(self) -> tuple[int, int, int]:
        return (self.nz, self.ny * self.s, self.nx * self.s)

    @property
    def image_shape(self) -> tuple[int, int]:
        return (self.ny * self.n, self.nx * self.n)

    # -- layout conversions (numpy) -------------------------------------------------------
    def volume_to_channels(self, vol: np.ndarray) -> np.ndarray:
        """``(nz, ny·s, nx·s)`` → flat ``[c, v, u]`` with ``c = k s² + b s + a``."""
        s = self.s
        v = np.asarray(vol, dtype=np.float32).reshape(self.nz, self.ny, s, self.nx, s)
        return np.ascontiguousarray(v.transpose(0, 2, 4, 1, 3)).ravel()

    def channels_to_volume(self, flat: np.ndarray) -> np.ndarray:
        s = self.s
        v = np.asarray(flat, dtype=np.float32).reshape(self.nz, s, s, self.ny, self.nx)
        return np.ascontiguousarray(v.transpose(0, 3, 1, 4, 2)).reshape(self.volume_shape)

    def image_to_polyphase(self, img: np.ndarray) -> np.ndarray:
        """``(ny·n, nx·n)`` → flat ``[ry·n + rx, v, u]``."""
        n = self.n
        a = np.asarray(img, dtype=np.float32).reshape(self.ny, n, self.nx, n)
        return np.ascontiguousarray(a.transpose(1, 3, 0, 2)).ravel()

    def polyphase_to_image(self, flat: np.ndarray) -> np.ndarray:
        n = self.n
        a = np.asarray(flat, dtype=np.float32).reshape(n, n, self.ny, self.nx)
        return np.ascontiguousarray(a.transpose(2, 0, 3, 1)).reshape(self.image_shape)

    # -- projections on Dr.Jit arrays ------------------------------------------------------
    def _project(self, src, word, weight, offsets, n_groups: int, sign: int):
        dr, Float, UInt32, Int32 = _dr_types()
        plane = self.nx * self.ny
        tid = dr.arange(UInt32, n_groups * plane)
        group = tid // plane
        rem = tid - group * plane
        v = Int32(rem // self.nx)
        u = Int32(rem - (rem // self.nx) * self.nx)
        start = dr.gather(UInt32, offsets, group)
        end = dr.gather(UInt32, offsets, group + 1)
        nx, ny = self.nx, self.ny

        def cond(i, acc):
            return i < end

        def body(i, acc):
            wd = dr.gather(UInt32, word, i)
            wt = dr.gather(Float, weight, i)
            other = wd & 0xFFFF
            qy = Int32((wd >> 16) & 0xFF) - 128
            qx = Int32(wd >> 24) - 128
            y = v - qy if sign < 0 else v + qy
            x = u - qx if sign < 0 else u + qx
            ok = (y >= 0) & (y < ny) & (x >= 0) & (x < nx)
            idx = other * plane + UInt32(dr.select(ok, y * nx + x, 0))
            acc = dr.fma(wt, dr.gather(Float, src, idx, ok), acc)
            return i + 1, acc

        # max_iterations=-1: the loop is a plain sum over entries, which lets Dr.Jit
        # differentiate it in reverse mode without storing its trajectory.
        _, acc = dr.while_loop(
            (start, dr.zeros(Float, n_groups * plane)), cond, body, max_iterations=-1
        )
        return acc

    def forward_dr(self, channels):
        """``H``: flat volume channels (Dr.Jit Float) → flat polyphase image."""
        return self._project(channels, self._f_word, self._f_w, self._f_off, self.n_res, -1)

    def backward_dr(self, polyphase):
        """``Hᵀ``: flat polyphase image (Dr.Jit Float) → flat volume channels."""
        return self._project(polyphase, self._b_word, self._b_w, self._b_off, self.n_channels, +1)

    # -- numpy interface -------------------------------------------------------------------
    def forward(self, volume: np.ndarray) -> np.ndarray:
        """``H x``: volume ``(nz, ny·s, nx·s)`` → light-field image ``(ny·n, nx·n)``."""
        vol = np.asarray(volume)
        if vol.shape != self.volume_shape:
            raise InputError(f"volume shape {vol.shape} != projector's {self.volume_shape}")
        dr, Float, _, _ = _dr_types()
        out = self.forward_dr(Float(self.volume_to_channels(vol)))
        dr.eval(out)
        return self.polyphase_to_image(out.numpy())

    def backward(self, image: np.ndarray) -> np.ndarray:
        """``Hᵀ y``: image ``(ny·n, nx·n)`` → volume ``(nz, ny·s, nx·s)``."""
        img = np.asarray(image)
        if img.shape != self.image_shape:
            raise InputError(f"image shape {img.shape} != projector's {self.image_shape}")
        dr, Float, _, _ = _dr_types()
        out = self.backward_dr(Float(self.image_to_polyphase(img)))
        dr.eval(out)
        return self.channels_to_volume(out.numpy())
