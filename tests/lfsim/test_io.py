"""Atomic writes, JSON and TIFF round trips (lfsim.io)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import tifffile

from hrvbase.errors import InputError
from lfsim.errors import ConfigError, OutputError
from lfsim.io import (
    METADATA_TAG,
    atomic_write_bytes,
    atomic_write_text,
    read_json,
    read_tiff,
    sha256_file,
    write_json,
    write_tiff,
)


def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def _ratio(tag_value) -> float:
    num, den = tag_value
    return num / den


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_image_round_trip(tmp_path, dtype):
    rng = np.random.default_rng(0)
    img = rng.integers(0, np.iinfo(dtype).max, size=(30, 40), endpoint=True).astype(dtype)
    meta = {"frame": 3, "noise": {"model": "gaussian", "snr": 17.0}, "ids": [1, 2], "x": None}
    path = write_tiff(tmp_path / "img.tif", img, metadata=meta, pixel_size_um=1.6666)
    back, meta_back = read_tiff(path)
    assert back.dtype == dtype and back.shape == (30, 40)
    assert np.array_equal(back, img)
    assert meta_back == meta
    # An ImageJ image that Fiji shows in µm: pixels per µm, unit in the description.
    with tifffile.TiffFile(path) as tif:
        assert tif.series[0].axes == "YX" and len(tif.pages) == 1
        assert tif.imagej_metadata["unit"] == "um"
        page = tif.pages[0]
        assert json.loads(page.tags[METADATA_TAG].value) == meta
        assert _ratio(page.tags["XResolution"].value) == pytest.approx(1 / 1.6666, rel=1e-9)
        assert page.tags["ResolutionUnit"].value == tifffile.RESUNIT.NONE


def test_image_without_pixel_size_and_anisotropic(tmp_path):
    img = np.arange(12, dtype=np.uint16).reshape(3, 4)
    write_tiff(tmp_path / "a.tif", img, metadata={})
    back, meta = read_tiff(tmp_path / "a.tif")
    assert np.array_equal(back, img) and meta == {}
    with tifffile.TiffFile(tmp_path / "a.tif") as tif:
        assert "unit" not in tif.imagej_metadata  # no scale: ImageJ shows pixels
    write_tiff(tmp_path / "b.tif", img, metadata={"k": 1}, pixel_size_um=(2.0, 1.0))
    with tifffile.TiffFile(tmp_path / "b.tif") as tif:
        x = tif.pages[0].tags["XResolution"].value
        y = tif.pages[0].tags["YResolution"].value
    assert _ratio(x) == pytest.approx(1.0) and _ratio(y) == pytest.approx(0.5)  # per µm


@pytest.mark.parametrize("shape", [(5, 6, 7), (1, 4, 3), (3, 4, 4)])
def test_volume_round_trip_with_voxel_size(tmp_path, shape):
    vol = np.random.default_rng(1).standard_normal(shape).astype(np.float32)
    meta = {"iterations": 3, "z_um": [-80.0, 720.0]}
    write_tiff(tmp_path / "v.tif", vol, metadata=meta, pixel_size_um=(5.0, 1.64, 1.62))
    back, meta_back = read_tiff(tmp_path / "v.tif")
    assert back.dtype == np.float32 and back.shape == shape
    assert np.array_equal(back, vol)
    assert meta_back == {**meta, "voxel_size_um": [5.0, 1.64, 1.62]}


def test_volume_scale_and_origin_for_imagej_readers(tmp_path):
    """Fiji (and napari-tiff) read the ImageJ hyperstack entries; our JSON rides along."""
    vol = np.random.default_rng(2).random((6, 5, 4)).astype(np.float32)
    origin = (-20.5, 12.25, -80.0)
    path = write_tiff(
        tmp_path / "v.tif",
        vol,
        metadata={"frame": 0},
        pixel_size_um=(5.0, 25 / 3, 1.62),
        origin_xyz_um=origin,
    )
    with tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        assert series.axes == "ZYX" and series.shape == (6, 5, 4)
        assert np.array_equal(series.asarray(), vol)
        ij = tif.imagej_metadata
        assert ij["spacing"] == 5.0 and ij["unit"] == "um" and ij["slices"] == 6
        page = tif.pages[0]
        dx = 1 / _ratio(page.tags["XResolution"].value)
        dy = 1 / _ratio(page.tags["YResolution"].value)
        assert (dx, dy) == (pytest.approx(1.62, rel=1e-9), pytest.approx(25 / 3, rel=1e-9))
        assert page.tags["ResolutionUnit"].value == tifffile.RESUNIT.NONE
        # ImageJ: coordinate = (index - origin) * size; voxel 0 is at the given origin.
        assert -ij["xorigin"] * dx == pytest.approx(origin[0], rel=1e-9)
        assert -ij["yorigin"] * dy == pytest.approx(origin[1], rel=1e-9)
        assert -ij["zorigin"] * 5.0 == pytest.approx(origin[2], rel=1e-12)
    back, meta = read_tiff(path)
    assert np.array_equal(back, vol)
    assert meta == {
        "frame": 0,
        "voxel_size_um": [5.0, 25 / 3, 1.62],
        "origin_xyz_um": list(origin),
    }
    # the track reader finds the same scale and origin
    from track.volumes import scan_volumes

    (tmp_path / "series").mkdir()
    write_tiff(
        tmp_path / "series" / "000000.tif",
        vol,
        metadata={},
        pixel_size_um=(5.0, 25 / 3, 1.62),
        origin_xyz_um=origin,
    )
    (info,) = scan_volumes(tmp_path / "series")
    assert info.shape == (6, 5, 4) and info.voxel_size_um == (5.0, 25 / 3, 1.62)
    assert info.origin_xyz_um == pytest.approx(origin)


def test_other_dtypes_are_plain_tiff_with_the_same_metadata(tmp_path):
    """ImageJ holds 8/16-bit integers and float32 only; float64 stays a plain TIFF."""
    vol = np.random.default_rng(3).random((2, 3, 4))
    path = write_tiff(tmp_path / "v.tif", vol, metadata={"k": 1}, pixel_size_um=2.0)
    back, meta = read_tiff(path)
    assert back.dtype == np.float64 and np.array_equal(back, vol) and meta == {"k": 1}
    with tifffile.TiffFile(path) as tif:
        assert tif.imagej_metadata is None
        page = tif.pages[0]
        assert _ratio(page.tags["XResolution"].value) == pytest.approx(5e3)  # pixels per cm
        assert page.tags["ResolutionUnit"].value == tifffile.RESUNIT.CENTIMETER


def _write_previous_layout(path, arr, meta, pixel_size_um):
    """A file as write_tiff wrote it before the ImageJ layout: JSON in the ImageDescription,
    resolution in pixels per cm, the shape in tag 65000."""
    sizes = (pixel_size_um,) * arr.ndim if np.isscalar(pixel_size_um) else pixel_size_um
    tifffile.imwrite(
        path,
        arr,
        photometric="minisblack",
        description=json.dumps(meta),
        metadata=None,
        software=False,
        extratags=[(65000, "s", 0, json.dumps({"shape": list(arr.shape)}), True)],
        resolution=(1e4 / sizes[-1], 1e4 / sizes[-2]),
        resolutionunit="CENTIMETER",
    )


def test_files_of_the_previous_layout_still_read(tmp_path):
    from track.volumes import scan_volumes

    img = np.arange(20, dtype=np.uint16).reshape(4, 5)
    _write_previous_layout(tmp_path / "img.tif", img, {"frame": 1, "noise": None}, 1.6)
    back, meta = read_tiff(tmp_path / "img.tif")
    assert np.array_equal(back, img) and meta == {"frame": 1, "noise": None}

    folder = tmp_path / "vols"
    folder.mkdir()
    vol = np.ones((1, 3, 4), np.float32)
    old = {"depths_um": [-80.0], "origin_um": [10.0, 20.0], "voxel_size_um": [5.0, 2.0, 2.0]}
    _write_previous_layout(folder / "000000.tif", vol, old, (5.0, 2.0, 2.0))
    back, meta = read_tiff(folder / "000000.tif")
    assert back.shape == (1, 3, 4) and meta == old
    (info,) = scan_volumes(folder)
    assert info.shape == (1, 3, 4) and info.voxel_size_um == (5.0, 2.0, 2.0)
    # recon's old files: origin_um is the corner of lenslet (0, 0); voxel centres are half a
    # voxel further in.
    assert info.origin_xyz_um == pytest.approx((11.0, 21.0, -80.0))


def test_track_reads_a_volume_resaved_by_fiji(tmp_path):
    """Fiji keeps the ImageJ calibration but drops our private tags."""
    from track.volumes import scan_volumes

    vol = np.zeros((3, 4, 5), np.float32)
    tifffile.imwrite(
        tmp_path / "000000.tif",
        vol,
        imagej=True,
        resolution=(1 / 1.5, 1 / 2.5),
        metadata={"axes": "ZYX", "unit": "micron", "spacing": 4.0, "zorigin": 20.0},
    )
    (info,) = scan_volumes(tmp_path)
    assert info.voxel_size_um == pytest.approx((4.0, 2.5, 1.5))
    assert info.origin_xyz_um == pytest.approx((0.0, 0.0, -80.0))
    # an uncalibrated ImageJ file (unit pixel) has no voxel size
    (tmp_path / "000000.tif").unlink()
    tifffile.imwrite(tmp_path / "000000.tif", vol, imagej=True, metadata={"axes": "ZYX"})
    with pytest.raises(InputError, match="no voxel size"):
        scan_volumes(tmp_path)


def test_bad_pixel_size_and_arrays(tmp_path):
    vol = np.zeros((2, 3, 4), np.float32)
    with pytest.raises(ConfigError, match="pixel_size_um"):
        write_tiff(tmp_path / "v.tif", vol, metadata={}, pixel_size_um=(1.0, 2.0))
    with pytest.raises(ConfigError, match="pixel_size_um"):
        write_tiff(tmp_path / "v.tif", vol, metadata={}, pixel_size_um=-1.0)
    with pytest.raises(ConfigError, match="2-D"):
        write_tiff(tmp_path / "v.tif", np.zeros(5), metadata={})
    with pytest.raises(InputError, match="JSON"):
        write_tiff(tmp_path / "v.tif", vol, metadata={"bad": object()})
    with pytest.raises(ConfigError, match="origin_xyz_um"):
        write_tiff(tmp_path / "v.tif", vol, metadata={}, pixel_size_um=1.0, origin_xyz_um=(0, 0))
    with pytest.raises(ConfigError, match="origin_xyz_um needs pixel_size_um"):
        write_tiff(tmp_path / "v.tif", vol, metadata={}, origin_xyz_um=(0, 0, 0))
    with pytest.raises(ConfigError, match="volumes only"):
        write_tiff(
            tmp_path / "v.tif", vol[0], metadata={}, pixel_size_um=1.0, origin_xyz_um=(0, 0, 0)
        )
    assert _files(tmp_path) == []
    # JSON has no NaN: every writer of the toolkit stores it as null (hrvbase.io.to_json).
    write_tiff(tmp_path / "v.tif", vol, metadata={"nan": float("nan"), "x": [1.0, float("inf")]})
    assert read_tiff(tmp_path / "v.tif")[1] == {"nan": None, "x": [1.0, None]}


def test_refuses_to_overwrite(tmp_path):
    path = tmp_path / "img.tif"
    write_tiff(path, np.ones((4, 4), np.uint8), metadata={"v": 1})
    before = path.read_bytes()
    with pytest.raises(OutputError, match=r"img\.tif"):
        write_tiff(path, np.zeros((4, 4), np.uint8), metadata={"v": 2})
    assert path.read_bytes() == before
    write_tiff(path, np.zeros((4, 4), np.uint8), metadata={"v": 2}, overwrite=True)
    arr, meta = read_tiff(path)
    assert meta == {"v": 2} and not arr.any()
    assert _files(tmp_path) == ["img.tif"]
    with pytest.raises(OutputError, match="already exists"):
        atomic_write_text(path, "x", overwrite=False)


def test_atomic_writes_leave_no_temp_files(tmp_path, monkeypatch):
    atomic_write_bytes(tmp_path / "sub" / "a.bin", b"abc")
    atomic_write_text(tmp_path / "b.txt", "héllo")
    write_json(tmp_path / "c.json", {"a": np.float64(1.5), "b": np.arange(3), "c": np.int32(2)})
    write_tiff(tmp_path / "d.tif", np.zeros((3, 3), np.uint8), metadata={})
    assert _files(tmp_path) == ["b.txt", "c.json", "d.tif", "sub", "sub/a.bin"]
    assert (tmp_path / "sub" / "a.bin").read_bytes() == b"abc"
    assert (tmp_path / "b.txt").read_text(encoding="utf-8") == "héllo"
    assert read_json(tmp_path / "c.json") == {"a": 1.5, "b": [0, 1, 2], "c": 2}

    # A writer that dies half-way leaves neither a partial file nor a temporary one.
    def broken(path, *args, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"II*\x00partial")
        raise ValueError("disk on fire")

    monkeypatch.setattr(tifffile, "imwrite", broken)
    with pytest.raises(ConfigError, match="disk on fire"):
        write_tiff(tmp_path / "d.tif", np.ones((3, 3), np.uint8), metadata={}, overwrite=True)
    assert _files(tmp_path) == ["b.txt", "c.json", "d.tif", "sub", "sub/a.bin"]
    arr, _ = read_tiff(tmp_path / "d.tif")
    assert not arr.any()  # the old file is intact


def test_unwritable_folder_names_the_path(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    target = blocker / "img.tif"
    with pytest.raises(OutputError, match=r"img\.tif"):
        write_tiff(target, np.zeros((2, 2), np.uint8), metadata={})
    with pytest.raises(OutputError, match=r"out\.json"):
        write_json(blocker / "out.json", {})


def test_read_errors_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"missing\.tif"):
        read_tiff(tmp_path / "missing.tif")
    bad = tmp_path / "corrupt.tif"
    bad.write_bytes(b"this is not a tiff file at all")
    with pytest.raises(ConfigError, match=r"corrupt\.tif"):
        read_tiff(bad)
    odd = tmp_path / "odd.tif"
    tifffile.imwrite(
        odd, np.zeros((2, 2), np.uint8), extratags=[(METADATA_TAG, "s", 0, "[1]", True)]
    )
    with pytest.raises(ConfigError, match=r"odd\.tif: metadata tag 65001"):
        read_tiff(odd)
    with pytest.raises(InputError, match=r"nothing\.json"):
        read_json(tmp_path / "nothing.json")
    (tmp_path / "bad.json").write_text("{oops")
    with pytest.raises(InputError, match=r"bad\.json"):
        read_json(tmp_path / "bad.json")


def test_sha256_file(tmp_path):
    p = tmp_path / "x.bin"
    data = bytes(range(256)) * 5000
    p.write_bytes(data)
    assert sha256_file(p) == hashlib.sha256(data).hexdigest()
    with pytest.raises(InputError, match="nope"):
        sha256_file(tmp_path / "nope")
