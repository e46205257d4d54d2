"""The tables and fields as pandas DataFrames (track.dataframes), trackpy's column names, and
the units and NaN of the ParaView .vti fields."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import track
from hrvbase.errors import InputError
from track import dataframes as dfs
from track import field_files, tables
from track.fields import GridSettings, gridded_field
from track.pipeline import track_clouds
from track.series import SeriesSettings, link_tracks

from .test_cli import VOXEL, _volumes

_A = np.array([[0.0, 0.0, 0.1], [0.0, 0.02, 0.0], [0.0, 0.0, -0.01]])  # u = A x (µm)


def _field(sigma=True):
    X = np.random.default_rng(0).uniform([0, 10, -5], [100, 80, 60], (80, 3))
    if not sigma:
        return gridded_field(X, X @ _A.T, GridSettings(spacing_um=12.0, uncertainty=False))
    s = np.broadcast_to([0.2, 0.3, 2.0], X.shape)
    return gridded_field(X, X @ _A.T, GridSettings(spacing_um=12.0), sigma_xyz_um=s)


def test_particles_round_trip_exactly_with_frame_and_row(tmp_path):
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(7, 3)) * 100
    inten = rng.uniform(1, 9, 7)
    sig = rng.uniform(0.1, 2, (7, 3))
    sig[2, 1] = np.nan  # unknown
    p = tables.write_points_csv(tmp_path / "000003.csv", xyz, inten, sigma_xyz_um=sig)
    df = track.read_particles(p)
    want = ["frame", "row", "x_um", "y_um", "z_um", "intensity", *tables.SIGMA_COLUMNS]
    assert list(df.columns) == want
    assert df["frame"].dtype == np.int64 and (df["frame"] == 3).all()
    assert df["row"].tolist() == list(range(7))
    assert np.array_equal(df[["x_um", "y_um", "z_um"]].to_numpy(), xyz)  # exact
    assert np.array_equal(df["intensity"].to_numpy(), inten)
    assert np.array_equal(df[list(tables.SIGMA_COLUMNS)].to_numpy(), sig, equal_nan=True)
    # DataFrame → our writer → the same bytes
    q = dfs.write_particles(tmp_path / "copy" / "000003.csv", df)
    assert q.read_bytes() == p.read_bytes()
    # a table without the optional columns, under another name: only what it has
    plain = tables.write_points_csv(tmp_path / "cloud.csv", xyz)
    df2 = track.read_particles(plain)
    assert list(df2.columns) == ["row", "x_um", "y_um", "z_um"]
    assert dfs.write_particles(tmp_path / "c2.csv", df2).read_bytes() == plain.read_bytes()


def test_a_folder_of_particle_tables_is_one_frame_in_frame_order(tmp_path):
    rng = np.random.default_rng(2)
    clouds = {5: rng.normal(size=(3, 3)), 0: rng.normal(size=(4, 3)), 12: np.zeros((0, 3))}
    for k, xyz in clouds.items():
        tables.write_points_csv(tmp_path / "particles" / f"{k:06d}.csv", xyz)
    (tmp_path / "particles" / "notes.csv").write_text("not,a,table\n")  # not numbered: skipped
    for where in (tmp_path, tmp_path / "particles"):
        df = track.read_particles(where)
        assert df["frame"].tolist() == [0] * 4 + [5] * 3
        assert df["row"].tolist() == [0, 1, 2, 3, 0, 1, 2]
        assert np.array_equal(df[["x_um", "y_um", "z_um"]].to_numpy(), np.r_[clouds[0], clouds[5]])


def test_matches_round_trip_with_both_frames(tmp_path):
    rng = np.random.default_rng(3)
    m = np.array([[0, 2], [1, 0], [3, 1]])
    d = rng.normal(size=(3, 3))
    s = rng.uniform(0.1, 1, (3, 3))
    p = tables.write_matches_csv(tmp_path / "matches_000004.csv", m, d, sigma_xyz_um=s, dt_s=0.04)
    tables.write_matches_csv(tmp_path / "matches_000002.csv", m[:1], d[:1])
    df = track.read_matches(p)  # no summary.json: the reference frame is unknown
    cols = ["def_frame", "row_ref", "row_def", "ux_um", "uy_um", "uz_um"]
    assert list(df.columns) == [*cols, *tables.MATCH_SIGMA_COLUMNS, *tables.VELOCITY_COLUMNS]
    assert (df["def_frame"] == 4).all() and df["row_ref"].dtype == np.int64
    assert np.array_equal(df[["row_ref", "row_def"]].to_numpy(), m)
    assert np.array_equal(df[["ux_um", "uy_um", "uz_um"]].to_numpy(), d)
    assert np.array_equal(df[list(tables.MATCH_SIGMA_COLUMNS)].to_numpy(), s)
    v = np.loadtxt(p, delimiter=",", skiprows=1)[:, -3:]  # the file's own values
    assert np.array_equal(df[list(tables.VELOCITY_COLUMNS)].to_numpy(), v)
    incs = [{"ref_frame": 0, "def_frame": 2}, {"ref_frame": 2, "def_frame": 4}]
    (tmp_path / "summary.json").write_text(json.dumps({"increments": incs}))
    all_ = track.read_matches(tmp_path)
    assert all_[["ref_frame", "def_frame"]].to_numpy().tolist() == [[0, 2]] + [[2, 4]] * 3
    assert all_["sigma_dx_um"].isna().tolist() == [True, False, False, False]


def test_tracks_round_trip_to_the_same_bytes_and_through_trackpy_names(tmp_path):
    m = np.array([[0, 2], [1, 0], [3, 1]])
    xyz = [np.arange(12.0).reshape(4, 3) / 7, np.arange(9.0).reshape(3, 3) / 3 + 0.1]
    sig = [np.full((4, 3), 0.25), np.full((3, 3), 0.5)]
    tr = link_tracks([4, 3], [m], positions_um=xyz, sigmas_um=sig)
    p = tables.write_tracks_csv(tmp_path / "tracks.csv", tr, times_s={0: 0.0, 1: 0.04})
    df = track.read_tracks(tmp_path)
    cols = ["frame", "track_id", "x_um", "y_um", "z_um", *tables.SIGMA_COLUMNS, "time_s"]
    assert list(df.columns) == cols
    t = tables.read_tracks_csv(p)
    for c in cols:
        assert np.array_equal(df[c].to_numpy(), t[c]), c
    assert df["frame"].dtype == np.int64 and df["track_id"].dtype == np.int64
    assert dfs.write_tracks(tmp_path / "copy.csv", df).read_bytes() == p.read_bytes()
    tp = track.to_trackpy(df)
    assert list(tp.columns[:5]) == ["frame", "particle", "x", "y", "z"]
    assert np.array_equal(tp["x"].to_numpy(), df["x_um"].to_numpy())  # still µm
    back = track.from_trackpy(tp)
    pd.testing.assert_frame_equal(back, df)
    # rows in any order are written sorted by frame, then track
    shuffled = df.sample(frac=1.0, random_state=0)
    assert dfs.write_tracks(tmp_path / "c2.csv", shuffled).read_bytes() == p.read_bytes()
    bad = df.assign(time_s=np.arange(len(df), dtype=float))
    with pytest.raises(InputError, match="frame 0 has more than one time_s"):
        dfs.write_tracks(tmp_path / "c3.csv", bad)


def test_tracks_frame_and_time_read_the_same_in_plain_pandas(tmp_path):
    """tracks.csv as pandas' own reader sees it: integer frame and track_id, time in s."""
    m = np.array([[0, 0], [1, 1]])
    tr = link_tracks([2, 2, 2], [m, m], positions_um=[np.eye(2, 3) * k + 0.25 for k in range(3)])
    p = tables.write_tracks_csv(tmp_path / "tracks.csv", tr, times_s={0: 0.0, 1: 0.5, 2: 1.25})
    raw = pd.read_csv(p)
    assert raw["frame"].dtype == np.int64 and raw["track_id"].dtype == np.int64
    assert raw["frame"].tolist() == [0, 0, 1, 1, 2, 2]
    assert raw["time_s"].tolist() == [0.0, 0.0, 0.5, 0.5, 1.25, 1.25]
    pd.testing.assert_frame_equal(raw, track.read_tracks(p))


def test_fields_npz_round_trip_exactly(tmp_path):
    g = _field()
    p = field_files.write_field_npz(tmp_path / "fields" / "000007.npz", g, frame=7, time_s=0.28)
    df = track.read_fields(p)
    nz, ny, nx = g.shape
    assert len(df) == nx * ny * nz
    z, y, x = np.meshgrid(g.z_um, g.y_um, g.x_um, indexing="ij")
    assert np.array_equal(
        df[["x_um", "y_um", "z_um"]].to_numpy(), np.c_[x.ravel(), y.ravel(), z.ravel()]
    )
    assert np.array_equal(df[["ux_um", "uy_um", "uz_um"]].to_numpy(), g.u.reshape(-1, 3))
    ax = "xyz"
    for i in range(3):
        for j in range(3):
            assert np.array_equal(df[f"F_{ax[i]}{ax[j]}"], g.F[..., i, j].ravel())
            assert np.array_equal(df[f"sigma_F_{ax[i]}{ax[j]}"], g.F_std[..., i, j].ravel())
            if i <= j:
                for name in ("E", "e"):
                    assert np.array_equal(
                        df[f"{name}_{ax[i]}{ax[j]}"], getattr(g, name)[..., i, j].ravel()
                    )
                assert np.array_equal(df[f"sigma_e_{ax[i]}{ax[j]}"], g.e_std[..., i, j].ravel())
    assert np.array_equal(df[["sigma_ux_um", "sigma_uy_um", "sigma_uz_um"]], g.u_std.reshape(-1, 3))
    assert df["mask"].dtype == bool and np.array_equal(df["mask"], g.mask.ravel())
    assert (df["frame"] == 7).all() and (df["time_s"] == 0.28).all()
    # a folder: every total field, increments left out
    field_files.write_field_npz(tmp_path / "fields" / "000003.npz", _field(False), frame=3)
    field_files.write_field_npz(tmp_path / "fields" / "increment_000007.npz", g, frame=7)
    both = track.read_fields(tmp_path)
    assert both["frame"].tolist() == [3] * len(df) + [7] * len(df)
    assert both["time_s"].isna().sum() == len(df)  # frame 3's time is unknown
    assert both["sigma_ux_um"].isna().sum() == len(df)  # frame 3 has no uncertainties


def test_vti_reads_back_as_the_field_in_float32_with_nan_outside_the_mask(tmp_path):
    g = _field()
    for enc in ("binary", "ascii"):
        p = field_files.write_field_vti(
            tmp_path / f"{enc}.vti", g, encoding=enc, frame=2, time_s=0.5
        )
        v = track.read_fields(p)
        n = track.read_fields(
            field_files.write_field_npz(tmp_path / f"{enc}.npz", g, frame=2, time_s=0.5)
        )
        assert list(v.columns) == list(n.columns)
        inside = n["mask"].to_numpy()
        assert np.array_equal(v["mask"], inside) and 0.2 < inside.mean() < 0.95
        assert np.allclose(v[["x_um", "y_um", "z_um"]], n[["x_um", "y_um", "z_um"]], rtol=1e-12)
        values = [
            c for c in n.columns if c not in ("x_um", "y_um", "z_um", "mask", "frame", "time_s")
        ]
        assert v.loc[~inside, values].isna().all().all()
        assert np.allclose(v.loc[inside, values], n.loc[inside, values], rtol=1e-6, atol=1e-7)
        assert (v["frame"] == 2).all() and (v["time_s"] == 0.5).all()


def test_vti_units_and_nan_in_vtks_own_reader(tmp_path):
    """What ParaView shows: NaN (blank) at the nodes outside the mask, the mask kept, units
    in the array names, in VTK's UNITS_LABEL of the length arrays and in the field data."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkDataArray
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    g = _field()
    for enc in ("binary", "ascii"):
        p = field_files.write_field_vti(
            tmp_path / f"{enc}.vti", g, encoding=enc, frame=4, time_s=0.125
        )
        reader = vtkXMLImageDataReader()
        reader.SetFileName(str(p))
        reader.Update()
        img = reader.GetOutput()
        pd_ = img.GetPointData()
        names = [pd_.GetArrayName(i) for i in range(pd_.GetNumberOfArrays())]
        assert "displacement_um" in names and "displacement_std_um" in names
        assert "displacement" not in names
        inside = vtk_to_numpy(pd_.GetArray("mask")).astype(bool)
        assert np.array_equal(inside, g.mask.ravel())
        for name in names:
            a = vtk_to_numpy(pd_.GetArray(name)).reshape(len(inside), -1)
            if name != "mask":
                assert np.isnan(a[~inside]).all() and np.isfinite(a[inside]).all(), name
        u = vtk_to_numpy(pd_.GetArray("displacement_um"))
        assert np.allclose(u[inside], g.u[g.mask], rtol=1e-6, atol=1e-6)
        key = vtkDataArray.UNITS_LABEL()
        for name in names:
            info = pd_.GetArray(name).GetInformation()
            assert info.Has(key) == name.endswith("_um"), name
            if name.endswith("_um"):
                assert info.Get(key) == "um"
        fd = img.GetFieldData()
        units = fd.GetAbstractArray("units")
        listed = dict(units.GetValue(i).split(": ") for i in range(units.GetNumberOfValues()))
        assert list(listed) == names
        assert listed["displacement_um"] == "um" and listed["E_xz"] == "1" and listed["mask"] == "1"
        assert fd.GetAbstractArray("length_unit").GetValue(0) == "um"
        assert fd.GetAbstractArray("time_unit").GetValue(0) == "s"
        assert (
            fd.GetArray("TimeValue").GetValue(0) == 0.125 and fd.GetArray("frame").GetValue(0) == 4
        )


@pytest.fixture(scope="module")
def linked(tmp_path_factory):
    """A ``track link`` results folder: three clouds under simple-shear increments."""
    rng = np.random.default_rng(5)
    X = rng.uniform([0, 0, 0], [400, 400, 300], (150, 3))
    clouds = [X @ np.array([[1, 0, 0.02 * k], [0, 1, 0], [0, 0, 1.0]]).T for k in range(3)]
    out = tmp_path_factory.mktemp("df") / "r"
    track_clouds(clouds, out, series=SeriesSettings(grid=GridSettings(target_nodes=1000)))
    return out, clouds


def test_a_results_folder_reads_as_dataframes_that_join(linked):
    out, clouds = linked
    res = track.read_results(out)
    assert isinstance(res, track.ResultsTables) and res.summary["command"] == "link"
    assert np.array_equal(
        res.particles[["x_um", "y_um", "z_um"]].to_numpy(), np.concatenate(clouds)
    )
    assert res.particles["frame"].tolist() == [0] * 150 + [1] * 150 + [2] * 150
    # every match joins its two particles by (frame, row): u = x_def − x_ref
    m = res.matches
    assert set(zip(m["ref_frame"], m["def_frame"], strict=True)) == {(0, 1), (1, 2)}
    p = res.particles.set_index(["frame", "row"])
    ref = p.loc[list(zip(m["ref_frame"], m["row_ref"], strict=True)), ["x_um", "y_um", "z_um"]]
    dfm = p.loc[list(zip(m["def_frame"], m["row_def"], strict=True)), ["x_um", "y_um", "z_um"]]
    u = m[["ux_um", "uy_um", "uz_um"]].to_numpy()
    assert len(m) >= 0.95 * 300 and np.allclose(dfm.to_numpy() - ref.to_numpy(), u, atol=1e-9)
    # tracks: the same particle (same row here) carries one track_id through the frames
    t = res.tracks.merge(res.particles, on=["frame", "x_um", "y_um", "z_um"])
    assert (t.groupby("track_id")["row"].nunique() == 1).all() and len(t) == len(res.tracks)
    assert sorted(res.field_files) == [1, 2]
    f = track.read_fields(res.field_files[2])
    gamma = 2 * f.loc[f["mask"], "e_xz"]
    assert abs(gamma.median() - 0.04) < 0.004  # two 0.02 increments
    assert (f["frame"] == 2).all()


def test_bad_files_give_the_csv_readers_one_line_errors(tmp_path):
    tp, tm, tt = tables.read_points_csv, tables.read_matches_csv, tables.read_tracks_csv
    neg = "x_um,y_um,z_um,sigma_x_um,sigma_y_um,sigma_z_um\n1,2,3,-1,0,0\n"
    cases = [
        ("particles/000001.csv", "x_um,y_um,z_um\n1,2,abc\n", tp, track.read_particles),
        ("matches_000001.csv", "row_ref,row_def,ux_um\n0,1,2\n", tm, track.read_matches),
        ("tracks.csv", "frame,track_id,x_um,y_um,z_um\n0.5,1,1,2,3\n", tt, track.read_tracks),
        ("p2/000002.csv", neg, tables.read_point_sigmas, track.read_particles),
    ]
    for name, text, ours, reader in cases:
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        with pytest.raises(InputError) as want:
            ours(p)
        with pytest.raises(InputError) as got:
            reader(p)
        assert str(got.value) == str(want.value) and str(p) in str(got.value)
        assert "\n" not in str(got.value)
    with pytest.raises(InputError, match=r"particles: no particle tables NNNNNN\.csv"):
        (tmp_path / "empty" / "particles").mkdir(parents=True)
        track.read_particles(tmp_path / "empty")
    with pytest.raises(InputError, match="does not exist"):
        track.read_tracks(tmp_path / "empty")
    with pytest.raises(InputError, match=r"summary\.json does not exist"):
        track.read_results(tmp_path / "empty")
    with pytest.raises(InputError, match=r"expected a field file \.npz or \.vti"):
        track.read_fields(tmp_path / "tracks.csv")
    bad = tmp_path / "000001.vti"
    bad.write_text("<VTKFile type='PolyData'/>")
    with pytest.raises(InputError, match="not a VTK ImageData file written by track"):
        track.read_fields(bad)
    with pytest.raises(InputError, match="the particle DataFrame has no column"):
        dfs.write_particles(tmp_path / "x.csv", pd.DataFrame({"x": [1.0]}))


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:The inplace keyword in DataFrame.sort_values")
def test_trackpy_links_what_track_detect_found(tmp_path):
    """``track detect`` on three volumes of 20 blobs moving 1.5 µm along x per frame:
    ``trackpy.link(to_trackpy(read_particles(results)), 3 µm)`` gives each blob one
    particle id through the frames, and written back as tracks.csv they read as ours."""
    trackpy = pytest.importorskip("trackpy")  # in the test extra
    centres = _volumes(tmp_path / "vols")  # (z, y, x) voxels of frame 0
    out = tmp_path / "res"
    track.track_volumes(
        tmp_path / "vols", out, detect=track.DetectSettings(deconvolution_iterations=0)
    )
    origin = np.asarray(track.volumes.scan_volumes(tmp_path / "vols")[0].origin_xyz_um)
    truth = origin + centres[:, ::-1] * np.asarray(VOXEL[::-1])  # µm, x y z
    res = track.read_results(out)  # detection only: particles, no matches, tracks or fields
    assert res.matches is None and res.tracks is None and res.field_files == {}
    assert res.summary["command"] == "detect"
    f = track.to_trackpy(track.read_particles(out))
    pd.testing.assert_frame_equal(f, track.to_trackpy(res.particles))
    assert {"frame", "x", "y", "z"} <= set(f.columns)
    linked = trackpy.link(f, search_range=3.0, memory=0)
    # each detection's blob: the nearest truth centre (moved 1.5 µm per frame), within 1 µm
    shift = np.c_[1.5 * linked["frame"], np.zeros((len(linked), 2))]
    dist = np.linalg.norm((linked[["x", "y", "z"]].to_numpy() - shift)[:, None] - truth, axis=2)
    assert (dist.min(axis=1) < 1.0).all()
    linked = linked.assign(blob=dist.argmin(axis=1))
    # every blob found in every frame, and trackpy's particles are the blobs: one particle
    # per blob, one blob per particle
    assert len(linked) == 3 * len(truth)
    assert (linked.groupby("blob")["frame"].nunique() == 3).all()
    assert linked["blob"].nunique() == linked["particle"].nunique() == len(truth)
    assert (linked.groupby("blob")["particle"].nunique() == 1).all()
    # trackpy's trajectories as our tracks.csv
    p = dfs.write_tracks(out / "tracks_trackpy.csv", track.from_trackpy(linked))
    back = track.read_tracks(p)
    assert len(back) == len(linked) and back["track_id"].nunique() == len(truth)
    want = linked.sort_values(["frame", "particle"])[["frame", "particle", "x", "y", "z"]]
    assert np.array_equal(track.to_trackpy(back)[list(want.columns)].to_numpy(), want.to_numpy())


def test_import_track_imports_pandas_only_for_the_dataframes():
    code = (
        "import sys, track; a = 'pandas' in sys.modules; track.read_tracks; "
        "print(a, 'pandas' in sys.modules, track.read_tracks is track.dataframes.read_tracks)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "True"]
