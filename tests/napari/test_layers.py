"""The plugin's layer data (no display): kinds of folder, layer types, shapes, and world
coordinates against the known truth of the test study (conftest.py)."""

from __future__ import annotations

import numpy as np
import pytest

from hrvptm_napari import ReadError, folder_kind, read_layers
from hrvptm_napari.layers import STRAIN_COMPONENTS

from .conftest import N_FRAMES, ORIGIN_XYZ_UM, SHAPE, STEP_X_UM, VOXEL_UM, truth_xyz


def _by_name(layers):
    return {kw["name"]: (data, kw, kind) for data, kw, kind in layers}


def test_folder_kinds(study_report, tmp_path):
    v = study_report / "mismatched"
    assert folder_kind(study_report) == "study"
    assert folder_kind(study_report / "study.json") == "study"
    assert folder_kind(v / "track") == "results"
    assert folder_kind(v / "track" / "tracks.csv") == "results"
    assert folder_kind(v / "volumes") == "volumes"
    assert folder_kind(v / "dataset") is None
    assert folder_kind(tmp_path) is None
    with pytest.raises(ReadError, match="not a study report, a track results folder"):
        read_layers(tmp_path)


def test_volume_layer_puts_voxel_centres_on_the_truth(study_report):
    data, kw, kind = read_layers(study_report / "mismatched" / "volumes")[0]
    assert kind == "image" and data.shape == (N_FRAMES, *SHAPE)
    x0, y0, z0 = ORIGIN_XYZ_UM
    assert kw["scale"] == (1.0, *VOXEL_UM) and kw["translate"] == (0.0, z0, y0, x0)
    lo, hi = kw["contrast_limits"]
    assert 0.5 < lo < 2.0 and hi > 50  # background (1 ± 0.3) to the particles' peaks (100)
    scale, translate = np.array(kw["scale"]), np.array(kw["translate"])
    for t in range(N_FRAMES):
        vol = np.asarray(data[t])
        for x, y, z in truth_xyz(t):
            idx = np.round((np.array([t, z, y, x]) - translate) / scale).astype(int)
            k, j, i = idx[1:]
            box = vol[k - 2 : k + 3, j - 2 : j + 3, i - 2 : i + 3]
            peak = np.array(np.unravel_index(np.argmax(box), box.shape)) + idx[1:] - 2
            world = translate[1:] + peak * scale[1:]  # napari: index i's centre at t + i·s
            assert np.allclose(world, [z, y, x], atol=1e-9)


def test_results_layers_match_the_truth(study_report):
    layers = _by_name(read_layers(study_report / "mismatched" / "track"))
    kinds = {name: kind for name, (_, _, kind) in layers.items()}
    assert kinds == {
        "particles": "points", "tracks": "tracks", "displacement": "vectors",
        "displacement field": "vectors", **{f"E_{c}": "image" for c in STRAIN_COMPONENTS},
    }  # fmt: skip
    pts, kw, _ = layers["particles"]
    n = len(truth_xyz(0))
    assert pts.shape == (N_FRAMES * n, 4)
    assert set(kw["features"]) >= {"frame", "intensity", "sigma_x_um", "sigma_y_um",
                                    "sigma_z_um"}  # fmt: skip
    assert np.all(kw["features"]["sigma_z_um"] > 0) and np.all(kw["features"]["intensity"] > 10)
    for t in range(N_FRAMES):
        got = pts[pts[:, 0] == t][:, 1:]
        want = truth_xyz(t)[:, ::-1]  # (z, y, x)
        d = np.linalg.norm(got[:, None, :] - want[None], axis=2).min(axis=1)
        assert len(got) == n and d.max() < 0.1
    tracks, kw, _ = layers["tracks"]
    assert tracks.shape == (N_FRAMES * n, 5)  # track_id, t, z, y, x
    for tid in np.unique(tracks[:, 0]):
        tr = tracks[tracks[:, 0] == tid]
        assert np.array_equal(tr[:, 1], np.arange(N_FRAMES))  # t: the frame index, in order
        assert np.allclose(np.diff(tr[:, 4]), STEP_X_UM, atol=0.05)  # x is the last column
        assert np.allclose(np.diff(tr[:, 2:4], axis=0), 0, atol=0.05)
    vec, kw, _ = layers["displacement"]
    assert vec.shape == ((N_FRAMES - 1) * n, 2, 4)
    assert set(np.unique(vec[:, 0, 0])) == {1.0, 2.0}  # shown at the deformed frame
    assert np.allclose(vec[:, 1, 1:], [0, 0, STEP_X_UM], atol=0.05)  # (uz, uy, ux)
    assert np.allclose(kw["features"]["u_um"], STEP_X_UM, atol=0.05)
    exx, kw, _ = layers["E_xx"]
    fld = np.load(study_report / "mismatched" / "track" / "fields" / "000001.npz")
    assert exx.shape == (N_FRAMES, *fld["mask"].shape)
    assert kw["translate"] == (0.0, fld["z_um"][0], fld["y_um"][0], fld["x_um"][0])
    assert np.allclose(kw["scale"][1:], [np.diff(fld[a]).mean() for a in ("z_um", "y_um",
                                                                           "x_um")])  # fmt: skip
    assert np.all(np.isnan(exx[0]))  # frame 0 has no field
    assert np.array_equal(np.isfinite(exx[1]), fld["mask"])
    assert np.nanmax(np.abs(exx[1:])) < 0.01  # a translation: no strain
    field_vec, _, _ = layers["displacement field"]
    for t in (1, 2):  # the total field from frame 0, at the reference grid's nodes
        u = field_vec[field_vec[:, 0, 0] == t][:, 1, 1:]
        assert len(u) == fld["mask"].sum() and np.allclose(u, [0, 0, STEP_X_UM * t], atol=0.05)


def test_study_layers_add_the_volumes_and_the_truth(study_report):
    layers = _by_name(read_layers(study_report))
    assert {"volumes", "particles", "tracks", "displacement", "truth"} <= set(layers)
    truth, kw, kind = layers["truth"]
    assert kind == "points" and truth.shape == (N_FRAMES * len(truth_xyz(0)), 4)
    for t in range(N_FRAMES):
        assert np.allclose(truth[truth[:, 0] == t][:, 1:], truth_xyz(t)[:, ::-1])
    assert np.array_equal(kw["features"]["id"][: len(truth_xyz(0))], np.arange(12))
