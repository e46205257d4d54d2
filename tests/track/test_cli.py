"""The ``track`` command line (track.cli)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import tifffile

from track import field_files, tables
from track.cli import main

from .conftest import random_centres, render_blobs

N = 300


def _error_line(err: str) -> str:
    """The one error line of a failed run (library warnings such as detect's may precede it)."""
    lines = err.strip().splitlines()
    assert sum(ln.startswith("track: error:") for ln in lines) == 1 and "Traceback" not in err
    assert lines[-1].startswith("track: error:")
    return lines[-1]


def _write_cloud(path: Path, xyz, extra=True):
    cols = "x_um,y_um,z_um,intensity" if extra else "x_um,y_um,z_um"
    lines = [cols] + [",".join(repr(float(v)) for v in (*p, 1.0)[: 4 if extra else 3]) for p in xyz]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """Three clouds under small simple-shear increments, rows shuffled with known ids."""
    d = tmp_path_factory.mktemp("clouds")
    rng = np.random.default_rng(7)
    X = rng.uniform([0, 0, 0], [400, 400, 300], (N, 3))
    ids = [np.arange(N)]
    paths = [d / "a.csv"]
    _write_cloud(paths[0], X)
    for k in (1, 2):
        F = np.array([[1, 0, 0.02 * k], [0, 1, 0], [0, 0, 1.0]])
        perm = rng.permutation(N)
        ids.append(perm)
        paths.append(d / f"{'bc'[k - 1]}.csv")
        _write_cloud(paths[-1], (X @ F.T)[perm])
    return paths, ids


def _run(argv, capsys, out=False):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return (rc, cap.err, cap.out) if out else (rc, cap.err)


@pytest.fixture(scope="module")
def linked(clouds, tmp_path_factory):
    paths, _ = clouds
    out = tmp_path_factory.mktemp("res") / "results"
    argv = ["link", *paths, "-o", out, "--target-nodes", "2000", "--no-progress", "-q"]
    rc = main([str(a) for a in argv])
    assert rc == 0
    return out


def test_link_writes_all_outputs(clouds, linked):
    paths, ids = clouds
    out = linked
    for k in range(3):
        assert (out / "particles" / f"{k:06d}.csv").is_file()
    for k in (1, 2):
        f = out / f"matches_{k:06d}.csv"
        assert f.read_text().splitlines()[0] == "row_ref,row_def,ux_um,uy_um,uz_um"
        m, _ = tables.read_matches_csv(f)
        assert len(m) >= 0.95 * N
        # row_ref in frame k-1 and row_def in frame k must be the same particle
        assert np.array_equal(ids[k - 1][m[:, 0]], ids[k][m[:, 1]])
        assert (out / "fields" / f"{k:06d}.npz").is_file()
        assert (out / "fields" / f"{k:06d}.vti").is_file()
    assert (out / "tracks.csv").read_text().startswith("frame,track_id,x_um,y_um,z_um\n")
    t = tables.read_tracks_csv(out / "tracks.csv")
    # the track id of a particle is its row in frame 0 (known through the permutations)
    for k in (1, 2):
        sel = t["frame"] == k
        xyz = np.c_[t["x_um"], t["y_um"], t["z_um"]][sel]
        rows = np.array(
            [np.flatnonzero(np.all(tables.read_points_csv(paths[k]) == p, 1))[0] for p in xyz]
        )
        matched = t["track_id"][sel] < N
        assert matched.mean() > 0.95
        assert np.array_equal(t["track_id"][sel][matched], ids[k][rows][matched])
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "complete" and s["command"] == "link"
    assert [i["status"] for i in s["increments"]] == ["ok", "ok"]
    assert all(i["tracking_ratio"] > 0.95 for i in s["increments"])
    assert all(len(i["smoothing_xyz"]) == 3 for i in s["increments"])  # GCV's λ, recorded
    assert s["parameters"]["series"]["grid"]["smoothing"] == "gcv"
    assert {"link_s", "fields_s", "total_s"} <= set(s["timings"])
    g = field_files.read_field_npz(out / "fields" / "000002.npz")
    gamma = 2 * g.e[..., 0, 2][g.mask]
    assert abs(np.median(gamma) - 0.04) < 0.004  # two 0.02 increments of simple shear


def test_existing_results_are_protected(clouds, linked, tmp_path, capsys):
    paths, _ = clouds
    before = {p: p.stat().st_mtime_ns for p in linked.rglob("*")}
    # other inputs into the same folder: refused, nothing touched
    rc, err = _run(["link", paths[0], paths[2], "-o", linked, "--no-progress"], capsys)
    assert rc == 2 and err.startswith("track: error:") and len(err.strip().splitlines()) == 1
    assert "other inputs" in err
    assert {p: p.stat().st_mtime_ns for p in linked.rglob("*")} == before
    # a user's folder is never overwritten, even with --overwrite
    user = tmp_path / "mine"
    user.mkdir()
    (user / "notes.txt").write_text("keep")
    rc, err = _run(["link", *paths, "-o", user, "--overwrite", "--no-progress"], capsys)
    assert rc == 2 and "no summary.json" in err
    assert os.listdir(user) == ["notes.txt"]


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("", "is empty; expected a header"),
        ("x_um,y_um,z_um\n1,2,3\n1,nan,3\n", "line 3"),
        ("x_um,y_um\n1,2\n", "missing column"),
    ],
)
def test_bad_clouds_exit_2_with_one_line(clouds, tmp_path, capsys, content, match):
    paths, _ = clouds
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    out = tmp_path / "out"
    rc, err = _run(["link", paths[0], bad, "-o", out, "--no-progress"], capsys)
    assert rc == 2
    assert err.startswith("track: error:") and len(err.strip().splitlines()) == 1
    assert match in err and str(bad) in err
    assert not out.exists()


def test_frame_with_fewer_than_4_particles_fails_loudly(clouds, tmp_path, capsys):
    """A pair that cannot be linked: exit status 3 and one line naming the frames and the
    reason; what worked is still written, summary.json says "failed"."""
    paths, _ = clouds
    few = tmp_path / "few.csv"
    _write_cloud(few, [[1, 2, 3], [4, 5, 6], [7, 8, 10]], extra=False)
    out = tmp_path / "out"
    argv = ["link", paths[0], paths[1], few, "-o", out, "--target-nodes", "500", "--no-progress"]
    rc, err, stdout = _run(argv, capsys, out=True)
    assert rc == 3
    assert err.count("\n") == 1 and err.startswith("track: error: frames 1 → 2: skipped: fewer ")
    assert "in frame 2 (3 found)" in err and "--allow-partial" in err
    assert stdout.startswith("RESULTS: 3 clouds, 3–300 particles/frame, 1/2 pairs linked")
    assert stdout.rstrip().endswith("(FAILED)")
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and s["allow_partial"] is False
    assert s["increments"][0]["status"] == "ok"
    assert s["increments"][1]["status"].startswith("skipped: fewer than 4 particles in frame 2")
    assert s["increments"][1]["tracking_ratio"] is None
    assert len(s["failures"]) == 1 and s["failures"][0] in err
    assert (out / "fields" / "000001.npz").is_file()  # the pair that worked is kept
    assert not (out / "fields" / "000002.npz").exists()
    # two failing pairs: still one line, naming the first and counting the others
    argv[1:4] = [paths[0], few, paths[1]]
    rc, err = _run([*argv, "--overwrite"], capsys)
    assert rc == 3 and err.count("\n") == 1
    assert err.startswith("track: error: frames 0 → 1: skipped: fewer than 4 particles in frame 1")
    assert "and 1 more pair failed" in err
    # --allow-partial: the same results, warnings, exit 0, status "partial"
    rc, err, stdout = _run([*argv, "--allow-partial", "-q"], capsys, out=True)
    assert rc == 0 and err == "" and stdout == ""
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "partial" and len(s["failures"]) == 2
    rc, err = _run([*argv, "--allow-partial"], capsys)
    assert rc == 0 and err.count("track: warning: frames ") == 2 and "Traceback" not in err


def test_grid_spacing_and_target_nodes_are_refused_up_front(clouds, tmp_path, capsys):
    paths, _ = clouds
    out = tmp_path / "out"
    for spacing, what in (("0.01", "grid nodes over frame 0's particles"), ("1e6", "single")):
        rc, err = _run(["link", *paths, "-o", out, "--grid-spacing-um", spacing], capsys)
        assert rc == 2 and err.count("\n") == 1, err
        assert err.startswith(f"track: error: --grid-spacing-um {float(spacing):g} µm ")
        assert what in err
        assert not out.exists()
    # 400 × 400 × 300 µm at 5 µm: 81 × 81 × 61 = 400 221 nodes, within 10 × 50 000
    rc, err = _run(["link", *paths, "-o", out, "--grid-spacing-um", "5", "--no-fields"], capsys)
    assert rc == 0, err
    rc, err = _run(
        ["link", *paths, "-o", tmp_path / "o2", "--grid-spacing-um", "5", "--target-nodes", "9000"],
        capsys,
    )
    assert rc == 2 and "more than 90000 (at most 10 × --target-nodes" in err
    for n in ("0", "7", "1000000000000", "1e12", "2000001"):
        rc, err = _run(["link", *paths, "-o", out, "--target-nodes", n], capsys)
        assert rc == 2 and err.count("\n") == 1
        assert f"argument --target-nodes: expected an integer in 8..2000000, got '{n}'" in err


def test_usage_errors_are_one_line(tmp_path, capsys):
    rc, err = _run(["link", "-o", tmp_path / "x"], capsys)
    assert rc == 2 and err.startswith("track: error:") and len(err.strip().splitlines()) == 1
    rc, err = _run(["run", tmp_path / "nothere", "-o", tmp_path / "x"], capsys)
    assert rc == 2 and "does not exist" in err
    rc, err = _run(["link", tmp_path / "a.csv", "-o", tmp_path / "x", "--mode", "x"], capsys)
    assert rc == 2 and "invalid choice" in err
    rc, err = _run(["link", tmp_path / "a.csv", "-o", tmp_path / "x", "--smoothing", "-1"], capsys)
    assert rc == 2 and "expected 'gcv' or a number >= 0, got '-1'" in err


# -- volumes ---------------------------------------------------------------------------------
SHAPE = (30, 64, 64)
VOXEL = (2.0, 1.0, 1.0)


def _volumes(folder: Path, n_frames=3, shift_um=1.5, vs=VOXEL, seed=3, empty=()):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    c = random_centres(rng, SHAPE, 20, (8, 6, 6), (5, 5, 5))
    for k in range(n_frames):
        vol = render_blobs(
            SHAPE, c + np.array([0, 0, shift_um * k / vs[2]]), (2.5, 1.2, 1.2), 100.0, 1.0
        )
        if k in empty:
            vol = np.ones(SHAPE)
        vol += rng.normal(0, 0.5, SHAPE)
        tifffile.imwrite(
            folder / f"{k:06d}.tif",
            vol.astype(np.float32),
            description=json.dumps({"voxel_size_um": list(vs)}),
            photometric="minisblack",
        )
    return c


def test_run_end_to_end_and_resume(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols)
    out = tmp_path / "res"
    argv = ["run", vols, "-o", out, "--no-deconvolution", "--grid-spacing-um", "4", "--no-progress"]
    rc, err, stdout = _run(argv, capsys, out=True)
    assert rc == 0, err
    line = stdout.strip()
    assert line.count("\n") == 0 and line.startswith("RESULTS: 3 volumes, ")
    # 20 blobs, two of them 10.3 planes (1.7 FWHM) apart along z: the band-pass at the
    # particle scale joins them at the threshold; resolved, they are split, not rejected
    assert "20 particles/frame, 2/2 pairs linked, tracking ratio ≥ 1.00, 2 fields, " in line
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "complete" and len(s["frames"]) == 3 and s["failures"] == []
    assert all(len(f["input_sha256"]) == 64 for f in s["frames"])
    for k in range(3):
        assert tables.read_points_csv(out / "particles" / f"{k:06d}.csv").shape[0] >= 10
    for inc in s["increments"]:
        assert inc["status"] == "ok" and inc["tracking_ratio"] > 0.9
        _, d = tables.read_matches_csv(out / f"matches_{inc['def_frame']:06d}.csv")
        assert np.allclose(np.median(d, axis=0), [1.5, 0, 0], atol=0.1)
    g = field_files.read_field_npz(out / "fields" / "000002.npz")
    assert np.allclose(np.median(g.u[g.mask], axis=0), [3.0, 0, 0], atol=0.15)
    # resume: detection is skipped for unchanged volumes, outputs are rewritten
    mtime = (out / "particles" / "000001.csv").stat().st_mtime_ns
    rc, err = _run(argv, capsys)
    assert rc == 0, err
    s2 = json.loads((out / "summary.json").read_text())
    assert all(f.get("reused") for f in s2["frames"])
    assert (out / "particles" / "000001.csv").stat().st_mtime_ns == mtime
    # other detection settings: refused without --overwrite, accepted with it
    rc, err = _run([*argv, "--threshold", "0.3"], capsys)
    assert rc == 2 and "other inputs or settings" in err
    rc, err = _run([*argv, "--threshold", "0.3", "--overwrite"], capsys)
    assert rc == 0, err


def test_run_refuses_a_grid_finer_than_the_volume_allows_before_detection(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=2)
    out = tmp_path / "res"
    rc, err = _run(["run", vols, "-o", out, "--grid-spacing-um", "0.01", "--no-progress"], capsys)
    assert rc == 2 and err.count("\n") == 1
    assert "--grid-spacing-um 0.01 µm gives" in err and "over the volume (63 × 63 × 58 µm)" in err
    assert not out.exists()


def test_detect_fails_on_a_volume_without_particles(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=2, empty=(1,))
    out = tmp_path / "res"
    argv = ["detect", vols, "-o", out, "--no-deconvolution", "--no-progress"]
    rc, err, stdout = _run(argv, capsys, out=True)
    assert rc == 3 and _error_line(err) == (
        "track: error: volume 000001.tif: no particle found "
        "(use --allow-partial to keep partial results)"
    )
    assert stdout.startswith("RESULTS: 2 volumes, 0–")
    assert (out / "particles" / "000000.csv").is_file()
    rc, err = _run([*argv, "--allow-partial"], capsys)
    assert rc == 0 and "warning: volume 000001.tif: no particle found" in err


def test_run_bad_series_exit_2(tmp_path, capsys):
    vols = tmp_path / "gap"
    _volumes(vols)
    (vols / "000001.tif").unlink()
    rc, err = _run(["run", vols, "-o", tmp_path / "r1", "--no-progress"], capsys)
    assert rc == 2 and "000001.tif is missing" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r1").exists()
    vols2 = tmp_path / "mixed"
    _volumes(vols2, n_frames=2)
    _volumes(tmp_path / "other", n_frames=3, vs=(2.0, 1.2, 1.2))
    os.replace(tmp_path / "other" / "000002.tif", vols2 / "000002.tif")
    rc, err = _run(["detect", vols2, "-o", tmp_path / "r2", "--no-progress"], capsys)
    assert rc == 2 and "mismatched voxel sizes" in err
    assert not (tmp_path / "r2").exists()


def test_run_with_an_empty_volume_fails_unless_partial_results_are_allowed(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=3, empty=(2,))
    out = tmp_path / "res"
    argv = ["run", vols, "-o", out, "--no-deconvolution", "--grid-spacing-um", "4"]
    rc, err = _run([*argv, "--no-progress"], capsys)
    assert rc == 3 and _error_line(err).startswith(
        "track: error: frames 1 → 2: skipped: fewer than 4 particles in frame 2"
    )
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"
    # the same folder resumes (detection reused) and keeps the partial results when allowed
    rc, err = _run([*argv, "--no-progress", "--allow-partial"], capsys)
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "partial" and all(f.get("reused") for f in s["frames"])
    assert s["frames"][2]["n_particles"] < 4
    assert s["increments"][0]["status"] == "ok"
    assert s["increments"][1]["status"].startswith("skipped: fewer than 4 particles in frame 2")
    assert s["increments"][1]["field"] is None
    assert (out / "fields" / "000001.npz").is_file()
    assert not (out / "fields" / "000002.npz").exists()
    assert "Traceback" not in err


def test_detector_band_pass_and_significance_options(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=1)
    out = tmp_path / "res"
    argv = ["detect", vols, "-o", out, "--no-deconvolution", "--no-progress"]
    rc, err = _run([*argv, "--smooth-fwhm", "0.3", "--background-fwhm", "0.2"], capsys)
    assert rc == 2 and err.count("\n") == 1 and not out.exists()
    assert "--background-fwhm (0.2) must exceed --smooth-fwhm (0.3)" in err
    rc, err = _run([*argv, "--max-rel-aspect", "0.5"], capsys)
    assert rc == 2 and "argument --max-rel-aspect: expected a number >= 1, got '0.5'" in err
    # a significance far above every particle's peak rejects them all, and says so
    rc, err = _run([*argv, "--min-peak-snr", "1e6", "--allow-partial"], capsys)
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    det = s["parameters"]["detect"]
    assert det["min_peak_snr"] == 1e6 and det["smooth_fwhm"] == 0.25
    assert s["frames"][0]["report"]["rejections"]["insignificant"] >= 18
    assert "no particle found" in err


def test_uncertainty_model_options(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=2)
    out = tmp_path / "res"
    argv = ["run", vols, "-o", out, "--no-deconvolution", "--no-progress", "--no-fields"]
    rc, err = _run([*argv, "--sigma-systematic-um", "1,2"], capsys)
    assert rc == 2 and err.count("\n") == 1 and not out.exists()
    assert "--sigma-systematic-um: expected three numbers Z,Y,X >= 0 separated by commas" in err
    rc, err = _run([*argv, "--sigma-noise-factor", "0"], capsys)
    assert rc == 2 and "expected one number or three numbers Z,Y,X > 0" in err
    rc, err = _run([*argv, "--sigma-snr-um", "1,-2,0"], capsys)
    assert rc == 2 and "--sigma-snr-um: expected three numbers Z,Y,X >= 0" in err
    # the SNR term on volumes that have no camera SNR (not from recon run): one line, nothing
    rc, err = _run([*argv, "--sigma-snr-um", "5,1,1"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "has no camera SNR" in err, err
    assert not out.exists()
    opts = ["--sigma-noise-factor", "3,5,5", "--sigma-systematic-um", "3,0.2,0.2"]
    opts += ["--bias-sigma-um", "1.5,0.1,0.1", "--bias-length-um", "5"]
    rc, err = _run([*argv, *opts], capsys)
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["parameters"]["detect"]["sigma_noise_factor"] == [3.0, 5.0, 5.0]
    # the σ of a particle holds the systematic part: ≥ 3 µm in z, ≥ 0.2 µm laterally
    sig = tables.read_point_sigmas(out / "particles" / "000000.csv")  # x, y, z
    assert np.all(sig >= [0.2, 0.2, 3.0]) and np.all(sig[:, 2] > 5 * sig[:, 0])
    with_bias = tables.read_match_sigmas(out / "matches_000001.csv")
    # without the moving-bias term the per-match σ is smaller (the systematic part cancels)
    rc, err = _run([*argv, *opts[:4], "--overwrite"], capsys)
    assert rc == 0, err
    without = tables.read_match_sigmas(out / "matches_000001.csv")
    assert np.all(with_bias >= without) and np.all(with_bias[:, 2] > without[:, 2])
    # the lateral bias's own depth length: a bad value is one line, a good one is recorded
    rc, err = _run([*argv, *opts, "--bias-lateral-depth-length-um", "0", "--overwrite"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "--bias-lateral-depth-length-um" in err, err
    rc, err = _run([*argv, *opts, "--bias-lateral-depth-length-um", "500", "--overwrite"], capsys)
    assert rc == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["parameters"]["series"]["bias_lateral_depth_length_um"] == 500.0


def test_link_options_set_the_bridging_of_tracks():
    from track.cli import build_parser, series_settings

    p = build_parser()
    s = series_settings(p.parse_args(["link", "a.csv", "b.csv", "-o", "out"]))
    assert s.bridge_tracks is True and s.max_gap_frames == 2
    args = p.parse_args(["link", "a.csv", "b.csv", "-o", "out", "--no-bridge"])
    assert series_settings(args).bridge_tracks is False
    args = p.parse_args(["link", "a.csv", "b.csv", "-o", "out", "--max-gap-frames", "0"])
    assert series_settings(args).max_gap_frames == 0


def _hyperstacks(folder: Path, n_frames=3) -> Path:
    """The volumes of :func:`_volumes` rewritten as ``recon run`` writes them (ImageJ
    hyperstacks of ``lfsim.io.write_tiff``, every page's header after the voxels)."""
    from lfsim.io import write_tiff

    _volumes(folder, n_frames=n_frames)
    for p in sorted(folder.glob("*.tif")):
        vol = tifffile.imread(p)
        p.unlink()
        write_tiff(p, vol, metadata={"frame": int(p.stem)}, pixel_size_um=VOXEL)
    return folder


@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_truncated_hyperstack_is_one_line_naming_it(tmp_path, capsys, keep):
    vols = _hyperstacks(tmp_path / "vols")
    p = vols / "000001.tif"
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * keep)])
    out = tmp_path / "res"
    rc, err = _run(["run", vols, "-o", out, "--no-progress"], capsys)
    assert rc == 2 and err.count("\n") == 1, err
    assert err.startswith("track: error: TIFF volume ") and f"{p} is truncated" in err
    assert not out.exists()


def test_a_truncated_zarr_chunk_is_one_line_naming_the_frame(tmp_path, capsys):
    from .test_zarr_volumes import write_ngff

    rng = np.random.default_rng(1)
    data = rng.normal(10, 1, (3, 8, 16, 16)).astype(np.float32)
    store = write_ngff(tmp_path / "v.zarr", data, "tzyx", (1, 2, 1, 1))
    chunk = next(p for p in sorted((store / "0" / "c" / "1").rglob("*")) if p.is_file())
    chunk.write_bytes(chunk.read_bytes()[:10])
    out = tmp_path / "res"
    rc, err = _run(["run", store, "-o", out, "--no-progress"], capsys)
    assert rc == 2 and err.count("\n") == 1, err
    assert err.startswith(f"track: error: cannot read volume {store}[t=1]")
    assert not out.exists()


def _snapshot(folder: Path) -> dict:
    import hashlib

    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.parametrize("damage", ["truncated", "nan"])
def test_a_rerun_on_a_damaged_volume_keeps_the_previous_results(tmp_path, capsys, damage):
    """A finished run, then one volume truncated (or holding NaN): the rerun is one line
    naming the file and leaves every previous result as it was."""
    vols = _hyperstacks(tmp_path / "vols")
    out = tmp_path / "res"
    argv = ["run", vols, "-o", out, "--no-deconvolution", "--grid-spacing-um", "4"]
    rc, err = _run([*argv, "--no-progress"], capsys)
    assert rc == 0, err
    before = _snapshot(out)
    assert "tracks.csv" in before and "matches_000002.csv" in before
    p = vols / "000002.tif"
    good = p.read_bytes()
    if damage == "truncated":
        p.write_bytes(good[: len(good) // 2])
    else:
        from lfsim.io import read_tiff, write_tiff

        vol, meta = read_tiff(p)
        vol[3, 4, 5] = np.nan
        write_tiff(p, vol, metadata=meta, pixel_size_um=VOXEL, overwrite=True)
    rc, err = _run([*argv, "--no-progress"], capsys)
    assert rc == 2 and err.count("\n") == 1 and str(p) in err, err
    assert _snapshot(out) == before
    p.write_bytes(good)
    rc, err = _run([*argv, "--no-progress"], capsys)
    assert rc == 0, err
    assert _snapshot(out).keys() == before.keys()


def test_recorded_camera_frame_numbers_and_times_flow_into_every_output(tmp_path, capsys):
    """Volumes of camera frames 0, 1 and 5 (recon.json's numbers and times): the tables are
    named and labelled by those frames, 1 → 5 is one increment spanning 4 camera frames, and
    velocities use the recorded times."""
    vols = _hyperstacks(tmp_path / "vols")
    numbers, times = [0, 1, 5], [0.0, 0.01, 0.05]
    frames = [
        {"index": k, "number": n, "time_s": t, "output": {}}
        for k, (n, t) in enumerate(zip(numbers, times, strict=True))
    ]
    (vols / "recon.json").write_text(json.dumps({"frames": frames}))
    out = tmp_path / "res"
    argv = ["run", vols, "-o", out, "--no-deconvolution", "--grid-spacing-um", "4"]
    rc, err = _run([*argv, "--no-progress"], capsys)
    assert rc == 0, err
    assert sorted(p.name for p in (out / "particles").iterdir()) == [
        "000000.csv",
        "000001.csv",
        "000005.csv",
    ]
    assert sorted(p.name for p in out.glob("matches_*.csv")) == [
        "matches_000001.csv",
        "matches_000005.csv",
    ]
    s = json.loads((out / "summary.json").read_text())
    assert [(f["index"], f["frame"], f["time_s"]) for f in s["frames"]] == [
        (0, 0, 0.0),
        (1, 1, 0.01),
        (2, 5, 0.05),
    ]
    assert s["frame_ids"] == numbers and s["frame_times_s"] == times
    inc = s["increments"][1]
    assert (inc["ref_frame"], inc["def_frame"], inc["frames_spanned"]) == (1, 5, 4)
    assert (inc["ref_time_s"], inc["def_time_s"]) == (0.01, 0.05)
    assert inc["dt_s"] == pytest.approx(0.04)
    t = tables.read_tracks_csv(out / "tracks.csv")
    assert sorted(set(t["frame"].tolist())) == numbers
    np.testing.assert_allclose(t["time_s"], np.array(times)[[numbers.index(f) for f in t["frame"]]])
    head = (out / "matches_000005.csv").read_text().splitlines()[0].split(",")
    assert head[-3:] == ["vx_um_per_s", "vy_um_per_s", "vz_um_per_s"]
    m = tables.read_matches_csv(out / "matches_000005.csv")[1]
    v = np.loadtxt(out / "matches_000005.csv", delimiter=",", skiprows=1)[:, -3:]
    np.testing.assert_allclose(v, m / 0.04, rtol=1e-6)
    with np.load(out / "fields" / "000005.npz") as z:
        assert int(z["frame"]) == 5 and float(z["time_s"]) == 0.05
    vti = (out / "fields" / "000005.vti").read_text()
    assert 'Name="TimeValue"' in vti
