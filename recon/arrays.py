"""Array worlds of the reconstruction: numpy on the host, Dr.Jit on its backend.

Every projector computes in one *array world* — :class:`NumpyArrays` for the scipy.sparse
CPU projector, :class:`DrJitArrays` for the Dr.Jit gather projector (the GPU path) — and
exposes it as ``projector.arrays``. Richardson–Lucy (:mod:`recon.deconvolve`) and the depth
filter (:meth:`recon.filters.DepthFilter.channel_filter`) do all their arithmetic through
that object, so an iteration never copies between worlds: the image enters once, the volume
leaves once.

An array world holds flat float32 arrays (the projectors' internal layouts) and offers the
few operations the solver needs. Reductions (sums, the KL divergence) accumulate in float64.
"""

from __future__ import annotations

import numpy as np


class NumpyArrays:
    """Flat float32 numpy arrays on the host (the scipy.sparse projector's world)."""

    name = "numpy"

    def from_numpy(self, a: np.ndarray) -> np.ndarray:
        """A flat float32 copy of ``a`` in this world."""
        return np.array(a, dtype=np.float32, copy=True).ravel()

    def to_numpy(self, a: np.ndarray) -> np.ndarray:
        """``a`` as a flat float32 numpy array (no copy)."""
        return np.asarray(a, dtype=np.float32)

    def full(self, value: float, size: int) -> np.ndarray:
        return np.full(int(size), value, dtype=np.float32)

    def eval(self, *arrays) -> None:
        """Nothing to do: numpy evaluates eagerly."""

    def synchronize(self) -> None:
        """Nothing to do: numpy is synchronous."""

    def sum(self, a: np.ndarray) -> float:
        return float(np.sum(a, dtype=np.float64))

    def where_positive(self, a: np.ndarray, value: float) -> np.ndarray:
        """``value`` where ``a > 0``, else 0."""
        return np.where(a > 0, np.float32(value), np.float32(0.0))

    def reciprocal_or_zero(self, a: np.ndarray) -> np.ndarray:
        """``1 / a`` where ``a > 0``, else 0."""
        out = np.zeros_like(a)
        np.divide(np.float32(1.0), a, out=out, where=a > 0)
        return out

    def add_scalar(self, a: np.ndarray, value: float) -> np.ndarray:
        """``a + value``; may reuse ``a``'s storage."""
        a += np.float32(value)
        return a

    def ratio(self, num: np.ndarray, den: np.ndarray, tiny: float) -> np.ndarray:
        """``num / den`` where ``den > tiny``, else 0."""
        out = np.zeros_like(den)
        np.divide(num, den, out=out, where=den > tiny)
        return out

    def multiply(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        """``a · b · c`` (as ``(a · b) · c``); may reuse ``b``'s storage."""
        np.multiply(a, b, out=b)
        b *= c
        return b

    def l1_change(self, new: np.ndarray, old: np.ndarray) -> tuple[float, float]:
        """``(Σ |new − old|, Σ |old|)``."""
        d = np.subtract(new, old)
        np.abs(d, out=d)
        return float(d.sum(dtype=np.float64)), float(np.abs(old).sum(dtype=np.float64))

    def kl(self, y: np.ndarray, model: np.ndarray) -> float:
        """``Σ y log(y / m) − y + m`` (0 log 0 = 0; m = 0 with y > 0 gives inf)."""
        y = np.asarray(y, dtype=np.float64)
        m = np.asarray(model, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(y > 0, y * np.log(y / m), 0.0) - y + m
        return float(np.sum(t))


class DrJitArrays:
    """Flat Dr.Jit arrays on the LLVM (CPU) or CUDA backend (the gather projector's world).

    Parameters
    ----------
    device : {"llvm", "cuda"}
        The backend, as :func:`lfsim.backend.init_backend` chose it.

    Attributes
    ----------
    Float, Float64, UInt32, Int32 : type
        The backend's differentiable array types (``drjit.llvm.ad`` or ``drjit.cuda.ad``).
    """

    name = "drjit"

    def __init__(self, device: str):
        import drjit as dr

        if device not in ("llvm", "cuda"):
            raise ValueError(f"device must be 'llvm' or 'cuda', got {device!r}")
        mod = dr.cuda.ad if device == "cuda" else dr.llvm.ad
        self.dr = dr
        self.device = device
        self.Float, self.Float64 = mod.Float, mod.Float64
        self.UInt32, self.Int32 = mod.UInt32, mod.Int32

    def from_numpy(self, a: np.ndarray):
        return self.Float(np.ascontiguousarray(a, dtype=np.float32).ravel())

    def to_numpy(self, a) -> np.ndarray:
        self.dr.eval(a)
        return np.asarray(a.numpy(), dtype=np.float32)

    def full(self, value: float, size: int):
        return self.dr.full(self.Float, value, int(size))

    def eval(self, *arrays) -> None:
        self.dr.eval(*arrays)

    def synchronize(self) -> None:
        """Wait for the kernels launched so far (timing)."""
        self.dr.sync_thread()

    def _sum64(self, a) -> float:
        return float(self.dr.sum(self.Float64(a))[0])

    def sum(self, a) -> float:
        return self._sum64(a)

    def where_positive(self, a, value: float):
        return self.dr.select(a > 0, value, 0.0)

    def reciprocal_or_zero(self, a):
        return self.dr.select(a > 0, self.dr.rcp(a), 0.0)

    def add_scalar(self, a, value: float):
        return a + value

    def ratio(self, num, den, tiny: float):
        return self.dr.select(den > tiny, num / den, 0.0)

    def multiply(self, a, b, c):
        return a * b * c

    def l1_change(self, new, old) -> tuple[float, float]:
        dr = self.dr
        return self._sum64(dr.abs(new - old)), self._sum64(dr.abs(old))

    def kl(self, y, model) -> float:
        dr = self.dr
        y64, m64 = self.Float64(y), self.Float64(model)
        t = dr.select(y64 > 0, y64 * dr.log(y64 / m64), 0.0) - y64 + m64
        return float(dr.sum(t)[0])


NUMPY = NumpyArrays()

_DRJIT: dict[str, DrJitArrays] = {}


def drjit_arrays() -> DrJitArrays:
    """The Dr.Jit world of the current backend (initialised with the defaults if not yet)."""
    from lfsim.backend import backend_info, init_backend

    info = backend_info() or init_backend()
    if info.device not in _DRJIT:
        _DRJIT[info.device] = DrJitArrays(info.device)
    return _DRJIT[info.device]
