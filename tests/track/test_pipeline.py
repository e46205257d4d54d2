"""The library pipeline (track.pipeline): results in memory and the same results folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

import track
from track import field_files, tables
from track.errors import FailedFramesError, InputError
from track.fields import GridSettings
from track.pipeline import TrackResult, track_clouds, track_volumes
from track.series import SeriesSettings

from .test_cli import _volumes

N = 200
SERIES = SeriesSettings(grid=GridSettings(target_nodes=2000))


def _shear_clouds(n_frames=3, gamma=0.02, seed=5):
    """Clouds under simple-shear increments γ per frame, rows in the same order."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([0, 0, 0], [400, 400, 300], (N, 3))
    out = []
    for k in range(n_frames):
        F = np.array([[1, 0, gamma * k], [0, 1, 0], [0, 0, 1.0]])
        out.append(X @ F.T)
    return out


def test_track_clouds_returns_what_it_writes(tmp_path):
    clouds = _shear_clouds()
    res = track_clouds(clouds, tmp_path / "r", series=SERIES)
    assert isinstance(res, TrackResult) and res.command == "link" and res.status == "complete"
    assert res.failures == () and [f.n for f in res.frames] == [N, N, N]
    assert np.array_equal(res.frames[2].positions_um, clouds[2])
    assert [(p.ref_frame, p.def_frame) for p in res.pairs] == [(0, 1), (1, 2)]
    for p in res.pairs:
        assert p.ok and p.status == p.field_status == "ok" and p.tracking_ratio > 0.95
        assert np.array_equal(p.matches[:, 0], p.matches[:, 1])  # same row = same particle
        assert np.allclose(p.displacement_um, clouds[p.def_frame][p.matches[:, 1]]
                           - clouds[p.ref_frame][p.matches[:, 0]])  # fmt: skip
    fld = res.pairs[1].field
    gamma = 2 * fld.e[..., 0, 2][fld.mask]
    assert abs(np.median(gamma) - 0.04) < 0.004  # two 0.02 increments
    disk = field_files.read_field_npz(tmp_path / "r" / "fields" / "000002.npz")
    assert np.array_equal(disk.u, fld.u) and np.array_equal(disk.mask, fld.mask)
    assert res.grid is not None and res.grid.shape == disk.u.shape[:3]
    # trajectories: frame 0 row r is track r in every frame
    t = res.tracks
    assert np.array_equal(np.unique(t.frame), [0, 1, 2])
    for k in (1, 2):
        assert np.array_equal(t.track_id[t.frame == k][t.row[t.frame == k]], np.arange(N))
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary == json.loads(json.dumps(res.summary, default=list))
    assert summary["inputs"][0] == {"path": "array 0", "sha256": summary["inputs"][0]["sha256"]}
    assert res.results_line().startswith(
        "RESULTS: 3 clouds, 200 particles/frame, 2/2 pairs linked, tracking ratio ≥ 1.00, "
        "2 fields, "
    )


def test_failed_pairs_raise_with_the_written_result_unless_allowed(tmp_path):
    clouds = _shear_clouds(5)
    clouds[2] = clouds[2][:3]
    with pytest.raises(FailedFramesError) as info:
        track_clouds(clouds, tmp_path / "r", series=SERIES)
    exc = info.value
    assert len(exc.failures) == 3  # 1 → 2 and 2 → 3 unlinked; 3 → 4's total field missing
    assert exc.failures[0].startswith("frames 1 → 2: skipped: fewer than 4 particles in frame 2")
    assert exc.failures[2] == "frames 3 → 4: field skipped: increment 1 → 2 missing"
    assert str(exc).endswith("and 2 more pairs failed (results kept, see summary.json; use "
                             "allow_partial=True to keep partial results)")  # fmt: skip
    assert exc.result.status == "failed" and exc.result.pairs[0].ok
    assert not exc.result.pairs[1].ok and exc.result.pairs[2].field is None
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["status"] == "failed"
    res = track_clouds(clouds, tmp_path / "r", series=SERIES, allow_partial=True)
    assert res.status == "partial" and res.failures == exc.failures


def test_grid_spacing_and_settings_are_refused_before_any_work(tmp_path):
    clouds = _shear_clouds(2)
    fine = SeriesSettings(grid=GridSettings(spacing_um=0.5))  # 801 × 794 × 597 nodes
    with pytest.raises(InputError, match=r"spacing_um 0.5 µm gives 3.8e\+08 grid nodes over"):
        track_clouds(clouds, tmp_path / "r", series=fine)
    with pytest.raises(InputError, match="target_nodes must be at most 2000000"):
        SeriesSettings(grid=GridSettings(target_nodes=10**12))
    with pytest.raises(InputError, match="point cloud 1 must be a finite"):
        track_clouds([clouds[0], clouds[1][:, :2]], tmp_path / "r")
    with pytest.raises(InputError, match="link needs at least 2 point clouds"):
        track_clouds(clouds[:1], tmp_path / "r")
    assert not (tmp_path / "r").exists()


def test_track_volumes_detects_resumes_and_links(tmp_path):
    vols = tmp_path / "vols"
    _volumes(vols)
    out = tmp_path / "res"
    det = track.DetectSettings(deconvolution_iterations=0)
    res = track_volumes(vols, out, detect=det)  # no series: detection only
    assert res.command == "detect" and res.pairs == () and res.tracks is None
    assert [f.index for f in res.frames] == [0, 1, 2] and all(f.n >= 10 for f in res.frames)
    assert not any(f.reused for f in res.frames) and res.frames[0].report
    stored = tables.read_points_csv(out / "particles" / "000001.csv")
    assert np.allclose(stored, res.frames[1].positions_um, atol=1e-6)
    series = SeriesSettings(grid=GridSettings(spacing_um=4.0))
    res2 = track_volumes(vols, out, detect=det, series=series)  # same detection: resumed
    assert res2.command == "run" and all(f.reused for f in res2.frames)
    assert res2.status == "complete" and all(p.ok for p in res2.pairs)
    for p in res2.pairs:  # 1.5 µm along x per frame
        assert np.allclose(np.median(p.displacement_um, axis=0), [1.5, 0, 0], atol=0.1)
    assert json.loads((out / "summary.json").read_text())["command"] == "run"
    # Resume verifies what it keeps: a truncated particle table is detected again, only it.
    table = out / "particles" / "000002.csv"
    before = table.read_bytes()
    table.write_bytes(before[: len(before) // 2])
    res3 = track_volumes(vols, out, detect=det, series=series)
    assert [f.reused for f in res3.frames] == [True, True, False]
    assert table.read_bytes() == before


def test_a_lenslet_period_appearing_in_recon_json_is_a_new_input(tmp_path):
    """Detections made without the lenslet period (no recon.json) are not resumed once the
    series has one: the detector works differently with it (track.detect)."""
    vols = tmp_path / "vols"
    _volumes(vols)
    out = tmp_path / "res"
    det = track.DetectSettings(deconvolution_iterations=0)
    track_volumes(vols, out, detect=det)
    origin = track.volumes.scan_volumes(vols)[0].origin_xyz_um
    grid = {"s": 4, "lenslet_object_um": 4.0, "origin_um": [origin[0] - 0.5, origin[1] - 0.5]}
    (vols / "recon.json").write_text(json.dumps({"grid": grid}))
    assert track.volumes.scan_volumes(vols)[0].lenslet_period_vox == 4
    with pytest.raises(InputError, match="other inputs or settings"):
        track_volumes(vols, out, detect=det)
    res = track_volumes(vols, out, detect=det, overwrite=True)
    assert not any(f.reused for f in res.frames)
    assert res.summary["parameters"]["lenslet_period_vox"] == [4]
    assert track_volumes(vols, out, detect=det).frames[0].reused  # and then it resumes


def test_detections_in_front_of_the_specimens_surface_are_dropped(tmp_path):
    """recon.json's specimen surface reaches the detection of every frame: what lies more than
    a depth step in front of it is dropped from the particle tables, and a new surface is a
    new input."""
    vols = tmp_path / "vols"
    _volumes(vols)
    det = track.DetectSettings(deconvolution_iterations=0)
    base = track_volumes(vols, tmp_path / "base", detect=det)
    z = np.concatenate([f.positions_um[:, 2] for f in base.frames])
    surface = float(np.median(z))
    dz = track.volumes.scan_volumes(vols)[0].voxel_size_um[0]
    (vols / "recon.json").write_text(json.dumps({"surface_z_um": surface}))
    out = tmp_path / "res"
    res = track_volumes(vols, out, detect=det)
    assert res.summary["parameters"]["surface_z_um"] == [surface]
    for f, g in zip(res.frames, base.frames, strict=True):
        keep = g.positions_um[:, 2] >= surface - dz
        np.testing.assert_array_equal(f.positions_um, g.positions_um[keep])
        assert f.report["rejections"]["in_front_of_surface"] == np.count_nonzero(~keep)
        assert len(tables.read_points_csv(out / "particles" / f"{f.index:06d}.csv")) == keep.sum()
    assert sum(f.report["rejections"]["in_front_of_surface"] for f in res.frames) > 0
    (vols / "recon.json").write_text(json.dumps({"surface_z_um": surface - 50}))
    with pytest.raises(InputError, match="other inputs or settings"):
        track_volumes(vols, out, detect=det)


def test_the_snr_term_needs_every_frame_snr_and_follows_it(tmp_path):
    """sigma_snr_um on volumes without a camera SNR is refused before anything is written;
    with recon.json's SNRs each frame's σ follows its own, and a changed SNR is a new input."""
    vols = tmp_path / "vols"
    _volumes(vols)
    out = tmp_path / "res"
    det = track.DetectSettings(deconvolution_iterations=0, sigma_snr_um=(10.0, 2.0, 2.0))
    with pytest.raises(InputError, match=r"has no camera SNR .*3 of 3 volumes lack it"):
        track_volumes(vols, out, detect=det)
    assert not out.exists()
    snrs = [4.0, 40.0, 400.0]
    frames = [{"index": k, "preprocess": {"snr": v}} for k, v in enumerate(snrs)]
    (vols / "recon.json").write_text(json.dumps({"frames": frames}))
    res = track_volumes(vols, out, detect=det)
    off = track_volumes(
        vols, tmp_path / "off", detect=track.DetectSettings(deconvolution_iterations=0)
    )
    for f, g, snr in zip(res.frames, off.frames, snrs, strict=True):
        assert f.report["snr"] == snr
        want = np.hypot(g.sigma_xyz_um, np.array([2.0, 2.0, 10.0]) / snr)
        np.testing.assert_allclose(f.sigma_xyz_um, want)
    assert res.summary["parameters"]["frame_snr"] == snrs
    frames[0]["preprocess"]["snr"] = 8.0
    (vols / "recon.json").write_text(json.dumps({"frames": frames}))
    with pytest.raises(InputError, match="other inputs or settings"):
        track_volumes(vols, out, detect=det)
