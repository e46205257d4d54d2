"""`recon run --format zarr`: one OME-Zarr image (OME-NGFF 0.4 on Zarr format 2), read back
with napari-ome-zarr's reader, the ome-zarr reader and zarr-python, valid against the NGFF 0.4
models, resumed frame by frame (a store in Zarr format 3 continued in that format), refused
where TIFF output is, and tracked exactly like the TIFF series."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from recon.cli import main

from .test_pipeline import EXPERIMENT, FAST, ROOT

ARGS = [*FAST, "--iterations", "2", "--fps", "100"]


@pytest.fixture(scope="module")
def series(backend, tmp_path_factory):
    """The 3-frame test dataset reconstructed as TIFF files and as an OME-Zarr image (chunks of
    4 planes)."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment

    d = tmp_path_factory.mktemp("zarr")
    toml = d / "exp.toml"
    toml.write_text(EXPERIMENT.format(scene=(ROOT / "scenes" / "small.xml").as_posix()))
    dataset = d / "dataset"
    generate_dataset(load_experiment(toml), dataset, progress=False)
    tiff, store = d / "vol", d / "vol.zarr"
    assert main(["-q", "run", str(dataset), *ARGS, "-o", str(tiff)]) == 0
    argv = ["-q", "run", str(dataset), *ARGS, "--format", "zarr", "--zarr-chunk-z", "4"]
    assert main([*argv, "-o", str(store)]) == 0
    return dataset, tiff, store


def run(capsys, *args):
    rc = main([*map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def chunk_files(store: Path) -> dict[str, tuple[bytes, int]]:
    """Bytes and modification time of every chunk file (``0/t/z/y/x``), by key."""
    return {
        p.relative_to(store).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted((store / "0").rglob("*"))
        if p.is_file() and not p.name.startswith(".")
    }


def test_ome_zarr_reader_sees_shape_chunks_voxel_sizes_and_units(series):
    import zarr
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Multiscales, Reader

    from lfsim.io import read_tiff
    from recon.volume_store import NGFF_VERSION

    _, tiff, store = series
    meta = json.loads((store / "recon.json").read_text())
    assert meta["format"] == "zarr" and meta["status"] == "complete"
    nz, ny, nx = meta["volume_shape"]
    nodes = list(Reader(parse_url(str(store)))())
    node = nodes[0]
    assert node.load(Multiscales) is not None
    data = node.data[0]
    assert data.shape == (3, nz, ny, nx) and data.dtype == np.float32
    assert data.chunks[0] == (1, 1, 1) and data.chunks[2:] == ((ny,), (nx,))
    assert set(data.chunks[1][:-1]) == {4} and sum(data.chunks[1]) == nz
    assert zarr.open_array(str(store / "0"), mode="r").chunks == (1, 4, ny, nx)
    axes = node.metadata["axes"]
    assert [a["name"] for a in axes] == ["t", "z", "y", "x"]
    assert [a.get("unit") for a in axes] == ["second", *["micrometer"] * 3]
    assert [a["type"] for a in axes] == ["time", "space", "space", "space"]
    (scale, translation) = node.metadata["coordinateTransformations"][0]
    assert scale["type"] == "scale" and translation["type"] == "translation"
    assert scale["scale"] == pytest.approx([0.01, 20.0, 25 / 3, 25 / 3])  # 1/fps, dz, dy, dx
    # OME-NGFF 0.4 on Zarr format 2 (what Fiji's n5-zarr, MoBIE and BDV open): no Zarr v3
    # metadata anywhere, Blosc-LZ4 chunks, frame k's chunks in the folder 0/k.
    assert NGFF_VERSION == "0.4" and not list(store.rglob("zarr.json"))
    assert json.loads((store / ".zgroup").read_text()) == {"zarr_format": 2}
    zarray = json.loads((store / "0" / ".zarray").read_text())
    assert zarray["zarr_format"] == 2 and zarray["dimension_separator"] == "/"
    assert zarray["dtype"] == "<f4" and zarray["fill_value"] == "NaN"
    assert zarray["compressor"]["id"] == "blosc" and zarray["compressor"]["cname"] == "lz4"
    assert meta["zarr"]["ngff_version"] == "0.4"
    assert json.loads((store / ".zattrs").read_text())["multiscales"][0]["version"] == "0.4"
    assert {p.name for p in (store / "0").iterdir() if p.is_dir()} == {"0", "1", "2"}
    assert {p.name for p in (store / "0" / "1").iterdir()} == {str(i) for i in range(-(-nz // 4))}
    # The voxels are the TIFF series', placed at the same origin (centre of voxel 0).
    for k in range(3):
        vol, vmeta = read_tiff(tiff / f"{k:06d}.tif")
        np.testing.assert_allclose(
            np.asarray(data[k]), vol, rtol=1e-5, atol=1e-6 * float(np.abs(vol).max())
        )
        x0, y0, z0 = vmeta["origin_xyz_um"]
        assert translation["translation"] == pytest.approx([0.0, z0, y0, x0])
    # recon.json's checksum of each frame is that of its float32 values in C order.
    from hrvbase.io import array_sha256

    assert [f["output"]["sha256"] for f in meta["frames"]] == [
        array_sha256(np.asarray(data[k])) for k in range(3)
    ]


@pytest.mark.filterwarnings("ignore:`json_encoders` is deprecated:DeprecationWarning")
def test_napari_ome_zarr_reads_data_scale_axes_and_units(series):
    """napari-ome-zarr's reader (the function napari calls, without a viewer) gives one image
    layer: the voxels, the scale (1/fps s, dz, dy, dx µm), the axis names and units."""
    from napari_ome_zarr._reader import napari_get_reader

    from lfsim.io import read_tiff

    _, tiff, store = series
    reader = napari_get_reader(str(store))
    assert reader is not None
    ((data, kwargs, kind),) = reader(str(store))
    assert kind == "image" and len(data) == 1  # one resolution level
    vols = [read_tiff(tiff / f"{k:06d}.tif")[0] for k in range(3)]
    assert data[0].shape == (3, *vols[0].shape) and data[0].dtype == np.float32
    for k, vol in enumerate(vols):
        np.testing.assert_allclose(
            np.asarray(data[0][k]), vol, rtol=1e-5, atol=1e-6 * float(np.abs(vol).max())
        )
    assert kwargs["scale"] == pytest.approx([0.01, 20.0, 25 / 3, 25 / 3])
    assert kwargs["axis_labels"] == ("t", "z", "y", "x")
    assert kwargs["units"] == ("second", "micrometer", "micrometer", "micrometer")


def test_zarr_python_reads_it_as_zarr_format_2(series):
    import zarr

    from recon.volume_store import make_writer

    _, _, store = series
    group = zarr.open_group(str(store), mode="r", zarr_format=2)
    arr = group["0"]
    assert arr.metadata.zarr_format == 2 and arr.metadata.dimension_separator == "/"
    assert arr.chunks == (1, 4, *arr.shape[2:]) and np.isnan(arr.fill_value)
    writer = make_writer("zarr", store, zarr_chunk_z=4)
    for k in range(3):
        np.testing.assert_array_equal(arr[k], writer.read(k))
        assert np.isfinite(arr[k]).all()
    assert [f["t"] for f in group.attrs["recon"]["frames"]] == [0, 1, 2]
    assert group.attrs["multiscales"][0]["datasets"][0]["path"] == "0"


def test_metadata_is_valid_ngff_0_4(series, tmp_path):
    """The store validates against the OME-NGFF 0.4 models (ome-zarr-models); the same models
    refuse a store whose translation comes before its scale."""
    import zarr
    from ome_zarr_models.v04 import Image
    from pydantic import ValidationError

    _, _, store = series
    image = Image.from_zarr(zarr.open_group(str(store), mode="r"))
    (ms,) = image.attributes.multiscales
    assert [a.name for a in ms.axes] == ["t", "z", "y", "x"]
    assert [a.unit for a in ms.axes] == ["second", *["micrometer"] * 3]
    ((dataset,),) = image.datasets
    assert [tr.type for tr in dataset.coordinateTransformations] == ["scale", "translation"]
    bad = tmp_path / "bad.zarr"
    shutil.copytree(store, bad)
    zattrs = json.loads((bad / ".zattrs").read_text())
    zattrs["multiscales"][0]["datasets"][0]["coordinateTransformations"].reverse()
    (bad / ".zattrs").write_text(json.dumps(zattrs))
    with pytest.raises(ValidationError, match="scale"):
        Image.from_zarr(zarr.open_group(str(bad), mode="r"))


def test_resume_continues_a_zarr_format_3_store_in_its_format(series, tmp_path, capsys):
    """A store in OME-NGFF 0.5 (Zarr format 3) missing a frame: the resumed run writes that
    frame in format 3 (chunks under 0/c/k), keeps the others and adds no format 2 metadata;
    every reader reads it as before."""
    import zarr
    from ome_zarr_models.v05 import Image

    from track.volumes import read_volume, scan_volumes

    from .zarr_v3 import as_ngff05

    dataset, _, original = series
    store = as_ngff05(original, tmp_path / "old.zarr", drop=(2,))
    kept = {
        p.relative_to(store).as_posix(): p.stat().st_mtime_ns
        for p in (store / "0" / "c").rglob("*")
        if p.is_file()
    }
    assert {k.split("/")[2] for k in kept} == {"0", "1"}
    args = ["run", dataset, *ARGS, "--format", "zarr", "--zarr-chunk-z", "4", "-o", store]
    rc, out, err = run(capsys, *args)
    assert rc == 0, err
    assert "1 volume(s) reconstructed, 2 already done" in out
    assert not [p for p in store.rglob(".z*")]  # no Zarr format 2 metadata
    assert json.loads((store / "zarr.json").read_text())["zarr_format"] == 3
    assert json.loads((store / "recon.json").read_text())["zarr"]["ngff_version"] == "0.5"
    now = {
        p.relative_to(store).as_posix(): p.stat().st_mtime_ns
        for p in (store / "0" / "c").rglob("*")
        if p.is_file()
    }
    assert {k.split("/")[2] for k in now} == {"0", "1", "2"}
    assert {k: now[k] for k in kept} == kept  # frames 0 and 1 untouched
    Image.from_zarr(zarr.open_group(str(store), mode="r"))  # valid NGFF 0.5
    a, b = scan_volumes(original), scan_volumes(store)
    assert [v.origin_xyz_um for v in b] == [v.origin_xyz_um for v in a]
    assert [v.voxel_size_um for v in b] == [v.voxel_size_um for v in a]
    assert [v.time_s for v in b] == [0.0, 0.01, 0.02]
    for va, vb in zip(a, b, strict=True):
        np.testing.assert_array_equal(read_volume(vb), read_volume(va))


def test_a_zarr_format_3_store_resized_in_its_format_or_replaced_in_format_2(tmp_path):
    """The writer on a store in Zarr format 3: more frames resize its array in format 3;
    another chunking is refused (nothing touched) or, with overwrite, the whole image is
    written anew in OME-NGFF 0.4 (no format 3 file left)."""
    import zarr

    from recon.volume_store import OutputExistsError, VolumeGeometry, make_writer

    from .zarr_v3 import as_ngff05

    geometry = VolumeGeometry((5, 4, 3), (2.0, 1.0, 1.0), (-3.0, 2.0, 7.0))
    vols = np.random.default_rng(2).normal(size=(3, 5, 4, 3)).astype(np.float32)
    v2 = make_writer("zarr", tmp_path / "v2.zarr", zarr_chunk_z=2)
    v2.prepare(2, geometry, [0.0, 0.5])
    records = [v2.write(k, vols[k], {}) for k in range(2)]
    store = as_ngff05(v2.out, tmp_path / "v3.zarr")
    writer = make_writer("zarr", store, zarr_chunk_z=2)
    assert writer.zarr_format() == 3 and writer.indices() == [0, 1]
    assert writer.record_extra()["zarr"]["ngff_version"] == "0.5"
    assert all(writer.verify(k, r) for k, r in enumerate(records))
    writer.prepare(3, geometry, [0.0, 0.5, 1.0])
    writer.write(2, vols[2], {})
    assert (store / "0" / "c" / "2").is_dir() and not list(store.rglob(".z*"))
    arr = zarr.open_array(str(store), path="0", mode="r", zarr_format=3)
    assert arr.shape == (3, 5, 4, 3) and arr.metadata.dimension_names == ("t", "z", "y", "x")
    np.testing.assert_array_equal(arr[:], vols)
    ome = json.loads((store / "zarr.json").read_text())["attributes"]["ome"]
    assert ome["version"] == "0.5"
    assert ome["multiscales"][0]["datasets"][0]["coordinateTransformations"][0]["scale"] == [
        0.5, 2.0, 1.0, 1.0
    ]  # fmt: skip
    # Another chunking: refused, then replaced by an NGFF 0.4 image.
    other = make_writer("zarr", store, zarr_chunk_z=5)
    before = sorted(p.as_posix() for p in store.rglob("*"))
    with pytest.raises(OutputExistsError, match="chunking"):
        other.prepare(3, geometry, [0.0, 0.5, 1.0])
    assert sorted(p.as_posix() for p in store.rglob("*")) == before
    other.prepare(3, geometry, [0.0, 0.5, 1.0], overwrite=True)
    assert not list(store.rglob("zarr.json")) and other.zarr_format() == 2
    assert other.indices() == [] and other.record_extra()["zarr"]["ngff_version"] == "0.4"
    assert np.isnan(other.read(1)).all()  # a frame not written yet reads as NaN
    for k in range(3):
        other.write(k, vols[k], {})
    assert other.indices() == [0, 1, 2] and (store / "0" / "2" / "0" / "0" / "0").is_file()
    assert not (store / "0" / "c").exists()
    np.testing.assert_array_equal(
        zarr.open_array(str(store), path="0", mode="r", zarr_format=2)[:], vols
    )


def test_track_on_zarr_equals_track_on_tiff(series, tmp_path, capsys):
    from track.cli import main as track
    from track.tables import read_points_csv, read_tracks_csv
    from track.volumes import scan_volumes

    _, tiff, store = series
    a, b = scan_volumes(tiff), scan_volumes(store)
    assert [v.shape for v in a] == [v.shape for v in b]
    assert [v.voxel_size_um for v in a] == [v.voxel_size_um for v in b]
    for va, vb in zip(a, b, strict=True):
        assert vb.origin_xyz_um == pytest.approx(va.origin_xyz_um, abs=1e-9)
    outs = []
    for src in (tiff, store):
        out = tmp_path / src.name
        argv = ["run", src, "-o", out, "--no-progress"]
        assert track([str(v) for v in argv]) == 0, capsys.readouterr().err
        outs.append(out)
    ta, tb = (read_tracks_csv(o / "tracks.csv") for o in outs)
    assert len(ta["track_id"]) >= 12  # 5-6 particles in each of 3 frames
    for key in ta:
        np.testing.assert_allclose(tb[key], ta[key], rtol=1e-9, atol=1e-9)
    for k in range(3):
        pa, pb = (read_points_csv(o / "particles" / f"{k:06d}.csv") for o in outs)
        assert pa.shape[0] >= 4
        np.testing.assert_allclose(pb, pa, rtol=1e-9, atol=1e-9)
    s = json.loads((outs[1] / "summary.json").read_text())
    assert [f["input"] for f in s["frames"]] == [f"{store}[t={k}]" for k in range(3)]


def test_resume_redoes_exactly_the_damaged_frame(series, tmp_path, capsys):
    dataset, _, original = series
    store = tmp_path / "vol.zarr"
    shutil.copytree(original, store)
    args = ["run", dataset, *ARGS, "--format", "zarr", "--zarr-chunk-z", "4", "-o", store]
    before = chunk_files(store)
    # A truncated chunk of frame 1: that frame, and only it, is reconstructed again.
    damaged = store / "0" / "1" / "2" / "0" / "0"
    damaged.write_bytes(damaged.read_bytes()[:10])
    rc, out, err = run(capsys, *args)
    assert rc == 0, err
    assert "1 volume(s) reconstructed, 2 already done" in out
    assert "vol.zarr[t=1] changed on disk" in err
    after = chunk_files(store)
    assert {k: v[0] for k, v in after.items()} == {k: v[0] for k, v in before.items()}
    rewritten = {k.split("/")[1] for k in after if after[k][1] != before[k][1]}
    assert rewritten == {"1"}
    # A frame whose chunks are gone (an interrupted run): redone, the others kept.
    shutil.rmtree(store / "0" / "2")
    rc, out, err = run(capsys, *args)
    assert rc == 0 and "1 volume(s) reconstructed, 2 already done" in out
    again = chunk_files(store)
    assert {k: v[0] for k, v in again.items()} == {k: v[0] for k, v in before.items()}
    assert {k.split("/")[1] for k in again if again[k][1] != after[k][1]} == {"2"}


def test_refusals_and_bad_options(series, tmp_path, capsys):
    import zarr

    dataset, tiff, original = series
    store = tmp_path / "vol.zarr"
    shutil.copytree(original, store)
    before = chunk_files(store)
    zarr_args = ["--format", "zarr", "--zarr-chunk-z", "4"]
    # Other settings: refused, nothing touched; --overwrite replaces the store.
    other = ["run", dataset, *FAST, "--iterations", "1", *zarr_args, "-o", store]
    rc, _, err = run(capsys, "-q", *other)
    assert rc == 2 and "other inputs or settings" in err and err.count("\n") == 1
    assert chunk_files(store) == before
    # Another chunking of the same volumes: refused likewise.
    rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, "--format", "zarr", "-o", store)
    assert rc == 2 and "chunking" in err and str(store) in err and err.count("\n") == 1
    assert chunk_files(store) == before
    rc, _, err = run(capsys, "-q", *other, "--overwrite")
    assert rc == 0, err
    assert json.loads((store / "recon.json").read_text())["settings"]["iterations"] == 1
    # A Zarr store recon did not write: refused, even with --overwrite.
    foreign = tmp_path / "foreign.zarr"
    zarr.open_group(str(foreign), mode="w").attrs["mine"] = 1
    for extra in ([], ["--overwrite"]):
        rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, *zarr_args, "-o", foreign, *extra)
        assert rc == 2 and "not empty" in err and str(foreign) in err
    assert zarr.open_group(str(foreign), mode="r").attrs["mine"] == 1
    # One format over the other: refused.
    rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, *zarr_args, "-o", tiff)
    assert rc == 2 and "tiff volumes" in err and err.count("\n") == 1
    unnamed = tmp_path / "store"  # not named .zarr: TIFF volumes by default
    shutil.copytree(original, unnamed)
    rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, "-o", unnamed)
    assert rc == 2 and "zarr volumes" in err and err.count("\n") == 1
    # Bad options: one line naming the option.
    for bad, text in (
        (["--format", "foo"], "--format"),
        (["--zarr-chunk-z", "2"], "--zarr-chunk-z applies only to --format zarr"),
        (["--format", "zarr", "--zarr-chunk-z", "0"], "--zarr-chunk-z"),
    ):
        rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, *bad, "-o", tmp_path / "x")
        assert rc == 2 and text in err and "Traceback" not in err, err
        assert err.strip().count("\n") <= 1  # argparse: usage line + error line
    assert not (tmp_path / "x").exists()


def test_frames_written_concurrently_by_other_processes(tmp_path):
    """Writers pickle; frames written at once by worker processes land in their own chunks."""
    import multiprocessing
    import pickle
    from concurrent.futures import ProcessPoolExecutor

    from recon.volume_store import VolumeGeometry, make_writer

    rng = np.random.default_rng(5)
    vols = rng.normal(size=(6, 5, 4, 3)).astype(np.float32)
    writer = make_writer("zarr", tmp_path / "p.zarr", zarr_chunk_z=2)
    writer.prepare(6, VolumeGeometry((5, 4, 3), (2.0, 1.0, 1.0), (0.0, 0.0, 0.0)))
    assert pickle.loads(pickle.dumps(writer)) == writer
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=ctx) as pool:
        records = list(pool.map(writer.write, range(6), vols, [{}] * 6))
    assert writer.indices() == list(range(6))
    assert all(writer.verify(k, r) for k, r in enumerate(records))
    np.testing.assert_array_equal(np.stack([writer.read(k) for k in range(6)]), vols)
    # A frame's record does not fit another frame.
    assert not writer.verify(1, records[0]) and not writer.verify(1, {**records[1], "t": 0})


def test_resume_with_another_frame_rate(series, tmp_path, capsys):
    """The t axis and recon.json give the same times after a resume: another --fps is refused
    (nothing touched), with --overwrite every frame is written again with the new times."""
    dataset, _, original = series
    store = tmp_path / "vol.zarr"
    shutil.copytree(original, store)
    before = chunk_files(store)
    zattrs = (store / ".zattrs").read_bytes()
    args = ["run", dataset, *FAST, "--iterations", "2", "--format", "zarr", "--zarr-chunk-z", "4"]
    rc, _, err = run(capsys, "-q", *args, "--fps", "50", "-o", store)
    assert rc == 2 and err.count("\n") == 1, err
    assert "vol.zarr[t=1]" in err and "time 0.01 s, this run 0.02 s (--fps 100 then, 50 now)" in err
    assert chunk_files(store) == before and (store / ".zattrs").read_bytes() == zattrs
    rc, _, err = run(capsys, "-q", *args, "--fps", "50", "--overwrite", "-o", store)
    assert rc == 0, err
    meta = json.loads((store / "recon.json").read_text())
    assert [f["time_s"] for f in meta["frames"]] == [0.0, 0.02, 0.04] and meta["fps"] == 50
    ome = json.loads((store / ".zattrs").read_text())
    scale, translation = ome["multiscales"][0]["datasets"][0]["coordinateTransformations"]
    assert scale["scale"][0] == pytest.approx(0.02) and translation["translation"][0] == 0.0
    assert {k: v[0] for k, v in chunk_files(store).items()} == {k: v[0] for k, v in before.items()}


@pytest.mark.parametrize("fmt", ["zarr", "tiff"])
def test_a_failed_volume_write_names_the_output(tmp_path, fmt):
    """A write that hits the file-size limit (EFBIG) says which output and frame failed, not
    only "[Errno 27] File too large"."""
    import resource
    import signal

    from hrvbase.errors import HrvError
    from recon.volume_store import VolumeGeometry, make_writer

    out = tmp_path / f"v.{fmt}"
    writer = make_writer(fmt, out)
    writer.prepare(2, VolumeGeometry((4, 64, 64), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0)), [0.0, 0.1])
    volume = np.random.default_rng(0).random((4, 64, 64), dtype=np.float32)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (10_000, hard))
    try:
        with pytest.raises(OSError) as info:
            writer.write(1, volume, {"frame": 1})
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, handler)
    assert isinstance(info.value, HrvError), repr(info.value)
    message = str(info.value)
    assert str(out) in message and "cannot write" in message, message
    if fmt == "zarr":
        assert "frame t=1" in message and "File too large" in message, message


def test_output_named_zarr_is_written_as_ome_zarr(series, tmp_path, capsys):
    """-o NAME.zarr without --format writes the OME-Zarr image (not TIFF files into a folder
    named .zarr); --format tiff with such a name is refused."""
    dataset, _, _ = series
    store = tmp_path / "out.zarr"
    rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, "--zarr-chunk-z", "4", "-o", store)
    assert rc == 0, err
    assert json.loads((store / "recon.json").read_text())["format"] == "zarr"
    assert (store / ".zgroup").is_file() and not list(store.glob("*.tif"))
    other = tmp_path / "other.zarr"
    rc, _, err = run(capsys, "-q", "run", dataset, *ARGS, "--format", "tiff", "-o", other)
    assert rc == 2 and err.count("\n") == 1, err
    assert str(other) in err and "--format tiff" in err
    assert not other.exists()
