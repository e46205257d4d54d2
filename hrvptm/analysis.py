"""Compare a variant's detections, links and fields with the truth of its dataset.

One function per kind of study (:data:`hrvptm.config.KINDS`). Each returns an
:class:`Analysis`: per-frame (or per-pair) table rows, pooled summary numbers and the arrays
the plots need. Lengths in µm, strains dimensionless (0.01 = 1 %), Green–Lagrange
``E = (FᵀF − I)/2`` (docs/conventions.md); the imposed strain comes from the prescribed motion's
deformation gradient (``lfsim.motion``): one ``F`` for a homogeneous motion, the analytic
gradient at every grid node for a known heterogeneous field (``gaussian_indentation``,
``stiff_inclusion``), central differences of a user field.

Failed frames
-------------
A frame (or pair) *fails* when what the comparison needs was not measured; its numbers are
then not representative and the study is failed (:mod:`hrvptm.study`: no ✓ in the report,
``status: "failed"``). A frame fails when

- detection found no particle, fewer than :data:`MIN_PARTICLES` (the fewest a 3-D affine
  fit of a pair needs; fewer when the volume holds fewer true particles), or fewer than
  :data:`MIN_DETECTED_FRACTION` of the true particles inside the reconstructed volume;
- (pairs, series) ``track`` could not link it (its pair's status in ``summary.json`` is not
  ``"ok"``), could not grid its field, or its tracking ratio (correct tracks / particles
  detected in both frames) is below :data:`MIN_TRACKING_RATIO` or undefined.

Each row carries a ``failure`` column (empty when the frame is fine), the summary
``failed_frames`` (the number of distinct failed frames) and :attr:`Analysis.failures` the
reasons.

Uncertainty coverage
--------------------
``track`` reports a standard uncertainty σ per particle and axis (``sigma_{x,y,z}_um`` of
its tables) and per displacement (``sqrt(σ_a² + σ_b²)``). :func:`coverage` checks them on
the truth: the fraction of errors within 1σ and 2σ per axis (68 % and 95 % for a right,
Gaussian σ) and the RMS of ``error/σ`` (1 when right). Every analysis adds them to its
summary (``coverage_1sigma_x`` …) and its rows, and the errors with their σ to
:attr:`Analysis.arrays` (``"uncertainty"``) for :func:`hrvptm.plots.plot_uncertainty`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from .compare import (
    AXES,
    TENSOR_COMPONENTS,
    associate,
    green_lagrange,
    numerical_deformation_gradient,
    tensor_stats,
    vector_stats,
)
from .config import AS_AIR
from .errors import StageError
from .stages import VariantPaths, particle_tables

log = logging.getLogger(__name__)

#: Fewest detected particles of a frame (a 3-D affine fit of a pair needs 4).
MIN_PARTICLES = 4
#: Fewest detected particles of a frame, as a fraction of the true ones inside the volume.
MIN_DETECTED_FRACTION = 0.25
#: Lowest tracking ratio of a frame or pair that is not a failure (the studies measure 0.88–1).
MIN_TRACKING_RATIO = 0.5


@dataclass
class Analysis:
    """What one variant measured against the truth.

    Attributes
    ----------
    rows : list of dict
        One per frame (localization, series) or pair (pairs): the CSV table.
    summary : dict
        Pooled numbers (see the analysis functions).
    arrays : dict
        Data for the plots (vectors and fields of the peak frame, …).
    """

    rows: list[dict]
    summary: dict
    arrays: dict = field(default_factory=dict)
    failures: list[dict] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        """Whether any frame failed (see the module docstring)."""
        return bool(self.failures)


# -- inputs ------------------------------------------------------------------------------------
@dataclass
class VariantData:
    """The files of one variant, read once: truth, detections and the volume's extent."""

    study: object
    paths: VariantPaths
    truth_ids: list[np.ndarray]
    truth_xyz: list[np.ndarray]
    detections: list[np.ndarray]
    box_lo: np.ndarray
    box_hi: np.ndarray
    noise: list[dict]
    sigmas: list[np.ndarray] = field(default_factory=list)
    #: SNR of each camera frame as ``recon run`` measured it (None: not recorded)
    snr_measured: list = field(default_factory=list)
    #: Where the reconstruction puts a true depth, ``z_recon ≈ truth_z_scale · z``: 1, or
    #: for the ``as_air`` variant the specimen's axial scale (``Optics.axial_scale``). The
    #: detections are associated with the true particles, and the true particles counted in
    #: the volume, at those depths; every error is measured against the true ones.
    truth_z_scale: float = 1.0

    @classmethod
    def load(cls, study, paths: VariantPaths) -> VariantData:
        from hrvbase.formats.volumes import record_entry
        from hrvbase.io import read_json
        from lfsim.particles import Particles
        from track.tables import read_point_sigmas, read_points_csv

        n = study.experiment.frames
        tids, txyz, dets, noise, sigmas = [], [], [], [], []
        record = read_json(paths.dataset / "dataset.json")
        tables = particle_tables(study, paths)
        recs = {r["frame"]: r for r in record.get("frame_records", [])}
        for k in range(n):
            truth = Particles.from_csv(paths.dataset / "truth" / f"{k:06d}.csv")
            tids.append(np.asarray(truth.ids, dtype=int))
            txyz.append(np.asarray(truth.positions_um, dtype=float))
            table = tables / f"{k:06d}.csv"
            dets.append(read_points_csv(table))
            sigmas.append(read_point_sigmas(table))
            spec = study.experiment.noise_for_frame(k)
            nrec = dict(recs.get(k, {}).get("noise", {}))
            noise.append({"snr": nrec.get("snr", spec.snr), "fps": getattr(spec, "fps", None)})
        meta = read_json(paths.volumes / "recon.json")
        g = meta["grid"]
        corner = record_entry(g, "origin_xy_um")
        lo = np.array([corner[0], corner[1], min(g["depths_um"])], float)
        size = g["lenslet_object_um"] * np.asarray(record_entry(g, "n_lenslets_xy"), float)
        hi = np.array([lo[0] + size[0], lo[1] + size[1], max(g["depths_um"])], float)
        pre = {f.get("index"): f.get("preprocess") or {} for f in meta.get("frames", [])}
        measured = [pre.get(k, {}).get("snr") for k in range(n)]
        for k in range(n):
            noise[k]["snr_measured"] = math.nan if measured[k] is None else float(measured[k])
        z_scale = 1.0
        if paths.variant == AS_AIR:
            from .stages import recon_optics

            z_scale = recon_optics(study, study.dataset_variant(AS_AIR)).axial_scale
        return cls(study, paths, tids, txyz, dets, lo, hi, noise, sigmas, measured, z_scale)

    def _expected(self, xyz: np.ndarray) -> np.ndarray:
        """True positions (N, 3) where the reconstruction puts them (:attr:`truth_z_scale`)."""
        if self.truth_z_scale == 1.0:
            return xyz
        return np.asarray(xyz, float) * np.array([1.0, 1.0, self.truth_z_scale])

    def inv_snr2(self, *frames: int) -> float:
        """``Σ 1 / SNR²`` of the camera frames ``frames`` (``recon run``'s measurement; 0
        for a frame without one): the weight of ``DetectSettings.sigma_snr_um²`` in the
        variance of a position (one frame) or a displacement (two), for
        benchmarks/calibrate_sigma.py."""
        snr = [self.snr_measured[k] if k < len(self.snr_measured) else None for k in frames]
        return float(sum(0.0 if v is None else 1.0 / v**2 for v in snr))

    def in_volume(self, xyz: np.ndarray) -> np.ndarray:
        """Mask of points inside the reconstructed volume."""
        return np.all((xyz >= self.box_lo) & (xyz <= self.box_hi), axis=1)

    def truth_by_id(self, k: int) -> dict[int, np.ndarray]:
        return dict(zip(self.truth_ids[k].tolist(), self.truth_xyz[k], strict=True))

    def associate(self, k: int, points: np.ndarray) -> np.ndarray:
        """Truth id of each point of frame ``k`` (−1: no true particle within the radius)."""
        ids = np.full(len(points), -1, dtype=int)
        truth = self._expected(self.truth_xyz[k])
        i_p, i_t = associate(points, truth, self.study.study.match_radius_um)
        ids[i_p] = self.truth_ids[k][i_t]
        return ids

    def n_in_volume(self, k: int) -> int:
        return int(self.in_volume(self._expected(self.truth_xyz[k])).sum())


#: Coverage a right standard uncertainty gives within 1σ and 2σ (normal errors).
COVERAGE_TARGETS = (0.6827, 0.9545)


def _nan_reduce(reduce, values) -> float:
    """``reduce`` of the values that are not NaN, or NaN when none is (a study whose every
    frame failed), without numpy's all-NaN warning."""
    kept = [float(v) for v in values if not math.isnan(v)]
    return float(reduce(kept)) if kept else math.nan


def coverage(error: np.ndarray, sigma: np.ndarray, prefix: str = "") -> dict[str, float]:
    """How well standard uncertainties describe the actual errors, per axis.

    Parameters
    ----------
    error : ndarray, shape (K, 3)
        Measured − true (µm, x, y, z).
    sigma : ndarray, shape (K, 3)
        Their predicted standard uncertainties (µm); rows with a NaN or non-positive σ are
        left out.

    Returns
    -------
    dict
        ``{prefix}coverage_1sigma_{x,y,z}`` and ``{prefix}coverage_2sigma_{x,y,z}``
        (fractions of ``|error| ≤ σ``, ``≤ 2σ``), ``{prefix}zscore_rms_{x,y,z}`` (RMS of
        ``error/σ``), ``{prefix}sigma_rms_{x,y,z}`` (RMS σ, µm) and
        ``{prefix}coverage_n`` (errors with a σ); NaN without any.
    """
    e = np.asarray(error, dtype=float).reshape(-1, 3)
    sg = np.asarray(sigma, dtype=float).reshape(-1, 3)
    known = np.all(np.isfinite(sg) & (sg > 0), axis=1) & np.all(np.isfinite(e), axis=1)
    e, sg = e[known], sg[known]
    out: dict[str, float] = {f"{prefix}coverage_n": int(known.sum())}
    for j, ax in enumerate(AXES):
        if len(e):
            z = np.abs(e[:, j]) / sg[:, j]
            out[f"{prefix}coverage_1sigma_{ax}"] = float(np.mean(z <= 1.0))
            out[f"{prefix}coverage_2sigma_{ax}"] = float(np.mean(z <= 2.0))
            out[f"{prefix}zscore_rms_{ax}"] = float(np.sqrt(np.mean(z**2)))
            out[f"{prefix}sigma_rms_{ax}"] = float(np.sqrt(np.mean(sg[:, j] ** 2)))
        else:
            for k in ("coverage_1sigma", "coverage_2sigma", "zscore_rms", "sigma_rms"):
                out[f"{prefix}{k}_{ax}"] = math.nan
    return out


def _displacement_sigma(study, sigma_a, sigma_b, displacement_um) -> np.ndarray:
    """σ (K, 3) of displacements between two images of the same particles, as ``track``
    computes it (:func:`track.series.match_sigma` with the study's settings)."""
    from track.series import match_sigma

    common = np.asarray(study.track.detect.sigma_systematic_um, float)[::-1]
    series = study.track.series
    k = np.arange(len(sigma_a))
    return match_sigma(
        np.column_stack([k, k]),
        sigma_a,
        sigma_b,
        common,
        displacement_um=displacement_um,
        bias_sigma_xyz_um=series.bias_sigma_um[::-1],
        bias_length_xyz_um=series.bias_lengths_xyz_um,
        bias_period_um=series.bias_period_um,
    )


def _uncertainty(
    errors: list[np.ndarray],
    sigmas: list[np.ndarray],
    displacements: list[np.ndarray] | None = None,
    inv_snr2: list[float] | None = None,
) -> dict:
    """Pooled errors and σ (K, 3) for the summary and the plots, and for recalibration
    (benchmarks/calibrate_sigma.py) the measured displacement (K, 3) each σ was computed for
    (NaN for positions) and ``Σ 1/SNR²`` (K,) of the frames of each error (one value per
    chunk of ``errors``; :meth:`VariantData.inv_snr2`)."""
    e = np.concatenate([x.reshape(-1, 3) for x in errors]) if errors else np.zeros((0, 3))
    s = np.concatenate([x.reshape(-1, 3) for x in sigmas]) if sigmas else np.zeros((0, 3))
    if displacements is None:
        u = np.full(e.shape, np.nan)
    else:
        u = np.concatenate([x.reshape(-1, 3) for x in displacements]) if errors else e.copy()
    q = np.zeros(len(e))
    if inv_snr2 is not None and errors:
        sizes = [len(x.reshape(-1, 3)) for x in errors]
        q = np.repeat(np.asarray(inv_snr2, dtype=float), sizes)
    return {"error": e, "sigma": s, "displacement": u, "inv_snr2": q}


def _pooled(errors: list[np.ndarray], prefix: str) -> dict:
    e = np.concatenate([x.reshape(-1, 3) for x in errors]) if errors else np.zeros((0, 3))
    return vector_stats(e, prefix)


# -- failed frames -----------------------------------------------------------------------------
def _detection_failure(data: VariantData, k: int) -> str:
    """Why detection failed in frame ``k`` (empty: it did not), see the module docstring."""
    n = len(data.detections[k])
    n_truth = data.n_in_volume(k)
    if n == 0:
        return f"frame {k}: no particle detected ({n_truth} in the volume)"
    if n < min(MIN_PARTICLES, n_truth) or (n_truth and n < MIN_DETECTED_FRACTION * n_truth):
        return f"frame {k}: only {n} of {n_truth} particles detected"
    return ""


def _ratio_failure(where: str, ratio: float, reasons: list) -> list[str]:
    """A tracking ratio below :data:`MIN_TRACKING_RATIO` (or undefined) as a failure, unless
    an earlier reason already explains the frame."""
    if reasons or (math.isfinite(ratio) and ratio >= MIN_TRACKING_RATIO):
        return []
    if not math.isfinite(ratio):
        return [f"{where}: no particle detected in both frames"]
    return [f"{where}: tracking ratio {100 * ratio:.0f} % (< {100 * MIN_TRACKING_RATIO:.0f} %)"]


def _track_failures(paths: VariantPaths) -> dict[int, str]:
    """Pairs ``track`` could not link or grid, by deformed frame, from its ``summary.json``."""
    from hrvbase.errors import HrvError
    from hrvbase.io import read_json

    path = paths.track / "summary.json"
    try:
        summary = read_json(path)
    except HrvError as exc:
        raise StageError(f"{path}: {exc}") from None
    out: dict[int, str] = {}
    for inc in summary.get("increments", []):
        where = f"frames {inc['ref_frame']} → {inc['def_frame']}"
        if inc["status"] != "ok":
            out[int(inc["def_frame"])] = f"{where}: {inc['status']}"
        elif summary.get("fields_requested", True) and inc.get("field_status", "ok") != "ok":
            out[int(inc["def_frame"])] = f"{where}: field {inc['field_status']}"
    return out


def _with_failures(a: Analysis, failures: list[dict]) -> Analysis:
    a.failures = failures
    a.summary["failed_frames"] = len({f["frame"] for f in failures})
    if failures:
        log.warning("%d failed frame(s): %s", a.summary["failed_frames"], failures[0]["reason"])
    return a


# -- localization (Fig. 4a) ----------------------------------------------------------------------
def analyse_localization(data: VariantData) -> Analysis:
    """Detected centres of every frame against the true ones.

    Row keys: ``frame, snr, fps, n_truth`` (true particles inside the reconstructed volume),
    ``n_detected, n_matched, recall, precision`` and ``mean_/rmsd_/maxabs_{x,y,z}`` of
    ``detected − true`` (µm), with their :func:`coverage` by the particles' σ. Summary: the
    same pooled over frames, plus the worst frame's RMSD.
    """
    rows, errs, sigs, failures = [], [], [], []
    for k, det in enumerate(data.detections):
        ids = data.associate(k, det)
        truth = data.truth_by_id(k)
        ok = ids >= 0
        err = det[ok] - np.array([truth[i] for i in ids[ok]]).reshape(-1, 3)
        errs.append(err)
        sigs.append(_frame_sigma(data, k)[ok])
        n_truth = data.n_in_volume(k)
        rows.append(
            {
                "frame": k,
                **data.noise[k],
                "n_truth": n_truth,
                "n_detected": len(det),
                "n_matched": int(ok.sum()),
                "recall": ok.sum() / n_truth if n_truth else math.nan,
                "precision": ok.sum() / len(det) if len(det) else math.nan,
                **vector_stats(err),
                **coverage(err, sigs[-1]),
                "failure": _detection_failure(data, k),
            }
        )
        if rows[-1]["failure"]:
            failures.append({"frame": k, "reason": rows[-1]["failure"]})
    summary = _pooled(errs, "pooled_")
    for ax in AXES:
        summary[f"worst_rmsd_{ax}"] = _nan_reduce(max, [r[f"rmsd_{ax}"] for r in rows])
        summary[f"worst_maxabs_{ax}"] = _nan_reduce(max, [r[f"maxabs_{ax}"] for r in rows])
        summary[f"worst_abs_mean_{ax}"] = _nan_reduce(max, [abs(r[f"mean_{ax}"]) for r in rows])
    summary["mean_recall"] = _nan_reduce(np.mean, [r["recall"] for r in rows])
    unc = _uncertainty(errs, sigs, inv_snr2=[data.inv_snr2(k) for k in range(len(errs))])
    summary.update(coverage(unc["error"], unc["sigma"]))
    return _with_failures(Analysis(rows, summary, {"uncertainty": unc}), failures)


def _frame_sigma(data: VariantData, k: int) -> np.ndarray:
    """σ (N_k, 3) of frame ``k``'s detections (NaN when its table has none)."""
    if k < len(data.sigmas):
        return data.sigmas[k]
    return np.full(data.detections[k].shape, np.nan)


# -- zero-displacement pairs (Figs. 4b, 4c) ------------------------------------------------------
def _pairs(n_frames: int, group: int) -> list[tuple[int, int]]:
    """``(first, other)`` frame pairs of consecutive groups of ``group`` shots."""
    return [(g, g + j) for g in range(0, n_frames - group + 1, group) for j in range(1, group)]


def analyse_pairs(data: VariantData) -> Analysis:
    """Link the first frame of each group of shots to the others (pairs ``(0, 1), (2, 3), …``
    for groups of 2) and compare the displacements with the truth.

    Row keys: ``pair, frame_a, frame_b, snr, fps`` (of the pair's first frame), ``n_a, n_b,
    n_links, n_correct, n_wrong, tracking_ratio`` (correct links / particles detected in both
    frames) and ``u_mean_/u_rmsd_/u_maxabs_{x,y,z}`` of ``measured − true`` displacement (µm).
    """
    from track.matching import LinkSettings, link_pair

    rows, errs, hist, failures, sigs, disp = [], [], [], [], [], []
    group = data.study.study.group_size
    for p, (a, b) in enumerate(_pairs(len(data.detections), group)):
        ca, cb = data.detections[a], data.detections[b]
        ida, idb = data.associate(a, ca), data.associate(b, cb)
        trackable = len(np.intersect1d(ida[ida >= 0], idb[idb >= 0]))
        row = {"pair": p, "frame_a": a, "frame_b": b, **data.noise[a], "n_a": len(ca)}
        row["n_b"] = len(cb)
        err = np.zeros((0, 3))
        sig = du = np.zeros((0, 3))
        found = {f: _detection_failure(data, f) for f in (a, b)}
        fails = [(f, r) for f, r in found.items() if r]
        if min(len(ca), len(cb)) >= MIN_PARTICLES:
            res = link_pair(ca, cb, LinkSettings())
            m = res.matches if res.ok else np.zeros((0, 2), int)
            if not res.ok:
                fails.append((b, f"frames {a} → {b}: not linked: {res.reason}"))
        else:
            m = np.zeros((0, 2), int)
        ta, tb = data.truth_by_id(a), data.truth_by_id(b)
        known = ida[m[:, 0]] >= 0 if len(m) else np.zeros(0, bool)
        mk = m[known]
        if len(mk):
            true_u = np.array([tb[i] - ta[i] for i in ida[mk[:, 0]]])
            err = (cb[mk[:, 1]] - ca[mk[:, 0]]) - true_u
            sa, sb = _frame_sigma(data, a)[mk[:, 0]], _frame_sigma(data, b)[mk[:, 1]]
            du = cb[mk[:, 1]] - ca[mk[:, 0]]
            sig = _displacement_sigma(data.study, sa, sb, du)
        correct = int(np.sum(ida[m[:, 0]] == idb[m[:, 1]]) if len(m) else 0)
        correct -= int(np.sum((ida[m[:, 0]] < 0) & (idb[m[:, 1]] < 0)) if len(m) else 0)
        row.update(
            {
                "n_links": len(m),
                "n_correct": correct,
                "n_wrong": len(m) - correct,
                "tracking_ratio": correct / trackable if trackable else math.nan,
                **vector_stats(err, "u_"),
                **coverage(err, sig, "u_"),
            }
        )
        ratio = _ratio_failure(f"frames {a} → {b}", row["tracking_ratio"], fails)
        fails += [(b, r) for r in ratio]
        row["failure"] = "; ".join(r for _, r in fails)
        failures += [{"frame": f, "reason": r} for f, r in fails]
        rows.append(row)
        errs.append(err)
        hist.append(err)
        sigs.append(sig)
        disp.append(du)
    summary = _pooled(errs, "pooled_u_")
    for ax in AXES:
        summary[f"worst_u_rmsd_{ax}"] = _nan_reduce(max, [r[f"u_rmsd_{ax}"] for r in rows])
    summary["min_tracking_ratio"] = _nan_reduce(min, [r["tracking_ratio"] for r in rows])
    summary["wrong_links"] = int(sum(r["n_wrong"] for r in rows))
    pairs = _pairs(len(data.detections), group)
    unc = _uncertainty(errs, sigs, disp, [data.inv_snr2(a, b) for a, b in pairs])
    summary.update(coverage(unc["error"], unc["sigma"], "u_"))
    arrays = {"errors": hist, "uncertainty": unc}
    return _with_failures(Analysis(rows, summary, arrays), failures)


# -- tracked series (Figs. 5-7) ------------------------------------------------------------------
def imposed_amplitude(motion, k: int) -> tuple[str, float]:
    """Name and value of the imposed motion at frame ``k`` for the plots' abscissa."""
    name = getattr(motion, "type_name", "")
    if name == "translation":
        return "translation (µm)", float(np.linalg.norm(motion.amplitude(k)))
    if name == "rotation":
        return "rotation (°)", float(motion.amplitude(k))
    if name == "uniaxial_tension":
        return "engineering strain (%)", 100.0 * float(motion.amplitude(k))
    if name == "simple_shear":
        return "shear γ (%)", 100.0 * float(motion.amplitude(k))
    if name == "gaussian_indentation":
        return "indentation depth (µm)", float(motion.amplitude(k))
    if name == "stiff_inclusion":
        return "far-field strain (%)", 100.0 * float(motion.amplitude(k))
    return "frame", float(k)


def imposed_F(motion, k: int, X_um: np.ndarray) -> np.ndarray:
    """Deformation gradient of the prescribed motion from frame 0 to frame ``k``: (3, 3) for a
    homogeneous motion, else (K, 3, 3) at the reference points ``X_um``."""
    if motion is None:
        return np.eye(3)
    if getattr(motion, "homogeneous", False):
        return np.asarray(motion.deformation_gradient(k), float)
    if hasattr(motion, "deformation_gradient_at"):  # a known field: its analytic gradient
        return np.asarray(motion.deformation_gradient_at(X_um, k), float)
    return numerical_deformation_gradient(lambda X: motion.displacement(X, k), X_um)


def is_layer(points_um: np.ndarray, ratio: float = 0.05) -> bool:
    """``True`` when particles lie in (nearly) one plane, where a 3-D strain is undefined.

    The cloud is a layer when its smallest principal standard deviation is below ``ratio``
    times the middle one (e.g. the single layer of Fig. 5b: a few µm of localisation noise
    over a millimetre-wide plane). Fewer than 4 points also count as a layer.
    """
    p = np.asarray(points_um, dtype=float).reshape(-1, 3)
    if p.shape[0] < 4:
        return True
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return bool(sv[2] < ratio * sv[1])


def _sampling_floor(truth0: dict, ids: np.ndarray, true_u: np.ndarray, fld) -> np.ndarray | None:
    """Strain on ``fld``'s supported nodes from the *true* displacements of the tracked
    particles, interpolated exactly (no noise, no smoothing): the error left by sampling the
    field at these particles only, shape (K, 3, 3); None with fewer than 10 particles."""
    from track.fields import GridSettings, field_on_grid, fit_displacement

    if len(ids) < 10:
        return None
    P0 = np.array([truth0[i] for i in ids])
    ideal = field_on_grid(fit_displacement(P0, true_u, GridSettings(smoothing=0.0)), fld.axes)
    return ideal.E[fld.mask]


def heterogeneous_errors(motion, k: int, fld, X0_um: np.ndarray, grid, E_meas, E_true) -> dict:
    """A heterogeneous field against its truth at the same nodes, and against the best the
    pipeline could do with these particles.

    Parameters
    ----------
    motion : lfsim.motion.Motion
        The imposed (non-homogeneous) motion.
    k : int
        Frame (the field is from frame 0 to ``k``).
    fld : track.fields.GridField
        The measured total field of frame ``k``.
    X0_um : numpy.ndarray, shape (N, 3)
        Detected frame-0 positions of the particles tracked to frame ``k`` (µm).
    grid : track.fields.GridSettings
        The study's gridding settings (``[track.grid]``).
    E_meas, E_true : numpy.ndarray, shape (K, 3, 3)
        Measured and imposed Green–Lagrange strain at the K supported nodes of ``fld``.

    Returns
    -------
    dict
        ``u_node_rmsd_{x,y,z}``: the gridded displacement against the imposed one at the
        supported nodes (µm); ``u_node_ideal_rmsd_{x,y,z}`` and ``E_ideal_rmsd_c``: the same
        for the *ideal* field, the imposed displacement evaluated at the detected particles
        ``X0_um`` and gridded exactly as the study grids (same settings, same grid, same
        nodes): what perfect localisation and tracking would give, the error of sampling the
        field at these particles only (NaN with fewer than 10 particles);
        ``E_ratio_ideal_c = E_rmsd_c / E_ideal_rmsd_c``. Strains dimensionless.
    """
    from track.fields import field_on_grid, fit_displacement

    Z, Y, X = np.meshgrid(fld.z_um, fld.y_um, fld.x_um, indexing="ij")
    nodes = np.column_stack([X[fld.mask], Y[fld.mask], Z[fld.mask]])
    u_true = motion.displacement(nodes, k)
    out = {}
    d_meas = fld.u[fld.mask] - u_true
    ideal = None
    if len(X0_um) >= 10:
        u_at = motion.displacement(X0_um, k)
        ideal = field_on_grid(fit_displacement(X0_um, u_at, grid), fld.axes)
    for j, ax in enumerate(AXES):
        out[f"u_node_rmsd_{ax}"] = float(np.sqrt(np.mean(d_meas[:, j] ** 2)))
        out[f"u_node_ideal_rmsd_{ax}"] = (
            float(np.sqrt(np.mean((ideal.u[fld.mask][:, j] - u_true[:, j]) ** 2)))
            if ideal is not None
            else math.nan
        )
    for c, (i, j) in TENSOR_COMPONENTS.items():
        meas = float(np.sqrt(np.mean((E_meas[:, i, j] - E_true[:, i, j]) ** 2)))
        if ideal is not None:
            d = ideal.E[fld.mask][:, i, j] - E_true[:, i, j]
            floor = float(np.sqrt(np.mean(d**2)))
        else:
            floor = math.nan
        out[f"E_ideal_rmsd_{c}"] = floor
        out[f"E_ratio_ideal_{c}"] = meas / floor if floor > 0 else math.nan
    return out


def _pool_heterogeneous(rows: list[dict], summary: dict) -> None:
    """Pooled (RMS over frames, weighted by the nodes) numbers of :func:`heterogeneous_errors`."""
    rows = [r for r in rows if "E_ideal_rmsd_xx" in r and r.get("E_n")]
    if not rows:
        return
    w = np.array([r["E_n"] for r in rows], float)

    def pool(key: str) -> float:
        v = np.array([r[key] for r in rows], float)
        ok = np.isfinite(v)
        return float(np.sqrt(np.sum(w[ok] * v[ok] ** 2) / np.sum(w[ok]))) if ok.any() else math.nan

    for ax in AXES:
        summary[f"pooled_u_node_rmsd_{ax}"] = pool(f"u_node_rmsd_{ax}")
        summary[f"pooled_u_node_ideal_rmsd_{ax}"] = pool(f"u_node_ideal_rmsd_{ax}")
    for c in TENSOR_COMPONENTS:
        summary[f"pooled_E_ideal_rmsd_{c}"] = floor = pool(f"E_ideal_rmsd_{c}")
        meas = summary.get(f"pooled_E_rmsd_{c}", math.nan)
        summary[f"pooled_E_ratio_ideal_{c}"] = meas / floor if floor > 0 else math.nan


def _frame_strain(row: dict, st, k: int, fld, tracked: tuple, strain_err, floor_err):
    """Compare the gridded strain ``fld`` of frame ``k`` with the imposed one: its statistics
    (and, for a heterogeneous motion, the node-by-node comparison) into ``row``, its errors
    and those of the sampling floor appended to ``strain_err`` and ``floor_err`` by
    component. ``tracked``: the reference positions of the tracked true particles, the true
    positions at frame 0 (by particle id), their ids and their true displacements. Returns
    the imposed strain at the field's nodes."""
    motion = st.experiment.motion
    x_tracked, truth0, ids, true_u = tracked
    Z, Y, X = np.meshgrid(fld.z_um, fld.y_um, fld.x_um, indexing="ij")
    nodes = np.column_stack([X[fld.mask], Y[fld.mask], Z[fld.mask]])
    F_true = imposed_F(motion, k, nodes)
    E_true = green_lagrange(F_true)
    E_meas = fld.E[fld.mask]
    ts = tensor_stats(E_meas, E_true, "E_", n_independent=max(len(ids), 1))
    row.update(ts)
    if motion is not None and not getattr(motion, "homogeneous", False):
        E_t = np.broadcast_to(E_true, E_meas.shape)
        grid = st.track.series.grid
        row.update(heterogeneous_errors(motion, k, fld, x_tracked, grid, E_meas, E_t))
    E_floor = _sampling_floor(truth0, ids, true_u, fld)
    for c in TENSOR_COMPONENTS:
        i, j = TENSOR_COMPONENTS[c]
        t = np.broadcast_to(E_true, E_meas.shape)[:, i, j]
        strain_err[c].append(E_meas[:, i, j] - t)
        if E_floor is not None:
            d = E_floor[:, i, j] - t
            row[f"E_floor_rmsd_{c}"] = float(np.sqrt(np.mean(d**2)))
            floor_err[c].append(d)
    return E_true


def _series_summary(rows: list[dict], errs: list, strain_err: dict, floor_err: dict) -> dict:
    """The pooled and worst-frame numbers of :func:`analyse_series` over its ``rows``."""
    summary = _pooled(errs, "pooled_u_")
    for ax in AXES:
        summary[f"worst_u_rmsd_{ax}"] = _nan_reduce(max, [r[f"u_rmsd_{ax}"] for r in rows])
    for c, chunks in strain_err.items():
        e = np.concatenate(chunks) if chunks else np.zeros(0)
        summary[f"pooled_E_rmsd_{c}"] = float(np.sqrt(np.mean(e**2))) if len(e) else math.nan
        f = np.concatenate(floor_err[c]) if floor_err[c] else np.zeros(0)
        summary[f"pooled_E_floor_rmsd_{c}"] = float(np.sqrt(np.mean(f**2))) if len(f) else math.nan
        summary[f"pooled_E_err_{c}"] = float(e.mean()) if len(e) else math.nan
        vals = [abs(r[f"E_err_{c}"]) for r in rows if not math.isnan(r[f"E_err_{c}"])]
        summary[f"worst_E_abs_mean_err_{c}"] = float(max(vals)) if vals else math.nan
    _pool_heterogeneous(rows, summary)
    summary["min_tracking_ratio"] = _nan_reduce(min, [r["tracking_ratio"] for r in rows])
    summary["wrong_tracks"] = int(sum(r["n_tracked"] - r["n_correct"] for r in rows))
    return summary


def analyse_series(data: VariantData) -> Analysis:
    """Cumulative displacements of the tracked particles and the gridded strain fields.

    Row keys (frame ``k`` against frame 0): ``frame, time_s, amplitude`` (imposed, see
    :func:`imposed_amplitude`), ``n_detected, n_tracked`` (tracks present in frames 0 and
    ``k`` whose start is a true particle), ``n_correct, tracking_ratio`` (correct tracks /
    particles detected in both frames), ``u_true_{x,y,z}`` (mean imposed displacement),
    ``u_meas_{x,y,z}``, ``u_mean_/u_rmsd_/u_maxabs_{x,y,z}`` (µm) and for the strain field
    (nodes supported by particles) ``E_true_c, E_meas_c, E_se_c, E_err_c, E_rmsd_c`` for
    ``c`` in xx, yy, zz, xy, xz, yz (``E_se`` with n = tracked particles). ``E_floor_rmsd_c``
    is the sampling floor: the RMSD of the strain gridded (exactly, on the same grid and nodes)
    from the *true* displacements of the same tracked particles — zero for homogeneous
    motions, the error no tracker can beat with this particle density otherwise. For a
    heterogeneous motion (not homogeneous: a known field or a user field) the rows also hold
    the node-by-node comparison of :func:`heterogeneous_errors` (``u_node_rmsd_*``,
    ``u_node_ideal_rmsd_*``, ``E_ideal_rmsd_*``, ``E_ratio_ideal_*``) and the summary their
    pooled values (``pooled_u_node_rmsd_*``, ``pooled_E_ideal_rmsd_*``,
    ``pooled_E_ratio_ideal_*``).
    """
    from track.field_files import read_field_npz
    from track.tables import read_tracks_csv

    st = data.study
    motion = st.experiment.motion
    n = st.experiment.frames
    tr_path = data.paths.track / "tracks.csv"
    if not tr_path.is_file():
        raise StageError(f"missing {tr_path}")
    tracks = read_tracks_csv(tr_path)
    xyz = np.column_stack([tracks["x_um"], tracks["y_um"], tracks["z_um"]])
    sxyz = np.column_stack([tracks["sigma_x_um"], tracks["sigma_y_um"], tracks["sigma_z_um"]])
    fr, tid = tracks["frame"], tracks["track_id"]
    at0 = fr == 0
    ids0 = tid[at0]
    x0 = xyz[at0]
    truth0 = data.truth_by_id(0)
    tid0_truth = data.associate(0, x0)
    det_ids0 = data.associate(0, data.detections[0])
    rows, errs, strain_err = [], [], {c: [] for c in TENSOR_COMPONENTS}
    sigs, disp = [], []
    s0 = sxyz[at0]
    linked = _track_failures(data.paths)
    failures = []
    if reason := _detection_failure(data, 0):
        failures.append({"frame": 0, "reason": reason})
    floor_err: dict[str, list] = {c: [] for c in TENSOR_COMPONENTS}
    arrays: dict = {"amplitude_label": imposed_amplitude(motion, 1)[0] if motion else "frame"}
    dt = st.study.time_step_s
    vectors: dict[int, dict] = {}
    peak_field, peak_amp = None, -math.inf
    flat = is_layer(x0)
    if flat:
        log.info("the tracked particles form a layer: no 3-D strain is compared")
    for k in range(1, n):
        amp = imposed_amplitude(motion, k)[1] if motion else float(k)
        atk = fr == k
        _, i0, ik = np.intersect1d(ids0, tid[atk], return_indices=True)
        xk = xyz[atk][ik]
        start = tid0_truth[i0]
        end = data.associate(k, xk)
        known = start >= 0
        truthk = data.truth_by_id(k)
        true_u = np.array([truthk[i] - truth0[i] for i in start[known]]).reshape(-1, 3)
        meas_u = (xk - x0[i0])[known]
        err = meas_u - true_u
        errs.append(err)
        sigs.append(_displacement_sigma(st, s0[i0], sxyz[atk][ik], xk - x0[i0])[known])
        disp.append(meas_u)
        correct = int(np.sum((start == end) & known))
        det_idsk = data.associate(k, data.detections[k])
        trackable = len(np.intersect1d(det_ids0[det_ids0 >= 0], det_idsk[det_idsk >= 0]))
        row = {
            "frame": k,
            "time_s": k * dt if dt else math.nan,
            "amplitude": amp,
            "n_detected": len(data.detections[k]),
            "n_tracked": int(known.sum()),
            "n_correct": correct,
            "tracking_ratio": correct / trackable if trackable else math.nan,
        }
        reasons = [r for r in (linked.get(k, ""), _detection_failure(data, k)) if r]
        reasons += _ratio_failure(f"frame {k}", row["tracking_ratio"], reasons)
        failures += [{"frame": k, "reason": r} for r in reasons]
        for j, ax in enumerate(AXES):
            row[f"u_true_{ax}"] = float(true_u[:, j].mean()) if len(true_u) else math.nan
            row[f"u_meas_{ax}"] = float(meas_u[:, j].mean()) if len(meas_u) else math.nan
        row.update(vector_stats(err, "u_"))
        row.update(coverage(err, sigs[-1], "u_"))
        fpath = data.paths.track / "fields" / f"{k:06d}.npz"
        if fpath.is_file() and not flat:
            fld = read_field_npz(fpath)
            tracked = (x0[i0][known], truth0, start[known], true_u)
            E_true = _frame_strain(row, st, k, fld, tracked, strain_err, floor_err)
            if abs(amp) >= peak_amp:
                peak_amp = abs(amp)
                peak_field = {"frame": k, "field": fld, "E_true": E_true}
        else:
            row.update(tensor_stats(np.zeros((0, 3, 3)), np.eye(3), "E_"))
        row["failure"] = "; ".join(reasons)
        rows.append(row)
        vectors[k] = {"X_um": x0[i0][known], "true_u": true_u, "meas_u": meas_u}
    # The plots show the peak frame (largest imposed amplitude; the last one on ties).
    peak = max(range(1, n), key=lambda k: (abs(rows[k - 1]["amplitude"]), k))
    arrays["peak_frame"] = peak
    arrays["motion"] = motion
    arrays["vectors"] = vectors[peak]
    if peak_field is not None:
        arrays["field"] = peak_field
    summary = _series_summary(rows, errs, strain_err, floor_err)
    unc = _uncertainty(errs, sigs, disp, [data.inv_snr2(0, k) for k in range(1, n)])
    summary.update(coverage(unc["error"], unc["sigma"], "u_"))
    arrays["uncertainty"] = unc
    return _with_failures(Analysis(rows, summary, arrays), failures)


ANALYSES = {
    "localization": analyse_localization,
    "pairs": analyse_pairs,
    "series": analyse_series,
}


def analyse(study, paths: VariantPaths) -> Analysis:
    """Run the analysis of ``study.study.kind`` on one variant's files."""
    return ANALYSES[study.study.kind](VariantData.load(study, paths))
