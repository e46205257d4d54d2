"""The comparison with the truth on synthetic point clouds with known errors (no rendering).

A fake variant folder holds what lfsim, recon and track would write: truth tables, the
dataset record, the volume extent and particle tables made from the truth plus a known bias
and noise. The analyses must report exactly those errors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hrvptm.analysis import (
    VariantData,
    analyse_localization,
    analyse_pairs,
    analyse_series,
    is_layer,
)
from hrvptm.config import study_from_dict
from hrvptm.stages import VariantPaths

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def _study(frames: int, motion: dict | None, kind: str, snr=17.0, **study):
    data = {
        "experiment": {"name": "synthetic", "scene": str(SCENES / "medium.xml"), "frames": frames},
        "particles": {
            "kind": "box",
            "count": 60,
            "bounds_xyz_um": [[-400, 400], [-300, 300], [120, 400]],
        },
        "noise": {"model": "gaussian", "snr": snr},
        "study": {"kind": kind, **study},
    }
    if motion:
        data["motion"] = motion
    return study_from_dict(data, base_dir=SCENES)


def _write_csv(path: Path, header: str, rows: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt="%.9g")


def _fake_variant(tmp: Path, study, bias, noise_um, seed=0, drop=(), keep_n=None, name="v"):
    """Truth from the study's motion; detections = truth + bias + N(0, noise) (per axis).
    ``keep_n``: ``{frame: n}`` keeps only ``n`` detections of those frames (failed frames)."""
    rng = np.random.default_rng(seed)
    exp = study.experiment
    X = np.column_stack(
        [rng.uniform(-400, 400, 60), rng.uniform(-300, 300, 60), rng.uniform(120, 400, 60)]
    )
    paths = VariantPaths(tmp / name)
    records = []
    for k in range(exp.frames):
        x = exp.positions(X, k)
        ids = np.arange(len(X))
        _write_csv(
            paths.dataset / "truth" / f"{k:06d}.csv",
            "id,x_um,y_um,z_um,diameter_um,brightness",
            np.column_stack([ids, x, np.full(len(X), 15.0), np.ones(len(X))]),
        )
        det = x + np.asarray(bias) + rng.normal(0, 1, x.shape) * np.asarray(noise_um)
        keep = np.setdiff1d(ids, drop) if k > 0 else ids
        det = det[keep][rng.permutation(len(keep))]
        rows = det[: (keep_n or {}).get(k, len(det))]
        _write_csv(paths.track / "particles" / f"{k:06d}.csv", "x_um,y_um,z_um", rows)
        records.append({"frame": k, "noise": {"snr": exp.noise_for_frame(k).snr}})
    (paths.dataset / "dataset.json").write_text(json.dumps({"frame_records": records}))
    paths.volumes.mkdir(parents=True)
    grid = {"origin_um": [-500, -380], "depths_um": [40, 460], "lenslet_object_um": 25.0}
    grid["n_lenslets"] = [40, 30]
    (paths.volumes / "recon.json").write_text(json.dumps({"grid": grid}))
    return paths


def _link(tmp: Path, paths, frames: int) -> None:
    """Link the (already detected) clouds with the track library, as a study would (failed
    pairs are kept: the analysis counts them)."""
    from track.fields import GridSettings
    from track.pipeline import track_clouds
    from track.series import SeriesSettings

    clouds = [paths.track / "particles" / f"{k:06d}.csv" for k in range(frames)]
    link_dir = tmp / "linked"
    series = SeriesSettings(grid=GridSettings(target_nodes=4000))
    track_clouds(clouds, link_dir, series=series, allow_partial=True)
    for name in ("tracks.csv", "fields", "summary.json"):
        if (link_dir / name).exists():  # no fields when no increment could be linked
            (link_dir / name).rename(paths.track / name)


def test_localization_reports_the_injected_bias_and_noise(tmp_path):
    study = _study(3, None, "localization")
    paths = _fake_variant(tmp_path, study, bias=(0.5, -0.2, 3.0), noise_um=(0.3, 0.3, 2.0))
    a = analyse_localization(VariantData.load(study, paths))
    assert len(a.rows) == 3
    for r in a.rows:
        assert r["n_truth"] == r["n_detected"] == r["n_matched"] == 60
        assert r["recall"] == r["precision"] == 1.0
    s = a.summary
    assert s["pooled_mean_x"] == pytest.approx(0.5, abs=0.06)
    assert s["pooled_mean_z"] == pytest.approx(3.0, abs=0.4)
    assert s["pooled_rmsd_y"] == pytest.approx(np.hypot(0.2, 0.3), rel=0.15)
    assert s["pooled_rmsd_z"] == pytest.approx(np.hypot(3.0, 2.0), rel=0.15)


def test_pairs_cancel_the_bias_and_add_the_noise_of_both_frames(tmp_path):
    study = _study(4, None, "pairs")
    paths = _fake_variant(tmp_path, study, bias=(2.0, 2.0, 5.0), noise_um=(0.2, 0.2, 1.0))
    a = analyse_pairs(VariantData.load(study, paths))
    assert [(r["frame_a"], r["frame_b"]) for r in a.rows] == [(0, 1), (2, 3)]
    for r in a.rows:
        assert r["n_correct"] == r["n_links"] == 60
        assert r["tracking_ratio"] == 1.0 and r["n_wrong"] == 0
    # Zero displacement: a constant bias cancels, independent noise adds in quadrature.
    assert a.summary["pooled_u_mean_x"] == pytest.approx(0.0, abs=0.06)
    assert a.summary["pooled_u_rmsd_x"] == pytest.approx(0.2 * np.sqrt(2), rel=0.2)
    assert a.summary["pooled_u_rmsd_z"] == pytest.approx(1.0 * np.sqrt(2), rel=0.2)


def test_pairs_of_three_shots(tmp_path):
    study = _study(6, None, "pairs", group_size=3)
    paths = _fake_variant(tmp_path, study, bias=(0, 0, 0), noise_um=(0.1, 0.1, 0.5))
    a = analyse_pairs(VariantData.load(study, paths))
    assert [(r["frame_a"], r["frame_b"]) for r in a.rows] == [(0, 1), (0, 2), (3, 4), (3, 5)]


def _shear_xz(step_gamma: float) -> dict:
    """Simple shear in the xz plane about z = 250 µm, ``step_gamma`` more every frame."""
    return {
        "type": "simple_shear",
        "plane": "xz",
        "step_gamma": step_gamma,
        "center_xyz_um": [0, 0, 250],
    }


def test_series_shear_displacements_strains_and_tracking(tmp_path):
    study = _study(4, _shear_xz(0.05), "series")
    paths = _fake_variant(
        tmp_path, study, bias=(1.0, 1.0, 4.0), noise_um=(0.05, 0.05, 0.2), drop=(3, 7)
    )
    _link(tmp_path, paths, 4)
    a = analyse_series(VariantData.load(study, paths))
    assert [r["frame"] for r in a.rows] == [1, 2, 3]
    assert [r["amplitude"] for r in a.rows] == pytest.approx([5.0, 10.0, 15.0])  # γ in %
    for r in a.rows:
        assert r["n_tracked"] == r["n_correct"] == 58  # two particles lost after frame 0
        assert r["tracking_ratio"] == 1.0
        assert r["u_rmsd_x"] < 0.15 and r["u_rmsd_z"] < 0.6
        assert r["E_true_xz"] == pytest.approx(r["amplitude"] / 200)  # E_xz = γ / 2
        assert r["E_true_zz"] == pytest.approx((r["amplitude"] / 100) ** 2 / 2)
        assert abs(r["E_err_xz"]) < 0.005  # 0.5 % strain with 0.05 µm noise
        assert r["E_floor_rmsd_xz"] < 1e-6  # an affine field is sampled exactly
    assert a.summary["wrong_tracks"] == 0
    assert a.summary["pooled_E_floor_rmsd_zz"] < 1e-6
    assert "E_ideal_rmsd_xx" not in a.rows[0]  # node-by-node columns: heterogeneous motions
    assert a.arrays["peak_frame"] == 3
    assert a.arrays["field"]["frame"] == 3


def test_a_layer_of_particles_has_no_3d_strain():
    """Fig. 5b's single layer: ±3 µm of axial noise over a 1.9 × 1.1 mm plane (tilted, so that
    the test does not depend on the axes) is a layer; the paper-size volumes are not."""
    rng = np.random.default_rng(2)
    p = np.c_[rng.uniform(-950, 950, 60), rng.uniform(-550, 550, 60), rng.normal(160, 3, 60)]
    c, s_ = np.cos(0.3), np.sin(0.3)
    tilt = np.array([[1, 0, 0], [0, c, -s_], [0, s_, c]])
    assert is_layer(p) and is_layer(p @ tilt.T) and is_layer(p[:3])
    box = np.c_[p[:, :2], rng.uniform(100, 400, 60)]  # the 300 µm tall seeded volume
    assert not is_layer(box)
    test_size = np.c_[rng.uniform(-220, 220, (18, 2)), rng.uniform(120, 400, 18)]
    assert not is_layer(test_size)


def test_series_of_a_non_affine_field_reports_the_sampling_floor(tmp_path):
    """A user field (the non-uniform shear study's) with almost noise-free detections: the
    strain error is the floor of sampling the field at 60 particles, which is reported, and
    the measured error sits on it (GCV does not add to it)."""
    fn = SCENES / "experiments" / "fields" / "nonuniform_shear.py"
    motion = {
        "type": "user_field",
        "function": f"{fn}:nonuniform_shear",
        "params": {"gamma_step": 0.05, "width_um": 600.0},
    }
    study = _study(3, motion, "series")
    paths = _fake_variant(tmp_path, study, bias=(0, 0, 0), noise_um=(0.02, 0.02, 0.05))
    _link(tmp_path, paths, 3)
    a = analyse_series(VariantData.load(study, paths))
    last = a.rows[-1]
    for c in ("xz", "xy"):
        floor = last[f"E_floor_rmsd_{c}"]
        assert floor > 0.002  # a cosine across 600 µm sampled by 60 particles: not exact
        assert floor <= last[f"E_rmsd_{c}"] < 1.1 * floor  # measured 0.81/0.83, 0.67/0.70 %
    assert a.summary["pooled_E_floor_rmsd_xz"] > 0.002


def test_series_of_a_stiff_inclusion_against_the_truth_node_by_node(tmp_path):
    """A known heterogeneous field (a rigid sphere in a matrix stretched along x): the truth is
    the analytic field at every node, not an affine fit; with almost noise-free detections the
    measured error sits on the ideal field's (the truth at the detected particles, gridded the
    study's way), and the report has the section that compares them."""
    from hrvptm.report import markdown

    motion = {
        "type": "stiff_inclusion",
        "radius_um": 130.0,
        "center_xyz_um": [0, 0, 260],
        "step_strain": 0.05,
    }
    study = _study(3, motion, "series")
    paths = _fake_variant(tmp_path, study, bias=(0, 0, 0), noise_um=(0.02, 0.02, 0.05))
    _link(tmp_path, paths, 3)
    a = analyse_series(VariantData.load(study, paths))
    assert a.arrays["amplitude_label"] == "far-field strain (%)"
    assert [r["amplitude"] for r in a.rows] == pytest.approx([5.0, 10.0])
    E_true = a.arrays["field"]["E_true"]  # per node, varying: 3 ε at the poles, ≈ 0 inside
    assert E_true.ndim == 3 and np.ptp(E_true[:, 0, 0]) > 0.1
    last = a.rows[-1]
    assert last["tracking_ratio"] == 1.0
    for c in ("xx", "yy", "xy"):
        ideal = last[f"E_ideal_rmsd_{c}"]
        assert ideal > 0.002  # 60 particles do not resolve the sphere: a real sampling floor
        assert 0.9 < last[f"E_ratio_ideal_{c}"] < 1.25  # measured / ideal ≈ 1 without noise
        assert last[f"E_rmsd_{c}"] == pytest.approx(last[f"E_ratio_ideal_{c}"] * ideal)
    for ax in "xyz":
        assert last[f"u_node_rmsd_{ax}"] < 1.5 * last[f"u_node_ideal_rmsd_{ax}"] + 0.05
    s = a.summary
    assert s["pooled_E_ideal_rmsd_xx"] > 0.002 and 0.9 < s["pooled_E_ratio_ideal_xx"] < 1.25
    assert s["pooled_u_node_rmsd_x"] > 0
    variant = {"seconds": {}, "summary": s, "rows": a.rows, "failures": []}
    md = markdown(study.to_dict(), {"variants": {"mismatched": variant}})
    assert "## Heterogeneous field against the truth and the sampling floor" in md
    row = next(
        line for line in md.splitlines() if line.startswith("| mismatched | strain RMSD E_xx")
    )
    assert f"{100 * s['pooled_E_ideal_rmsd_xx']:.2f} %" in row


def test_localization_counts_a_frame_without_detections_as_failed(tmp_path):
    study = _study(3, None, "localization")
    paths = _fake_variant(tmp_path, study, (0, 0, 0), (0.1, 0.1, 0.5), keep_n={1: 0, 2: 10})
    a = analyse_localization(VariantData.load(study, paths))
    assert [r["failure"] for r in a.rows] == [
        "",
        "frame 1: no particle detected (60 in the volume)",
        "frame 2: only 10 of 60 particles detected",  # < 25 % of the true particles
    ]
    assert a.summary["failed_frames"] == 2 and a.failed
    assert a.summary["pooled_rmsd_x"] < 0.2  # the numbers alone would look fine


def _failed_series(tmp_path, name="v", frames=5, keep_n=None):
    """Simple shear (Fig. 6c) over ``frames`` frames, linked, whose frames ``keep_n`` (as
    :func:`_fake_variant`) kept few or no detections; by default frame 2 of 5 kept only 3:
    pairs 1 → 2 and 2 → 3 cannot be linked and no track from frame 0 reaches frames 2–4."""
    study = _study(frames, _shear_xz(0.02), "series", figure="6c")
    keep_n = {2: 3} if keep_n is None else keep_n
    paths = _fake_variant(tmp_path, study, (0, 0, 0), (0.05, 0.05, 0.2), keep_n=keep_n, name=name)
    _link(tmp_path, paths, frames)
    return study, paths


def test_series_with_untracked_frames_is_failed_and_meets_no_bound(tmp_path):
    from hrvptm.report import comparison, failed_line, markdown

    study, paths = _failed_series(tmp_path)
    a = analyse_series(VariantData.load(study, paths))
    assert [r["tracking_ratio"] for r in a.rows] == [1.0, 0.0, 0.0, 0.0]
    fails = [r["failure"] for r in a.rows]
    assert fails[0] == ""
    assert fails[1].startswith("frames 1 → 2: skipped: fewer than 4 particles in frame 2")
    assert fails[1].endswith("; frame 2: only 3 of 60 particles detected")
    assert fails[2].startswith("frames 2 → 3: skipped: fewer than 4 particles in frame 2")
    assert fails[3] == "frames 3 → 4: field skipped: increment 1 → 2 missing"
    assert a.summary["failed_frames"] == 3
    # the tracked frame alone is accurate: without the failure every bound would be met
    assert a.summary["pooled_E_rmsd_xz"] < 0.005 and a.summary["pooled_u_rmsd_x"] < 0.2
    summaries = {"matched": a.summary}
    rows = comparison("6c", summaries)
    assert rows and all(r["matched_meets"] is False for r in rows if r["bound"] is not None)
    ok = comparison("6c", {"matched": {**a.summary, "failed_frames": 0}})
    assert any(r.get("matched_meets") for r in ok)  # the same numbers, not failed: ✓
    variant = {"seconds": {}, "summary": a.summary, "rows": a.rows, "failures": a.failures}
    result = {"variants": {"matched": variant}, "comparison": rows, "status": "failed"}
    line = failed_line(result)
    assert line.startswith("FAILED: matched: 3 failed frames (2, 3, 4): frames 1 → 2: skipped")
    md = markdown(study.to_dict(), result)
    assert f"**{line}**" in md and "✓" not in md.split("✓/✗")[0]


def test_run_study_reports_a_failed_study_then_raises(tmp_path, monkeypatch):
    """The study runner writes the report of a failed study (status failed, failed_frames,
    FAILED line, no ✓) and raises, unless partial results are allowed."""
    import hrvptm.study as hs
    import lfsim
    from hrvptm.errors import StageError

    monkeypatch.setattr(lfsim, "init_backend", lambda: None)
    for stage in ("simulate", "reconstruct", "track_stage"):
        monkeypatch.setattr(hs, stage, lambda *a, **k: 0.0)
    report = tmp_path / "report"
    study, _ = _failed_series(tmp_path, name="report/matched")
    state = {"tool": "hrvptm", "name": study.name, "runs": [], "seconds_total": {}}
    (report / "study.json").write_text(json.dumps(state))
    with pytest.raises(StageError, match=r"study 'synthetic' failed: matched: 3 failed frames"):
        hs.run_study(study, report)
    s = json.loads((report / "summary.json").read_text())
    assert s["status"] == "failed" and s["failed_frames"] == 3
    assert s["variants"]["matched"]["failed_frames"] == 3
    assert not any(r.get("matched_meets") for r in s["comparison"])
    md = (report / "summary.md").read_text()
    assert "**FAILED: matched: 3 failed frames (2, 3, 4)" in md
    assert "✓" not in md.split("✓/✗")[0]
    result = hs.run_study(study, report, allow_partial=True)
    assert result["status"] == "failed" and result["allow_partial"] is True


def _with_sigma(paths, frames: int, sigma_xyz_um) -> None:
    """Add ``sigma_{x,y,z}_um`` columns (the same σ for every particle) to the tables."""
    from track.tables import read_points_csv, write_points_csv

    for k in range(frames):
        p = paths.track / "particles" / f"{k:06d}.csv"
        xyz = read_points_csv(p)
        sig = np.broadcast_to(np.asarray(sigma_xyz_um, float), xyz.shape)
        write_points_csv(p, xyz, sigma_xyz_um=sig, overwrite=True)


def test_coverage_of_right_and_wrong_uncertainties(tmp_path):
    """Detections = truth + N(0, σ): the reported σ covers 68 % / 95 % of the errors (± the
    sampling spread of 6 × 60 errors); half the σ covers far less; no σ gives NaN."""
    from hrvptm import plots
    from hrvptm.analysis import coverage
    from hrvptm.report import coverage_lines

    study = _study(6, None, "localization")
    noise = (0.3, 0.3, 2.0)
    paths = _fake_variant(tmp_path, study, bias=(0, 0, 0), noise_um=noise)
    a = analyse_localization(VariantData.load(study, paths))
    assert a.summary["coverage_n"] == 0 and np.isnan(a.summary["coverage_1sigma_x"])
    assert coverage_lines("v", a.summary) == []
    _with_sigma(paths, 6, noise)
    a = analyse_localization(VariantData.load(study, paths))
    s = a.summary
    assert s["coverage_n"] == 360
    for ax in "xyz":
        assert s[f"coverage_1sigma_{ax}"] == pytest.approx(0.6827, abs=0.06)
        assert s[f"coverage_2sigma_{ax}"] == pytest.approx(0.9545, abs=0.03)
        assert s[f"zscore_rms_{ax}"] == pytest.approx(1.0, abs=0.1)
    assert a.rows[0]["coverage_n"] == 60
    lines = "\n".join(coverage_lines("v", s))
    assert "uncertainty coverage (360 positions" in lines and "| z |" in lines
    png = plots.plot_uncertainty({"mismatched": a}, tmp_path / "u.png")
    assert png.stat().st_size > 10_000
    e, sg = a.arrays["uncertainty"]["error"], a.arrays["uncertainty"]["sigma"]
    # positions: no displacement for the moving-bias term (benchmarks/calibrate_sigma.py)
    assert np.isnan(a.arrays["uncertainty"]["displacement"]).all()
    half = coverage(e, sg / 2)
    assert half["coverage_1sigma_x"] < 0.5 and half["zscore_rms_x"] == pytest.approx(2, rel=0.1)


def test_the_uncertainty_arrays_carry_the_frames_measured_snr(tmp_path):
    """Σ 1/SNR² of the camera frames of each error (benchmarks/calibrate_sigma.py fits
    sigma_snr_um on it) and the measured SNR in each row; 0 and NaN where recon has none."""
    study = _study(4, None, "pairs")
    noise = (0.2, 0.2, 1.0)
    paths = _fake_variant(tmp_path, study, bias=(0, 0, 0), noise_um=noise)
    _with_sigma(paths, 4, noise)
    a = analyse_pairs(VariantData.load(study, paths))
    assert not a.arrays["uncertainty"]["inv_snr2"].any()
    assert all(np.isnan(r["snr_measured"]) for r in a.rows)
    rj = paths.volumes / "recon.json"
    meta = json.loads(rj.read_text())
    snr = [5.0, 10.0, 20.0, 40.0]
    meta["frames"] = [{"index": k, "preprocess": {"snr": v}} for k, v in enumerate(snr)]
    rj.write_text(json.dumps(meta))
    a = analyse_pairs(VariantData.load(study, paths))
    q = a.arrays["uncertainty"]["inv_snr2"]
    assert q.shape == (120,)  # 60 particles in each pair of frames (0, 1), (2, 3)
    np.testing.assert_allclose(q[:60], 1 / 25 + 1 / 100)
    np.testing.assert_allclose(q[60:], 1 / 400 + 1 / 1600)
    assert [r["snr_measured"] for r in a.rows] == [5.0, 20.0]


def test_pairs_coverage_uses_the_displacement_sigma(tmp_path):
    """Two images of static particles with σ = noise: the displacement σ is σ√2, and a
    systematic part declared in the study's detection settings cancels."""
    study = _study(4, None, "pairs")
    noise = (0.2, 0.2, 1.0)
    paths = _fake_variant(tmp_path, study, bias=(2.0, 2.0, 5.0), noise_um=noise)
    _with_sigma(paths, 4, noise)
    a = analyse_pairs(VariantData.load(study, paths))
    assert a.summary["u_coverage_n"] == 120
    # the measured displacement each σ was computed for: static particles, noise only
    u = a.arrays["uncertainty"]["displacement"]
    assert u.shape == (120, 3) and np.all(np.abs(u) < 6 * np.array(noise))
    assert a.summary["u_sigma_rms_z"] == pytest.approx(np.sqrt(2.0))
    assert a.summary["u_coverage_2sigma_z"] == pytest.approx(0.9545, abs=0.05)


def test_series_with_no_frame_compared_has_no_tracking_ratio_and_no_numpy_warning(tmp_path):
    """A series whose frames after the first kept no detection compares no particle in any
    step: the minimum tracking ratio is undefined (NaN), said without a numpy warning."""
    import math
    import warnings

    study, paths = _failed_series(tmp_path, frames=4, keep_n={1: 0, 2: 0, 3: 0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a = analyse_series(VariantData.load(study, paths))
    assert all(math.isnan(r["tracking_ratio"]) for r in a.rows)
    assert math.isnan(a.summary["min_tracking_ratio"]) and a.failed
