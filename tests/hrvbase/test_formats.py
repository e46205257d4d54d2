"""The reader registry (hrvbase.formats): formats chosen by content or name, the Phantom .cine
reader against files written to the published format, one volume geometry, one TIFF layout,
and a new format added as one module."""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest
import tifffile

from hrvbase.errors import InputError
from hrvbase.formats import cine, registry, tiff_frames

from .cine_writer import TRIGGER_SECONDS, write_cine

RNG = np.random.default_rng(27)


def frames8(n=3, shape=(24, 40)):
    return RNG.integers(0, 256, size=(n, *shape)).astype(np.uint8)


def frames16(n=3, shape=(24, 40), hi=4096):
    return RNG.integers(0, hi, size=(n, *shape)).astype(np.uint16)


def read_all(path: Path, n: int) -> np.ndarray:
    f = cine.open_file(path)
    try:
        return np.stack([f.read(i, f"{path} [page {i}]") for i in range(n)])
    finally:
        f.close()


def one_line_error(path: Path, *words: str) -> None:
    """Probing ``path`` is refused with one line naming the file and every one of ``words``."""
    with pytest.raises(InputError) as exc:
        registry.probe_frames(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg, msg
    for w in words:
        assert w in msg, (w, msg)


# -- the registry ----------------------------------------------------------------------------
def test_formats_by_content_then_by_name(tmp_path):
    tif = tmp_path / "a.tif"
    tifffile.imwrite(tif, frames16(1)[0])
    movie = write_cine(tmp_path / "m.cine", frames8())
    assert registry.frame_format_for(tif) is tiff_frames
    assert registry.frame_format_for(movie) is cine
    # content first: a renamed file keeps its format
    (tmp_path / "m.dat").write_bytes(movie.read_bytes())
    (tmp_path / "t.cine").write_bytes(tif.read_bytes())
    assert registry.frame_format_for(tmp_path / "m.dat") is cine
    assert registry.frame_format_for(tmp_path / "t.cine") is tiff_frames
    # by name when the content says nothing (missing or foreign file)
    assert registry.frame_format_for(tmp_path / "none.CINE") is cine
    assert registry.frame_format_for(tmp_path / "none.png") is None
    assert {".tif", ".tiff", ".cine"} <= set(registry.frame_suffixes())


def test_a_new_frame_format_is_one_registered_module(tmp_path, monkeypatch):
    """A toy format (raw uint16 after a 4-byte magic) registered once is read by recon."""
    from recon.frames import FrameReader, build_series, folder_frames

    shape = (5, 7)

    class Raw:
        def __init__(self, path, what):
            self.path = path

        def read(self, page, label):
            return np.frombuffer(self.path.read_bytes()[4:], "<u2").reshape(shape)

        def close(self):
            pass

    def probe(path, what="frame"):
        return registry.FrameHeader(1, shape, "uint16", 16, time_s=0.25)

    fmt = types.SimpleNamespace(
        NAME="raw16",
        SUFFIXES=(".raw16",),
        sniff=lambda head: head[:4] == b"RAW1",
        probe=probe,
        open_file=Raw,
    )
    monkeypatch.setattr(registry, "_EXTRA_FRAME", [])
    registry.register_frame_format(fmt)
    img = frames16(1, shape)[0]
    for k in (3, 1):
        (tmp_path / f"f_{k}.raw16").write_bytes(b"RAW1" + (img * k).astype("<u2").tobytes())
    files = folder_frames(tmp_path)
    assert [p.name for p in files] == ["f_1.raw16", "f_3.raw16"]
    refs = build_series(files)
    assert [(r.number, r.time_s) for r in refs] == [(1, 0.25), (3, 0.25)]
    with FrameReader() as reader:
        np.testing.assert_array_equal(reader.read(refs[1]), img * 3)
    with pytest.raises(InputError, match="must define"):
        registry.register_frame_format(types.SimpleNamespace(NAME="half", SUFFIXES=()))


def test_a_new_volume_format_is_one_registered_module(tmp_path, monkeypatch):
    """A toy volume format (a folder of .npy) registered once is scanned and read by track."""
    from hrvbase.formats import VolumeInfo
    from track.volumes import read_volume, scan_volumes

    vols = [RNG.random((2, 3, 4)).astype(np.float32) for _ in range(2)]
    for k, v in enumerate(vols):
        np.save(tmp_path / f"{k}.npy", v)

    def scan(folder):
        return [
            VolumeInfo(
                shape=(2, 3, 4),
                voxel_size_um=(2.0, 1.0, 1.0),
                origin_xyz_um=(0.0, 0.0, 0.0),
                path=folder / f"{k}.npy",
                index=k,
            )
            for k in range(2)
        ]

    fmt = types.SimpleNamespace(
        NAME="npy-folder",
        matches=lambda p: p.is_dir() and any(p.glob("*.npy")),
        scan=scan,
        read=lambda info: np.load(info.path),
    )
    monkeypatch.setattr(registry, "_EXTRA_VOLUME", [])
    registry.register_volume_format(fmt)
    infos = scan_volumes(tmp_path)
    assert [v.format for v in infos] == ["npy-folder", "npy-folder"]
    for info, v in zip(infos, vols, strict=True):
        np.testing.assert_array_equal(read_volume(info), v)


def test_one_geometry_type_and_one_tiff_layout():
    import lfsim.io
    import recon.volume_store
    import track.volumes
    from hrvbase.formats import VolumeGeometry, VolumeInfo, tiff_layout, volume_zarr

    assert recon.volume_store.VolumeGeometry is VolumeGeometry
    assert track.volumes.VolumeInfo is VolumeInfo and issubclass(VolumeInfo, VolumeGeometry)
    assert track.volumes.is_zarr is volume_zarr.is_zarr
    for name in ("METADATA_TAG", "SHAPE_TAG", "VOXEL_SIZE_KEY", "ORIGIN_KEY", "IMAGEJ_DTYPES"):
        assert getattr(lfsim.io, name) is getattr(tiff_layout, name)
    src = Path(track.volumes.__file__).read_text(encoding="utf-8")
    assert "65001" not in src and "65000" not in src


def test_tiff_volume_written_by_lfsim_is_read_by_the_registry(tmp_path):
    from hrvbase.formats import read_volume, scan_volumes
    from lfsim.io import write_tiff

    vol = RNG.random((3, 4, 5)).astype(np.float32)
    write_tiff(
        tmp_path / "000000.tif",
        vol,
        metadata={"number": 7, "time_s": 0.5},
        pixel_size_um=(4.0, 2.0, 2.0),
        origin_xyz_um=(1.0, 2.0, 3.0),
    )
    (info,) = scan_volumes(tmp_path)
    assert info.format == "tiff-folder" and info.shape == (3, 4, 5)
    assert info.voxel_size_um == (4.0, 2.0, 2.0) and info.origin_xyz_um == (1.0, 2.0, 3.0)
    assert (info.number, info.time_s, info.frame) == (7, 0.5, 7)
    np.testing.assert_array_equal(read_volume(info), vol)


# -- Phantom .cine ---------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["8-bit", "16-bit", "12-bit-in-16"])
def test_cine_pixels_come_back_exactly(tmp_path, kind):
    data = {"8-bit": frames8(), "16-bit": frames16(hi=65536), "12-bit-in-16": frames16()}[kind]
    bits = {"8-bit": None, "16-bit": None, "12-bit-in-16": 12}[kind]
    path = write_cine(tmp_path / "m.cine", data, bits=bits)
    h = cine.probe(path)
    assert (h.n_images, h.shape, h.dtype) == (3, (24, 40), str(data.dtype))
    assert h.bits == {"8-bit": 8, "16-bit": 16, "12-bit-in-16": 12}[kind]
    got = read_all(path, 3)
    assert got.dtype == data.dtype
    np.testing.assert_array_equal(got, data)


def test_cine_metadata_numbers_times_rate_exposure(tmp_path):
    times = [-0.0021, -0.0011, -0.0001, 0.0009]  # from the trigger, not quite periodic
    path = write_cine(
        tmp_path / "m.cine",
        frames16(4),
        fps=1000,
        exposure_s=250e-6,
        bits=12,
        first_image_no=-3,
        first_movie_image=-10,
        times_s=times,
    )
    h = cine.probe(path)
    # numbers: positions in the recording (first saved image -3, recording starts at -10)
    assert h.numbers == (7, 8, 9, 10)
    assert h.times_s == pytest.approx(times, abs=1e-9)  # TIME64: 2^-32 s ≈ 0.23 ns
    assert h.frame_interval_s == pytest.approx(1e-3, rel=1e-12)
    cam = h.camera
    assert cam["format"] == "cine" and cam["frame_rate_hz"] == 1000.0
    assert cam["exposure_s"] == pytest.approx(250e-6, abs=1e-9) and cam["bit_depth"] == 12
    assert cam["first_image_number"] == -3
    assert cam["trigger_time_utc"] == "2026-01-02T03:04:05+00:00"
    assert TRIGGER_SECONDS == 1_767_323_045


def test_cine_exposures_that_differ_are_listed(tmp_path):
    path = write_cine(tmp_path / "m.cine", frames8(), exposure_s=[100e-6, 200e-6, 300e-6])
    assert cine.probe(path).camera["exposure_s"] == pytest.approx([1e-4, 2e-4, 3e-4], abs=1e-9)


def test_bad_cine_files_are_one_line_errors_naming_the_file(tmp_path):
    good = write_cine(tmp_path / "good.cine", frames16())
    data = good.read_bytes()
    cut = tmp_path / "cut.cine"
    cut.write_bytes(data[:-100])  # the last image cut short
    one_line_error(cut, "truncated", "image 2")
    header_only = tmp_path / "header.cine"
    header_only.write_bytes(data[:120])
    one_line_error(header_only, "cannot read", ".cine")
    no_blocks = write_cine(tmp_path / "noblocks.cine", frames16(), time_block=False)
    one_line_error(no_blocks, "cannot read", "time and exposure blocks")
    packed = write_cine(tmp_path / "packed.cine", frames16(), packed12=True)
    one_line_error(packed, "packed 12-bit")
    colour = bytearray(data)
    colour[84 + 808 : 84 + 812] = (1).to_bytes(4, "little")  # SETUP.CFA
    (tmp_path / "colour.cine").write_bytes(bytes(colour))
    one_line_error(tmp_path / "colour.cine", "colour")
    junk = tmp_path / "junk.cine"
    junk.write_bytes(b"CX" + bytes(200))
    with pytest.raises(InputError) as exc:
        cine.probe(junk)
    assert "not a Phantom .cine file" in str(exc.value) and str(junk) in str(exc.value)
    with pytest.raises(InputError, match=r"only 3 image"):
        cine.open_file(good).read(3, "good.cine [page 3]")
    with pytest.raises(InputError, match="holds 3 images; expected one"):
        cine.open_file(good).read(None, "good.cine")
