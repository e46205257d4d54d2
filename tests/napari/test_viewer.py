"""The plugin in a real napari viewer under Xvfb: discovery, ``viewer.open`` of a study, the
placement of every layer, a screenshot against the truth, the run widget, and the OME-Zarr
round trip (OME-NGFF 0.4, and 0.5 on Zarr format 3) through the plugin and napari-ome-zarr."""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest

from .conftest import N_FRAMES, ORIGIN_XYZ_UM, PARTICLES_KJI, SHAPE, VOXEL_UM, truth_xyz

STRAIN = [f"E_{c}" for c in ("xx", "yy", "zz", "xy", "xz", "yz")]

#: npe2's manifest models use pydantic-1 idioms that pydantic 2 warns about.
pytestmark = [
    pytest.mark.filterwarnings("ignore::DeprecationWarning:npe2.*"),
    pytest.mark.filterwarnings("ignore:`json_encoders` is deprecated:DeprecationWarning"),
]


def test_the_plugin_is_discovered_and_its_manifest_valid(study_report):
    from npe2 import PluginManager, PluginManifest

    manifest = PluginManifest.from_distribution("hrvptm")  # validated on load
    assert manifest.name == "hrvptm"
    assert {c.id for c in manifest.contributions.commands} == {"hrvptm.read", "hrvptm.run_widget"}
    pm = PluginManager.instance()
    pm.discover()
    assert "hrvptm" in {m.name for m in pm.iter_manifests()}
    readers = [r.command for r in pm.iter_compatible_readers([str(study_report)])]
    assert "hrvptm.read" in readers
    tracks_csv = study_report / "mismatched" / "track" / "tracks.csv"
    assert "hrvptm.read" in [r.command for r in pm.iter_compatible_readers([str(tracks_csv)])]


def test_viewer_opens_a_study_with_every_layer_in_place(study_in_viewer):
    viewer, layers = study_in_viewer
    kinds = {layer.name: type(layer).__name__ for layer in layers}
    assert kinds == {
        "volumes": "Image", "particles": "Points", "tracks": "Tracks", "displacement": "Vectors",
        "displacement field": "Vectors", "truth": "Points", **dict.fromkeys(STRAIN, "Image"),
    }  # fmt: skip
    vol = viewer.layers["volumes"]
    x0, y0, z0 = ORIGIN_XYZ_UM
    assert vol.data.shape == (N_FRAMES, *SHAPE)
    assert np.allclose(vol.scale, (1, *VOXEL_UM)) and np.allclose(vol.translate, (0, z0, y0, x0))
    for t in range(N_FRAMES):  # the centre of the voxel each true particle sits on
        for (k, j, i), xyz in zip(PARTICLES_KJI, truth_xyz(t), strict=True):
            world = vol.data_to_world((t, k, j, i + t))  # one voxel along x per frame
            assert np.allclose(world, (t, *xyz[::-1]), atol=1e-9)
    assert viewer.layers["tracks"].data.shape == (N_FRAMES * len(PARTICLES_KJI), 5)
    assert viewer.layers["truth"].data.shape == (N_FRAMES * len(PARTICLES_KJI), 4)
    assert viewer.dims.ndim == 4 and viewer.dims.range[0].stop == N_FRAMES - 1


def test_screenshot_shows_the_particles_where_the_truth_is(study_in_viewer):
    viewer, _ = study_in_viewer
    for layer in viewer.layers:
        layer.visible = layer.name == "volumes"
    plane = [n for n, (k, _, _) in enumerate(PARTICLES_KJI) if k == PARTICLES_KJI[0][0]]
    truth = truth_xyz(0)
    viewer.dims.set_point(0, 0)
    viewer.dims.set_point(1, truth[plane[0], 2])  # the z plane of four of the particles
    viewer.reset_view()
    img = viewer.screenshot(canvas_only=True, flash=False)[..., :3].astype(float).mean(axis=2)
    h, w = img.shape
    camera = viewer.scene.camera if hasattr(viewer, "scene") else viewer.camera  # napari ≥ 0.9
    cy, cx = camera.center[-2:]
    zoom = camera.zoom  # screen pixels per µm
    assert img.std() > 5 and np.median(img) < 20  # not blank: dark background, bright spots
    r = int(2 * VOXEL_UM[2] * zoom)  # two voxels
    for n, (x, y, _) in enumerate(truth):
        row, col = (y - cy) * zoom + h / 2, (x - cx) * zoom + w / 2
        rr, cc = round(row), round(col)
        win = img[rr - r : rr + r + 1, cc - r : cc + r + 1]
        if n in plane:
            assert win.max() > 200, f"particle {n} not shown near ({row:.0f}, {col:.0f})"
            yy, xx = np.indices(win.shape)
            wgt = np.where(win > win.max() / 2, win, 0)
            centroid = (
                np.sum(yy * wgt) / wgt.sum() + rr - r,
                np.sum(xx * wgt) / wgt.sum() + cc - r,
            )
            assert np.hypot(centroid[0] - row, centroid[1] - col) < 0.25 * VOXEL_UM[2] * zoom
        else:  # in another z plane: not shown in this one
            assert win.max() < 60, f"particle {n} of another plane shown"


def test_run_widget_tracks_a_folder_and_opens_the_results(viewer, study_report, tmp_path):
    from qtpy.QtWidgets import QApplication

    from hrvptm_napari.widget import RunWidget

    dock, widget = viewer.window.add_plugin_dock_widget("hrvptm", "Run recon / track")
    assert isinstance(widget, RunWidget) and widget.viewer is not None  # napari hands it over
    widget.task.value = "track run"
    widget.source.value = study_report / "mismatched" / "volumes"
    widget.output.value = tmp_path / "res"
    worker = widget.start()
    assert worker is not None
    t0 = time.monotonic()
    while widget.result is None and widget.error is None and time.monotonic() - t0 < 120:
        QApplication.processEvents()
        time.sleep(0.02)
    assert widget.error is None, widget.status.value
    assert widget.result.status == "complete"
    assert widget.progress.value == widget.progress.max == N_FRAMES
    assert {"particles", "tracks", "displacement"} <= {layer.name for layer in viewer.layers}
    assert json.loads((tmp_path / "res" / "summary.json").read_text())["command"] == "run"
    # recon run on a folder without frames: refused, said in the status line, nothing written
    widget.task.value = "recon run"
    widget.source.value = tmp_path / "res" / "fields"
    widget.output.value = tmp_path / "vol"
    assert widget.start() is None
    assert widget.status.value.startswith("recon run failed: ") and not (tmp_path / "vol").exists()
    viewer.window.remove_dock_widget(dock)


def _zarr_copy(study_report, tmp_path, ngff: str = "0.4"):
    """The study's volumes written as OME-Zarr by ``recon run``'s writer (OME-NGFF 0.4), or
    that image as OME-NGFF 0.5 on Zarr format 3 (``ngff="0.5"``)."""
    from hrvbase.formats.geometry import VolumeGeometry
    from recon.volume_store import make_writer
    from track.volumes import read_volume, scan_volumes

    vols = scan_volumes(study_report / "mismatched" / "volumes")
    out = tmp_path / "volumes.zarr"
    writer = make_writer("zarr", out)
    v = vols[0]
    writer.prepare(len(vols), VolumeGeometry(v.shape, v.voxel_size_um, v.origin_xyz_um))
    for k, info in enumerate(vols):
        writer.write(k, read_volume(info), {})
    if ngff == "0.5":
        from ..recon.zarr_v3 import as_ngff05

        return as_ngff05(out, tmp_path / "volumes_v3.zarr")
    return out


@pytest.mark.parametrize("ngff", ["0.4", "0.5"])
def test_an_ome_zarr_series_opens_in_place_with_the_plugin(viewer, study_report, tmp_path, ngff):
    store = _zarr_copy(study_report, tmp_path, ngff)
    assert (store / "zarr.json").is_file() == (ngff == "0.5")
    (layer,) = viewer.open(store, plugin="hrvptm")
    x0, y0, z0 = ORIGIN_XYZ_UM
    assert layer.data.shape == (N_FRAMES, *SHAPE)
    assert np.allclose(layer.scale, (1, *VOXEL_UM)) and np.allclose(
        layer.translate, (0, z0, y0, x0)
    )
    tif = viewer.open(study_report / "mismatched" / "volumes", plugin="hrvptm")[0]
    assert np.array_equal(np.asarray(layer.data[1]), np.asarray(tif.data[1]))


def _placed_origin(layer) -> np.ndarray:
    """World position of the centre of voxel (0, 0, 0) of frame 0, (z, y, x) µm."""
    return np.asarray(layer.data_to_world((0, 0, 0, 0)))[1:]


def test_napari_ome_zarr_opens_our_store_with_its_voxels_scale_and_axes(
    viewer, study_report, tmp_path
):
    store = _zarr_copy(study_report, tmp_path)
    (layer,) = viewer.open(store, plugin="napari-ome-zarr")
    assert layer.data.shape == (N_FRAMES, *SHAPE) and np.allclose(layer.scale, (1, *VOXEL_UM))
    assert tuple(layer.axis_labels) == ("t", "z", "y", "x")
    assert [str(u) for u in layer.units[1:]] == ["micrometer"] * 3
    tif = viewer.open(study_report / "mismatched" / "volumes", plugin="hrvptm")[0]
    for t in range(N_FRAMES):
        assert np.array_equal(np.asarray(layer.data[t]), np.asarray(tif.data[t]))


@pytest.mark.xfail(
    strict=True,
    reason="napari-ome-zarr 0.10.0 composes only the first coordinate transformation of a "
    "dataset (the scale); NGFF 0.4 requires scale then translation there, so the origin of "
    "a valid store is dropped (see test_ome_zarr_origin_at_the_multiscales_level)",
)
def test_napari_ome_zarr_places_our_store_at_its_origin(viewer, study_report, tmp_path):
    store = _zarr_copy(study_report, tmp_path)
    (layer,) = viewer.open(store, plugin="napari-ome-zarr")
    x0, y0, z0 = ORIGIN_XYZ_UM
    assert np.allclose(_placed_origin(layer), (z0, y0, x0))


def test_ome_zarr_origin_at_the_multiscales_level(viewer, study_report, tmp_path):
    """The one layout napari-ome-zarr 0.10.0 places right: the dataset's scale, and the
    translation alone in the multiscales' own ``coordinateTransformations``. NGFF 0.4 wants a
    scale first there too (the NGFF 0.4 models refuse it, hence not written); track's reader
    reads it right."""
    import zarr
    from ome_zarr_models.v04 import Image
    from pydantic import ValidationError

    from track.volumes import scan_zarr

    store = _zarr_copy(study_report, tmp_path)
    Image.from_zarr(zarr.open_group(str(store), mode="r"))  # as written: valid
    meta = json.loads((store / ".zattrs").read_text())
    ms = meta["multiscales"][0]
    scale, translation = ms["datasets"][0]["coordinateTransformations"]
    ms["datasets"][0]["coordinateTransformations"] = [scale]
    ms["coordinateTransformations"] = [translation]
    (store / ".zattrs").write_text(json.dumps(meta))
    with pytest.raises(ValidationError, match="scale"):
        Image.from_zarr(zarr.open_group(str(store), mode="r"))
    (layer,) = viewer.open(store, plugin="napari-ome-zarr")
    x0, y0, z0 = ORIGIN_XYZ_UM
    assert np.allclose(layer.scale, (1, *VOXEL_UM))
    assert np.allclose(_placed_origin(layer), (z0, y0, x0))
    assert scan_zarr(store)[0].origin_xyz_um == ORIGIN_XYZ_UM
    shutil.rmtree(store)
