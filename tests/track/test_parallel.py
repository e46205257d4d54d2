"""`track run|detect --workers` / `--scheduler`: detection on Dask workers gives the serial
results (particle tables, matches, tracks, fields, summary records) while linking starts on the
frames as they arrive; a failed frame fails the command alike, `--allow-partial` keeps it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from track.cli import EXIT_FAILED

from ..helpers import LoopbackCluster
from .test_cli import _run, _volumes

RUN = ["--grid-spacing-um", "4", "--no-progress"]


def outputs(res: Path) -> dict[str, bytes]:
    """Every result file but summary.json, by name."""
    return {
        str(p.relative_to(res)): p.read_bytes()
        for p in sorted(res.rglob("*"))
        if p.is_file() and p.name != "summary.json"
    }


def records(res: Path) -> dict:
    s = json.loads((res / "summary.json").read_text())
    frames = [{k: v for k, v in f.items() if k != "seconds"} for f in s["frames"]]
    for f in frames:  # timings apart
        f.get("report", {}).pop("timings", None)
    return {"frames": frames, "increments": s.get("increments"), "status": s["status"]}


@pytest.fixture(scope="module")
def volumes(tmp_path_factory):
    vols = tmp_path_factory.mktemp("vols") / "vols"
    _volumes(vols, n_frames=4)
    return vols


@pytest.fixture(scope="module")
def serial(volumes, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "res"
    from track.cli import main

    assert main(["-q", "run", str(volumes), "-o", str(out), *RUN]) == 0
    return out


@pytest.mark.slow  # two clusters: about 70 s on 2 busy cores
def test_two_local_workers_and_a_loopback_cluster_give_the_serial_results(
    volumes, serial, tmp_path, capsys
):
    out = tmp_path / "res2"
    rc, err = _run(["-q", "run", volumes, "-o", out, *RUN, "--workers", "2"], capsys)
    assert rc == 0, err
    assert outputs(out) == outputs(serial) and len(outputs(out)) > 10
    assert records(out) == records(serial)
    with LoopbackCluster(tmp_path) as cluster:
        out3 = tmp_path / "res3"
        argv = ["-q", "run", volumes, "-o", out3, *RUN, "--scheduler", cluster.address]
        rc, err = _run(argv, capsys)
    assert rc == 0, err
    assert outputs(out3) == outputs(serial)
    assert records(out3) == records(serial)


def test_a_failed_volume_fails_alike_and_allow_partial_keeps_it(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=3, empty=(1,))  # volume 1: no particle
    got = {}
    for name, extra in (("serial", []), ("workers", ["--workers", "2"])):
        out = tmp_path / name
        argv = ["detect", vols, "-o", out, "--no-progress", "--no-deconvolution", *extra]
        rc, err = _run(argv, capsys)
        lines = err.strip().splitlines()
        warnings = sorted(ln for ln in lines if ln.startswith("track: warning: "))
        got[name] = (rc, lines[-1], warnings, records(out))
    assert got["serial"][0] == EXIT_FAILED
    assert got["workers"] == got["serial"]  # the workers' warnings are shown here too
    assert any("no particle found" in w for w in got["serial"][2])
    assert "000001.tif: no particle found" in got["serial"][1]
    rc, err = _run(
        ["-q", "detect", vols, "-o", tmp_path / "p", "--allow-partial", "--workers", "2"], capsys
    )  # (with deconvolution: the PSF of the first volume goes to the workers)
    assert rc == 0, err
    assert records(tmp_path / "p")["status"] == "partial"


def test_bad_workers_is_one_line(tmp_path, capsys):
    vols = tmp_path / "vols"
    _volumes(vols, n_frames=2)
    rc, err = _run(["run", vols, "-o", tmp_path / "r", "--workers", "0"], capsys)
    assert rc == 2
    assert err == "track: error: --workers must be an integer >= 1 or 'auto', got '0'\n"


def test_linking_starts_before_the_last_frame_arrives():
    """link_pairs reads each cloud only when its first pair is linked."""
    import numpy as np

    from track.series import SeriesSettings, link_pairs

    rng = np.random.default_rng(4)
    base = rng.uniform(0, 300, (120, 3))
    events = []

    class Arriving:
        def __len__(self):
            return 4

        def __getitem__(self, i):
            if not 0 <= i < 4:
                raise IndexError(i)
            events.append(f"frame {i}")
            return base + np.array([1.0 * i, 0, 0])

    link_pairs(Arriving(), SeriesSettings(), on_pair=lambda p: events.append(f"pair {p.def_frame}"))
    first = {e: events.index(e) for e in reversed(events)}
    assert first["pair 1"] < first["frame 2"] < first["pair 2"] < first["frame 3"]


@pytest.mark.slow  # one local cluster: about 30 s on 2 busy cores
def test_link_fields_on_two_workers_are_the_serial_fields(tmp_path, capsys):
    """`track link --workers 2` fits and grids the increments on two Dask workers and composes
    them here: every file (fields with σ, increments, tracks) and record is the serial one's,
    byte for byte. 300 noisy particles: eigen-decompositions and products large enough for
    OpenBLAS to thread them in this process (which would round differently from a worker)."""
    import numpy as np

    from track.synthetic import make_series
    from track.tables import write_points_csv

    s = make_series("stiff_inclusion", 330, 0.05, 4, seed=3)
    paths = []
    for i, c in enumerate(s.frames_xyz_um):
        paths.append(tmp_path / f"c{i}.csv")
        write_points_csv(paths[-1], np.asarray(c))
    assert min(len(c) for c in s.frames_xyz_um) > 250
    argv = ["-q", "link", *paths, "--nodes-per-spacing", "1.5", "--no-progress"]
    rc, err = _run([*argv, "-o", tmp_path / "serial"], capsys)
    assert rc == 0, err
    rc, err = _run([*argv, "-o", tmp_path / "two", "--workers", "2"], capsys)
    assert rc == 0, err
    serial, two = outputs(tmp_path / "serial"), outputs(tmp_path / "two")
    assert two == serial
    assert sum(k.startswith("fields/increment_") for k in serial) == 3
    assert records(tmp_path / "two") == records(tmp_path / "serial")
    summary = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert all(len(set(inc["smoothing_xyz"])) == 3 for inc in summary["increments"])  # GCV
