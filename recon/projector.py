"""Forward and backward light-field projection, exploiting lenslet periodicity.

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

Two implementations of these same terms, chosen per backend by measurement
(``benchmarks/bench_projectors.py``; :func:`make_projector` picks). Each computes in its own
array world (``projector.arrays``, :mod:`recon.arrays`), in which Richardson–Lucy then keeps
all its arrays:

- :class:`LightFieldProjector` — Dr.Jit gathers, one thread per output element; runs on the
  LLVM and CUDA backends. On a GPU this is the projector.
- :class:`SparseProjector` — on the CPU, the same sum written as sparse × dense products per
  depth: for depth ``k`` the terms form a sparse matrix ``A_k`` (rows: pixel residues ``r``;
  columns: (lenslet shift ``q``, sub-position)) and ``H`` is ``Y += A_k · B_k`` with ``B_k``
  the volume channels shifted by every ``q`` — contiguous rows of ``nx · ny`` values, which
  the CPU streams with SIMD instead of gathering element by element; ``Hᵀ`` uses ``A_kᵀ``
  and adds the shifted rows back. Same terms, so the same operator to rounding (tested),
  and about 4× faster than the gathers on a 2-core CPU. Numpy arrays throughout; one
  projection is shared by a thread pool (``threads``, default every core), bit-identical
  for any thread count.
"""

from __future__ import annotations

import logging
from contextlib import nullcontext
from itertools import pairwise

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from hrvbase.errors import raised_as
from hrvbase.threads import available_cores, env_threads

from .arrays import NUMPY, drjit_arrays
from .errors import InputError
from .psf import PSFBank

log = logging.getLogger(__name__)


def _dr_types():
    """The Dr.Jit module and the current backend's ``Float``, ``UInt32``, ``Int32`` types."""
    arrays = drjit_arrays()
    return arrays.dr, arrays.Float, arrays.UInt32, arrays.Int32


class _ProjectorBase:
    """Shapes, layouts and the numpy interface shared by the projectors.

    A projector computes in one array world, :attr:`arrays` (:mod:`recon.arrays`):
    :meth:`forward_flat` and :meth:`backward_flat` take and return flat arrays of that world
    in the internal layouts; :meth:`forward` and :meth:`backward` wrap them for numpy volumes
    and images.
    """

    arrays = NUMPY

    def _init_common(self, bank: PSFBank, n_lenslets_xy: tuple[int, int]) -> None:
        self.bank = bank
        self.nx, self.ny = (int(v) for v in n_lenslets_xy)
        if self.nx < 1 or self.ny < 1:
            raise InputError(f"n_lenslets_xy must be positive, got {n_lenslets_xy!r}")
        self.n, self.s = bank.n, bank.s
        self.nz = len(bank.depths_um)
        self.n_channels = bank.n_channels
        self.n_res = self.n * self.n
        self.macs_per_projection = int(bank.nnz) * self.nx * self.ny

    def _terms(self):
        """Every bank entry as (channel c, residue r, lenslet shift qy, qx)."""
        bank = self.bank
        c = np.repeat(np.arange(self.n_channels, dtype=np.int64), np.diff(bank.offsets))
        qy, ry = np.divmod(bank.dy.astype(np.int64), self.n)
        qx, rx = np.divmod(bank.dx.astype(np.int64), self.n)
        return c, ry * self.n + rx, qy, qx

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

    # -- the operator in the projector's own array world -----------------------------------
    def forward_flat(self, channels):
        """``H``: flat volume channels → flat polyphase image, both in :attr:`arrays`."""
        raise NotImplementedError

    def backward_flat(self, polyphase):
        """``Hᵀ``: flat polyphase image → flat volume channels, both in :attr:`arrays`."""
        raise NotImplementedError

    # -- numpy interface -------------------------------------------------------------------
    def forward(self, volume: np.ndarray) -> np.ndarray:
        """``H x``: volume ``(nz, ny·s, nx·s)`` → light-field image ``(ny·n, nx·n)``."""
        vol = np.asarray(volume)
        if vol.shape != self.volume_shape:
            raise InputError(f"volume shape {vol.shape} != projector's {self.volume_shape}")
        a = self.arrays
        out = self.forward_flat(a.from_numpy(self.volume_to_channels(vol)))
        return self.polyphase_to_image(a.to_numpy(out))

    def backward(self, image: np.ndarray) -> np.ndarray:
        """``Hᵀ y``: image ``(ny·n, nx·n)`` → volume ``(nz, ny·s, nx·s)``."""
        img = np.asarray(image)
        if img.shape != self.image_shape:
            raise InputError(f"image shape {img.shape} != projector's {self.image_shape}")
        a = self.arrays
        out = self.backward_flat(a.from_numpy(self.image_to_polyphase(img)))
        return self.channels_to_volume(a.to_numpy(out))


class LightFieldProjector(_ProjectorBase):
    """``H`` and ``Hᵀ`` of a PSF bank over a grid of ``(nx, ny)`` lenslets (Dr.Jit gathers).

    Parameters
    ----------
    bank : PSFBank
    n_lenslets_xy : tuple of int
        ``(nx, ny)`` lenslets of the rectified image (image ``(ny·n, nx·n)`` pixels).

    Notes
    -----
    Volumes are ``(nz, ny·s, nx·s)`` float32 and images ``(ny·n, nx·n)`` float32 numpy
    arrays at the interface; :meth:`forward_flat` / :meth:`backward_flat` (alias
    :meth:`forward_dr` / :meth:`backward_dr`) work on flat Dr.Jit arrays of the current
    backend (``arrays``: :class:`recon.arrays.DrJitArrays`) in the internal layouts and are
    what the iterative solvers call.
    """

    def __init__(self, bank: PSFBank, n_lenslets_xy: tuple[int, int]):
        self._init_common(bank, n_lenslets_xy)
        if self.n_channels >= 1 << 16 or self.n_res >= 1 << 16:
            raise InputError("PSF bank too large for the packed projector (>= 65 536 channels)")
        self.arrays = drjit_arrays()
        _, Float, UInt32, _ = _dr_types()
        c, r, qy, qx = self._terms()
        if max(np.abs(qy).max(initial=0), np.abs(qx).max(initial=0)) > 127:
            raise InputError("PSF patterns wider than ±127 lenslets are not supported")
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

    def forward_flat(self, channels):
        return self.forward_dr(channels)

    def backward_flat(self, polyphase):
        return self.backward_dr(polyphase)


def resolve_threads(threads: int | None = None, workers: int = 1) -> int:
    """Threads for one projector: ``threads``, or the cores shared among ``workers``.

    Parameters
    ----------
    threads : int, optional
        Asked for (≥ 1); ``None``: the environment variable ``HRVPTM_THREADS`` if set (as for
        the Dr.Jit backend, :func:`lfsim.backend.init_backend`), else :func:`available_cores`
        divided among ``workers``.
    workers : int
        Frames reconstructed at once on this machine (each with its own projector), so that
        ``threads × workers`` stays within the cores.

    Returns
    -------
    int
        At least 1.
    """
    if int(workers) != workers or workers < 1:
        raise InputError(f"workers must be an integer >= 1, got {workers!r}")
    if threads is None:
        with raised_as(InputError):
            env = env_threads()
        if env is not None:
            return env
        return max(1, available_cores() // int(workers))
    if isinstance(threads, bool) or int(threads) != threads or threads < 1:
        raise InputError(f"threads must be an integer >= 1, got {threads!r}")
    return int(threads)


def _parts(n: int, k: int) -> list[tuple[int, int]]:
    """``[0, n)`` cut into at most ``k`` consecutive non-empty ranges of near-equal length."""
    k = max(1, min(k, n))
    edges = [n * j // k for j in range(k + 1)]
    return [(a, b) for a, b in pairwise(edges) if b > a]


def _parts_by_weight(weights: np.ndarray, k: int) -> list[tuple[int, int]]:
    """Indices ``[0, len(weights))`` cut into at most ``k`` consecutive non-empty ranges of
    about equal total weight."""
    n = len(weights)
    k = max(1, min(k, n))
    cum = np.r_[0.0, np.cumsum(np.asarray(weights, np.float64))]  # weight before index i
    edges = {0, n}
    for target in cum[-1] * np.arange(1, k) / k:
        i = int(np.searchsorted(cum, target))  # cum[i - 1] < target <= cum[i]
        edges.add(i if i > 0 and cum[i] - target < target - cum[i - 1] else max(i - 1, 0))
    return list(pairwise(sorted(edges)))


class SparseProjector(_ProjectorBase):
    """``H`` and ``Hᵀ`` as per-depth sparse × dense products (CPU; see the module docstring).

    Works in the numpy world (``arrays``: :data:`recon.arrays.NUMPY`): flat float32 numpy
    arrays in, flat float32 numpy arrays out, no Dr.Jit.

    Parameters
    ----------
    bank : PSFBank
    n_lenslets_xy : tuple of int
    block_mb : float
        Memory bound (MB) of one shifted-channel block ``B``; larger depths are split into
        groups of sub-positions.
    threads : int, optional
        Threads of one projection (default: every core, :func:`resolve_threads`).

    Notes
    -----
    **Threads.** scipy.sparse's compiled products and numpy's copies release the GIL, so the
    work is shared by a thread pool (one per call; nothing is kept between calls):

    - ``H``: the image is cut into slabs of lenslet rows ``v``; each thread builds the shifted
      channels ``B`` of its slab only and computes its slab of ``Y`` over every block;
    - ``Hᵀ``: the blocks (each its own channels; with few blocks for the threads, ranges of
      a block's channels) are shared out: a thread computes ``Z = Aᵀ Y`` of its channels and
      adds the shifted ``Z`` planes into them. Up to ``threads`` such ``Z`` (each at most
      ``block_mb``) are held at once.

    Every output element is summed by one thread in the same order whatever the number of
    threads (the slabs and ranges cut only *which* elements a thread computes), so the result
    is bit-identical for any ``threads`` (tested for 1, 2, 3 and 16), and to the serial
    formulation.
    """

    def __init__(
        self,
        bank: PSFBank,
        n_lenslets_xy: tuple[int, int],
        block_mb: float = 256.0,
        threads: int | None = None,
    ):
        import scipy.sparse as sp

        self._init_common(bank, n_lenslets_xy)
        self.threads = resolve_threads(threads)
        c, r, qy, qx = self._terms()
        s2 = self.s * self.s
        plane = self.nx * self.ny
        self._blocks = []  # (first channel, n channels, shifts (Q, 2), A (R × Q·C))
        depth = c // s2
        bounds = np.searchsorted(depth, np.arange(self.nz + 1))
        for k in range(self.nz):
            lo, hi = bounds[k], bounds[k + 1]
            if lo == hi:
                continue
            q = np.stack([qy[lo:hi], qx[lo:hi]], axis=1)
            shifts, q_index = np.unique(q, axis=0, return_inverse=True)
            q_index = q_index.ravel()
            per_channel = len(shifts) * plane * 4 / 1e6
            group = max(1, min(s2, int(block_mb // max(per_channel, 1e-9))))
            local = c[lo:hi] - k * s2
            for g0 in range(0, s2, group):
                sel = (local >= g0) & (local < g0 + group)
                if not sel.any():
                    continue
                ng = min(group, s2 - g0)
                cols = q_index[sel] * ng + (local[sel] - g0)
                a = sp.csr_matrix(
                    (bank.w[lo:hi][sel].astype(np.float32), (r[lo:hi][sel], cols)),
                    shape=(self.n_res, len(shifts) * ng),
                )
                self._blocks.append((k * s2 + g0, ng, shifts, a))

        # Hᵀ tasks: a block, or where there are few blocks for the threads a range of its
        # channels (about equal non-zeros), with the rows of Aᵀ of those channels
        self._backward_tasks = []  # (first channel, n channels, shifts, Aᵀ rows (Q·n × R))
        split = -(-4 * self.threads // max(len(self._blocks), 1))
        for c0, ng, shifts, a in self._blocks:
            at = a.T.tocsr()  # rows i·ng + channel
            per_channel = np.diff(at.indptr).reshape(len(shifts), ng).sum(axis=0)
            for g0, g1 in _parts_by_weight(per_channel, split):
                rows = (np.arange(len(shifts))[:, None] * ng + np.arange(g0, g1)).ravel()
                self._backward_tasks.append((c0 + g0, g1 - g0, shifts, at[rows]))

    # -- helpers ---------------------------------------------------------------------------
    def _map(self, pool, fn, items) -> list:
        """``fn`` over ``items`` on ``pool`` (in order; inline when there is no pool)."""
        if pool is None:
            return [fn(item) for item in items]
        return list(pool.map(fn, items))

    def _pool(self):
        from concurrent.futures import ThreadPoolExecutor

        if self.threads == 1:
            return nullcontext(None)
        return ThreadPoolExecutor(self.threads, thread_name_prefix="recon-projector")

    # -- H ---------------------------------------------------------------------------------
    def _forward_slab(self, v: np.ndarray, v0: int, v1: int) -> np.ndarray:
        """Rows ``v0 … v1 − 1`` of the lenslet grid of ``H v``: ``(n_res, (v1 − v0)·nx)``."""
        ny, nx = self.ny, self.nx
        rows = v1 - v0
        y = np.zeros((self.n_res, rows * nx), np.float32)
        for c0, ng, shifts, a in self._blocks:
            hy = int(np.abs(shifts[:, 0]).max())
            hx = int(np.abs(shifts[:, 1]).max())
            # voxel lenslet rows v0 − hy … v1 + hy − 1 of these channels, zero outside
            vp = np.zeros((ng, rows + 2 * hy, nx + 2 * hx), np.float32)
            s0, s1 = max(0, v0 - hy), min(ny, v1 + hy)
            vp[:, s0 - (v0 - hy) : s1 - (v0 - hy), hx : hx + nx] = v[c0 : c0 + ng, s0:s1]
            # pixel lenslet (v, u) reads voxel lenslet (v − qy, u − qx): B[i] is the window
            # of vp at (hy − qy, hx − qx); one gather for all shifts, (Q, ng, rows, nx)
            win = sliding_window_view(vp, (rows, nx), axis=(1, 2)).transpose(1, 2, 0, 3, 4)
            b = win[hy - shifts[:, 0], hx - shifts[:, 1]]
            y += a @ b.reshape(len(shifts) * ng, rows * nx)
        return y

    def forward_flat(self, channels: np.ndarray) -> np.ndarray:
        """``H``: flat channels → flat polyphase image (numpy float32)."""
        ny, nx = self.ny, self.nx
        v = np.asarray(channels, np.float32).reshape(self.n_channels, ny, nx)
        slabs = _parts(ny, self.threads)
        with self._pool() as pool:
            parts = self._map(pool, lambda r: self._forward_slab(v, *r), slabs)
        if len(slabs) == 1:
            return parts[0].ravel()
        y = np.empty((self.n_res, ny, nx), np.float32)
        for (v0, v1), part in zip(slabs, parts, strict=True):
            y[:, v0:v1] = part.reshape(self.n_res, v1 - v0, nx)
        return y.ravel()

    # -- Hᵀ --------------------------------------------------------------------------------
    def _backward_task(self, yr: np.ndarray, out: np.ndarray, task) -> None:
        """Channels ``c0 … c0 + n − 1`` of ``Hᵀ``: ``Z = Aᵀ Y``, then the shifted ``Z`` planes
        added into ``out`` (these channels are no other task's)."""
        ny, nx = self.ny, self.nx
        c0, n, shifts, at = task
        z = (at @ yr).reshape(len(shifts), n, ny, nx)
        dst = out[c0 : c0 + n]
        for zi, (sy, sx) in zip(z, shifts, strict=True):
            # voxel lenslet (v, u) gathers pixel lenslet (v + qy, u + qx), shifts in order
            a0, a1 = max(0, -sy), min(ny, ny - sy)
            b0, b1 = max(0, -sx), min(nx, nx - sx)
            if a0 < a1 and b0 < b1:
                dst[:, a0:a1, b0:b1] += zi[:, a0 + sy : a1 + sy, b0 + sx : b1 + sx]

    def backward_flat(self, polyphase: np.ndarray) -> np.ndarray:
        """``Hᵀ``: flat polyphase image → flat channels (numpy float32)."""
        yr = np.asarray(polyphase, np.float32).reshape(self.n_res, self.ny * self.nx)
        out = np.zeros((self.n_channels, self.ny, self.nx), np.float32)
        with self._pool() as pool:
            self._map(pool, lambda t: self._backward_task(yr, out, t), self._backward_tasks)
        return out.ravel()


PROJECTORS = ("auto", "gather", "sparse")


def make_projector(
    bank: PSFBank,
    n_lenslets_xy: tuple[int, int],
    kind: str = "auto",
    threads: int | None = None,
    workers: int = 1,
):
    """The fastest projector for the current backend (or the one asked for).

    ``"auto"``: :class:`SparseProjector` on the CPU (LLVM backend), :class:`LightFieldProjector`
    on CUDA — the choice measured by ``benchmarks/bench_projectors.py``. ``threads``: threads
    of the CPU projector, ``None``: the cores divided among ``workers``, the frames
    reconstructed at once on this machine (:func:`resolve_threads`). The gather projector
    runs on the Dr.Jit backend's own threads (:func:`lfsim.backend.init_backend`).
    """
    if kind not in PROJECTORS:
        raise InputError(f"projector must be one of {PROJECTORS}, got {kind!r}")
    threads = resolve_threads(threads, workers)
    if kind == "auto":
        from lfsim.backend import backend_info, init_backend

        info = backend_info() or init_backend()
        kind = "gather" if info.device == "cuda" else "sparse"
    if kind == "gather":
        return LightFieldProjector(bank, n_lenslets_xy)
    return SparseProjector(bank, n_lenslets_xy, threads=threads)
