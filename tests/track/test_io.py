"""Files of track: CSV tables, gridded fields (npz, vti), volume series, the track.io façade."""

from __future__ import annotations

import base64
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import tifffile

from hrvbase.errors import InputError, OutputError
from hrvbase.io import sha256_file, write_json
from track import field_files, tables, volumes
from track.fields import GridSettings, gridded_field
from track.series import link_tracks

from ..helpers import assert_bad_file_named

_A = np.array([[0.0, 0.0, 0.1], [0.0, 0.02, 0.0], [0.0, 0.0, -0.01]])  # u = A x (µm)


def _field():
    X = np.random.default_rng(0).uniform([0, 10, -5], [100, 80, 60], (80, 3))
    return gridded_field(X, X @ _A.T, GridSettings(spacing_um=12.0))


def test_points_csv_round_trip_and_extra_columns(tmp_path):
    xyz = np.random.default_rng(1).normal(size=(7, 3)) * 100
    p = tables.write_points_csv(tmp_path / "particles" / "000000.csv", xyz, np.arange(7.0))
    assert p.read_text().splitlines()[0] == "x_um,y_um,z_um,intensity"
    assert np.array_equal(tables.read_points_csv(p), xyz)  # repr() round-trips floats exactly
    other = tmp_path / "other.csv"
    other.write_text("id,z_um,y_um,x_um,note\n3,1.5,2.5,3.5,a\n4,4,5,6,b\n")
    assert np.array_equal(tables.read_points_csv(other), [[3.5, 2.5, 1.5], [6, 5, 4]])
    header_only = tmp_path / "h.csv"
    header_only.write_text("x_um,y_um,z_um\n")
    assert tables.read_points_csv(header_only).shape == (0, 3)
    with pytest.raises(OutputError, match="already exists"):
        tables.write_points_csv(p, xyz)
    assert not list(tmp_path.glob("particles/.*.tmp"))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "is empty; expected a header"),
        ("x_um,y_um\n1,2\n", "line 1: missing column"),
        ("x_um,y_um,z_um\n1,2,3\n4,nan,6\n", "line 3, column 'y_um': expected a finite"),
        ("x_um,y_um,z_um\n1,2,3\n4,5\n", "line 3: expected 3 values"),
        ("x_um,y_um,z_um\n1,2,abc\n", "line 2, column 'z_um': expected a number, got 'abc'"),
    ],
)
def test_bad_point_csv_names_file_and_line(tmp_path, text, match):
    assert_bad_file_named(tmp_path / "bad.csv", text, tables.read_points_csv, InputError, match)


def test_missing_csv(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        tables.read_points_csv(tmp_path / "none.csv")


def test_matches_and_tracks_round_trip(tmp_path):
    m = np.array([[0, 2], [1, 0], [3, 1]])
    d = np.array([[0.1, 0.2, 0.3], [1, 2, 3], [-1, 0, 1.5]])
    p = tables.write_matches_csv(tmp_path / "matches_000001.csv", m, d)
    assert p.read_text().splitlines()[0] == "row_ref,row_def,ux_um,uy_um,uz_um"
    m2, d2 = tables.read_matches_csv(p)
    assert np.array_equal(m2, m) and m2.dtype.kind == "i" and np.array_equal(d2, d)
    xyz = [np.zeros((4, 3)), np.ones((3, 3))]
    tr = link_tracks([4, 3], [m], positions_um=xyz)
    p = tables.write_tracks_csv(tmp_path / "tracks.csv", tr)
    assert p.read_text().splitlines()[0] == "frame,track_id,x_um,y_um,z_um"
    t = tables.read_tracks_csv(p)
    assert list(t["frame"]) == [0, 0, 0, 0, 1, 1, 1]
    assert sorted(t["track_id"][t["frame"] == 1]) == [0, 1, 3]


def test_field_npz_round_trip(tmp_path):
    g = _field()
    p = field_files.write_field_npz(tmp_path / "fields" / "000001.npz", g)
    g2 = field_files.read_field_npz(p)
    for k in ("x_um", "y_um", "z_um", "u", "F", "E", "e", "mask"):
        assert np.array_equal(getattr(g2, k), getattr(g, k))


# VTK XML ImageData, decoded from the file format's definition (not from the writer): points
# are numbered x fastest, then y, then z over the extent; position = origin + index · spacing;
# inline "binary" data are base64 of (header_type byte count + data in byte_order).
_VTK_TYPES = {"Float32": "f4", "Float64": "f8", "UInt8": "u1", "Int32": "i4", "UInt64": "u8"}


def _read_vti_xml(path):
    root = ET.parse(path).getroot()
    assert root.get("type") == "ImageData"
    end = {"LittleEndian": "<", "BigEndian": ">"}[root.get("byte_order")]
    header = np.dtype(end + _VTK_TYPES[root.get("header_type", "UInt32")])
    img = root.find("ImageData")
    e = [int(v) for v in img.get("WholeExtent").split()]
    n = [e[1] - e[0] + 1, e[3] - e[2] + 1, e[5] - e[4] + 1]  # points along x, y, z
    origin = np.array([float(v) for v in img.get("Origin").split()])
    spacing = np.array([float(v) for v in img.get("Spacing").split()])
    pid = np.arange(n[0] * n[1] * n[2])
    ijk = np.c_[pid % n[0], (pid // n[0]) % n[1], pid // (n[0] * n[1])] + [e[0], e[2], e[4]]
    points = origin + ijk * spacing
    arrays = {}
    for da in img.find("Piece/PointData").findall("DataArray"):
        dtype = np.dtype(end + _VTK_TYPES[da.get("type")])
        nc = int(da.get("NumberOfComponents", "1"))
        if da.get("format") == "ascii":
            vals = np.array(da.text.split(), dtype=dtype)
        else:
            raw = base64.b64decode(da.text)
            nbytes = int(np.frombuffer(raw[: header.itemsize], header)[0])
            assert nbytes == len(raw) - header.itemsize
            vals = np.frombuffer(raw[header.itemsize :], dtype)
        arrays[da.get("Name")] = vals.reshape(len(pid), nc)
    return points, arrays


def _check_vti_against_truth(points, arrays, g):
    """At every node supported by particles the values are those of the affine field u = A x
    at the node's position; at the others every array but ``mask`` is NaN."""
    nz, ny, nx = g.shape
    assert points.shape == (nx * ny * nz, 3)
    assert np.allclose(points.min(axis=0), g.origin_xyz_um)
    assert np.allclose(points.max(axis=0), [g.x_um[-1], g.y_um[-1], g.z_um[-1]])
    names = {"displacement_um", "F", "E", "e", "E_xx", "E_xz", "e_yz", "gamma_xz", "mask"}
    assert names <= set(arrays)
    # the mask: in the VTK point order (x fastest), the same nodes as the field's
    inside = arrays["mask"][:, 0].astype(bool)
    assert np.array_equal(inside, g.mask.ravel())
    assert 0.2 < g.mask.mean() < 0.95  # not trivial: both kinds of node occur
    for name, a in arrays.items():
        if name != "mask":
            assert np.isnan(a[~inside]).all() and np.isfinite(a[inside]).all(), name
    arrays = {k: v[inside] for k, v in arrays.items()}
    u = points[inside] @ _A.T
    assert np.allclose(arrays["displacement_um"], u, rtol=1e-5, atol=1e-4)  # Float32, ~10 µm
    F = np.eye(3) + _A
    E = 0.5 * (F.T @ F - np.eye(3))
    e = 0.5 * (_A + _A.T)
    for name, want in (("F", F), ("E", E), ("e", e)):  # 9 components, row-major
        assert np.allclose(arrays[name], want.ravel(), atol=1e-6), name
    assert np.allclose(arrays["E_xx"][:, 0], E[0, 0], atol=1e-6)
    assert np.allclose(arrays["E_xz"][:, 0], E[0, 2], atol=1e-6)
    assert np.allclose(arrays["e_yz"][:, 0], e[1, 2], atol=1e-6)
    assert np.allclose(arrays["gamma_xz"][:, 0], 0.1 - 0.0, atol=1e-6)  # 2 e_xz = A_xz + A_zx


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_vti_holds_the_field_at_each_point(tmp_path, encoding):
    g = _field()
    p = field_files.write_field_vti(tmp_path / "f.vti", g, encoding=encoding)
    _check_vti_against_truth(*_read_vti_xml(p), g)


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_vti_reads_in_vtk(tmp_path, encoding):
    """VTK's own reader (what ParaView uses; vtk is in the test extra) sees the same points and
    values."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    g = _field()
    p = field_files.write_field_vti(tmp_path / "f.vti", g, encoding=encoding)
    reader = vtkXMLImageDataReader()
    reader.SetFileName(str(p))
    reader.Update()
    img = reader.GetOutput()
    assert img.GetDimensions() == g.shape[::-1]
    points = np.array([img.GetPoint(i) for i in range(img.GetNumberOfPoints())])
    pd = img.GetPointData()
    arrays = {}
    for i in range(pd.GetNumberOfArrays()):
        a = vtk_to_numpy(pd.GetArray(i))
        arrays[pd.GetArrayName(i)] = a.reshape(a.shape[0], -1)
    assert pd.GetVectors().GetName() == "displacement_um" and pd.GetTensors().GetName() == "F"
    _check_vti_against_truth(points, arrays, g)


def _volume(path, vs=(5.0, 1.6, 1.6), meta=None):
    desc = json.dumps({"voxel_size_um": list(vs), **(meta or {})}) if vs is not None else None
    tifffile.imwrite(
        path, np.zeros((4, 6, 5), np.float32), description=desc, photometric="minisblack"
    )


def test_scan_volume_series_with_metadata(tmp_path):
    for k in range(3):
        _volume(tmp_path / f"{k:06d}.tif", meta={"origin_um": [10.0, 20.0], "depths_um": [-5]})
    vols = volumes.scan_volumes(tmp_path)
    assert [v.index for v in vols] == [0, 1, 2]
    assert vols[0].shape == (4, 6, 5) and vols[0].voxel_size_um == (5.0, 1.6, 1.6)
    assert vols[0].origin_xyz_um == pytest.approx((10.8, 20.8, -5.0))
    assert volumes.read_volume(vols[1]).dtype == np.float32


def test_recon_json_supplies_voxel_size(tmp_path):
    for k in range(2):
        _volume(tmp_path / f"{k:06d}.tif", vs=None)
    with pytest.raises(InputError, match="no voxel size"):
        volumes.scan_volumes(tmp_path)
    recon = {"voxel_size_um": [4, 2, 2], "grid": {"origin_um": [0, 0], "depths_um": [100, 104]}}
    (tmp_path / "recon.json").write_text(json.dumps(recon))
    vols = volumes.scan_volumes(tmp_path)
    assert vols[1].voxel_size_um == (4.0, 2.0, 2.0)
    assert vols[1].origin_xyz_um == pytest.approx((1.0, 1.0, 100.0))


def test_recon_json_supplies_the_lenslet_period_and_phase(tmp_path, caplog):
    for k in range(2):
        _volume(tmp_path / f"{k:06d}.tif", vs=None)
    # 10 µm lenslets, s = 5 (2 µm voxels); the volumes start 3 columns (x) and 1 row (y)
    # after the corner of lenslet (0, 0): a crop whose voxel (0, 0) sits at phase (1, 3)
    grid = {"s": 5, "lenslet_object_um": 10.0, "origin_um": [-20.0, 4.0], "depths_um": [0, 4]}
    recon = {"voxel_size_um": [4, 2, 2], "grid": grid}
    (tmp_path / "recon.json").write_text(json.dumps(recon))
    vols = volumes.scan_volumes(tmp_path)
    assert vols[0].lenslet_period_vox == 5 and vols[0].lenslet_phase_vox == (0, 0)
    assert volumes.lenslet_phases(recon, (4, 2, 2), (-20 + 7.0, 4 + 3.0, 0), "r") == (5, (1, 3))
    # the corner under the name recon writes gives the same phase; it wins over the older name
    new = {**grid, "origin_xy_um": grid["origin_um"]}
    del new["origin_um"]
    assert volumes.lenslet_phases({"grid": new}, (4, 2, 2), (-13.0, 7.0, 0), "r") == (5, (1, 3))
    both = {"grid": {**new, "origin_um": [0.0, 0.0]}}
    assert volumes.lenslet_phases(both, (4, 2, 2), (-13.0, 7.0, 0), "r") == (5, (1, 3))
    # no s (an older recon.json): no period
    assert volumes.lenslet_phases({"grid": {"origin_um": [0, 0]}}, (4, 2, 2), (1, 1, 0), "r") == (
        None,
        (0, 0),
    )
    # resampled volumes (voxel size not pitch / s) or an origin off the grid: no period, said
    for vs, origin in (((4, 1, 1), (-19.0, 5.0, 0)), ((4, 2, 2), (-19.5, 5.0, 0))):
        with caplog.at_level("WARNING", logger="track.volumes"):
            assert volumes.lenslet_phases(recon, vs, origin, "r") == (None, (0, 0))
        assert "lenslet period does not apply" in caplog.text
        caplog.clear()
    for bad in ({"grid": [1]}, {"grid": {**grid, "s": 2.5}}, {"grid": {**grid, "s": 0}}):
        with pytest.raises(InputError, match="grid"):
            volumes.lenslet_phases(bad, (4, 2, 2), (-19.0, 5.0, 0), "recon.json")


def test_a_tiff_carries_its_lenslet_grid_without_recon_json(tmp_path):
    """recon run writes its grid into each TIFF: copied alone, the volumes keep the period;
    a bad one is refused, naming the file."""
    grid = {"s": 5, "lenslet_object_um": 10.0, "origin_um": [-20.0, 4.0], "depths_um": [0, 4]}
    meta = {"origin_um": [-20.0, 4.0], "depths_um": [0, 4], "grid": grid}
    for k in range(2):
        _volume(tmp_path / f"{k:06d}.tif", vs=(4, 2, 2), meta=meta)
    vols = volumes.scan_volumes(tmp_path)
    assert [(v.lenslet_period_vox, v.lenslet_phase_vox) for v in vols] == [(5, (0, 0))] * 2
    _volume(tmp_path / "000001.tif", vs=(4, 2, 2), meta={**meta, "grid": {**grid, "s": 2.5}})
    with pytest.raises(InputError, match=r"000001\.tif: grid\.s must be a positive integer"):
        volumes.scan_volumes(tmp_path)


def test_each_volume_knows_its_camera_snr(tmp_path):
    """recon.json's record of each frame gives its SNR, else the TIFF's metadata; a bad one
    is refused naming the file; none: None."""
    for k in range(3):
        _volume(tmp_path / f"{k:06d}.tif", meta={"snr": 7.0} if k == 2 else None)
    assert [v.snr for v in volumes.scan_volumes(tmp_path)] == [None, None, 7.0]
    frames = [{"index": k, "preprocess": {"snr": 10.0 + k}} for k in range(2)]
    (tmp_path / "recon.json").write_text(json.dumps({"frames": frames}))
    assert [v.snr for v in volumes.scan_volumes(tmp_path)] == [10.0, 11.0, 7.0]
    frames[1]["preprocess"]["snr"] = -3
    (tmp_path / "recon.json").write_text(json.dumps({"frames": frames}))
    with pytest.raises(InputError, match=r"recon\.json frame 1: snr must be a finite number > 0"):
        volumes.scan_volumes(tmp_path)


def test_each_volume_knows_the_specimens_surface(tmp_path):
    """recon.json's ``surface_z_um`` (where the guard planes end), else the TIFF's metadata;
    a bad one is refused naming the file; none: None."""
    for k in range(2):
        _volume(tmp_path / f"{k:06d}.tif", meta={"surface_z_um": -12.5} if k else None)
    assert [v.surface_z_um for v in volumes.scan_volumes(tmp_path)] == [None, -12.5]
    (tmp_path / "recon.json").write_text(json.dumps({"surface_z_um": 40}))
    assert [v.surface_z_um for v in volumes.scan_volumes(tmp_path)] == [40.0, 40.0]
    (tmp_path / "recon.json").write_text(json.dumps({"surface_z_um": "deep"}))
    with pytest.raises(InputError, match=r"recon\.json: surface_z_um must be a finite number"):
        volumes.scan_volumes(tmp_path)


def test_mismatched_voxel_sizes(tmp_path):
    _volume(tmp_path / "000000.tif")
    _volume(tmp_path / "000001.tif", vs=(5.0, 1.7, 1.6))
    with pytest.raises(InputError, match="mismatched voxel sizes") as info:
        volumes.scan_volumes(tmp_path)
    assert "000001.tif" in str(info.value)


def test_missing_volume_in_series(tmp_path):
    for k in (0, 1, 3):
        _volume(tmp_path / f"{k:06d}.tif")
    with pytest.raises(InputError, match=r"000002\.tif is missing"):
        volumes.scan_volumes(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no numbered volumes"):
        volumes.scan_volumes(empty)
    with pytest.raises(InputError, match="not a folder"):
        volumes.scan_volumes(tmp_path / "000000.tif")


def test_json_writes_nan_as_null(tmp_path):
    p = write_json(tmp_path / "s.json", {"a": float("nan"), "b": np.float32(1.5), "c": [1]})
    assert json.loads(p.read_text()) == {"a": None, "b": 1.5, "c": [1]}
    assert len(sha256_file(p)) == 64


def test_io_facade_re_exports_the_three_modules():
    from track import io

    owners = (tables, field_files, volumes)
    for name in io.__all__:
        homes = [m for m in owners if name in m.__all__]
        assert len(homes) == 1, f"track.io.{name} is defined in {len(homes)} modules"
        assert getattr(io, name) is getattr(homes[0], name)
    assert {*tables.__all__, *field_files.__all__} <= set(io.__all__)
    assert {"VolumeInfo", "numbered", "read_volume", "scan_volumes"} <= set(io.__all__)


def _field_with_std():
    X = np.random.default_rng(0).uniform([0, 10, -5], [100, 80, 60], (80, 3))
    sigma = np.broadcast_to([0.2, 0.3, 2.0], X.shape)
    return gridded_field(X, X @ _A.T, GridSettings(spacing_um=12.0), sigma_xyz_um=sigma)


def test_field_npz_round_trip_with_uncertainties(tmp_path):
    g = _field_with_std()
    assert g.u_std is not None and g.F_std is not None and g.e_std is not None
    p = field_files.write_field_npz(tmp_path / "000001.npz", g)
    with np.load(p) as z:
        assert {"u_std", "F_std", "e_std"} <= set(z.files)
        assert z["u_std"].shape == (*g.shape, 3) and z["e_std"].shape == (*g.shape, 3, 3)
    g2 = field_files.read_field_npz(p)
    for k in ("u", "u_std", "F_std", "e_std"):
        assert np.array_equal(getattr(g2, k), getattr(g, k))
    plain = gridded_field(
        np.random.default_rng(0).uniform(0, 100, (80, 3)),
        np.zeros((80, 3)),
        GridSettings(spacing_um=12.0, uncertainty=False),
    )
    assert plain.u_std is None
    g0 = field_files.read_field_npz(field_files.write_field_npz(tmp_path / "0.npz", plain))
    assert g0.u_std is None and g0.e_std is None  # a field without uncertainties stays so


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_vti_uncertainties_read_in_vtk(tmp_path, encoding):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    g = _field_with_std()
    p = field_files.write_field_vti(tmp_path / "f.vti", g, encoding=encoding)
    reader = vtkXMLImageDataReader()
    reader.SetFileName(str(p))
    reader.Update()
    pd = reader.GetOutput().GetPointData()
    arrays = {}
    for i in range(pd.GetNumberOfArrays()):
        a = vtk_to_numpy(pd.GetArray(i))
        arrays[pd.GetArrayName(i)] = a.reshape(a.shape[0], -1)
    inside = g.mask.ravel()
    n = int(inside.sum())
    for name in ("displacement_std_um", "e_std", "F_std", "e_std_xz"):
        assert np.isnan(arrays[name][~inside]).all(), name  # unsupported nodes: NaN
        arrays[name] = arrays[name][inside]
    assert np.allclose(arrays["displacement_std_um"], g.u_std[g.mask], rtol=1e-6, atol=0)
    assert np.allclose(arrays["e_std"], g.e_std[g.mask].reshape(n, 9), rtol=1e-6, atol=0)
    assert np.allclose(arrays["F_std"], g.F_std[g.mask].reshape(n, 9), rtol=1e-6, atol=0)
    assert np.allclose(arrays["e_std_xz"][:, 0], g.e_std[..., 0, 2][g.mask], rtol=1e-6, atol=0)
    # the σ of u_z (2 µm per particle) shows: 2 / 0.3 × that of u_y, σ/√N < u_std < σ
    u_sd = arrays["displacement_std_um"]
    assert np.all(u_sd[:, 2] > 2.0 / np.sqrt(80)) and np.all(u_sd[:, 2] < 2.0)
    assert np.median(u_sd[:, 2] / u_sd[:, 1]) > 3.0


def test_each_volume_knows_its_camera_frame_number_and_time(tmp_path, caplog):
    """recon.json's record of each frame gives its camera number and time, else the TIFF's
    metadata; none: numbered by the files; recorded for some volumes only: dropped with a
    warning; they must increase with the volumes."""
    for k in range(3):
        _volume(tmp_path / f"{k:06d}.tif", meta={"number": 2 * k, "time_s": 0.5 * k})
    vols = volumes.scan_volumes(tmp_path)
    assert [(v.index, v.frame, v.time_s) for v in vols] == [(0, 0, 0.0), (1, 2, 0.5), (2, 4, 1.0)]
    frames = [{"index": k, "number": n, "time_s": n / 100} for k, n in enumerate((0, 1, 5))]
    (tmp_path / "recon.json").write_text(json.dumps({"frames": frames}))
    vols = volumes.scan_volumes(tmp_path)
    assert [(v.frame, v.time_s) for v in vols] == [(0, 0.0), (1, 0.01), (5, 0.05)]
    frames[2] = {"index": 2, "number": None, "time_s": None}
    (tmp_path / "recon.json").write_text(json.dumps({"frames": frames}))
    with caplog.at_level("WARNING", logger="track"):
        vols = volumes.scan_volumes(tmp_path)
    assert [(v.frame, v.time_s) for v in vols] == [(0, None), (1, None), (2, None)]
    assert "000002.tif has no recorded frame number but other volumes have" in caplog.text
    frames[2] = {"index": 2, "number": 1, "time_s": 0.02}
    (tmp_path / "recon.json").write_text(json.dumps({"frames": frames}))
    with pytest.raises(InputError, match=r"frame number 1 is recorded for both .*000001\.tif and"):
        volumes.scan_volumes(tmp_path)


def test_vti_carries_the_frame_and_its_time(tmp_path):
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    p = field_files.write_field_vti(tmp_path / "f.vti", _field(), frame=5, time_s=0.05)
    reader = vtkXMLImageDataReader()
    reader.SetFileName(str(p))
    reader.Update()
    fd = reader.GetOutput().GetFieldData()
    assert fd.GetArray("TimeValue").GetValue(0) == 0.05 and fd.GetArray("frame").GetValue(0) == 5
    q = field_files.write_field_npz(tmp_path / "f.npz", _field(), frame=5)
    with np.load(q) as z:
        assert int(z["frame"]) == 5 and np.isnan(z["time_s"])
