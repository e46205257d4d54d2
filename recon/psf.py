"""The light-field PSF bank: the image of a point source at every depth and sub-lenslet position.

The light-field microscope is periodic over lenslets: moving a source by one lenslet pitch in
object space (``p / M``) moves its light-field image by exactly one lenslet. The forward model
therefore needs only ``n_depths × s²`` patterns — one per depth and per voxel position inside
a lenslet — instead of one per voxel. Each pattern is traced with :mod:`lfsim`'s direct Dr.Jit
tracer from the same :class:`~lfsim.optics.Optics` the images come from (geometric optics plus
the diffraction blur of paper §2.2), and stored sparsely: the pixels holding light, with their
offsets from the top-left pixel of the source's own lenslet.

Weights are the fraction of the light emitted into the collection cone that reaches each
pixel, so a pattern sums to the collected fraction (≈ 1 for ideal optics): a volume in
"photons emitted into the cone" maps to an image in photons.

Banks are cached on disk (``.npz``) under a key hashing the optics, depths, ``s``, the ray
count, the seed and the bank format.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .errors import InputError

log = logging.getLogger(__name__)

BANK_FORMAT = 1


def default_cache_dir() -> Path:
    """``$HRVPTM_CACHE/psf`` or ``~/.cache/hrvptm/psf``."""
    base = os.environ.get("HRVPTM_CACHE") or Path.home() / ".cache" / "hrvptm"
    return Path(base) / "psf"


@dataclass(frozen=True)
class PSFBank:
    """Sparse light-field patterns of point sources.

    Channel ``c = k · s² + b · s + a`` is the source at depth ``depths_um[k]`` and sub-lenslet
    position ``(a, b)`` along (x, y). Its entries are ``offsets[c]:offsets[c + 1]`` of
    ``dy``, ``dx`` (pixels from the top-left pixel of the source's lenslet) and ``w``.

    Attributes
    ----------
    depths_um : ndarray, shape (nz,)
    s : int
    n : int
        Pixels per lenslet (the rectified pitch).
    offsets : ndarray of int64, shape (nz·s² + 1,)
    dy, dx : ndarray of int32, shape (nnz,)
    w : ndarray of float32, shape (nnz,)
    optics : dict
        ``Optics.to_dict()`` of the optics the bank was traced with.
    """

    depths_um: np.ndarray
    s: int
    n: int
    offsets: np.ndarray
    dy: np.ndarray
    dx: np.ndarray
    w: np.ndarray
    optics: dict

    @property
    def n_channels(self) -> int:
        return len(self.offsets) - 1

    @property
    def nnz(self) -> int:
        return len(self.w)

    def pattern(self, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Entries ``(dy, dx, w)`` of channel ``c``."""
        lo, hi = self.offsets[c], self.offsets[c + 1]
        return self.dy[lo:hi], self.dx[lo:hi], self.w[lo:hi]

    def dense_pattern(self, c: int) -> tuple[np.ndarray, int, int]:
        """Channel ``c`` as a dense image with the offsets of its top-left pixel."""
        dy, dx, w = self.pattern(c)
        y0, x0 = int(dy.min()), int(dx.min())
        img = np.zeros((int(dy.max()) - y0 + 1, int(dx.max()) - x0 + 1), np.float32)
        img[dy - y0, dx - x0] = w
        return img, y0, x0

    def save(self, path: str | os.PathLike) -> Path:
        """Write the bank as ``.npz``, atomically (concurrent writers of the same cache entry
        each publish a complete file)."""
        from hrvbase.io import atomic_path

        path = Path(path)
        with atomic_path(path, overwrite=True) as tmp, open(tmp, "wb") as fh:
            np.savez(
                fh,
                depths_um=self.depths_um,
                s=self.s,
                n=self.n,
                offsets=self.offsets,
                dy=self.dy,
                dx=self.dx,
                w=self.w,
                optics=json.dumps(self.optics),
                format=BANK_FORMAT,
            )
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> PSFBank:
        try:
            with np.load(path) as z:
                if int(z["format"]) != BANK_FORMAT:
                    raise InputError(f"PSF bank {str(path)!r} has an old format; delete it")
                return cls(
                    depths_um=z["depths_um"],
                    s=int(z["s"]),
                    n=int(z["n"]),
                    offsets=z["offsets"],
                    dy=z["dy"],
                    dx=z["dx"],
                    w=z["w"],
                    optics=json.loads(str(z["optics"])),
                )
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"cannot read PSF bank {str(path)!r}: {exc}") from exc


def bank_key(optics, depths_um, s: int, rays_per_pattern: int, seed: int, threshold: float) -> str:
    payload = json.dumps(
        {
            "optics": optics.fingerprint_dict(),
            "depths": [round(float(d), 9) for d in depths_um],
            "s": int(s),
            "rays": int(rays_per_pattern),
            "seed": int(seed),
            "threshold": float(threshold),
            "format": BANK_FORMAT,
        },
        sort_keys=True,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:20]


def pattern_radius_lenslets(optics, z_um: float) -> int:
    """Half-width (in lenslets) of the window that holds a depth's whole pattern.

    ``z_um`` is a true depth in the specimen; its image lies at the apparent depth, scaled by
    the largest ratio of apparent to true depth over the cone
    (:attr:`lfsim.optics.Optics.max_axial_scale`), plus one lenslet for the interfaces'
    aberrations.
    """
    d = abs(optics.magnification**2 * z_um) * optics.max_axial_scale  # image distance (µm)
    cone = d * math.tan(math.asin(optics.image_na))  # radius of the light cone at the array
    spread = 1.0 + optics.mla_focal_um / max(d, optics.mla_focal_um)
    sigma = 4 * (optics.sigma_mla_um + optics.sigma_sensor_um)
    extra = 2 if optics.has_interfaces else 1
    return math.ceil((cone * spread + optics.mla_pitch_um + sigma) / optics.mla_pitch_um) + extra


def sparse_pattern(img: np.ndarray, h: int, n: int, threshold: float):
    """The pixels of one dense pattern above ``threshold`` × its peak, as bank entries.

    Parameters
    ----------
    img : ndarray, shape ((2h + 1) n, (2h + 1) n)
        The pattern on a window of ``2h + 1`` lenslets whose pixel ``(h n, h n)`` is the top-left
        pixel of the source's lenslet.
    h, n : int
        Window radius (lenslets) and pixels per lenslet.
    threshold : float
        Relative threshold; an all-zero pattern has no entries.

    Returns
    -------
    dy, dx : ndarray of int32, shape (k,)
        Offsets (pixels) from the top-left pixel of the source's lenslet.
    w : ndarray, shape (k,)
        The values there, in ``img``'s type.
    """
    peak = float(img.max())
    keep = img > threshold * peak if peak > 0 else np.zeros(img.shape, bool)
    yy, xx = np.nonzero(keep)
    return (yy - h * n).astype(np.int32), (xx - h * n).astype(np.int32), img[yy, xx]


def bank_from_patterns(images, depths_um, s: int, n: int, threshold: float, optics) -> PSFBank:
    """The :class:`PSFBank` of dense patterns, each made sparse (:func:`sparse_pattern`) as it
    arrives.

    Parameters
    ----------
    images : iterable of (k, h, stack)
        Depth index ``k`` (any order, each once), window radius ``h`` (lenslets) and the
        patterns of that depth, ndarray of shape ``(s², (2h + 1) n, (2h + 1) n)`` in channel
        order ``b · s + a``.
    depths_um : ndarray, shape (nz,)
    s, n : int
        Voxels and pixels per lenslet.
    threshold : float
        Relative threshold of :func:`sparse_pattern`.
    optics : lfsim.optics.Optics
        The optics the patterns were computed for (recorded in the bank).
    """
    parts: dict[int, list] = {}
    for k, h, stack in images:
        entries = []
        for img in stack:
            dy, dx, w = sparse_pattern(img, h, n, threshold)
            entries.append((dy, dx, w.astype(np.float32)))
        parts[k] = entries
    flat = [e for k in range(len(depths_um)) for e in parts[k]]
    counts = [len(e[0]) for e in flat]
    return PSFBank(
        depths_um=depths_um,
        s=int(s),
        n=n,
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        dy=np.concatenate([e[0] for e in flat]),
        dx=np.concatenate([e[1] for e in flat]),
        w=np.concatenate([e[2] for e in flat]),
        optics=optics.to_dict(),
    )


def cached_bank(cache_dir, key: str) -> tuple[Path | None, PSFBank | None]:
    """The cache file of the bank ``key`` (None when ``cache_dir == ""``: no caching; default
    :func:`default_cache_dir`) and the bank it holds (None when it does not exist yet)."""
    if cache_dir == "":
        return None, None
    path = Path(cache_dir or default_cache_dir()) / f"psf_{key}.npz"
    if path.is_file():
        log.info("PSF bank from cache %s", path)
        return path, PSFBank.load(path)
    return path, None


def compute_psf_bank(
    optics,
    depths_um,
    s: int,
    *,
    rays_per_pattern: int = 200_000,
    seed: int = 0,
    threshold: float = 1e-3,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
) -> PSFBank:
    """Trace (or load from the cache) the PSF bank for these optics, depths and ``s``.

    Parameters
    ----------
    optics : lfsim.optics.Optics
        Must have an integer number of pixels per lenslet (a rectified geometry).
    depths_um : array_like, shape (nz,)
        Source depths from the native object plane (µm).
    s : int
        Super-resolution factor (voxels per lenslet along x and y).
    rays_per_pattern : int
        Rays traced per pattern (Monte Carlo noise of a pattern pixel ~ 1/sqrt(rays · w)).
    seed : int
        Seed of the rays of the first depth (depth ``k`` uses ``seed + k``).
    threshold : float
        Pixels below ``threshold × max`` of their pattern are dropped (sparsity).
    cache_dir : path, optional
        Default :func:`default_cache_dir`; ``""`` disables caching.
    progress : bool
        Show a progress bar over the depths.

    Returns
    -------
    PSFBank
    """
    from lfsim.backend import backend_info, init_backend
    from lfsim.tracer import RenderSettings, Sources, trace_paraxial

    n = optics.px_per_lenslet
    if abs(n - round(n)) > 1e-6:
        raise InputError(
            f"the PSF bank needs an integer number of pixels per lenslet, got {n:.4g}; "
            "rectify the images first"
        )
    n = round(n)
    depths = np.asarray(depths_um, dtype=np.float64)
    if int(s) != s or s < 1:
        raise InputError(f"super-resolution factor s must be a positive integer, got {s!r}")
    key = bank_key(optics, depths, s, rays_per_pattern, seed, threshold)
    path, cached = cached_bank(cache_dir, key)
    if cached is not None:
        return cached
    if backend_info() is None:
        init_backend()
    p_obj = optics.lenslet_object_um
    sub = ((np.arange(s) + 0.5) / s - 0.5) * p_obj
    settings = RenderSettings(
        rays_per_particle=rays_per_pattern, mode="expected", seed=seed, batch_rays=1 << 23
    )
    it = range(len(depths))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="PSF bank", unit="depth", leave=False)

    def traced():
        for k in it:
            z = depths[k]
            h = pattern_radius_lenslets(optics, z)
            win = (2 * h + 1) * n
            wopt = replace(
                optics, sensor_xy_px=(win, win), axis_xy_px=(h * n + n / 2, h * n + n / 2)
            )
            gx, gy = np.meshgrid(sub, sub, indexing="xy")  # a along x fastest, then b along y
            centers = np.c_[gx.ravel(), gy.ravel(), np.full(s * s, z)]
            stack = trace_paraxial(
                wopt,
                Sources.spheres(centers, 0.0),
                replace(settings, seed=seed + k),
                per_source=True,
                virtual_front=True,  # guard planes in front of a specimen: the specimen goes on
            )
            yield k, h, stack.astype(np.float64) / rays_per_pattern

    bank = bank_from_patterns(traced(), depths, s, n, threshold, optics)
    log.info(
        "PSF bank: %d depths × %d² patterns, %d non-zeros (%.0f per pattern)",
        len(depths),
        s,
        bank.nnz,
        bank.nnz / bank.n_channels,
    )
    if path is not None:
        bank.save(path)
    return bank
