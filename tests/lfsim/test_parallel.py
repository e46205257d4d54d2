"""`lfsim dataset --workers 2`: frames rendered by Mitsuba/Dr.Jit in two Dask worker processes
are byte-identical to the serial ones (each frame seeded from (seed, k))."""

from __future__ import annotations

import json

from lfsim.cli import main

from .test_dataset import made, snapshot, tiny  # noqa: F401  (made: a fixture)


def records(folder):
    rec = json.loads((folder / "dataset.json").read_text())
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rec["frame_records"]], rec


def test_two_workers_render_the_serial_dataset(made, tmp_path, capsys):  # noqa: F811
    exp, serial = made
    out = tmp_path / "ds"
    rc = main(["-q", "dataset", str(exp.source), "-o", str(out), "--workers", "2"])
    assert rc == 0, capsys.readouterr().err
    assert snapshot(out) == snapshot(serial)
    got, rec = records(out)
    assert got == records(serial)[0]
    assert rec["status"] == "complete"
    assert rec["parallel"]["mode"].startswith("2 local Dask workers")
    assert len(rec["parallel"]["peak_memory_bytes"]) == 2


def test_bad_workers_is_one_line(made, tmp_path, capsys):  # noqa: F811
    exp, _ = made
    rc = main(["dataset", str(exp.source), "-o", str(tmp_path / "ds"), "--workers", "-1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err == "lfsim: error: --workers must be an integer >= 1 or 'auto', got '-1'\n"
    assert not (tmp_path / "ds").exists()
