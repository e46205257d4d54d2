"""The shared base's files: verified outputs, the input guard, JSON policy (hrvbase.io)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from hrvbase.errors import InputError, OutputError
from hrvbase.io import (
    atomic_write_text,
    check_output_file,
    check_output_folder,
    file_record,
    guard_output,
    read_json,
    verify_record,
    write_json,
)


def test_verify_record_catches_truncation_and_corruption(tmp_path):
    p = tmp_path / "v.bin"
    p.write_bytes(bytes(range(256)) * 100)
    rec = file_record(p)
    assert rec["size"] == 25600 and verify_record(p, rec)
    with open(p, "r+b") as fh:  # truncated: size differs
        fh.truncate(1000)
    assert not verify_record(p, rec)
    p.write_bytes(bytes(range(255, -1, -1)) * 100)  # same size, other bytes
    assert not verify_record(p, rec)
    assert not verify_record(tmp_path / "missing", rec)
    assert not verify_record(p, None) and not verify_record(p, {"size": 25600})


def test_guard_output_refuses_inputs_their_folders_and_folders_around_them(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    frame = data / "img_1.tif"
    frame.write_bytes(b"x")
    for out, why in [
        (frame, "inside the input folder"),
        (data / "out.tif", "inside the input folder"),
        (data / "sub" / "deep", "inside the input folder"),
        (tmp_path, "contains the input"),
    ]:
        with pytest.raises(OutputError, match=why):
            guard_output(out, [data])
    with pytest.raises(OutputError, match="is an input"):
        guard_output(frame, [frame])
    link = tmp_path / "alias.tif"
    os.symlink(frame, link)
    with pytest.raises(OutputError, match="is an input"):
        guard_output(link, [frame])  # links are resolved
    guard_output(tmp_path / "results", [data, None])  # a sibling folder is fine


def test_check_output_file(tmp_path):
    src = tmp_path / "p.csv"
    src.write_text("x_um,y_um,z_um\n")
    with pytest.raises(OutputError, match="is an input"):
        check_output_file(src, inputs=[src], overwrite=True)
    existing = tmp_path / "old.tif"
    existing.write_bytes(b"keep")
    with pytest.raises(OutputError, match="already exists"):
        check_output_file(existing)
    assert check_output_file(existing, overwrite=True) == existing
    with pytest.raises(OutputError, match="is a folder"):
        check_output_file(tmp_path)
    with pytest.raises(OutputError, match="is a file, not a folder"):
        check_output_file(src / "x.tif")
    assert existing.read_bytes() == b"keep"


def test_check_output_folder(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    for out in (blocker / "out", blocker / "a" / "b"):
        with pytest.raises(OutputError, match=f"cannot create {out}: {blocker} is a file"):
            check_output_folder(out)
    assert check_output_folder(tmp_path / "new" / "out") == tmp_path / "new" / "out"
    assert check_output_folder(tmp_path) == tmp_path  # an existing folder: the tool judges it
    assert check_output_folder(blocker) == blocker  # a file: the tool's own message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"]  # nothing created


def test_json_policy_nan_is_null_and_no_silent_overwrite(tmp_path):
    p = write_json(tmp_path / "a.json", {"r": np.float32(0.5), "n": float("nan"), "i": np.int64(3)})
    assert json.loads(p.read_text()) == {"r": 0.5, "n": None, "i": 3}
    with pytest.raises(OutputError, match="already exists"):
        write_json(p, {})
    write_json(p, {"b": 1}, overwrite=True)
    assert read_json(p) == {"b": 1}
    with pytest.raises(InputError, match="is a folder"):
        read_json(tmp_path)
    with pytest.raises(InputError, match="JSON"):
        write_json(tmp_path / "b.json", {"x": object()})
    assert not (tmp_path / "b.json").exists()


def test_unwritable_folder_is_one_clear_error(tmp_path):
    if os.geteuid() == 0:
        blocker = tmp_path / "f"
        blocker.write_text("")
        with pytest.raises(OutputError, match="is a file, not a folder"):
            atomic_write_text(blocker / "x" / "y.txt", "z")
        return
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    with pytest.raises(OutputError, match="not writable"):
        atomic_write_text(ro / "y.txt", "z")


def test_concurrent_writes_finish_every_file_and_report_the_first_failure(tmp_path):
    from hrvbase.io import ConcurrentWrites, atomic_write_bytes

    with ConcurrentWrites(threads=3) as writes:
        for i in range(20):
            writes.submit(atomic_write_bytes, tmp_path / f"f{i:02d}.bin", bytes([i]) * 1000)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"f{i:02d}.bin" for i in range(20)]
    assert all((tmp_path / f"f{i:02d}.bin").read_bytes() == bytes([i]) * 1000 for i in range(20))

    (tmp_path / "taken.bin").write_bytes(b"user data")
    with pytest.raises(OutputError, match=r"taken\.bin already exists"):
        with ConcurrentWrites() as writes:
            writes.submit(atomic_write_bytes, tmp_path / "a.bin", b"a")
            writes.submit(atomic_write_bytes, tmp_path / "taken.bin", b"new")
            writes.submit(atomic_write_bytes, tmp_path / "b.bin", b"b")
    # the others still completed; the existing file was not touched; no temporary left
    assert (tmp_path / "a.bin").read_bytes() == b"a" and (tmp_path / "b.bin").read_bytes() == b"b"
    assert (tmp_path / "taken.bin").read_bytes() == b"user data"
    assert not list(tmp_path.glob(".*.tmp"))
    with pytest.raises(InputError, match="threads"):
        ConcurrentWrites(threads=0)
