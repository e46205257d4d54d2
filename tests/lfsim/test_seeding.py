"""Seeding: minimum spacing, box bounds, reproducibility, impossible requests, speed, specs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial import cKDTree

from lfsim.errors import ConfigError
from lfsim.particles import Particles
from lfsim.seeding import SeedingSpec, count_from_density, seed_box, seed_layer

BOX = ((-200.0, 200.0), (-150.0, 150.0), (0.0, 300.0))


def _min_distance(pos):
    d, _ = cKDTree(pos).query(pos, k=2)
    return d[:, 1].min()


def _inside(pos, box):
    b = np.asarray(box)
    return np.all(pos >= b[:, 0]) and np.all(pos < b[:, 1])


def test_seed_box_spacing_and_bounds():
    pos = seed_box(300, BOX, 30.0, np.random.default_rng(1))
    assert pos.shape == (300, 3)
    assert pos.dtype == np.float64
    assert _min_distance(pos) >= 30.0
    assert _inside(pos, BOX)


def test_seed_box_dense_still_respects_spacing():
    # volume fraction of the exclusion spheres ~ 0.2: many rejections, still exact spacing
    box = ((0.0, 200.0),) * 3
    n = int(0.2 * 200.0**3 / (np.pi / 6 * 20.0**3))
    pos = seed_box(n, box, 20.0, np.random.default_rng(2))
    assert len(pos) == n
    assert _min_distance(pos) >= 20.0
    assert _inside(pos, box)


def test_seed_box_reproducible():
    a = seed_box(100, BOX, 15.0, np.random.default_rng(42))
    b = seed_box(100, BOX, 15.0, np.random.default_rng(42))
    c = seed_box(100, BOX, 15.0, np.random.default_rng(43))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_seed_box_uniform_marginals():
    """Each coordinate is uniform over its range: a Kolmogorov–Smirnov test per axis (the
    whole distribution, not only its mean) at the 1 % level, fixed seed. With 4 000 points
    it refuses a marginal whose CDF departs from the uniform one by more than about
    1.63 / sqrt(4000) = 0.026 anywhere, e.g. points crowding a face or the centre."""
    box = ((0.0, 1000.0), (-300.0, 300.0), (50.0, 450.0))
    pos = seed_box(4000, box, 15.0, np.random.default_rng(3))
    for axis, (lo, hi) in enumerate(box):
        res = stats.kstest(pos[:, axis], "uniform", args=(lo, hi - lo))
        assert res.pvalue > 0.01, (axis, res)
    # the test can fail: the same points squeezed towards the middle of x are refused
    squeezed = 500.0 + 0.9 * (pos[:, 0] - 500.0)
    assert stats.kstest(squeezed, "uniform", args=(0.0, 1000.0)).pvalue < 1e-6


def test_seed_box_impossible_by_packing():
    with pytest.raises(ConfigError, match=r"1000 particles.*placed 0.*at most"):
        seed_box(1000, ((0.0, 50.0),) * 3, 15.0, np.random.default_rng(0))


def test_seed_box_gives_up_and_says_how_many():
    # below the densest packing, far above what random throwing reaches in 2000 tries
    with pytest.raises(ConfigError, match=r"placed only \d+ after 2000") as info:
        seed_box(60, ((0.0, 60.0),) * 3, 15.0, np.random.default_rng(0), max_tries=2000)
    assert "placed only 60 " not in str(info.value)


def test_seed_box_zero_spacing_and_zero_count():
    pos = seed_box(10, BOX, 0.0, np.random.default_rng(0))
    assert pos.shape == (10, 3) and _inside(pos, BOX)
    assert seed_box(0, BOX, 15.0, np.random.default_rng(0)).shape == (0, 3)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((-1, BOX, 15.0), "count"),
        ((5, ((0, 1), (0, 1)), 15.0), "bounds_xyz_um"),
        ((5, ((0, 1), (0, 1), (2, 1)), 15.0), "lo <= hi"),
        ((5, BOX, -1.0), "min_spacing_um"),
    ],
)
def test_seed_box_bad_arguments(args, match):
    with pytest.raises(ConfigError, match=match):
        seed_box(*args, np.random.default_rng(0))


def test_seed_10000():
    """A paper-size seeding (its time: benchmarks/bench_seeding.py)."""
    box = ((-1000.0, 1000.0), (-700.0, 700.0), (-80.0, 720.0))
    pos = seed_box(10_000, box, 15.0, np.random.default_rng(5))
    assert pos.shape == (10_000, 3)
    assert _min_distance(pos) >= 15.0
    assert _inside(pos, box)


def test_seed_layer():
    pos = seed_layer(80, ((-300.0, 300.0), (-200.0, 200.0)), 160.0, 20.0, np.random.default_rng(7))
    assert pos.shape == (80, 3)
    assert np.all(pos[:, 2] == 160.0)
    assert _min_distance(pos) >= 20.0
    assert _inside(pos[:, :2], ((-300.0, 300.0), (-200.0, 200.0)))
    with pytest.raises(ConfigError, match="densest packing"):
        seed_layer(10_000, ((0.0, 100.0), (0.0, 100.0)), 0.0, 15.0, np.random.default_rng(0))


def test_count_from_density():
    # 1 mm³ box at 50 per mm³
    assert count_from_density(50.0, ((0.0, 1000.0),) * 3) == 50
    assert count_from_density(100.0, ((0, 500), (0, 400), (0, 300))) == 6  # 0.06 mm³
    with pytest.raises(ConfigError, match="density_per_mm3"):
        count_from_density(-1.0, ((0, 1),) * 3)


def test_spec_box_make():
    spec = SeedingSpec.from_dict(
        {"kind": "box", "count": 60, "bounds_xyz_um": [list(r) for r in BOX]}
    )
    assert spec.min_spacing_um is None and spec.diameter_um == 15.0
    p = spec.make(np.random.default_rng(0))
    assert isinstance(p, Particles) and len(p) == 60
    np.testing.assert_array_equal(p.ids, np.arange(60))
    np.testing.assert_array_equal(p.diameter_um, 15.0)
    np.testing.assert_array_equal(p.brightness, 1.0)
    assert _min_distance(p.positions_um) >= 15.0
    assert p.equals(spec.make(np.random.default_rng(0)))
    # same positions as the plain function with the same generator
    np.testing.assert_array_equal(p.positions_um, seed_box(60, BOX, 15.0, np.random.default_rng(0)))
    assert SeedingSpec.from_dict(spec.to_dict()) == spec


def test_spec_density_layer_and_jitter():
    spec = SeedingSpec(
        kind="layer",
        density_per_mm3=1000.0,
        bounds_xyz_um=((-250.0, 250.0), (-200.0, 200.0), (150.0, 250.0)),
        z_um=160.0,
        min_spacing_um=25.0,
        brightness=2.0,
        brightness_jitter=0.1,
    )
    assert spec.n_particles == 20  # 0.5 * 0.4 * 0.1 mm³ * 1000
    p = spec.make(np.random.default_rng(3))
    assert len(p) == 20
    assert np.all(p.positions_um[:, 2] == 160.0)
    assert _min_distance(p.positions_um) >= 25.0
    assert np.all(p.brightness >= 0) and np.std(p.brightness) > 0
    assert abs(np.mean(p.brightness) - 2.0) < 4 * 0.2 / np.sqrt(20)


def test_spec_csv(tmp_path):
    src = Particles(np.arange(12.0).reshape(4, 3), diameter_um=[10, 11, 12, 13], ids=[3, 4, 5, 6])
    src.to_csv(tmp_path / "parts.csv")
    spec = SeedingSpec.from_dict({"kind": "csv", "csv": "parts.csv"}, base_dir=tmp_path)
    assert spec.make(np.random.default_rng(0)).equals(src)


@pytest.mark.parametrize(
    ("d", "match"),
    [
        (
            {"kind": "box", "count": 5, "bounds_xyz_um": BOX, "colour": "red"},
            r"unknown seeding key.*colour",
        ),
        ({"count": 5, "bounds_xyz_um": BOX}, "kind"),
        ({"kind": "sphere", "count": 5, "bounds_xyz_um": BOX}, "kind"),
        ({"kind": "box", "bounds_xyz_um": BOX}, "exactly one of 'count' and 'density_per_mm3'"),
        ({"kind": "box", "count": 5, "density_per_mm3": 3.0, "bounds_xyz_um": BOX}, "exactly one"),
        ({"kind": "box", "count": 5}, "bounds_xyz_um"),
        ({"kind": "box", "count": 5, "bounds_xyz_um": BOX, "z_um": 3.0}, "z_um"),
        ({"kind": "layer", "count": 5, "bounds_xyz_um": BOX[:2]}, "z_um"),
        ({"kind": "layer", "density_per_mm3": 5.0, "bounds_xyz_um": BOX[:2], "z_um": 0}, "z range"),
        ({"kind": "box", "count": 5, "bounds_xyz_um": BOX, "diameter_um": 0}, "diameter_um"),
        ({"kind": "box", "count": 5, "bounds_xyz_um": BOX, "brightness_jitter": -1}, "jitter"),
        ({"kind": "box", "count": 2.5, "bounds_xyz_um": BOX}, "count"),
        ({"kind": "csv"}, "'csv'"),
        ({"kind": "csv", "csv": "a.csv", "count": 3}, r"does not take \['count'\]"),
    ],
)
def test_spec_errors(d, match):
    with pytest.raises(ConfigError, match=match):
        SeedingSpec.from_dict(d)
