"""Standard uncertainties through track: tables, per-match σ, noise floor; series predictor."""

from __future__ import annotations

import numpy as np
import pytest

from track.errors import InputError
from track.matching import link_pair
from track.pipeline import track_clouds
from track.series import (
    SeriesSettings,
    bias_decorrelation,
    link_pairs,
    match_sigma,
    noise_floor,
)
from track.synthetic import make_series, score_link
from track.tables import (
    read_match_sigmas,
    read_matches_csv,
    read_point_sigmas,
    read_points_csv,
    read_tracks_csv,
    write_points_csv,
)


def test_point_table_sigma_round_trip_and_old_tables(tmp_path):
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    sig = np.array([[0.1, 0.2, 0.3], [0.4, np.nan, 0.6]])
    p = write_points_csv(tmp_path / "a.csv", xyz, np.ones(2), sigma_xyz_um=sig)
    assert p.read_text().splitlines()[0].endswith("sigma_x_um,sigma_y_um,sigma_z_um")
    np.testing.assert_array_equal(read_points_csv(p), xyz)
    np.testing.assert_array_equal(read_point_sigmas(p), sig)
    old = write_points_csv(tmp_path / "old.csv", xyz)  # a table from before the σ columns
    assert np.all(np.isnan(read_point_sigmas(old))) and read_point_sigmas(old).shape == (2, 3)
    with pytest.raises(InputError, match="negative"):
        write_points_csv(tmp_path / "b.csv", xyz, sigma_xyz_um=-sig)
    with pytest.raises(InputError, match="1 uncertainties for 2"):
        write_points_csv(tmp_path / "c.csv", xyz, sigma_xyz_um=sig[:1])
    bad = tmp_path / "bad.csv"
    bad.write_text("x_um,y_um,z_um,sigma_x_um,sigma_y_um,sigma_z_um\n1,2,3,0.1,-1,0.1\n")
    with pytest.raises(InputError, match="uncertainties must be >= 0"):
        read_point_sigmas(bad)


def test_match_sigma_adds_in_quadrature_and_removes_the_shared_part():
    sa = np.array([[0.3, 0.4, 1.0], [0.1, 0.1, 0.1]])
    sb = np.array([[0.4, 0.3, 1.0]])
    m = np.array([[0, 0]])
    np.testing.assert_allclose(match_sigma(m, sa, sb), [[0.5, 0.5, np.sqrt(2.0)]])
    # a shared (systematic) part s of each σ cancels: sqrt(σa² + σb² − 2 s²)
    np.testing.assert_allclose(match_sigma(m, sa, sb, (0.0, 0.0, 1.0)), [[0.5, 0.5, 0.0]])
    # a bias that decorrelates as the particle moves: + 2 b² (1 − exp(−|u|²/2L²))
    b = (0.0, 0.0, 2.0)
    u = np.array([[3.0, 4.0, 0.0]])
    rho = np.exp(-0.5 * 25.0 / 5.0**2)
    got = match_sigma(m, sa, sb, (0.0, 0.0, 1.0), displacement_um=u, bias_sigma_xyz_um=b)
    np.testing.assert_allclose(got, [[0.5, 0.5, np.sqrt(8.0 * (1 - rho))]])
    still = match_sigma(m, sa, sb, displacement_um=0 * u, bias_sigma_xyz_um=b)
    np.testing.assert_allclose(still, match_sigma(m, sa, sb))
    with pytest.raises(InputError, match="bias_sigma_um"):
        SeriesSettings(bias_sigma_um=(1.0, -1.0, 0.0))
    with pytest.raises(InputError, match="bias_length_um"):
        SeriesSettings(bias_length_um=0.0)
    assert SeriesSettings(bias_length_um=2).bias_length_um == (2.0, 2.0, 2.0)
    # per-axis lengths: a move along z only barely changes a bias with a long z length
    u = np.array([[0.0, 0.0, 3.0]])
    got = match_sigma(
        m, sa, sb, displacement_um=u, bias_sigma_xyz_um=b, bias_length_xyz_um=(1, 1, 30.0)
    )
    np.testing.assert_allclose(got[0, 2], np.sqrt(2.0 + 8.0 * (1 - np.exp(-0.5 * 0.01))))


def test_the_lenslet_periodic_bias_follows_each_coordinates_own_phase():
    """With a lateral period P (the lenslet pitch in the object) the bias comes back after a
    move of one pitch, changes most at half a pitch, is Gaussian for small moves, and a
    lateral coordinate's bias ignores moves along the other lateral axis; the axial one
    follows both. Without a period it is the isotropic Gaussian."""

    L, P = (4.0, 3.0, 10.0), 25.0  # x, y, z
    u = np.array(
        [
            [25.0, 0.0, 0.0],  # one pitch along x
            [12.5, 0.0, 0.0],  # half a pitch along x
            [0.0, 12.5, 0.0],  # half a pitch along y
            [0.2, 0.0, 0.0],  # small
            [0.0, 0.0, 10.0],  # in depth only
            [12.5, 50.0, 0.0],
        ]
    )
    omr = bias_decorrelation(u, L, P)
    half_x = 1 - np.exp(-0.5 * (P / (np.pi * 4.0)) ** 2)
    half_y = 1 - np.exp(-0.5 * (P / (np.pi * 3.0)) ** 2)
    np.testing.assert_allclose(omr[0], [0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(omr[1], [half_x, 0.0, half_x])
    np.testing.assert_allclose(omr[2], [0.0, half_y, half_y])
    small = 1 - np.exp(-0.5 * (0.2 / 4.0) ** 2)  # the Gaussian of a small move
    np.testing.assert_allclose(omr[3], [small, 0.0, small], rtol=1e-3)
    depth = 1 - np.exp(-0.5)
    np.testing.assert_allclose(omr[4], [depth, depth, depth])
    np.testing.assert_allclose(omr[5], [half_x, 0.0, half_x], atol=1e-12)  # 50 µm = 2 P in y
    # without a period: every coordinate's bias changes with a move along any axis
    iso = bias_decorrelation(u, L)
    rho = np.exp(-0.5 * np.sum((u / np.asarray(L)) ** 2, axis=1))
    np.testing.assert_allclose(iso, np.repeat((1 - rho)[:, None], 3, axis=1))
    # through match_sigma and the settings
    m, s0 = np.array([[0, 0]]), np.zeros((1, 3))
    got = match_sigma(
        m,
        s0,
        s0,
        displacement_um=u[1:2],
        bias_sigma_xyz_um=(1.0, 1.0, 2.0),
        bias_length_xyz_um=L,
        bias_period_um=P,
    )
    np.testing.assert_allclose(got, np.sqrt(2 * np.array([[1.0, 0.0, 4.0]]) * omr[1]))
    assert SeriesSettings(bias_period_um=25).bias_period_um == 25.0
    for bad in (-1.0, float("inf"), "25", True):
        with pytest.raises(InputError, match="bias_period_um"):
            SeriesSettings(bias_period_um=bad)


def test_the_lateral_bias_may_change_more_slowly_with_depth():
    """A fourth length ``L_z,lat``: the lateral coordinates' depth factor, the axial one kept;
    the settings give it (unset: the z length, as before)."""
    L, P = (4.0, 3.0, 5.0), 25.0
    u = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 40.0], [12.5, 0.0, 5.0]])
    same = bias_decorrelation(u, L, P)
    np.testing.assert_allclose(bias_decorrelation(u, (*L, 5.0), P), same)
    slow = bias_decorrelation(u, (*L, 50.0), P)
    np.testing.assert_allclose(slow[:, 2], same[:, 2])  # the axial bias: unchanged
    g_lat = np.exp(-0.5 * (u[:, 2] / 50.0) ** 2)
    np.testing.assert_allclose(slow[:2, :2], np.repeat(1 - g_lat[:2, None], 2, axis=1))
    k_x = np.exp(-0.5 * (P / (np.pi * 4.0)) ** 2)  # half a period along x
    np.testing.assert_allclose(slow[2], [1 - k_x * g_lat[2], 1 - g_lat[2], same[2, 2]])
    assert slow[1, 0] < 0.3 < 0.99 < same[1, 0]  # a 40 µm move in depth: the x bias mostly kept
    # without a period too
    iso = bias_decorrelation(u, (*L, 50.0))
    np.testing.assert_allclose(iso[:, 0], 1 - np.exp(-0.5 * (u[:, 0] / 4.0) ** 2) * g_lat)
    np.testing.assert_allclose(iso[:, 2], 1 - np.exp(-0.5 * np.sum((u / L) ** 2, axis=1)))
    st = SeriesSettings(bias_length_um=(5.0, 3.0, 4.0))
    assert st.bias_lengths_xyz_um == (4.0, 3.0, 5.0, 5.0)
    st = SeriesSettings(bias_length_um=(5.0, 3.0, 4.0), bias_lateral_depth_length_um=50)
    assert st.bias_lengths_xyz_um == (4.0, 3.0, 5.0, 50.0)
    for bad in (0.0, -1.0, float("inf"), "50", True):
        with pytest.raises(InputError, match="bias_lateral_depth_length_um"):
            SeriesSettings(bias_lateral_depth_length_um=bad)


def test_track_clouds_writes_match_sigmas_and_the_noise_floor(tmp_path, rng):
    """Three frames of the same particles with known noise σ = (0.1, 0.2, 0.5) µm: the match
    σ is σ√2, and the static-frame noise floor measures it (RMS within 15 %)."""
    true_sig = np.array([0.1, 0.2, 0.5])
    x0 = np.stack(np.meshgrid(*[np.arange(6) * 20.0] * 3, indexing="ij"), -1).reshape(-1, 3)
    paths = []
    for k in range(3):
        xyz = x0 + rng.normal(0, 1, x0.shape) * true_sig
        sig = np.broadcast_to(true_sig, xyz.shape)
        paths.append(write_points_csv(tmp_path / f"f{k}.csv", xyz, sigma_xyz_um=sig))
    res = track_clouds(
        paths,
        tmp_path / "out",
        series=SeriesSettings(static_frames=3, compute_fields=False),
    )
    m, _ = read_matches_csv(tmp_path / "out" / "matches_000001.csv")
    assert len(m) == len(x0)
    np.testing.assert_allclose(
        read_match_sigmas(tmp_path / "out" / "matches_000001.csv"),
        np.broadcast_to(true_sig * np.sqrt(2), (len(m), 3)),
    )
    np.testing.assert_allclose(res.pairs[0].sigma_displacement_xyz_um[0], true_sig * np.sqrt(2))
    floor = res.summary["noise_floor"]
    assert floor["frames"] == 3 and floor["n_displacements"] == 2 * len(x0)
    np.testing.assert_allclose(floor["rms_xyz_um"], true_sig * np.sqrt(2), rtol=0.15)
    np.testing.assert_allclose(floor["predicted_xyz_um"], true_sig * np.sqrt(2))
    assert "noise floor" in res.results_line()
    tr = read_tracks_csv(tmp_path / "out" / "tracks.csv")
    np.testing.assert_allclose(tr["sigma_z_um"], 0.5)
    # clouds without σ: no σ columns, no predicted floor
    plain = [write_points_csv(tmp_path / f"p{k}.csv", read_points_csv(p)) for k, p in
             enumerate(paths)]  # fmt: skip
    res = track_clouds(plain, tmp_path / "out2", series=SeriesSettings(compute_fields=False))
    assert res.pairs[0].sigma_displacement_xyz_um is None
    assert "sigma_dx_um" not in (tmp_path / "out2" / "matches_000001.csv").read_text()
    assert np.all(np.isnan(read_tracks_csv(tmp_path / "out2" / "tracks.csv")["sigma_x_um"]))
    assert noise_floor(res.pairs, 1) is None


def test_series_predictor_tracks_a_steady_heterogeneous_motion():
    """Incremental linking of a vortex whose displacement grows by 1.3 mean spacings per
    frame: with the previous increment as the predictor every pair is tracked at ≥ 99 %,
    no worse than without it (measured: 1, 1, 1, 0.998 against 1, 1, 1, 0.980), and the
    predictor is what the linker starts from."""
    s = make_series("vortex", 1000, 1.3, 5, seed=7)
    guesses = []

    def linker(ref, dfm, settings, initial_guess=None):
        guesses.append(initial_guess is not None)
        return link_pair(ref, dfm, settings, initial_guess=initial_guess)

    ratios = {}
    for on in (True, False):
        guesses.clear()
        st = SeriesSettings(compute_fields=False, predictor=on)
        pairs = link_pairs(s.frames_xyz_um, st, linker=linker)
        assert guesses == [False] + [on] * 3
        ratios[on] = [score_link(s.pair(k, k + 1), p.matches).tracking_ratio
                      for k, p in enumerate(pairs)]  # fmt: skip
    print("tracking ratios with / without the predictor:", ratios[True], ratios[False])
    assert min(ratios[True]) >= 0.99
    assert np.mean(ratios[True]) >= np.mean(ratios[False]) - 1e-9
    with pytest.raises(InputError, match="predictor"):
        SeriesSettings(predictor="yes")
    with pytest.raises(InputError, match="static_frames"):
        SeriesSettings(static_frames=-1)
