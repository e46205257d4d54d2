"""Particle segmentation: threshold, connected components, size / shape / edge filters.

The paper (§3.2, Table 1) binarises the deconvolved volume (threshold 0.25 of the normalised
intensity; active contours in its code), keeps binary regions between a minimum and maximum
size "chosen by the user based on a histogram of sizes" (1000–5000 voxels at
1.64 × 1.64 × 5 µm), and so drops reconstruction artefacts, noise and clumps. This module does
the same with documented automatic choices:

Threshold
    A float ``t`` in (0, 1) is a fraction of the intensity range:
    ``min + t (max − min)`` (the paper's 0.25, the default). ``"auto"`` is a robust noise
    threshold ``median + k σ`` with ``σ = 1.4826 MAD`` (``k = auto_k_sigma``): particles
    fill a small fraction of a seeded volume, so the median and MAD describe the background
    and its noise. Unlike Otsu's method it does not assume two classes of comparable size,
    and unlike a fraction of the maximum it does not depend on the brightest particle. It is
    floored at 5 % of the range above the median so that a noise-free volume still gets a
    meaningful level.
Components
    :func:`scipy.ndimage.label` with face connectivity (6 neighbours), which merges fewer
    touching particles than 26-connectivity. When ``split_min_sep_vox`` (the particle FWHM
    per axis) is given, a component holding regional maxima of prominence ≥
    ``clump_prominence`` × (peak − threshold) that lie at least one FWHM apart (distance
    ``sqrt(Σ (Δ_i / FWHM_i)²) ≥ 1``), with a valley between them at least ``SPLIT_DIP`` (half)
    the fainter one's height deep and the fainter at least ``SPLIT_MIN_RATIO`` of the
    brightest (resolved particles of similar brightness, not a particle's fainter axial side
    lobes), is split between them (watershed of the component from its maxima); other maxima
    stay one blob and meet the shape and clump tests below.
Edges
    Blobs whose maximum lies within ``edge_margin_vox`` voxels of a face (on it when the
    margin is 0), or whose core (the voxels above half the blob's height over the threshold)
    comes that close to one face of an axis, are rejected: their centre is cut off or biased
    (and reconstructions pile light from outside the field onto their faces). Along an axis
    where the core is longer than half the volume, as the axial images of few
    Richardson–Lucy iterations can be (their length depends on the iterations, not on the
    particle), only the maximum is tested: the blob is kept when its maximum is inside.
Size
    ``blob_min_vox``/``blob_max_vox`` when given; otherwise ``auto_size_factors`` × the
    *voxel-weighted* median blob size (the size of the blob holding the median segmented
    voxel) over blobs of at least ``MIN_AUTO_VOX`` (8) voxels, and never below that floor.
    Weighting by size makes the reference the typical particle even when noise specks
    outnumber the particles; the floor keeps pure-noise volumes free of detections.
Shape
    The second-moment tensor ``C`` of each blob in µm² (weights ``I − threshold``) is compared
    with the element-wise median ``C₀`` of the size-accepted blobs: the *relative aspect*
    ``sqrt(μmax / μmin)``, with ``μ`` the eigenvalues of ``C₀^{-1/2} C C₀^{-1/2}``, is 1 for a
    particle of the median shape whatever its brightness (a brighter particle has a larger but
    similar ellipsoid at a fixed threshold), and large for streaks and merged pairs even though
    every particle image is elongated along z. Blobs above the limit are rejected: the limit
    is ``max_rel_aspect`` or, where the size-accepted blobs scatter more (sharp, noisy or
    sub-voxel images, as many Richardson–Lucy iterations make them), the upper Tukey fence
    ``exp(Q3 + 1.5 IQR)`` of their log aspects (at least 4 blobs), so that the test follows the
    reconstruction and still finds the outliers (streaks, merged pairs).
Clumps
    Blobs with two or more regional maxima of prominence ≥ ``clump_prominence`` × (peak −
    threshold) (h-maxima transform, Soille 2003, of the blob smoothed with a 0.5-voxel
    Gaussian) are rejected as merged particles.

Every blob is reported, with the reason for rejection where there is one.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.morphology import h_maxima

from hrvbase.errors import raised_as
from hrvbase.validate import finite_float, fixed_length, int_in_range, positive_float

from .errors import InputError
from .localize import check_triple, check_volume, check_voxel_size_um

log = logging.getLogger(__name__)

MIN_AUTO_VOX = 8
#: Depth of the valley between two maxima of one component, as a fraction of the fainter
#: one's height above the threshold, from which they are split as resolved particles.
SPLIT_DIP = 0.5
#: Height (above the threshold) a maximum needs, as a fraction of its component's brightest,
#: to be split off: the axial side lobes of a particle's image (no depth filter, many
#: iterations) are deep-valleyed but fainter (measured 0.37–0.51 of the main lobe).
SPLIT_MIN_RATIO = 0.7
"""Smallest blob (voxels) taken into the automatic size reference."""


@dataclass(frozen=True)
class SegmentSettings:
    """Settings of :func:`segment` (module docstring); :class:`track.detect.DetectSettings`
    takes its segmentation defaults from here.

    Parameters
    ----------
    threshold : float or "auto"
        Fraction of the intensity range in (0, 1) (paper: 0.25), or ``"auto"``.
    auto_k_sigma : float
        ``k`` of the automatic threshold ``median + k σ`` (> 0).
    blob_min_vox, blob_max_vox : int or None
        Blob size limits (voxels); None chooses each from the size histogram.
    auto_size_factors : tuple of 2 float
        Automatic limits as factors of the voxel-weighted median blob size
        (``0 < low <= 1 <= high``).
    max_rel_aspect : float
        Largest accepted relative aspect ratio (≥ 1) against the median blob, unless the
        blobs' own scatter is wider (module docstring).
    clump_prominence : float
        Prominence, as a fraction of ``peak − threshold``, that makes a second maximum count,
        in [0, 1); 0 disables the clump test.
    """

    threshold: float | str = 0.25
    auto_k_sigma: float = 5.0
    blob_min_vox: int | None = None
    blob_max_vox: int | None = None
    auto_size_factors: tuple[float, float] = (0.1, 3.0)
    max_rel_aspect: float = 1.8
    clump_prominence: float = 0.2

    def __post_init__(self) -> None:
        with raised_as(InputError):
            thr = self.threshold
            if thr != "auto":
                if isinstance(thr, str) or not 0 < finite_float(thr, "threshold") < 1:
                    raise InputError(
                        f"threshold must be a fraction in (0, 1) or 'auto', got {thr!r}"
                    )
                thr = float(thr)
            k = positive_float(self.auto_k_sigma, "auto_k_sigma")
            aspect = finite_float(self.max_rel_aspect, "max_rel_aspect")
            if not aspect >= 1:
                raise InputError(f"max_rel_aspect must be >= 1, got {self.max_rel_aspect!r}")
            prom = finite_float(self.clump_prominence, "clump_prominence")
            if not 0 <= prom < 1:
                raise InputError(
                    f"clump_prominence must lie in [0, 1), got {self.clump_prominence!r}"
                )
            sizes = [
                None if v is None else int_in_range(v, name, 1)
                for name, v in (
                    ("blob_min_vox", self.blob_min_vox),
                    ("blob_max_vox", self.blob_max_vox),
                )
            ]
            if None not in sizes and sizes[0] > sizes[1]:
                raise InputError(
                    f"blob_min_vox ({sizes[0]}) must not exceed blob_max_vox ({sizes[1]})"
                )
            what = "two numbers with 0 < low <= 1 <= high"
            lo_hi = fixed_length(self.auto_size_factors, "auto_size_factors", 2, what)
            lo, hi = (finite_float(v, "auto_size_factors") for v in lo_hi)
            if not 0 < lo <= 1 <= hi:
                raise InputError(f"auto_size_factors must be {what}, got {lo_hi!r}")
        for name, v in (
            ("threshold", thr),
            ("auto_k_sigma", k),
            ("max_rel_aspect", aspect),
            ("clump_prominence", prom),
            ("blob_min_vox", sizes[0]),
            ("blob_max_vox", sizes[1]),
            ("auto_size_factors", (lo, hi)),
        ):
            object.__setattr__(self, name, v)


@dataclass(frozen=True)
class Blob:
    """One connected component of the thresholded volume.

    Attributes
    ----------
    label : int
        Label in :attr:`Segmentation.labels`.
    n_vox : int
        Voxel count.
    bbox : tuple of int
        Half-open bounding box ``(z0, z1, y0, y1, x0, x1)`` (voxels).
    centroid_vox : tuple of float
        Centroid ``(z, y, x)`` weighted by ``I − threshold`` (voxels).
    peak : float
        Maximum intensity.
    rel_aspect : float
        Relative aspect ratio against the median blob (NaN when not evaluated).
    n_maxima : int
        Regional maxima found by the clump test (0 when not evaluated).
    reason : str or None
        Why the blob was rejected; None for accepted blobs.
    """

    label: int
    n_vox: int
    bbox: tuple[int, int, int, int, int, int]
    centroid_vox: tuple[float, float, float]
    peak: float
    rel_aspect: float = float("nan")
    n_maxima: int = 0
    reason: str | None = None

    @property
    def accepted(self) -> bool:
        """True when no filter rejected the blob."""
        return self.reason is None

    def as_dict(self) -> dict:
        """Plain-type dictionary (for JSON reports)."""
        return {
            "label": self.label,
            "n_vox": self.n_vox,
            "bbox": list(self.bbox),
            "centroid_vox": [float(v) for v in self.centroid_vox],
            "peak": float(self.peak),
            "rel_aspect": float(self.rel_aspect),
            "n_maxima": self.n_maxima,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class Segmentation:
    """Result of :func:`segment`.

    Attributes
    ----------
    labels : ndarray, shape (nz, ny, nx), int32
        Connected components of the thresholded volume (0 = background).
    blobs : tuple of Blob
        Every component, accepted or not, in label order.
    threshold : float
        Intensity threshold used.
    size_bounds_vox : tuple of int
        ``(min, max)`` blob size used (voxels).
    reference_cov_um2 : ndarray, shape (3, 3)
        Median second-moment tensor ``(z, y, x)`` of the size-accepted blobs (µm²); NaN when
        there were none.
    counts : dict
        Blobs left after each stage: ``components``, ``edge``, ``size``, ``shape``, ``clump``.
    n_split : int
        Components split between resolved maxima (``split_min_sep_vox``) before the filters.
    """

    labels: np.ndarray
    blobs: tuple[Blob, ...]
    threshold: float
    size_bounds_vox: tuple[int, int]
    reference_cov_um2: np.ndarray
    counts: dict = field(default_factory=dict)
    n_split: int = 0

    @property
    def accepted(self) -> tuple[Blob, ...]:
        """Blobs that passed every filter."""
        return tuple(b for b in self.blobs if b.accepted)

    @property
    def rejected(self) -> tuple[Blob, ...]:
        """Blobs rejected by some filter (with :attr:`Blob.reason`)."""
        return tuple(b for b in self.blobs if not b.accepted)

    @property
    def rejections(self) -> dict[str, int]:
        """Rejected blobs counted by filter: ``edge``, ``too_small`` (noise specks under
        :data:`MIN_AUTO_VOX` voxels apart, in ``specks``), ``too_large``, ``elongated``,
        ``clump``."""
        out = dict.fromkeys(REJECTION_KINDS, 0)
        for b in self.rejected:
            kind = next(k for k, prefix in _REASON_PREFIX.items() if b.reason.startswith(prefix))
            if kind == "too_small" and b.n_vox < MIN_AUTO_VOX:
                kind = "specks"
            out[kind] += 1
        return out


#: Keys of :attr:`Segmentation.rejections`.
REJECTION_KINDS = ("edge", "too_small", "specks", "too_large", "elongated", "clump")
_REASON_PREFIX = {
    "edge": "touches",
    "too_small": "too small",
    "too_large": "too large",
    "elongated": "elongated",
    "clump": "clump",
}


#: Voxels of each face left out of the intensity range: light-field reconstructions pile
#: light from outside the field onto their outermost voxels (boundary artefacts), which must
#: not set the threshold of the particles inside.
FACE_VOX = 2


def interior(vol: np.ndarray) -> np.ndarray:
    """The volume without its :data:`FACE_VOX` outer voxels (axes too short keep them all)."""
    sl = tuple(
        slice(FACE_VOX, n - FACE_VOX) if n > 4 * FACE_VOX else slice(None) for n in vol.shape
    )
    return vol[sl]


def median_and_sigma(values: np.ndarray) -> tuple[float, float]:
    """Median and robust noise σ (1.4826 × the median absolute deviation) of ``values``."""
    v = np.asarray(values)
    med = float(np.median(v))
    return med, 1.4826 * float(np.median(np.abs(v - med)))


def auto_threshold(volume: np.ndarray, k_sigma: float = SegmentSettings.auto_k_sigma) -> float:
    """Robust noise threshold ``median + k · 1.4826 MAD``, floored at 5 % of the range (the
    range of the interior, see :func:`interior`); ``k_sigma`` defaults to
    :attr:`SegmentSettings.auto_k_sigma`."""
    vol = check_volume(volume)
    med, sigma = median_and_sigma(vol)
    top = float(interior(vol).max())
    return max(med + k_sigma * sigma, med + 0.05 * (top - med))


def _threshold(vol: np.ndarray, threshold: float | str, k_sigma: float) -> float:
    """The intensity threshold of a validated setting (:class:`SegmentSettings`)."""
    if threshold == "auto":
        return auto_threshold(vol, k_sigma)
    core = interior(vol)
    lo, hi = float(core.min()), float(core.max())
    return lo + float(threshold) * (hi - lo)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def segment(
    volume: np.ndarray,
    voxel_size_um: Sequence[float],
    settings: SegmentSettings | None = None,
    *,
    edge_margin_vox: Sequence[int] = (0, 0, 0),
    split_min_sep_vox: Sequence[float] | None = None,
) -> Segmentation:
    """Threshold a volume into particle blobs and filter them (see the module docstring).

    Parameters
    ----------
    volume : ndarray, shape (nz, ny, nx)
        Intensities (typically the deconvolved reconstruction).
    voxel_size_um : sequence of 3 float
        ``(dz, dy, dx)`` (µm), for the shape test.
    settings : SegmentSettings, optional
        Threshold and filters (default ``SegmentSettings()``).
    edge_margin_vox : sequence of 3 int
        Margin ``(z, y, x)`` in voxels a blob's bounding box must keep from the faces;
        0 rejects only blobs touching a face.
    split_min_sep_vox : sequence of 3 float or None
        Separation ``(z, y, x)`` (voxels, the particle FWHM) beyond which two maxima of one
        component are split into two blobs (module docstring); None (default): no split.

    Returns
    -------
    Segmentation

    Raises
    ------
    InputError
        For a bad volume, voxel size or parameter (the message names it).
    """
    vol = check_volume(volume)
    spacing = np.asarray(check_voxel_size_um(voxel_size_um))
    margin = check_triple(edge_margin_vox, "edge_margin_vox", positive=False, integer=True)
    if settings is None:
        settings = SegmentSettings()
    elif not isinstance(settings, SegmentSettings):
        raise InputError(f"settings must be a SegmentSettings, got {type(settings).__name__}")
    bmin, bmax = settings.blob_min_vox, settings.blob_max_vox
    f_lo, f_hi = settings.auto_size_factors
    max_rel_aspect = settings.max_rel_aspect
    clump_prominence = settings.clump_prominence

    thr = _threshold(vol, settings.threshold, settings.auto_k_sigma)
    mask = vol > thr
    labels, n = ndimage.label(mask, structure=ndimage.generate_binary_structure(3, 1))
    labels = labels.astype(np.int32)
    n_split = 0
    if split_min_sep_vox is not None and clump_prominence > 0:
        sep = np.asarray(
            check_triple(split_min_sep_vox, "split_min_sep_vox", positive=True), dtype=float
        )
        labels, n, n_split = _split_resolved(vol, labels, n, thr, float(clump_prominence), sep)
    slices = ndimage.find_objects(labels)

    info = _blob_stats(vol, labels, n, thr, spacing)
    _mark_edges(vol, labels, info, slices, thr, margin)
    info = [
        (r["label"], r["n_vox"], r["bbox"], r["cen"], r["peak"], r["cov"], r["edge"]) for r in info
    ]

    counts = {"components": len(info)}
    inner = [x for x in info if not x[6]]
    counts["edge"] = len(inner)
    bmin, bmax = _size_bounds(inner, bmin, bmax, f_lo, f_hi)
    sized = [x for x in inner if bmin <= x[1] <= bmax]
    counts["size"] = len(sized)
    ref_cov, whiten = _reference_shape(sized)
    aspect_limit = _aspect_limit(sized, whiten, max_rel_aspect)
    blobs, n_shape, n_clump = _classify(
        info, vol, labels, thr, (bmin, bmax), whiten, aspect_limit, float(clump_prominence)
    )
    counts["shape"] = n_shape
    counts["clump"] = n_clump
    log.info(
        "segment: threshold %.4g, %d components -> %d accepted (size %d..%d voxels)",
        thr,
        counts["components"],
        n_clump,
        bmin,
        bmax,
    )
    return Segmentation(
        labels=labels,
        blobs=tuple(blobs),
        threshold=float(thr),
        size_bounds_vox=(int(bmin), int(bmax)),
        reference_cov_um2=ref_cov,
        counts=counts,
        n_split=n_split,
    )


def _mark_edges(vol, labels, info, slices, thr, margin) -> None:
    """Set every blob record's ``bbox`` and ``edge`` (True when the blob is cut by or too
    close to a face, see :func:`segment`) in place."""
    edge_lo = np.maximum(np.asarray(margin), 1)
    shape = np.asarray(vol.shape)
    for rec, sl in zip(info, slices, strict=True):
        rec["bbox"] = (sl[0].start, sl[0].stop, sl[1].start, sl[1].stop, sl[2].start, sl[2].stop)
        # the blob's maximum must keep off the faces, and its core (above half its height over
        # the threshold) must not be cut by a face; a core longer than half the volume along
        # an axis (the axial image after few iterations) is judged by its maximum alone there
        own = labels[sl] == rec["label"]
        top = np.array(np.unravel_index(np.argmax(np.where(own, vol[sl], -np.inf)), own.shape))
        top += [s.start for s in sl]
        idx = np.nonzero(own & (vol[sl] >= 0.5 * (thr + rec["peak"])))
        lo = np.array([s.start + int(i.min()) for s, i in zip(sl, idx, strict=True)])
        hi = np.array([s.start + int(i.max()) + 1 for s, i in zip(sl, idx, strict=True)])
        cut = ((lo < edge_lo) | (hi > shape - edge_lo)) & (hi - lo < 0.5 * shape)
        rec["edge"] = bool(np.any(top < edge_lo) or np.any(top >= shape - edge_lo) or cut.any())


def _size_bounds(inner, bmin, bmax, f_lo, f_hi) -> tuple[int, int]:
    """The blob size bounds (voxels): ``bmin``/``bmax`` where given, else ``f_lo``/``f_hi``
    times the size-weighted median size of the blobs ``inner`` of at least
    :data:`MIN_AUTO_VOX` voxels."""
    if bmin is None or bmax is None:
        sizes = np.array([x[1] for x in inner], dtype=float)
        ref_pool = sizes[sizes >= MIN_AUTO_VOX]
        ref = _weighted_median(ref_pool, ref_pool) if ref_pool.size else float(MIN_AUTO_VOX)
        lo_auto = max(MIN_AUTO_VOX, int(np.floor(f_lo * ref)))
        hi_auto = max(lo_auto, int(np.ceil(f_hi * ref)))
        bmin = lo_auto if bmin is None else bmin
        bmax = hi_auto if bmax is None else bmax
    return bmin, bmax


def _reference_shape(sized) -> tuple[np.ndarray, np.ndarray | None]:
    """The median covariance (µm², 3 × 3) of the size-accepted blobs and its whitening
    matrix (None and NaN without blobs)."""
    if not sized:
        return np.full((3, 3), np.nan), None
    ref_cov = np.median(np.stack([x[5] for x in sized]), axis=0)
    ref_cov = 0.5 * (ref_cov + ref_cov.T)
    evals, evecs = np.linalg.eigh(ref_cov)
    if not evals.min() > 0:  # fall back to the diagonal
        ref_cov = np.diag(np.maximum(np.diag(ref_cov), 1e-12))
        evals, evecs = np.linalg.eigh(ref_cov)
    return ref_cov, evecs @ np.diag(evals**-0.5) @ evecs.T


def _rel_aspect(whiten, cov) -> float:
    """Aspect ratio of covariance ``cov`` relative to the reference shape (``whiten``)."""
    mu = np.linalg.eigvalsh(whiten @ cov @ whiten)
    return float(np.sqrt(mu.max() / mu.min())) if mu.min() > 0 else float("inf")


def _aspect_limit(sized, whiten, max_rel_aspect) -> float:
    """The aspect limit: ``max_rel_aspect``, or the upper Tukey fence of the size-accepted
    blobs' log aspects where their own scatter is wider (sharp, noisy or sub-voxel images
    scatter more; streaks and merged pairs stay outliers)."""
    aspect_limit = float(max_rel_aspect)
    if len(sized) >= 4:
        logs = np.log([_rel_aspect(whiten, x[5]) for x in sized])
        logs = logs[np.isfinite(logs)]
        if logs.size >= 4:
            q1, q3 = np.percentile(logs, [25, 75])
            aspect_limit = max(aspect_limit, float(np.exp(q3 + 1.5 * (q3 - q1))))
    return aspect_limit


def _classify(info, vol, labels, thr, bounds, whiten, aspect_limit, clump_prominence) -> tuple:
    """Every component as a :class:`Blob`, rejected (with its reason) by the edge, size
    (``bounds``: min, max voxels), shape and clump filters in that order, or accepted.
    Returns (blobs, number passing the shape filter, number accepted)."""
    bmin, bmax = bounds
    blobs = []
    n_shape = n_clump = 0
    for lab, nv, bbox, cen, peak, cov, edge in info:
        common = {
            "label": lab,
            "n_vox": nv,
            "bbox": tuple(int(v) for v in bbox),
            "centroid_vox": tuple(float(v) for v in cen),
            "peak": peak,
        }
        if edge:
            blobs.append(
                Blob(**common, reason="touches the volume edge (maximum within edge margin)")
            )
            continue
        if nv < bmin:
            blobs.append(Blob(**common, reason=f"too small ({nv} < blob_min_vox {bmin})"))
            continue
        if nv > bmax:
            blobs.append(Blob(**common, reason=f"too large ({nv} > blob_max_vox {bmax})"))
            continue
        rel = _rel_aspect(whiten, cov)
        if rel > aspect_limit:
            blobs.append(
                Blob(
                    **common,
                    rel_aspect=rel,
                    reason=f"elongated (relative aspect {rel:.2f} > limit {aspect_limit:.2f})",
                )
            )
            continue
        n_shape += 1
        n_max = _count_maxima(vol, labels, lab, bbox, thr, peak, clump_prominence)
        if n_max >= 2:
            blobs.append(
                Blob(**common, rel_aspect=rel, n_maxima=n_max, reason=f"clump ({n_max} maxima)")
            )
            continue
        n_clump += 1
        blobs.append(Blob(**common, rel_aspect=rel, n_maxima=n_max))
    return blobs, n_shape, n_clump


def _blob_stats(vol, labels, n, thr, spacing) -> list[dict]:
    """Size, peak, centroid and µm² second-moment tensor of labels 1..n (weights I − thr).

    :func:`skimage.measure.regionprops` with ``spacing`` (voxel sizes ``(dz, dy, dx)`` µm):
    the weighted central moments ``μ_pqr`` give the covariance ``C_ij = μ_(e_i+e_j) / μ_000``
    in µm², to which each voxel's own extent adds ``d_i² / 12`` on the diagonal; the weighted
    centroid is returned in voxels.
    """
    from skimage.measure import regionprops

    if n == 0:
        return []
    weights = np.where(labels > 0, np.maximum(vol.astype(np.float64) - thr, 1e-12), 0.0)
    unit = np.eye(3, dtype=int)
    out = []
    for p in regionprops(labels, intensity_image=weights, spacing=tuple(spacing)):
        m = p.moments_weighted_central
        cov = np.array([[m[tuple(unit[i] + unit[j])] for j in range(3)] for i in range(3)])
        out.append(
            {
                "label": int(p.label),
                "n_vox": int(p.num_pixels),
                "cen": np.asarray(p.centroid_weighted, dtype=np.float64) / spacing,
                "peak": float(p.intensity_max) + thr,
                # plus the variance of a voxel's own extent (a uniform box, d² / 12): a blob
                # one voxel wide (a particle image sharpened by many iterations) has a finite
                # width, not a degenerate tensor
                "cov": cov / m[0, 0, 0] + np.diag(spacing**2 / 12.0),
            }
        )
    return out


def _maxima_points(img, sub, h) -> list[np.ndarray]:
    """Voxel positions (local coordinates) of the regional maxima of prominence ≥ ``h`` of
    ``img`` inside the mask ``sub``, brightest first."""
    peaks = h_maxima(img, h) > 0
    lab, n = ndimage.label(peaks & sub, structure=np.ones((3, 3, 3), dtype=bool))
    if n < 2:
        return []
    pts = ndimage.maximum_position(img, lab, range(1, n + 1))
    pts = sorted(pts, key=lambda p: -img[p])
    return [np.asarray(p, dtype=float) for p in pts]


def _split_resolved(vol, labels, n, thr, prominence, sep_vox):
    """Split components whose prominent maxima lie ≥ one ``sep_vox`` (FWHM) apart.

    Returns the new labels, their count and the number of components split.
    """
    from skimage.segmentation import watershed

    slices = ndimage.find_objects(labels)
    out = labels
    nxt = n + 1
    n_split = 0
    for lab, sl in enumerate(slices, start=1):
        if sl is None:
            continue
        sub = labels[sl] == lab
        if sub.sum() < 2 * MIN_AUTO_VOX:
            continue
        img = ndimage.gaussian_filter(vol[sl].astype(np.float64), 0.5, mode="nearest")
        img = np.where(sub, img - thr, 0.0)
        h = prominence * float(img.max())
        if not h > 0:
            continue
        pts = _maxima_points(img, sub, h)
        # keep maxima resolved from every brighter one kept: one FWHM apart, and the valley
        # to the brighter one at least half the fainter one's height deep (fragments of one
        # particle image, as many Richardson–Lucy iterations make them, have shallower ones)
        kept: list[np.ndarray] = []
        for p in pts:
            if kept and not all(np.linalg.norm((p - q) / sep_vox) >= 1.0 for q in kept):
                continue
            ip = tuple(int(v) for v in p)
            if kept and img[ip] < SPLIT_MIN_RATIO * img[tuple(int(v) for v in kept[0])]:
                continue
            if kept and not h_maxima(img, SPLIT_DIP * img[ip])[ip]:
                continue
            kept.append(p)
        if len(kept) < 2:
            continue
        markers = np.zeros(sub.shape, dtype=np.int32)
        for i, p in enumerate(kept):
            markers[tuple(int(v) for v in p)] = i + 1
        parts = watershed(-img, markers, mask=sub)
        if out is labels:
            out = labels.copy()
        region = out[sl]
        for i in range(2, len(kept) + 1):
            region[parts == i] = nxt
            nxt += 1
        n_split += 1
    if n_split:
        log.info("segment: %d components split between resolved maxima", n_split)
    return out, nxt - 1, n_split


def _count_maxima(vol, labels, lab, bbox, thr, peak, prominence) -> int:
    """Regional maxima of prominence ≥ ``prominence (peak − thr)`` inside one blob."""
    if prominence <= 0:
        return 1
    pad = 2
    lo = [max(0, bbox[2 * i] - pad) for i in range(3)]
    hi = [min(vol.shape[i], bbox[2 * i + 1] + pad) for i in range(3)]
    sl = tuple(slice(lo[i], hi[i]) for i in range(3))
    sub = labels[sl] == lab
    img = ndimage.gaussian_filter(vol[sl].astype(np.float64), 0.5, mode="nearest")
    img = np.where(sub, img - thr, 0.0)
    h = prominence * (peak - thr)
    if not h > 0:
        return 1
    peaks = h_maxima(img, h) > 0
    _, n = ndimage.label(peaks & sub, structure=np.ones((3, 3, 3), dtype=bool))
    return max(int(n), 1)
