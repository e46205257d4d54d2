"""The linker on heterogeneous fields, and the known fields and clouds it is tested on.

Pairs come from :func:`track.synthetic.make_pair`: about 1 000 particles with a minimum
spacing (mean spacing ≈ 48 µm), both frames cropped to the same box (particles leave and
enter through the faces), 5 % missing from each frame, localisation noise σ = 0.25 µm
laterally and 2.5 µm axially. Acceptance per case: ≥ 99 % of the particles present in both
frames linked right, also within one spacing of the faces; ≤ 0.2 % wrong links (the goal is
0.5 %; none are seen); no displacement error above the noise floor.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from track.errors import InputError
from track.matching import (
    LinkSettings,
    fit_link_field,
    increment_predictor,
    link_pair,
    match_predicted,
)
from track.outliers import normalized_median_test
from track.regularize import fit_field, fit_field_refined, local_polynomial_predict
from track.synthetic import (
    FIELD_NAMES,
    HETEROGENEOUS,
    NOISE_XYZ_UM,
    make_field,
    make_pair,
    make_series,
    poisson_disc_cloud,
    score_link,
)

BOX = np.array([[0.0, 600.0], [0.0, 600.0], [0.0, 600.0]])
SPACING = 48.0


def _lattice(n=9):
    axes = [np.linspace(lo, hi, n) for lo, hi in BOX]
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T


# ----------------------------------------------------------------------------- the fields


@pytest.mark.parametrize("name", FIELD_NAMES)
def test_fields_reach_their_amplitude_and_have_exact_gradients(name):
    f = make_field(name, BOX, SPACING, 1.5 * SPACING)
    x = _lattice(25)
    peak = np.linalg.norm(f(x), axis=1).max()
    assert 0.9 * 1.5 * SPACING <= peak <= 1.001 * 1.5 * SPACING, (name, peak / SPACING)
    # analytic gradient against central differences
    h = 1e-3
    y = _lattice(6) + 7.3
    num = np.stack([(f(y + h * e) - f(y - h * e)) / (2 * h) for e in np.eye(3)], axis=2)
    assert np.allclose(f.gradient(y), num, atol=1e-6), name
    assert np.allclose(f.deform(y), y + f(y))


@pytest.mark.parametrize("name", HETEROGENEOUS)
def test_heterogeneous_gradients_grow_with_the_amplitude_to_about_0_6(name):
    steep = make_field(name, BOX, SPACING, 1.5 * SPACING).max_gradient
    mild = make_field(name, BOX, SPACING, 0.5 * SPACING).max_gradient
    assert 0.35 <= steep <= 0.75, (name, steep)
    assert mild < 0.5 * steep, (name, mild, steep)


def test_vortex_turns_45_degrees_on_its_axis_at_1_5_spacings():
    f = make_field("vortex", BOX, SPACING, 1.5 * SPACING)
    assert np.rad2deg(f.angle_rad) == pytest.approx(45.0, abs=0.1)
    g = f.gradient(np.array([[300.0, 300.0, 100.0]]))[0]  # on the axis: a rigid rotation
    c = s = np.sqrt(0.5)
    assert np.allclose(g[:2, :2] + np.eye(2), [[c, -s], [s, c]], atol=1e-3)
    assert np.allclose(g[2], 0.0) and np.allclose(g[:, 2], 0.0)


def test_stiff_inclusion_is_nearly_rigid_inside_and_stretched_far_away():
    f = make_field("stiff_inclusion", BOX, SPACING, 1.5 * SPACING)
    inside = f.gradient(np.array([[300.0, 310.0, 290.0]]))[0]
    assert np.abs(inside).max() <= 0.06 * f.strain
    far = f.gradient(np.array([[20.0, 20.0, 20.0]]))[0]
    assert far[0, 0] == pytest.approx(f.strain, rel=0.02)


def test_make_field_rejects_unknown_names_and_bad_sizes():
    with pytest.raises(InputError, match="unknown field"):
        make_field("tornado", BOX, SPACING, 10.0)
    with pytest.raises(InputError, match="amplitude_um"):
        make_field("vortex", BOX, SPACING, -1.0)
    with pytest.raises(InputError, match="bounds_xyz_um"):
        make_field("vortex", np.zeros((3, 2)), SPACING, 10.0)


# ----------------------------------------------------------------------------- the clouds


def test_poisson_disc_cloud_keeps_its_minimum_distance():
    x = poisson_disc_cloud(2000, BOX, 30.0, seed=3)
    assert x.shape == (2000, 3)
    assert np.all((x >= BOX[:, 0]) & (x <= BOX[:, 1]))
    d, _ = cKDTree(x).query(x, 2)
    assert d[:, 1].min() >= 30.0
    with pytest.raises(InputError, match="cannot place"):
        poisson_disc_cloud(2000, BOX, 120.0)


def test_make_pair_noise_drop_outs_crop_and_truth():
    p = make_pair("shear_wave_front", 1000, 1.0, seed=4)
    assert 45.0 < p.spacing_um < 52.0
    assert np.all(np.isin(p.def_ids, np.arange(p.seeds_um.shape[0])))
    for xyz in (p.ref_xyz_um, p.def_xyz_um):  # both frames hold the box's particles only
        assert np.all((xyz > p.bounds_xyz_um[:, 0] - 15) & (xyz < p.bounds_xyz_um[:, 1] + 15))
    sd = np.std(np.vstack([p.ref_noise_um, p.def_noise_um]), axis=0)
    assert np.allclose(sd, NOISE_XYZ_UM, rtol=0.1)
    assert 0.85 < p.common_ids.size / p.ref_ids.size < 0.95  # drop-outs and crossings
    t = p.true_matches()
    assert np.array_equal(p.ref_ids[t[:, 0]], p.def_ids[t[:, 1]])
    ok = score_link(p, t)
    assert ok.tracking_ratio == 1.0 and ok.n_wrong == 0 and ok.excess_rmse_spacings < 1e-6
    # raw error of right links = noise of two localisations per axis
    assert np.allclose(ok.raw_rmse_xyz_spacings, np.sqrt(2) * np.array(NOISE_XYZ_UM) / 49, 0.15)
    shifted = t.copy()
    shifted[:10, 1] = t[10:20, 1]
    bad = score_link(p, shifted)
    assert bad.n_wrong == 10 and bad.excess_rmse_spacings > 0.1


def test_series_frames_follow_the_field_step_by_step():
    s = make_series("vortex", 500, 0.5, 4, seed=2)
    assert len(s.frames_xyz_um) == 4
    p = s.pair(1, 3)
    assert np.allclose(p.true_displacement_um, 2 * s.field(s.seeds_um))
    assert score_link(p, p.true_matches()).n_wrong == 0
    with pytest.raises(InputError, match="frames"):
        s.pair(2, 2)


# ------------------------------------------------------------------------------ linking

#: The sparse grid of the family run here (10 000 particles: the benchmark).
CASES = [(name, 1.5) for name in HETEROGENEOUS] + [
    ("gaussian_indentation", 0.5),
    ("vortex", 1.0),
    ("translation", 1.5),
    ("rotation", 1.0),
    ("uniaxial_stretch", 1.5),
    ("simple_shear", 0.5),
]


@pytest.mark.parametrize(("name", "amplitude"), CASES)
def test_heterogeneous_and_homogeneous_fields_link_at_1000_particles(name, amplitude):
    p = make_pair(name, 1000, amplitude, seed=11)
    res = link_pair(p.ref_xyz_um, p.def_xyz_um)
    sc = score_link(p, res.matches, res.displacement_field)
    assert res.ok
    assert sc.tracking_ratio >= 0.99, (name, sc)
    assert sc.face_tracking_ratio >= 0.99, (name, sc)
    assert sc.wrong_fraction <= 0.002, (name, sc)
    assert sc.excess_rmse_spacings <= 0.01, (name, sc)
    # the regularised field is at the floor the true matches give (noise, resolution)
    floor = score_link(
        p, p.true_matches(), fit_link_field(p.ref_xyz_um, p.def_xyz_um, p.true_matches())
    )
    for got, best in zip(sc.field_rmse_xyz_spacings, floor.field_rmse_xyz_spacings, strict=True):
        assert got <= 1.2 * best + 0.002, (name, sc.field_rmse_xyz_spacings, floor)


def test_the_old_linker_lost_a_third_of_a_steep_shear_band_this_one_none():
    """Sinusoidal shear, gradient 0.6: the warp-and-match loop linked 63 % (all right)."""
    p = make_pair("sinusoidal_shear", 1000, 1.5, seed=1)
    res = link_pair(p.ref_xyz_um, p.def_xyz_um)
    sc = score_link(p, res.matches, res.displacement_field)
    assert sc.tracking_ratio >= 0.995 and sc.n_wrong == 0
    assert sc.field_rmse_xyz_spacings[0] < 0.03  # 0.18 with the 2-spacing grid alone
    assert res.history[-1].matcher == "polish"
    assert all(
        h.matcher in ("topology", "topology-moment", "nearest", "local", "polish")
        for h in res.history
    )


def test_anisotropic_noise_keeps_every_particle_of_a_translation():
    """Axial noise 10 × lateral: one scalar noise level rejected 8 % of right links."""
    p = make_pair("translation", 1000, 1.0, seed=5)
    res = link_pair(p.ref_xyz_um, p.def_xyz_um)
    assert score_link(p, res.matches).tracking_ratio >= 0.998
    fixed = link_pair(p.ref_xyz_um, p.def_xyz_um, LinkSettings(outlier_eps_xyz_um=(0.5, 0.5, 5.0)))
    assert score_link(p, fixed.matches).tracking_ratio >= 0.998


@pytest.mark.slow
def test_steep_vortex_10000_particles():
    p = make_pair("vortex", 10_000, 1.5, seed=12)
    res = link_pair(p.ref_xyz_um, p.def_xyz_um)  # its time: benchmarks/bench_heterogeneous.py
    sc = score_link(p, res.matches)
    assert sc.tracking_ratio >= 0.995 and sc.face_tracking_ratio >= 0.99 and sc.n_wrong == 0


# ---------------------------------------------------------------------- series predictor


def test_previous_increment_predicts_the_next_one():
    s = make_series("vortex", 1000, 1.5, 3, seed=5)
    first = link_pair(s.frames_xyz_um[0], s.frames_xyz_um[1])
    p = s.pair(1, 2)
    guess = increment_predictor(first.displacement_field)
    # the guess alone already puts most particles within a tenth of a spacing
    err = guess(p.ref_xyz_um) - p.true_displacement_um[p.ref_ids]
    assert np.median(np.linalg.norm(err, axis=1)) < 0.1 * p.spacing_um
    res = link_pair(p.ref_xyz_um, p.def_xyz_um, initial_guess=guess)
    sc = score_link(p, res.matches)
    assert res.history[0].matcher == "nearest"
    assert res.history[0].n_matches >= 0.8 * sc.n_common  # no bootstrap needed
    assert sc.tracking_ratio >= 0.99 and sc.n_wrong == 0


def test_a_wrong_guess_falls_back_to_the_bootstrap():
    p = make_pair("stiff_inclusion", 1000, 1.0, seed=6)
    s = p.spacing_um
    res = link_pair(p.ref_xyz_um, p.def_xyz_um, initial_guess=lambda x: np.full(x.shape, 2.3 * s))
    sc = score_link(p, res.matches)
    assert res.history[0].matcher == "nearest"
    assert res.history[1].matcher in ("topology", "topology-moment", "nearest")
    assert sc.tracking_ratio >= 0.99 and sc.n_wrong == 0


def test_increment_predictor_follows_material_points():
    step = np.array([10.0, 0.0, 0.0])

    def previous(x):  # a shear: displacement grows with y
        return np.outer(x[:, 1] / 100.0, step)

    y = np.array([[0.0, 100.0, 0.0], [5.0, 300.0, 1.0]])
    lag = increment_predictor(previous)(y)
    eul = increment_predictor(previous, lagrangian=False)(y)
    assert np.allclose(eul, previous(y))
    assert np.allclose(lag, previous(y))  # shear along x does not move y
    assert np.allclose(increment_predictor(previous, scale=0.5)(y), 0.5 * previous(y))
    with pytest.raises(InputError, match="callable"):
        increment_predictor(np.zeros(3))


# ------------------------------------------------------------------------ the building blocks


def test_median_test_uses_per_axis_noise_levels():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 500, (600, 3))
    u = rng.normal(0, 1, x.shape) * [0.3, 0.3, 3.0]
    u[:20, 0] += 3.0  # lateral outliers, as large as one axial σ
    iso = normalized_median_test(x, u, 10, 3.0, eps_um=3.0)
    per_axis = normalized_median_test(x, u, 10, 3.0, eps_um=[0.3, 0.3, 3.0])
    assert per_axis[:20].sum() <= 2 and iso[:20].sum() >= 10
    assert per_axis[20:].mean() >= 0.98
    rows = normalized_median_test(x, u, 10, 3.0, eps_um=np.full(x.shape, 0.5))
    assert rows.shape == (600,)
    with pytest.raises(InputError, match="eps_um"):
        normalized_median_test(x, u, eps_um=[1.0, 2.0])


def test_local_polynomial_fits_are_exact_for_their_degree():
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 10, (400, 3))
    a = np.array([[0.1, -0.3, 0.2], [0.0, 0.5, 0.1], [0.2, 0.0, -0.1]])
    lin = x @ a.T + [1.0, 2.0, 3.0]
    q = rng.uniform(2, 8, (50, 3))
    lp = local_polynomial_predict(x, lin, q, 12, 5.0, scale_um=1.5, ridge=0.0)
    assert np.allclose(lp.values_um, q @ a.T + [1.0, 2.0, 3.0], atol=1e-8)
    assert np.all(lp.misfit_um < 1e-8) and np.all(lp.degree == 1)
    quad = np.column_stack([x[:, 0] ** 2, x[:, 1] * x[:, 2], x[:, 2]])
    lq = local_polynomial_predict(x, quad, q, 25, 5.0, scale_um=1.5, ridge=0.0, degree=2)
    assert np.allclose(lq.values_um, np.column_stack([q[:, 0] ** 2, q[:, 1] * q[:, 2], q[:, 2]]))
    # leave-one-out: the excluded point is not used; no neighbour -> misfit inf
    self_ex = local_polynomial_predict(x, lin, x[:5], 12, 5.0, exclude=np.arange(5))
    assert np.all(self_ex.n_neighbors == 12)
    lone = local_polynomial_predict(x, lin, [[100.0, 100.0, 100.0]], 12, 5.0)
    assert lone.n_neighbors[0] == 0 and np.all(np.isinf(lone.misfit_um))
    with pytest.raises(InputError, match="degree"):
        local_polynomial_predict(x, lin, q, degree=3)


def test_refined_field_keeps_homogeneous_fields_and_resolves_a_shear_band():
    for name, corrected in (("simple_shear", False), ("sinusoidal_shear", True)):
        p = make_pair(name, 1000, 1.5, seed=7)
        t = p.true_matches()
        x = p.ref_xyz_um[t[:, 0]]
        u = p.def_xyz_um[t[:, 1]] - x
        b = np.column_stack([p.ref_xyz_um.min(0), p.ref_xyz_um.max(0)])
        f = fit_field_refined(fit_field(x, u, b, 2 * p.spacing_um), x, u, length_um=p.spacing_um)
        assert np.isfinite(f.scale_um[0]) == corrected, name
        assert not np.isfinite(f.scale_um[2])  # the noisy axial component stays smooth
        xt = p.seeds_um[p.common_ids]
        err = np.sqrt(np.mean((f(xt) - p.true_displacement_um[p.common_ids]) ** 2, axis=0))
        coarse = np.sqrt(
            np.mean((f.coarse(xt) - p.true_displacement_um[p.common_ids]) ** 2, axis=0)
        )
        assert np.all(err <= coarse * 1.001)
        if corrected:
            assert err[0] < 0.2 * coarse[0]


def test_match_predicted_uses_anisotropic_ellipsoids_and_refuses_ambiguity():
    warped = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    dfm = np.array(
        [
            [0.5, 0.0, 8.0],  # inside (1, 1, 10) semi-axes: q ≈ 0.94
            [100.0, 0.0, 3.0],  # two candidates for particle 1
            [100.0, 0.0, -3.5],
            [203.0, 0.0, 0.0],  # outside laterally: q = 3
        ]
    )
    tol = np.tile([1.0, 1.0, 10.0], (3, 1))
    pairs, q = match_predicted(warped, dfm, tol, 0.5)
    assert pairs.tolist() == [[0, 0]]
    assert q[0] == pytest.approx(np.hypot(0.5, 0.8))
