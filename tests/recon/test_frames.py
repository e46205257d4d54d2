"""Frame series of `recon run`: natural order, gaps, refusals, the frame → file record."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import tifffile

from recon import LensletGrid, synthetic_white
from recon.cli import main
from recon.errors import InputError
from recon.frames import format_numbers, natural_order, parse_frame_name

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "scenes" / "small.xml"

#: A fast reconstruction: 3 depths, 1 voxel per lenslet, 1 iteration, no background guess
#: (so that a frame scaled by n gives a volume scaled by n).
FAST = [
    "--z-range",
    "100:200",
    "--z-step",
    "50",
    "-s",
    "1",
    "--iterations",
    "1",
    "--rays-per-pattern",
    "20000",
    "--background",
    "none",
]


def run(capsys, *args):
    rc = main(["-q", *map(str, args)])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.fixture(scope="module")
def psf_cache(tmp_path_factory):
    """A private PSF cache for this module (never the user's)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HRVPTM_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def base_frame() -> np.ndarray:
    """Integer light-field-like pixels of the small scene's 300 × 300 px sensor."""
    grid = LensletGrid(15.0, 0.0, (157.5, 157.5), (300, 300))
    img = synthetic_white((300, 300), grid, noise_sigma=0.02, rng=5)
    return np.rint(50 + 1000 * np.clip(img, 0, None)).astype(np.uint16)


@pytest.fixture(scope="module")
def calib(backend, psf_cache, base_frame, tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("calib")
    white = d / "white.tif"
    tifffile.imwrite(white, base_frame)
    out = d / "calib.json"
    assert main(["-q", "calibrate", str(white), "--scene", str(SCENE), "-o", str(out)]) == 0
    return out


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
