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
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        assert json.loads(page.description) == meta
        x_res = page.tags["XResolution"].value
        assert x_res[0] / x_res[1] == pytest.approx(1e4 / 1.6666, rel=1e-6)  # pixels per cm


def test_image_without_pixel_size_and_anisotropic(tmp_path):
    img = np.arange(12, dtype=np.uint16).reshape(3, 4)
    write_tiff(tmp_path / "a.tif", img, metadata={})
    back, meta = read_tiff(tmp_path / "a.tif")
    assert np.array_equal(back, img) and meta == {}
    write_tiff(tmp_path / "b.tif", img, metadata={"k": 1}, pixel_size_um=(2.0, 1.0))
    with tifffile.TiffFile(tmp_path / "b.tif") as tif:
        x = tif.pages[0].tags["XResolution"].value
        y = tif.pages[0].tags["YResolution"].value
    assert x[0] / x[1] == pytest.approx(1e4) and y[0] / y[1] == pytest.approx(5e3)


@pytest.mark.parametrize("shape", [(5, 6, 7), (1, 4, 3), (3, 4, 4)])
def test_volume_round_trip_with_voxel_size(tmp_path, shape):
    vol = np.random.default_rng(1).standard_normal(shape).astype(np.float32)
    meta = {"iterations": 3, "z_um": [-80.0, 720.0]}
    write_tiff(tmp_path / "v.tif", vol, metadata=meta, pixel_size_um=(5.0, 1.64, 1.62))
    back, meta_back = read_tiff(tmp_path / "v.tif")
    assert back.dtype == np.float32 and back.shape == shape
    assert np.array_equal(back, vol)
    assert meta_back == {**meta, "voxel_size_um": [5.0, 1.64, 1.62]}


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
