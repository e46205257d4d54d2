"""Depth-adaptive anti-aliasing filter for light-field deconvolution (Stefanoiu et al. 2019).

A light field samples each depth of the object at a different rate, so a volume estimate on a
uniform voxel grid develops aliasing artefacts (grid patterns) wherever the grid is finer
than what the light field can resolve at that depth. Stefanoiu, Page, Symvoulidis, Westmeyer
& Lasser (Opt. Express 27, 2019) low-pass filter every depth of the estimate after each
Richardson–Lucy update with a Lanczos-windowed sinc whose width follows the depth; the
paper's "Lanczos filter width" (2) is the window parameter ``a``.

The cut-off used here, in cycles per lateral voxel, is derived from the optics:

- **geometric sampling** — a point at depth ``z`` images ``D = M² |z|`` from the array and is
  seen by about ``D / f_l`` lenslets per axis, whose views interleave: the light field samples
  that plane every ``p · f_l / D`` (intermediate-image units), never coarser than one lenslet
  ``p``. In voxels (``s`` per lenslet) the resolvable period is ``T = s · min(1, f_l / D)``
  and the cut-off ``1 / T``.
- **diffraction** — the band limit of Broxton et al. (2013), the paper's Eq. 2,
  ``ν(z) = p / (0.94 λ M |z|)`` cycles per µm in object space, i.e. ``ν · p / (M s)`` cycles
  per voxel.

The filter passes everything up to the lower of the two, and nothing is done where that is at
or above the grid's Nyquist frequency (0.5 cycles per voxel).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .errors import InputError


def cutoff_cycles_per_voxel(optics, depths_um, s: int) -> np.ndarray:
    """Lateral cut-off frequency (cycles / voxel) of every depth, capped at 0.5.

    Parameters
    ----------
    optics : lfsim.optics.Optics
    depths_um : array_like, shape (nz,)
    s : int
        Voxels per lenslet.

    Returns
    -------
    ndarray, shape (nz,)
    """
    # True depths in the specimen → apparent depths (what the optics images).
    z = np.abs(np.asarray(depths_um, dtype=np.float64)) * optics.axial_scale
    d = optics.magnification**2 * z  # image distance from the array (µm)
    with np.errstate(divide="ignore"):
        period = s * np.minimum(1.0, optics.mla_focal_um / np.where(d > 0, d, 1e-30))
        geometric = 1.0 / period
        voxel_um = optics.lenslet_object_um / s
        nu = optics.mla_pitch_um / (0.94 * optics.wavelength_um * optics.magnification * z)
        diffraction = np.where(z > 0, nu * voxel_um, np.inf)
    return np.minimum(0.5, np.minimum(geometric, diffraction))


def lanczos_kernel(cutoff: float, a: float = 2.0) -> np.ndarray:
    """1-D Lanczos-windowed sinc low-pass with cut-off ``cutoff`` cycles/sample, sum 1.

    ``h(x) ∝ sinc(2 f_c x) · sinc(2 f_c x / a)`` for ``|x| < a / (2 f_c)``.
    """
    if not (0 < cutoff <= 0.5):
        raise InputError(f"cutoff must lie in (0, 0.5] cycles per voxel, got {cutoff!r}")
    if a <= 0:
        raise InputError(f"Lanczos window a must be > 0, got {a!r}")
    half = int(np.floor(a / (2 * cutoff)))
    x = np.arange(-half, half + 1, dtype=np.float64)
    h = np.sinc(2 * cutoff * x) * np.sinc(2 * cutoff * x / a)
    return h / h.sum()


class DepthFilter:
    """Per-depth separable Lanczos low-pass of volumes ``(nz, ny, nx)``.

    Parameters
    ----------
    cutoffs : array_like, shape (nz,)
        Cut-off per depth in cycles per voxel (0.5 or more: that depth is left unchanged).
    a : float
        Lanczos window parameter (the paper's "Lanczos filter width", 2).
    """

    def __init__(self, cutoffs, a: float = 2.0):
        self.cutoffs = np.asarray(cutoffs, dtype=np.float64)
        self.a = float(a)
        self.kernels = [
            None if c >= 0.5 else lanczos_kernel(float(c), self.a) for c in self.cutoffs
        ]

    @classmethod
    def for_optics(cls, optics, depths_um, s: int, a: float = 2.0) -> DepthFilter:
        return cls(cutoff_cycles_per_voxel(optics, depths_um, s), a)

    @property
    def active(self) -> bool:
        return any(k is not None for k in self.kernels)

    def __call__(self, volume: np.ndarray) -> np.ndarray:
        """Filter a volume ``(nz, ny, nx)`` (a new array; the input is left as it is).

        Negative ringing is clipped to keep the volume ≥ 0.
        """
        vol = np.asarray(volume, dtype=np.float32)
        if vol.ndim != 3 or vol.shape[0] != len(self.kernels):
            raise InputError(
                f"volume shape {vol.shape} does not match the filter's {len(self.kernels)} depths"
            )
        out = vol.copy()
        for k, h in enumerate(self.kernels):
            if h is not None:
                out[k] = self._filter_plane(vol[k], h)
        return out

    @staticmethod
    def _filter_plane(plane: np.ndarray, h: np.ndarray) -> np.ndarray:
        sl = ndimage.correlate1d(plane, h, axis=0, mode="nearest")
        sl = ndimage.correlate1d(sl, h, axis=1, mode="nearest")
        return np.maximum(sl, 0.0, out=sl)

    def channel_filter(self, projector):
        """This filter on flat volume channels, in the projector's array world.

        Parameters
        ----------
        projector : recon.projector.LightFieldProjector or recon.projector.SparseProjector
            Gives the channel layout (``[c, v, u]`` with ``c = k s² + b s + a``, voxel
            ``(k, v·s + b, u·s + a)``; see :meth:`~recon.projector.LightFieldProjector.
            volume_to_channels`) and the array world (``projector.arrays``).

        Returns
        -------
        callable
            ``f(channels) -> channels``: flat float32 arrays of ``projector.arrays``
            (numpy: scipy.ndimage per depth; Dr.Jit: gathers on the projector's backend),
            equal to :meth:`__call__` on the volume to float32 rounding. The input is left
            as it is.
        """
        if len(self.kernels) != projector.nz:
            raise InputError(
                f"the filter has {len(self.kernels)} depths, the projector {projector.nz}"
            )
        layout = (projector.nz, projector.s, projector.ny, projector.nx)
        if projector.arrays.name == "numpy":
            return lambda flat: self._filter_channels_numpy(flat, *layout)
        return _DrJitChannelFilter(self.kernels, layout, projector.arrays)

    def _filter_channels_numpy(self, flat, nz: int, s: int, ny: int, nx: int) -> np.ndarray:
        ch = np.asarray(flat, dtype=np.float32).reshape(nz, s, s, ny, nx)
        out = np.empty_like(ch)
        for k, h in enumerate(self.kernels):
            if h is None:
                out[k] = ch[k]
                continue
            # channels (b, a, v, u) of depth k -> plane (v·s + b, u·s + a) and back
            plane = ch[k].transpose(2, 0, 3, 1).reshape(ny * s, nx * s)
            sl = self._filter_plane(plane, h)
            out[k] = sl.reshape(ny, s, nx, s).transpose(1, 3, 0, 2)
        return out.ravel()


class _DrJitChannelFilter:
    """The separable per-depth filter as two Dr.Jit gather passes over flat channels.

    One thread per voxel sums its depth's kernel over neighbours along y, then along x, with
    indices clamped at the edges (scipy.ndimage's ``mode="nearest"``); depths without a
    kernel get ``[1]`` (an exact copy). Negative values are clipped at the end.
    """

    def __init__(self, kernels, layout, arrays):
        self.nz, self.s, self.ny, self.nx = layout
        self.arrays = arrays
        full = [np.ones(1) if h is None else h for h in kernels]
        lengths = np.array([len(h) for h in full])
        self._w = arrays.Float(np.concatenate(full).astype(np.float32))
        self._off = arrays.UInt32(np.r_[0, np.cumsum(lengths)].astype(np.uint32))
        self._half = arrays.Int32((lengths // 2).astype(np.int32))

    def _pass(self, src, along_y: bool):
        a = self.arrays
        dr, Float, UInt32, Int32 = a.dr, a.Float, a.UInt32, a.Int32
        s, ny, nx = self.s, self.ny, self.nx
        plane = ny * nx
        s2 = s * s
        tid = dr.arange(UInt32, self.nz * s2 * plane)
        c = tid // plane
        rem = tid - c * plane
        v = rem // nx
        u = rem - v * nx
        k = c // s2
        b = (c - k * s2) // s
        ai = c - k * s2 - b * s
        start = dr.gather(UInt32, self._off, k)
        end = dr.gather(UInt32, self._off, k + 1)
        half = dr.gather(Int32, self._half, k)
        if along_y:
            pos, size = Int32(v * s + b), ny * s
        else:
            pos, size = Int32(u * s + ai), nx * s
        base = k * s2

        def cond(i, acc):
            return i < end

        def body(i, acc):
            q = UInt32(dr.clip(pos + Int32(i - start) - half, 0, size - 1))
            q_lens = q // s
            q_sub = q - q_lens * s
            if along_y:
                idx = (base + q_sub * s + ai) * plane + q_lens * nx + u
            else:
                idx = (base + b * s + q_sub) * plane + v * nx + q_lens
            acc = dr.fma(dr.gather(Float, self._w, i), dr.gather(Float, src, idx), acc)
            return i + 1, acc

        _, acc = dr.while_loop((start, dr.zeros(Float, dr.width(tid))), cond, body)
        return acc

    def __call__(self, flat):
        dr = self.arrays.dr
        tmp = self._pass(flat, along_y=True)
        dr.eval(tmp)
        out = dr.maximum(self._pass(tmp, along_y=False), 0.0)
        dr.eval(out)
        return out
