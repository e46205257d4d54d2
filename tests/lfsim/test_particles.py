"""Particles: validation, immutability, exact CSV round trip, CSV error messages."""

from __future__ import annotations

import numpy as np
import pytest

from lfsim.errors import ConfigError
from lfsim.particles import Particles

from ..helpers import assert_bad_file_named


def _random_particles(n=50, seed=0):
    rng = np.random.default_rng(seed)
    pos = rng.normal(scale=[300.0, 200.0, 400.0], size=(n, 3))
    pos[0] = [0.1, -0.0, 1e-300]  # awkward values: decimal non-representable, tiny
    pos[1] = [1 / 3, 2 / 3, -1e17]
    diam = rng.uniform(5.0, 25.0, n)
    bright = rng.uniform(0.0, 2.0, n)
    bright[2] = 0.0
    ids = rng.permutation(10 * n)[:n].astype(np.int64) - 7
    return Particles(pos, diam, bright, ids)


def test_defaults_and_readonly():
    p = Particles(np.zeros((4, 3)))
    assert len(p) == 4
    assert p.positions_um.dtype == np.float64
    np.testing.assert_array_equal(p.ids, np.arange(4))
    assert p.ids.dtype == np.int64
    np.testing.assert_array_equal(p.diameter_um, 15.0)
    np.testing.assert_array_equal(p.brightness, 1.0)
    with pytest.raises(ValueError):
        p.positions_um[0, 0] = 1.0


def test_copies_input():
    pos = np.ones((3, 3))
    p = Particles(pos)
    pos[0, 0] = 99.0
    assert p.positions_um[0, 0] == 1.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"positions_um": np.zeros((3, 2))}, "shape"),
        ({"positions_um": [[0, 0, np.nan]]}, "finite"),
        ({"positions_um": np.zeros((2, 3)), "diameter_um": [1.0, 0.0]}, "diameter_um"),
        ({"positions_um": np.zeros((2, 3)), "diameter_um": [1.0]}, "diameter_um"),
        ({"positions_um": np.zeros((2, 3)), "brightness": -1.0}, "brightness"),
        ({"positions_um": np.zeros((2, 3)), "ids": [1, 1]}, "unique"),
        ({"positions_um": np.zeros((2, 3)), "ids": [0.5, 1]}, "integer"),
    ],
)
def test_validation(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        Particles(**kwargs)


def test_with_positions_and_subset():
    p = _random_particles(10)
    q = p.with_positions(p.positions_um + 1.0)
    np.testing.assert_array_equal(q.positions_um, p.positions_um + 1.0)
    np.testing.assert_array_equal(q.ids, p.ids)
    np.testing.assert_array_equal(q.diameter_um, p.diameter_um)
    np.testing.assert_array_equal(q.brightness, p.brightness)
    with pytest.raises(ConfigError, match="shape"):
        p.with_positions(np.zeros((9, 3)))
    mask = np.arange(10) % 3 == 0
    s = p.subset(mask)
    assert len(s) == 4
    np.testing.assert_array_equal(s.ids, p.ids[mask])
    np.testing.assert_array_equal(s.positions_um, p.positions_um[mask])
    s2 = p.subset([9, 0])
    np.testing.assert_array_equal(s2.ids, p.ids[[9, 0]])
    with pytest.raises(ConfigError):
        p.subset(np.ones(3, dtype=bool))


def test_from_arrays_broadcasts():
    p = Particles.from_arrays(
        np.zeros((3, 3)), diameter_um=10.0, brightness=[1, 2, 3], ids=[5, 6, 7]
    )
    np.testing.assert_array_equal(p.diameter_um, [10.0, 10.0, 10.0])
    np.testing.assert_array_equal(p.brightness, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(p.ids, [5, 6, 7])


def test_csv_round_trip_exact(tmp_path):
    p = _random_particles(200)
    path = p.to_csv(tmp_path / "sub" / "truth.csv")
    assert path.read_text().splitlines()[0] == "id,x_um,y_um,z_um,diameter_um,brightness"
    q = Particles.from_csv(path)
    assert p.equals(q)
    for a, b in [
        (p.positions_um, q.positions_um),
        (p.diameter_um, q.diameter_um),
        (p.brightness, q.brightness),
        (p.ids, q.ids),
    ]:
        assert a.dtype == b.dtype
        assert np.array_equal(a, b)
    # no temporary files left behind
    assert sorted(x.name for x in path.parent.iterdir()) == ["truth.csv"]


def test_csv_empty_round_trip(tmp_path):
    p = Particles(np.zeros((0, 3)))
    q = Particles.from_csv(p.to_csv(tmp_path / "e.csv"))
    assert len(q) == 0


def test_csv_optional_columns_any_order(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_text("# hand-written\nz_um, x_um ,y_um\n\n1.5,2,3\n-4,5e1,6\n")
    p = Particles.from_csv(path, default_diameter_um=9.0, default_brightness=0.5)
    np.testing.assert_array_equal(p.positions_um, [[2.0, 3.0, 1.5], [50.0, 6.0, -4.0]])
    np.testing.assert_array_equal(p.ids, [0, 1])
    np.testing.assert_array_equal(p.diameter_um, [9.0, 9.0])
    np.testing.assert_array_equal(p.brightness, [0.5, 0.5])

    path2 = tmp_path / "ids.csv"
    path2.write_text("brightness,y_um,id,x_um,z_um\n2,1,10,0,3\n0,4,3,5,6\n")
    p2 = Particles.from_csv(path2)
    np.testing.assert_array_equal(p2.ids, [10, 3])
    np.testing.assert_array_equal(p2.brightness, [2.0, 0.0])
    np.testing.assert_array_equal(p2.diameter_um, [15.0, 15.0])
    assert Particles.from_csv(p2.to_csv(tmp_path / "again.csv")).equals(p2)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty"),
        ("x_um,y_um\n1,2\n", r"missing column.*z_um"),
        ("x_um,y_um,z_um,colour\n1,2,3,red\n", r"unknown column.*colour"),
        ("x_um,y_um,z_um,x_um\n1,2,3,4\n", "duplicated"),
        ("x_um,y_um,z_um\n1,2,3\n1,two,3\n", r"line 3, column 'y_um'.*'two'"),
        ("x_um,y_um,z_um\n1,2,nan\n", r"line 2, column 'z_um'.*finite"),
        ("x_um,y_um,z_um\n1,2,inf\n", r"line 2.*finite"),
        ("x_um,y_um,z_um\n1,2\n", r"line 2: expected 3 values"),
        ("id,x_um,y_um,z_um\n1.5,1,2,3\n", r"line 2, column 'id'.*integer"),
        ("x_um,y_um,z_um,diameter_um\n1,2,3,-1\n", "diameter_um must be > 0"),
        ("id,x_um,y_um,z_um\n1,1,2,3\n1,1,2,3\n", "unique"),
    ],
)
def test_bad_csv_names_file(tmp_path, text, match):
    assert_bad_file_named(tmp_path / "bad_table.csv", text, Particles.from_csv, ConfigError, match)


def test_missing_csv_names_file(tmp_path):
    path = tmp_path / "nope.csv"
    with pytest.raises(ConfigError, match=r"nope\.csv"):
        Particles.from_csv(path)


def test_overlaps_name_coincident_groups_and_overlapping_pairs():
    pos = np.array(
        [
            [0.0, 0.0, 150.0],
            [0.0, 0.0, 150.0],
            [100.0, 0.0, 150.0],
            [0.0, 0.0, 150.0],
            [105.0, 0.0, 150.0],  # 5 µm from row 2: overlapping 15 µm spheres
            [130.0, 0.0, 150.0],  # 25 µm from row 4: clear
        ]
    )
    coincident, overlapping = Particles(pos).overlaps()
    assert coincident == [[0, 1, 3]]
    assert overlapping == [(2, 4, pytest.approx(5.0))]
    assert Particles(pos[[0, 2, 5]]).overlaps() == ([], [])
    # the diameters decide: 4 µm beads 5 µm apart do not overlap
    assert Particles(pos[[2, 4]], diameter_um=4.0).overlaps() == ([], [])
