"""A Phantom .cine recording through `recon run` → `track run`: the same volumes and tracks as
the same frames exported as TIFF files, and the recording's times, frame rate, exposure and
bit depth in recon.json."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile

from recon.cli import main as recon

from ..hrvbase.cine_writer import write_cine
from .test_pipeline import EXPERIMENT, FAST, ROOT

FPS = 2000
#: Fewer depths and one iteration: fast, and still the particles of every frame.
ARGS = [*FAST, "--z-step", "40", "--iterations", "1"]


@pytest.fixture(scope="module")
def datasets(backend, tmp_path_factory):
    """The 3-frame test dataset, and a copy whose frames/ holds the same frames as one .cine
    recording (images 5, 6, 7 of a recording that starts at image -5, 0.5 ms apart)."""
    from lfsim.dataset import generate_dataset
    from lfsim.experiment import load_experiment

    d = tmp_path_factory.mktemp("cine")
    toml = d / "exp.toml"
    toml.write_text(EXPERIMENT.format(scene=(ROOT / "scenes" / "small.xml").as_posix()))
    tiff = d / "tiff"
    generate_dataset(load_experiment(toml), tiff, progress=False)
    names = sorted((tiff / "frames").glob("*.tif"))
    frames = np.stack([tifffile.imread(p) for p in names])
    movie = d / "movie"
    shutil.copytree(tiff, movie, ignore=shutil.ignore_patterns("frames"))
    (movie / "frames").mkdir()
    write_cine(
        movie / "frames" / "run1.cine",
        frames,
        fps=FPS,
        exposure_s=100e-6,
        first_image_no=0,
        first_movie_image=-5,
    )
    return tiff, movie, frames


def test_cine_series_gives_the_volumes_and_tracks_of_its_tiff_export(datasets, tmp_path, capsys):
    from track.cli import main as track
    from track.tables import read_points_csv, read_tracks_csv
    from track.volumes import read_volume, scan_volumes

    tiff, movie, frames = datasets
    assert frames.dtype == np.uint8 and frames.shape[0] == 3  # the dataset's 8-bit camera
    outs = {}
    for name, src, extra in (("tiff", tiff, ["--fps", str(FPS)]), ("cine", movie, [])):
        vol = tmp_path / f"vol_{name}"
        rc = recon(["-q", "run", str(src), *ARGS, *extra, "-o", str(vol)])
        assert rc == 0, capsys.readouterr().err
        trk = tmp_path / f"trk_{name}"
        assert track(["-q", "run", str(vol), "-o", str(trk), "--no-progress", "--no-fields"]) == 0
        outs[name] = (vol, trk)
    (vt, tt), (vc, tc) = outs["tiff"], outs["cine"]
    meta = json.loads((vc / "recon.json").read_text())
    # the recording's numbers (from its first image) and times (from the trigger)
    assert [f["number"] for f in meta["frames"]] == [5, 6, 7]
    assert [f["page"] for f in meta["frames"]] == [0, 1, 2]
    assert [f["time_s"] for f in meta["frames"]] == pytest.approx([0, 5e-4, 1e-3], abs=1e-9)
    assert meta["frame_times"] == "metadata" and meta["fps"] is None
    (cam,) = meta["camera"]
    assert cam["input"].endswith("run1.cine") and cam["format"] == "cine"
    assert cam["frame_rate_hz"] == FPS and cam["bit_depth"] == 8
    assert cam["exposure_s"] == pytest.approx(100e-6, abs=1e-9)
    assert json.loads((vt / "recon.json").read_text())["camera"] is None
    # byte-identical volumes
    va, vb = scan_volumes(vt), scan_volumes(vc)
    assert len(va) == len(vb) == 3
    for a, b in zip(va, vb, strict=True):
        assert read_volume(a).tobytes() == read_volume(b).tobytes()
        assert (a.voxel_size_um, a.origin_xyz_um) == (b.voxel_size_um, b.origin_xyz_um)
    assert [v.frame for v in vb] == [5, 6, 7] and [v.frame for v in va] == [0, 1, 2]
    # the same particles and tracks (the frames named by their camera numbers)
    for ka, kb in ((0, 5), (1, 6), (2, 7)):
        pa = read_points_csv(tt / "particles" / f"{ka:06d}.csv")
        pb = read_points_csv(tc / "particles" / f"{kb:06d}.csv")
        assert pa.shape[0] >= 4
        np.testing.assert_array_equal(pb, pa)
    ta, tb = read_tracks_csv(tt / "tracks.csv"), read_tracks_csv(tc / "tracks.csv")
    assert len(ta["track_id"]) >= 12
    for key in ("track_id", "x_um", "y_um", "z_um"):
        np.testing.assert_array_equal(tb[key], ta[key])
    s = json.loads((tc / "summary.json").read_text())
    assert s["frame_times_s"] == pytest.approx([0, 5e-4, 1e-3], abs=1e-9)
