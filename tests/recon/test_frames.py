"""Frame series of `recon run`: natural order, gaps, refusals, the frame → file record."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import tifffile

from recon.cli import main
from recon.errors import InputError
from recon.frames import format_numbers, natural_order, parse_frame_name

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "small.xml"

#: A fast reconstruction: 3 depths, 1 voxel per lenslet, 1 iteration, no background guess
#: (so that a frame scaled by n gives a volume scaled by n).
FAST = "--z-range 100:200 --z-step 50 -s 1 --iterations 1 --rays-per-pattern 20000".split()
FAST += ["--background", "none"]


def run(capsys, *args):
    rc = main(["-q", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


def write_series(folder: Path, names, base: np.ndarray) -> dict[str, int]:
    """Write frame ``name`` as ``base × number`` (number from the name); returns the scales."""
    folder.mkdir(parents=True, exist_ok=True)
    scale = {}
    for name in names:
        n = parse_frame_name(name)[1]
        tifffile.imwrite(folder / name, (base.astype(np.int64) * n).astype(np.uint16))
        scale[name] = n
    return scale


# -- ordering -----------------------------------------------------------------------------
def test_parse_frame_name():
    assert parse_frame_name("img_0012.tif") == ("img_", 12, "")
    assert parse_frame_name("run2_f7_cam.TIF") == ("run2_f", 7, "_cam")
    assert parse_frame_name("000003.tiff") == ("", 3, "")
    assert parse_frame_name("white.tif") is None


def test_natural_order_1_2_10(tmp_path):
    names = ["img_10.tif", "img_2.tif", "img_1.tif"]
    got = natural_order([tmp_path / n for n in names], where="folder x")
    assert [p.name for p in got] == ["img_1.tif", "img_2.tif", "img_10.tif"]
    # Zero padding of varying width orders by value too.
    got = natural_order([Path("f_0100.tif"), Path("f_99.tif"), Path("f_7.TIF")], where="x")
    assert [p.name for p in got] == ["f_7.TIF", "f_99.tif", "f_0100.tif"]


def test_format_numbers():
    assert format_numbers([4, 5, 6, 9]) == "4-6, 9"
    assert format_numbers([1, 2]) == "1, 2"
    assert format_numbers([3]) == "3"
    many = list(range(0, 60, 2))
    assert format_numbers(many).endswith(", … (30 in all)")


def test_gap_is_reported(tmp_path, caplog):
    names = [f"img_{k}.tif" for k in (1, 2, 3, 7, 8, 10)]
    with caplog.at_level(logging.WARNING, logger="recon"):
        got = natural_order([tmp_path / n for n in names], where="folder 'd'")
    assert [p.name for p in got] == names
    msgs = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(msgs) == 1
    assert "folder 'd': missing frames 4-6, 9;" in msgs[0] and "6 frames found" in msgs[0]


def test_steps_are_not_gaps(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="recon"):
        natural_order([tmp_path / f"a{k}.tif" for k in (0, 2, 4, 6)], where="x")
    assert not caplog.records
    with caplog.at_level(logging.WARNING, logger="recon"):
        natural_order([tmp_path / f"a{k}.tif" for k in (0, 2, 6)], where="x")
    assert "missing frames 4 (numbered in steps of 2)" in caplog.records[0].getMessage()


@pytest.mark.parametrize(
    ("names", "bad"),
    [
        (["img_1.tif", "img_01.tif"], ("img_1.tif", "img_01.tif", "both carry frame number 1")),
        (["img_1.tif", "dark.tif"], ("dark.tif", "img_1.tif", "has no number")),
        (["a_1.tif", "b_2.tif"], ("a_1.tif", "b_2.tif", "named differently")),
        (["img_1_x.tif", "img_2_y.tif"], ("img_1_x.tif", "img_2_y.tif", "named differently")),
    ],
)
def test_ambiguous_names_are_refused(names, bad):
    with pytest.raises(InputError) as exc:
        natural_order([Path("d") / n for n in names], where="folder 'd'")
    msg = str(exc.value)
    assert "folder 'd'" in msg and "give the order explicitly" in msg
    assert all(b in msg for b in bad)


# -- through `recon run` --------------------------------------------------------------------
def _check_mapping(vol_dir: Path, expected: list[str], scale: dict[str, int]) -> None:
    """recon.json maps volume k to the k-th expected file, and the volumes say the same."""
    from lfsim.io import read_json, read_tiff, sha256_file

    meta = read_json(vol_dir / "recon.json")
    assert meta["status"] == "complete"
    frames = meta["frames"]
    assert [f["index"] for f in frames] == list(range(len(expected)))
    assert [Path(f["input"]).name for f in frames] == expected
    for f in frames:
        assert f["input_sha256"] == sha256_file(f["input"])
    # Frame n is the base image times n, so volume k is the base volume times its number:
    # the volumes themselves show which file each was made from.
    sums = []
    for k, name in enumerate(expected):
        vol, vmeta = read_tiff(vol_dir / f"{k:06d}.tif")
        assert Path(vmeta["input"]).name == name
        sums.append(float(vol.sum(dtype=np.float64)) / scale[name])
    assert np.allclose(sums, sums[0], rtol=1e-3), sums


def test_run_orders_a_folder_naturally(calib, base_frame, tmp_path, capsys):
    names = ["img_10.tif", "img_2.tif", "img_1.tif", "img_3.TIF", "img_5.tiff"]
    scale = write_series(tmp_path / "frames", names, base_frame)
    (tmp_path / "frames" / ".img_4.tif").write_bytes(b"")  # hidden: ignored
    (tmp_path / "frames" / "notes.txt").write_text("not a frame")
    vol_dir = tmp_path / "vol"
    argv = ["run", tmp_path / "frames", "--scene", SCENE, "--calib", calib, *FAST, "-o", vol_dir]
    rc = main(list(map(str, argv)))
    err = capsys.readouterr().err
    assert rc == 0, err
    expected = ["img_1.tif", "img_2.tif", "img_3.TIF", "img_5.tiff", "img_10.tif"]
    _check_mapping(vol_dir, expected, scale)
    assert err.count("missing frames") == 1
    assert f"recon: warning: folder {str(tmp_path / 'frames')!r}: missing frames 4, 6-9;" in err


def test_run_keeps_the_order_of_explicit_files(calib, base_frame, tmp_path, capsys):
    names = ["f_1.tif", "f_10.tif", "f_2.tif"]  # as a shell expands f_*.tif
    scale = write_series(tmp_path, names, base_frame)
    vol_dir = tmp_path / "vol"
    rc = main(
        [
            "run",
            *(str(tmp_path / n) for n in names),
            "--scene",
            str(SCENE),
            "--calib",
            str(calib),
            *FAST,
            "-o",
            str(vol_dir),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 0, err
    _check_mapping(vol_dir, names, scale)
    assert "not in the order of their numbers (f_10.tif before f_2.tif)" in err


def test_run_refuses_an_ambiguous_folder(calib, base_frame, tmp_path, capsys):
    write_series(tmp_path / "frames", ["img_1.tif", "img_01.tif", "img_2.tif"], base_frame)
    vol_dir = tmp_path / "vol"
    rc, out, err = run(
        capsys,
        "run",
        tmp_path / "frames",
        "--scene",
        SCENE,
        "--calib",
        calib,
        *FAST,
        "-o",
        vol_dir,
    )
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("recon: error: ")
    assert str(tmp_path / "frames") in err and "'img_1.tif'" in err and "'img_01.tif'" in err
    assert "give the order explicitly (a list file or explicit files)" in err
    assert not vol_dir.exists()


# -- input forms --------------------------------------------------------------------------
def _recon(capsys, *frames_and_options, quiet=True):
    """`recon run` on the small scene and calibration; returns (rc, stdout, stderr)."""
    argv = ["run", *frames_and_options]
    rc = main(["-q", *map(str, argv)] if quiet else list(map(str, argv)))
    out = capsys.readouterr()
    return rc, out.out, out.err


def _opts(calib, out):
    return ["--scene", SCENE, "--calib", calib, *FAST, "-o", out]


def _refused(rc, out, err, *names):
    """Exit status 2 and one line on stderr naming every one of ``names``."""
    assert rc == 2 and out == "", err
    assert err.startswith("recon: error: ") and err.count("\n") == 1, err
    for name in names:
        assert name in err, (name, err)


def test_glob_pattern_is_ordered_naturally(calib, base_frame, tmp_path, capsys):
    scale = write_series(tmp_path / "d", ["a_10.tif", "a_9.tif", "a_11.tif"], base_frame)
    write_series(tmp_path / "d", ["b_1.tif"], base_frame)  # not matched
    rc, _, err = _recon(capsys, tmp_path / "d" / "a_*.tif", *_opts(calib, tmp_path / "v"))
    assert rc == 0, err
    _check_mapping(tmp_path / "v", ["a_9.tif", "a_10.tif", "a_11.tif"], scale)
    # A pattern matching nothing, or names that cannot be ordered: refused, nothing written.
    _refused(*_recon(capsys, tmp_path / "d" / "z_*.tif", *_opts(calib, tmp_path / "v2")), "z_*.tif")
    _refused(
        *_recon(capsys, tmp_path / "d" / "*.tif", *_opts(calib, tmp_path / "v2")),
        "'a_10.tif' and 'b_1.tif' are named differently",
        "give the order explicitly",
    )
    assert not (tmp_path / "v2").exists()


def test_list_file_gives_the_order(calib, base_frame, tmp_path, capsys):
    scale = write_series(tmp_path / "frames", ["x_3.tif", "x_1.tif", "x_2.tif"], base_frame)
    lst = tmp_path / "order.txt"
    lst.write_text(f"# my order\nframes/x_3.tif\n\n  frames/x_1.tif\n{tmp_path}/frames/x_2.tif\n")
    rc, _, err = _recon(capsys, lst, *_opts(calib, tmp_path / "v"))
    assert rc == 0, err
    _check_mapping(tmp_path / "v", ["x_3.tif", "x_1.tif", "x_2.tif"], scale)
    bad = tmp_path / "bad.txt"
    bad.write_text("frames/x_1.tif\nframes/x_4.tif\n")
    _refused(*_recon(capsys, bad, *_opts(calib, tmp_path / "v2")), "bad.txt", "line 2", "x_4.tif")
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n\n")
    _refused(*_recon(capsys, empty, *_opts(calib, tmp_path / "v2")), "empty.txt", "no frames")
    binary = tmp_path / "frame.png"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    _refused(*_recon(capsys, binary, *_opts(calib, tmp_path / "v2")), "frame.png", "neither")
    assert not (tmp_path / "v2").exists()


def test_stack_gives_one_frame_per_page(calib, base_frame, tmp_path, capsys):
    import hashlib

    from lfsim.io import read_json, read_tiff

    scales = [3, 1, 2, 5]
    stack = np.stack([base_frame * s for s in scales]).astype(np.uint16)
    path = tmp_path / "camera_export.tif"
    tifffile.imwrite(path, stack, photometric="minisblack")
    vol_dir = tmp_path / "v"
    rc, _, err = _recon(capsys, path, "--fps", "500", *_opts(calib, vol_dir))
    assert rc == 0, err
    meta = read_json(vol_dir / "recon.json")
    assert meta["fps"] == 500.0 and meta["frame_times"] == "fps"
    frames = meta["frames"]
    assert [f["page"] for f in frames] == [0, 1, 2, 3]
    assert [f["number"] for f in frames] == [0, 1, 2, 3]
    assert [f["time_s"] for f in frames] == pytest.approx([0.0, 0.002, 0.004, 0.006])
    assert all(f["input"] == str(path) for f in frames)
    for f, img in zip(frames, stack, strict=True):
        assert f["input_sha256"] == hashlib.sha256(img.tobytes()).hexdigest()
    sums = [
        float(read_tiff(vol_dir / f"{k:06d}.tif")[0].sum(dtype=np.float64)) / s
        for k, s in enumerate(scales)
    ]
    assert np.allclose(sums, sums[0], rtol=1e-3), sums
    assert read_tiff(vol_dir / "000002.tif")[1]["page"] == 2
    # Resuming recognises every page by its pixels.
    rc, out, err = _recon(capsys, path, "--fps", "500", *_opts(calib, vol_dir), quiet=False)
    assert rc == 0 and "0 volume(s) reconstructed, 4 already done" in out, err


def test_stacks_continue_their_numbering_and_imagej_times(calib, base_frame, tmp_path, capsys):
    from lfsim.io import read_json

    for name, n in (("part1.tif", 3), ("part2.tif", 2)):
        data = np.stack([base_frame] * n)
        meta = {"axes": "TYX", "finterval": 0.004}
        tifffile.imwrite(tmp_path / name, data, imagej=True, metadata=meta)
    rc, _, err = _recon(
        capsys, tmp_path / "part1.tif", tmp_path / "part2.tif", *_opts(calib, tmp_path / "v")
    )
    assert rc == 0, err
    meta = read_json(tmp_path / "v" / "recon.json")
    frames = meta["frames"]
    assert [(Path(f["input"]).name, f["page"], f["number"]) for f in frames] == [
        ("part1.tif", 0, 0),
        ("part1.tif", 1, 1),
        ("part1.tif", 2, 2),
        ("part2.tif", 0, 3),
        ("part2.tif", 1, 4),
    ]
    assert [f["time_s"] for f in frames] == pytest.approx([0, 0.004, 0.008, 0.012, 0.016])
    assert meta["frame_times"] == "metadata" and meta["fps"] is None


def test_times_from_fps_json_metadata_or_unknown(calib, base_frame, tmp_path, capsys):
    from lfsim.io import read_json, write_tiff

    for k in (4, 6):
        write_tiff(tmp_path / "d" / f"f{k}.tif", base_frame, metadata={"time_s": k * 0.01})
    rc, _, err = _recon(capsys, tmp_path / "d", *_opts(calib, tmp_path / "v1"))
    assert rc == 0, err
    frames = read_json(tmp_path / "v1" / "recon.json")["frames"]
    assert [f["number"] for f in frames] == [4, 6]
    assert [f["time_s"] for f in frames] == pytest.approx([0.04, 0.06])
    rc, _, err = _recon(capsys, tmp_path / "d", "--fps", "100", *_opts(calib, tmp_path / "v2"))
    assert rc == 0, err
    frames = read_json(tmp_path / "v2" / "recon.json")["frames"]
    assert [f["time_s"] for f in frames] == pytest.approx([0.04, 0.06])
    tifffile.imwrite(tmp_path / "plain.tif", base_frame)
    rc, _, err = _recon(capsys, tmp_path / "plain.tif", *_opts(calib, tmp_path / "v3"))
    assert rc == 0, err
    meta = read_json(tmp_path / "v3" / "recon.json")
    assert meta["frames"][0]["time_s"] is None and meta["frames"][0]["number"] is None
    assert meta["frame_times"] is None
    _refused(*_recon(capsys, tmp_path / "d", "--fps", "0", *_opts(calib, tmp_path / "v4")), "--fps")
    assert not (tmp_path / "v4").exists()


def test_frame_selection(calib, base_frame, tmp_path, capsys):
    from lfsim.io import read_json

    names = [f"s_{k}.tif" for k in range(1, 8)]
    scale = write_series(tmp_path / "d", names, base_frame)
    rc, _, err = _recon(capsys, tmp_path / "d", "--frames", "1:6:2", *_opts(calib, tmp_path / "v"))
    assert rc == 0, err
    _check_mapping(tmp_path / "v", ["s_2.tif", "s_4.tif", "s_6.tif"], scale)
    assert read_json(tmp_path / "v" / "recon.json")["frame_selection"] == "1:6:2"
    rc, _, err = _recon(capsys, tmp_path / "d", "--frames", "5:", *_opts(calib, tmp_path / "w"))
    assert rc == 0, err
    _check_mapping(tmp_path / "w", ["s_6.tif", "s_7.tif"], scale)
    for bad in ("3", "a:b", "4:2", "0:5:0", "7:9", "-1:3"):
        _refused(
            *_recon(capsys, tmp_path / "d", f"--frames={bad}", *_opts(calib, tmp_path / "x")),
            "--frames",
        )
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("odd", "what"),
    [
        (np.zeros((300, 280), np.uint16), "size 280 × 300 px, not 300 × 300"),
        (np.zeros((300, 300), np.uint8), "pixel type uint8, not uint16"),
        (np.zeros((300, 300), np.float32), "pixel type float32, not uint16"),
    ],
)
def test_mixed_series_is_refused(calib, base_frame, tmp_path, capsys, odd, what):
    write_series(tmp_path / "d", ["m_1.tif", "m_2.tif", "m_4.tif"], base_frame)
    tifffile.imwrite(tmp_path / "d" / "m_3.tif", odd)
    rc, out, err = _recon(capsys, tmp_path / "d", *_opts(calib, tmp_path / "v"))
    _refused(rc, out, err, "mixed series", "m_3.tif", "m_1.tif", what)
    assert not (tmp_path / "v").exists()


def test_bit_depth_and_stack_checks():
    from recon.frames import TiffHeader, check_uniform

    a = TiffHeader(1, (8, 8), "uint16", 16)
    b = TiffHeader(1, (8, 8), "uint16", 12)
    check_uniform([(Path("a.tif"), a), (Path("c.tif"), a)])
    with pytest.raises(InputError, match=r"'b.tif' differs .* 'a.tif' in bit depth 12, not 16"):
        check_uniform([(Path("a.tif"), a), (Path("b.tif"), b)])


def test_library_takes_paths_and_refuses_a_stack_as_one_frame(base_frame, tmp_path):
    from recon.calibration import LensletGrid as Grid
    from recon.frames import FrameRef
    from recon.pipeline import reconstruct_series

    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.stack([base_frame] * 2), photometric="minisblack")
    grid = Grid(15.0, 0.0, (157.5, 157.5), (300, 300))
    from lfsim import small_optics

    kw = {"optics": small_optics(), "grid": grid, "progress": False}
    with pytest.raises(InputError, match=r"stack\.tif' is a stack of 2 images"):
        reconstruct_series([stack], tmp_path / "v", **kw)
    with pytest.raises(InputError, match=r"stack.tif \[page 2\]'.* only 2 page"):
        reconstruct_series([FrameRef(stack, 2)], tmp_path / "v", **kw)
    assert not (tmp_path / "v").exists()
    assert FrameRef.of(tmp_path / "img_0042.tif").number == 42


def test_other_inputs_are_refused_and_a_shorter_run_is_extended(
    calib, base_frame, tmp_path, capsys
):
    names = [f"r_{k}.tif" for k in range(1, 5)]
    scale = write_series(tmp_path / "a", names, base_frame)
    vol = tmp_path / "v"
    rc, _, err = _recon(capsys, tmp_path / "a", "--frames", "0:2", *_opts(calib, vol))
    assert rc == 0, err
    before = {p.name: p.read_bytes() for p in vol.glob("*.tif")}
    # The whole series extends the first two frames.
    rc, out, err = _recon(capsys, tmp_path / "a", *_opts(calib, vol), quiet=False)
    assert rc == 0 and "2 volume(s) reconstructed, 2 already done" in out, err
    _check_mapping(vol, names, scale)
    assert all((vol / n).read_bytes() == b for n, b in before.items())
    # Other frames into the same folder: refused, nothing touched.
    snapshot = {p.name: p.read_bytes() for p in vol.iterdir()}
    rc, out, err = _recon(capsys, tmp_path / "a", "--frames", "1:3", *_opts(calib, vol))
    _refused(rc, out, err, "other inputs", "000000.tif", "r_1.tif", "r_2.tif", "--overwrite")
    rc, out, err = _recon(capsys, tmp_path / "a", "--frames", "0:2", *_opts(calib, vol))
    _refused(rc, out, err, "other inputs", "000002.tif", "this run has 2 frame(s)")
    assert {p.name: p.read_bytes() for p in vol.iterdir()} == snapshot
    # With --overwrite: the folder then holds exactly this run.
    rc, _, err = _recon(
        capsys, tmp_path / "a", "--frames", "1:3", *_opts(calib, vol), "--overwrite"
    )
    assert rc == 0, err
    _check_mapping(vol, ["r_2.tif", "r_3.tif"], scale)
    assert sorted(p.name for p in vol.glob("*.tif")) == ["000000.tif", "000001.tif"]


def test_frames_given_twice_or_numbered_alike_are_refused(calib, base_frame, tmp_path, capsys):
    from lfsim.io import read_json

    write_series(tmp_path / "fx", ["img_0.tif", "img_1.tif"], base_frame)
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.stack([base_frame] * 2), photometric="minisblack")
    vol = tmp_path / "v"
    # A stack's pages (numbered 0, 1) and a file numbered 0 by its name.
    _refused(
        *_recon(capsys, stack, tmp_path / "fx" / "img_0.tif", *_opts(calib, vol)),
        f"{stack} [page 0]",
        "img_0.tif",
        "both carry frame number 0",
    )
    # Two files of other folders numbered alike.
    tifffile.imwrite(tmp_path / "img_1.tif", base_frame)
    _refused(
        *_recon(capsys, tmp_path / "fx", tmp_path / "img_1.tif", *_opts(calib, vol)),
        "img_1.tif",
        "both carry frame number 1",
    )
    # A frame listed twice in a list file.
    lst = tmp_path / "list.txt"
    lst.write_text("fx/img_0.tif\nfx/img_1.tif\n# again\n./fx/img_0.tif\n")
    _refused(
        *_recon(capsys, lst, *_opts(calib, vol)), "list.txt", "img_0.tif", "twice (lines 1 and 4)"
    )
    # A file given twice: explicitly, or as a folder and a file in it; a stack given twice.
    for args in (
        [tmp_path / "fx" / "img_1.tif", tmp_path / "fx" / "img_1.tif"],
        [tmp_path / "fx", tmp_path / "fx" / "img_1.tif"],
        [stack, stack],
    ):
        rc, out, err = _recon(capsys, *args, *_opts(calib, vol))
        _refused(rc, out, err, str(args[-1]), "given twice")
        assert "also as" not in err  # the same path twice: named once
    rc, out, err = _recon(
        capsys, tmp_path / "fx", tmp_path / "fx" / ".." / "fx" / "img_1.tif", *_opts(calib, vol)
    )
    _refused(rc, out, err, "given twice (also as", str(tmp_path / "fx" / "img_1.tif"))
    assert not vol.exists()
    # Numbers that do not collide are kept: pages 0, 1, then the file numbered 7.
    tifffile.imwrite(tmp_path / "img_7.tif", base_frame)
    rc, _, err = _recon(capsys, stack, tmp_path / "img_7.tif", *_opts(calib, vol))
    assert rc == 0, err
    assert [f["number"] for f in read_json(vol / "recon.json")["frames"]] == [0, 1, 7]


def test_output_inside_the_folder_of_a_pattern_or_list_is_refused(
    calib, base_frame, tmp_path, capsys
):
    write_series(tmp_path / "fx", ["img_0.tif", "img_1.tif"], base_frame)
    lst = tmp_path / "list.txt"
    lst.write_text("fx/img_0.tif\nfx/img_1.tif\n")
    for frames in (tmp_path / "fx", tmp_path / "fx" / "img_*.tif", lst):
        out = tmp_path / "fx" / "v"
        _refused(
            *_recon(capsys, frames, *_opts(calib, out), "--overwrite"),
            f"-o {out} lies inside the input folder {tmp_path / 'fx'}",
        )
        assert not out.exists()
    # An explicit file's folder is not an input folder: `recon run img.tif -o v` is usual.
    rc, _, err = _recon(capsys, tmp_path / "fx" / "img_0.tif", *_opts(calib, tmp_path / "fx" / "v"))
    assert rc == 0, err


def test_camera_numbers_and_times_agree_in_recon_json_and_volumes(
    calib, base_frame, tmp_path, capsys
):
    """Frames numbered 0, 1, 5 by the camera keep their numbers and times (number / fps) in
    recon.json and in each volume's metadata; a resume with another --fps is refused (the kept
    volumes hold the earlier times), --overwrite writes the new times everywhere."""
    from lfsim.io import read_json, read_tiff

    write_series(tmp_path / "fx", ["img_0.tif", "img_1.tif", "img_5.tif"], base_frame)
    vol = tmp_path / "v"

    def recorded(fps: float) -> None:
        frames = read_json(vol / "recon.json")["frames"]
        assert [(f["index"], f["number"]) for f in frames] == [(0, 0), (1, 1), (2, 5)]
        assert [f["time_s"] for f in frames] == [n / fps for n in (0, 1, 5)]
        for f in frames:
            meta = read_tiff(vol / f"{f['index']:06d}.tif")[1]
            assert (meta["frame"], meta["number"], meta["time_s"]) == (
                f["index"],
                f["number"],
                f["time_s"],
            )

    rc, _, err = _recon(capsys, tmp_path / "fx", "--fps", "100", *_opts(calib, vol))
    assert rc == 0, err
    recorded(100.0)
    before = {p.name: p.read_bytes() for p in vol.iterdir()}
    _refused(
        *_recon(capsys, tmp_path / "fx", "--fps", "50", *_opts(calib, vol)),
        "volume 000001.tif",
        "time 0.01 s",
        "0.02 s",
        "--fps 100 then, 50 now",
        "--overwrite",
    )
    _refused(
        *_recon(capsys, tmp_path / "fx", *_opts(calib, vol)),
        "volume 000000.tif",
        "time 0 s, this run unknown (--fps 100 then, none now)",
    )
    assert {p.name: p.read_bytes() for p in vol.iterdir()} == before
    rc, _, err = _recon(capsys, tmp_path / "fx", "--fps", "50", "--overwrite", *_opts(calib, vol))
    assert rc == 0, err
    recorded(50.0)
    # The same frame rate resumes.
    rc, out, err = _recon(capsys, tmp_path / "fx", "--fps", "50", *_opts(calib, vol), quiet=False)
    assert rc == 0 and "0 volume(s) reconstructed, 3 already done" in out, err


@pytest.mark.parametrize(
    ("fps", "what"),
    [
        ("1e-320", "not a finite number"),
        ("inf", "finite number > 0"),
        ("-inf", "finite number > 0"),
        ("0", "finite number > 0"),
        ("fast", "invalid float value: 'fast'"),
    ],
)
def test_fps_must_give_finite_times(calib, base_frame, tmp_path, capsys, fps, what):
    write_series(tmp_path / "fx", ["img_0.tif", "img_1.tif"], base_frame)
    out = tmp_path / "v"
    _refused(*_recon(capsys, tmp_path / "fx", f"--fps={fps}", *_opts(calib, out)), "--fps", what)
    assert not out.exists()


def test_a_changed_input_frame_is_refused_saying_what_changed(calib, base_frame, tmp_path, capsys):
    import os

    from lfsim.io import read_json

    write_series(tmp_path / "fx", ["img_0.tif", "img_1.tif"], base_frame)
    vol = tmp_path / "v"
    rc, _, err = _recon(capsys, tmp_path / "fx", *_opts(calib, vol))
    assert rc == 0, err
    frame = tmp_path / "fx" / "img_1.tif"
    entry = read_json(vol / "recon.json")["frames"][1]
    assert entry["input_bytes"] == frame.stat().st_size and entry["input_mtime"].endswith("Z")
    # Other pixels, same size, a later time.
    tifffile.imwrite(frame, (base_frame.astype(np.int64) * 2).astype(np.uint16))
    assert frame.stat().st_size == entry["input_bytes"]
    os.utime(frame, (2e9, 2e9))
    _refused(
        *_recon(capsys, tmp_path / "fx", *_opts(calib, vol)),
        f"volume 000001.tif was made from {str(frame)!r}, which has changed since",
        f"SHA-256 {entry['input_sha256'][:12]}… then",
        f"same size ({entry['input_bytes']} bytes)",
        f"modified {entry['input_mtime']} then, 2033-05-18T03:33:20Z now",
        "--overwrite",
    )
    # A file of another size (compressed): its size is named too.
    tifffile.imwrite(frame, base_frame, compression="zlib")
    size = frame.stat().st_size
    _refused(
        *_recon(capsys, tmp_path / "fx", *_opts(calib, vol)),
        f"{entry['input_bytes']} bytes then, {size} now",
    )


@pytest.mark.parametrize(
    ("names", "unit", "dt"),
    [
        (["img_0.tif", "img_1.tif", "img_5.tif"], None, 1.0),
        (["c_2.tif", "c_4.tif"], "second", 0.02),
    ],
)
def test_zarr_records_camera_numbers_and_times(
    calib, base_frame, tmp_path, capsys, names, unit, dt
):
    """An OME-Zarr image carries each frame's number and time (its t axis alone cannot hold
    unevenly spaced times): recon.json inside it and the group's "recon" attributes agree."""
    import json

    from lfsim.io import read_json

    write_series(tmp_path / "fx", names, base_frame)
    store = tmp_path / "v.zarr"
    rc, _, err = _recon(capsys, tmp_path / "fx", "--fps", "100", *_opts(calib, store))
    assert rc == 0, err
    numbers = [parse_frame_name(n)[1] for n in names]
    frames = read_json(store / "recon.json")["frames"]
    assert [(f["number"], f["time_s"], f["output"]["t"]) for f in frames] == [
        (n, n / 100, k) for k, n in enumerate(numbers)
    ]
    attrs = json.loads((store / ".zattrs").read_text())
    assert attrs["recon"]["frames"] == [
        {"t": k, "number": n, "time_s": n / 100} for k, n in enumerate(numbers)
    ]
    multiscale = attrs["multiscales"][0]
    assert multiscale["axes"][0].get("unit") == unit
    scale, translation = multiscale["datasets"][0]["coordinateTransformations"]
    assert scale["scale"][0] == pytest.approx(dt)
    assert translation["translation"][0] == pytest.approx(0.0 if unit is None else numbers[0] / 100)
