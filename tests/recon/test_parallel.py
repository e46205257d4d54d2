"""`recon run --workers` / `--scheduler`: the same volumes and records as the serial run, on
two local workers and on a real loopback cluster (one of whose workers is killed mid-run),
and a frame that fails on a worker fails the command."""

from __future__ import annotations

from pathlib import Path

import pytest

from recon.cli import main

from ..helpers import LoopbackCluster
from .test_pipeline import FAST, ROOT, make_dataset, run

ARGS = [*FAST, "--iterations", "3"]


@pytest.fixture(scope="module")
def dataset4(backend, tmp_path_factory):
    """The pipeline tests' dataset with 4 frames."""
    return make_dataset(tmp_path_factory, frames=4)


@pytest.fixture(scope="module")
def serial(dataset4, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "vol"
    assert main(["-q", "run", str(dataset4), *ARGS, "-o", str(out)]) == 0
    return out


def frame_records(vol_dir: Path) -> list[dict]:
    from hrvbase.io import read_json

    meta = read_json(vol_dir / "recon.json")
    assert meta["status"] == "complete"
    return [{k: v for k, v in f.items() if k != "seconds"} for f in meta["frames"]]


def assert_same_run(a: Path, b: Path) -> None:
    """Byte-identical volumes, identical frame records (but for their timings)."""
    vols = sorted(p.name for p in a.glob("[0-9]*.tif"))
    assert vols == sorted(p.name for p in b.glob("[0-9]*.tif")) and len(vols) == 4
    for name in vols:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert frame_records(a) == frame_records(b)


def test_two_local_workers_give_the_serial_volumes(dataset4, serial, tmp_path, capsys):
    from hrvbase.io import read_json

    out = tmp_path / "vol"
    rc, _, err = run(capsys, "run", dataset4, *ARGS, "--workers", "2", "-o", out)
    assert rc == 0, err
    assert_same_run(serial, out)
    par = read_json(out / "recon.json")["parallel"]
    assert par["mode"].startswith("2 local Dask workers")
    assert len(par["peak_memory_bytes"]) == 2
    assert read_json(serial / "recon.json")["parallel"]["mode"] == "in process"
    # Resume: nothing left to do, with workers or without.
    rc, _, err = run(capsys, "run", dataset4, *ARGS, "-o", out)
    assert rc == 0, err
    assert_same_run(serial, out)


def test_loopback_cluster_with_a_killed_worker(dataset4, serial, tmp_path, capsys):
    out = tmp_path / "vol"
    with LoopbackCluster(tmp_path) as cluster:
        with cluster.killing_worker_when(
            lambda: any(out.glob("[0-9]*.tif")), timeout_s=120.0, poll_s=0.02
        ):
            rc, _, err = run(
                capsys, "run", dataset4, *ARGS, "--scheduler", cluster.address, "-o", out
            )
        assert cluster.workers[0].poll() is not None  # killed during the run
    assert rc == 0, err
    assert_same_run(serial, out)


def test_loopback_cluster_same_volumes(dataset4, serial, tmp_path, capsys, monkeypatch):
    import os

    from lfsim.io import read_tiff

    # Relative paths: the workers run in another folder (the repository).
    monkeypatch.chdir(tmp_path)
    frames = os.path.relpath(dataset4, tmp_path)
    with LoopbackCluster(tmp_path) as cluster:
        rc, _, err = run(capsys, "run", frames, *ARGS, "--scheduler", cluster.address, "-o", "vol")
    assert rc == 0, err
    assert not (ROOT / "vol").exists()
    out = tmp_path / "vol"
    vols = sorted(p.name for p in out.glob("[0-9]*.tif"))
    assert len(vols) == 4
    for name in vols:  # the same voxels (the metadata name the frames as given: relative)
        a, meta_a = read_tiff(serial / name)
        b, meta_b = read_tiff(out / name)
        assert a.tobytes() == b.tobytes(), name
        assert Path(meta_b["input"]).resolve() == Path(meta_a["input"]).resolve()


def test_a_frame_failing_on_a_worker_fails_the_command(dataset4, tmp_path, capsys):
    import shutil

    from hrvbase.io import read_json

    frames = tmp_path / "frames"
    shutil.copytree(dataset4 / "frames", frames)
    bad = frames / "000002.tif"
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 2])  # header intact, pixels cut
    out = tmp_path / "vol"
    calib = tmp_path / "calib.json"
    scene = ROOT / "scenes" / "small.xml"
    assert (
        main(
            [
                "-q",
                "calibrate",
                str(dataset4 / "white.tif"),
                "--scene",
                str(scene),
                "-o",
                str(calib),
            ]
        )
        == 0
    )
    rc, _, err = run(
        capsys,
        "run",
        frames,
        "--scene",
        scene,
        "--calib",
        calib,
        *ARGS,
        "--workers",
        "2",
        "-o",
        out,
    )
    assert rc == 2
    last = err.splitlines()[-1]
    assert last.startswith("recon: error: cannot read frame") and "000002.tif" in last, err
    assert "Traceback" not in err
    # Every volume written is recorded (frames running when frame 2 failed finished first)...
    records = {f["index"]: f for f in read_json(out / "recon.json")["frames"]}
    volumes = sorted(int(p.name[:6]) for p in out.glob("[0-9]*.tif"))
    assert 2 not in volumes
    assert all("output" in records[k] for k in volumes)
    assert not list(out.glob(".*"))  # no temporary file left behind
    # ... and the run resumes once the frame is repaired.
    bad.write_bytes(data)
    rc, _, err = run(capsys, "run", frames, "--scene", scene, "--calib", calib, *ARGS, "-o", out)
    assert rc == 0, err
    assert len(frame_records(out)) == 4


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--workers", "0"], "--workers must be an integer >= 1 or 'auto', got '0'"),
        (["--workers=-3"], "--workers must be an integer >= 1 or 'auto', got '-3'"),
        (
            ["--scheduler", "tcp://127.0.0.1:9"],
            "--scheduler tcp://127.0.0.1:9: nothing is listening",
        ),
    ],
)
def test_bad_parallel_options(dataset4, tmp_path, capsys, monkeypatch, option, message):
    monkeypatch.setattr("hrvbase.scheduler.CONNECT_TIMEOUT_S", 2.0)
    out = tmp_path / "vol"
    rc, _, err = run(capsys, "run", dataset4, *ARGS, *option, "-o", out)
    assert rc == 2
    assert err.startswith(f"recon: error: {message}") and err.count("\n") == 1, err
    assert not out.exists()  # nothing left behind


def test_zarr_written_by_two_workers_is_the_serial_volumes(dataset4, serial, tmp_path, capsys):
    """Workers write their frames into one OME-Zarr image: its voxels are the serial TIFFs'."""
    import tifffile

    from track.volumes import read_volume, scan_volumes

    out = tmp_path / "vol.zarr"
    rc, _, err = run(
        capsys, "run", dataset4, *ARGS, "--format", "zarr", "--workers", "2", "-o", out
    )
    assert rc == 0, err
    frames = scan_volumes(out)
    assert [v.index for v in frames] == [0, 1, 2, 3]
    for v in frames:
        want = tifffile.imread(serial / f"{v.index:06d}.tif")
        assert read_volume(v).tobytes() == want.astype("float32").tobytes(), v.name
