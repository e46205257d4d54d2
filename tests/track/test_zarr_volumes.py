"""OME-Zarr images as volume series (track.volumes.scan_zarr): frames, voxel size and origin
from the NGFF metadata, and one-line errors for what is not such an image."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hrvbase.io import array_sha256
from track.errors import InputError
from track.volumes import read_volume, scan_volumes, volume_checksum


def write_ngff(path, data, axes, scale, translation=None, units=None, **kw):
    """An OME-NGFF 0.5 image of one dataset ``0`` (ome-zarr's metadata writer)."""
    import zarr
    from ome_zarr.writer import write_multiscales_metadata

    group = zarr.open_group(str(path), mode="w", zarr_format=3)
    group.create_array("0", data=np.asarray(data), chunks=(1,) * (data.ndim - 2) + data.shape[-2:])
    transforms = [{"type": "scale", "scale": list(scale)}]
    if translation is not None:
        transforms.append({"type": "translation", "translation": list(translation)})
    units = units or {}
    spec = [
        {"name": a, "type": {"t": "time", "c": "channel"}.get(a, "space")}
        | ({"unit": units.get(a, "micrometer")} if a in "zyx" and units.get(a, 1) else {})
        for a in axes
    ]
    write_multiscales_metadata(
        group, [{"path": "0", "coordinateTransformations": transforms}], axes=spec, **kw
    )
    return path


def test_zyx_image_in_nanometres_is_one_volume(tmp_path):
    rng = np.random.default_rng(3)
    data = rng.normal(size=(4, 5, 6)).astype(np.float32)
    units = {a: "nanometer" for a in "zyx"}
    store = write_ngff(
        tmp_path / "a.zarr", data, "zyx", (2000, 500, 250), (-1000, 100, 3000), units
    )
    (v,) = scan_volumes(store)
    assert v.index == 0 and v.shape == (4, 5, 6) and v.lead == ()
    assert v.voxel_size_um == pytest.approx((2.0, 0.5, 0.25))
    assert v.origin_xyz_um == pytest.approx((3.0, 0.1, -1.0))  # (x, y, z) µm
    np.testing.assert_array_equal(read_volume(v), data)
    assert volume_checksum(v) == array_sha256(data)
    assert v.name == "a.zarr[t=0]"


def test_tczyx_image_with_one_channel_gives_its_frames(tmp_path):
    data = np.arange(3 * 1 * 2 * 3 * 4, dtype=np.uint16).reshape(3, 1, 2, 3, 4)
    store = write_ngff(tmp_path / "b.zarr", data, "tczyx", (0.1, 1, 5, 2, 2))
    vols = scan_volumes(store)
    assert [v.index for v in vols] == [0, 1, 2] and vols[2].lead == (2, 0)
    assert vols[0].voxel_size_um == pytest.approx((5.0, 2.0, 2.0))
    assert vols[0].origin_xyz_um == (0.0, 0.0, 0.0)
    out = read_volume(vols[2])
    assert out.dtype == np.float32 and np.array_equal(out, data[2, 0])


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p.mkdir() or p, "is not an OME-NGFF image"),
        (
            lambda p: write_ngff(p, np.zeros((2, 2, 3, 3)), "czyx", (1, 1, 1, 1)),
            "2 channels; expected one",
        ),
        (
            lambda p: write_ngff(p, np.zeros((2, 3, 3)), "tyx", (1, 1, 1)),
            "expected the axes (t, z, y, x) or (z, y, x)",
        ),
        (
            lambda p: write_ngff(p, np.zeros((2, 3, 3)), "zyx", (1, 1, 1), units={"z": None}),
            "axis 'z' has unit None; expected a length",
        ),
        (
            lambda p: write_ngff(p, np.zeros((2, 3, 3)), "zyx", (1, 0, 1)),
            "must be positive",
        ),
    ],
)
def test_bad_images_are_refused_in_one_line(tmp_path, make, message):
    store = make(tmp_path / "bad.zarr")
    with pytest.raises(InputError) as err:
        scan_volumes(store)
    assert message in str(err.value) and str(store) in str(err.value)
    assert "\n" not in str(err.value)


def test_frames_recon_has_not_written_are_missing(tmp_path):
    data = np.ones((3, 2, 3, 3), np.float32)
    store = write_ngff(tmp_path / "c.zarr", data, "tzyx", (1, 1, 1, 1))
    frames = [{"index": k, "output": {"t": k, "sha256": "0"} if k != 1 else None} for k in range(3)]
    (store / "recon.json").write_text(json.dumps({"format": "zarr", "frames": frames}))
    with pytest.raises(InputError, match=r"frame\(s\) t = 1 not written yet"):
        scan_volumes(store)


def test_recon_json_in_the_store_gives_the_lenslet_period(tmp_path):
    data = np.ones((2, 3, 10, 10), np.float32)
    # voxel (0, 0, 0) at x = -13, y = 7 µm: 3 and 1 voxels past the corner of lenslet (0, 0)
    store = write_ngff(tmp_path / "d.zarr", data, "tzyx", (1, 5, 2, 2), (0, 100, 7.0, -13.0))
    grid = {"s": 5, "lenslet_object_um": 10.0, "origin_um": [-20.0, 4.0]}
    frames = [{"index": k, "output": {"t": k}} for k in range(2)]
    (store / "recon.json").write_text(json.dumps({"grid": grid, "frames": frames}))
    vols = scan_volumes(store)
    assert [(v.lenslet_period_vox, v.lenslet_phase_vox) for v in vols] == [(5, (1, 3))] * 2


def test_track_cli_names_a_store_that_is_not_an_image(tmp_path, capsys):
    from track.cli import main

    store = tmp_path / "empty.zarr"
    store.mkdir()
    rc = main(["run", str(store), "-o", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("track: error: ") and str(store) in err
    assert err.strip().count("\n") == 0 and not (tmp_path / "out").exists()


def test_ngff_04_image_reads_quietly(tmp_path, capfd):
    """An OME-NGFF 0.4 image (Zarr format 2, older writers) is read like a 0.5 one."""
    import zarr
    from ome_zarr.format import FormatV04
    from ome_zarr.writer import write_image

    data = np.random.default_rng(0).normal(size=(2, 3, 8, 8)).astype(np.float32)
    group = zarr.open_group(str(tmp_path / "old.zarr"), mode="w", zarr_format=2)
    write_image(
        data,
        group,
        axes="tzyx",
        fmt=FormatV04(),
        scale={"t": 1.0, "z": 2.0, "y": 0.5, "x": 0.5},
        axes_units={a: "micrometer" for a in "zyx"},
        scale_factors=[],
    )
    capfd.readouterr()
    vols = scan_volumes(tmp_path / "old.zarr")
    assert len(vols) == 2 and vols[1].voxel_size_um == pytest.approx((2.0, 0.5, 0.5))
    np.testing.assert_array_equal(read_volume(vols[1]), data[1])
    assert capfd.readouterr().err == ""


def test_a_t_axis_in_milliseconds_gives_the_frame_times(tmp_path):
    data = np.ones((3, 2, 3, 3), np.float32)
    store = write_ngff(tmp_path / "t.zarr", data, "tzyx", (20, 1, 1, 1), (100, 0, 0, 0))
    meta = json.loads((store / "zarr.json").read_text())
    meta["attributes"]["ome"]["multiscales"][0]["axes"][0]["unit"] = "millisecond"
    (store / "zarr.json").write_text(json.dumps(meta))
    vols = scan_volumes(store)
    assert [(v.frame, v.time_s) for v in vols] == [(0, 0.1), (1, 0.12), (2, 0.14)]
    frames = [{"index": k, "number": 3 * k, "time_s": k, "output": {"t": k}} for k in range(3)]
    (store / "recon.json").write_text(json.dumps({"frames": frames}))  # recon's record first
    assert [(v.frame, v.time_s) for v in scan_volumes(store)] == [(0, 0.0), (3, 1.0), (6, 2.0)]
