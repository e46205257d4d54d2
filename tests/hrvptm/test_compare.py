"""Comparison primitives: association, statistics, imposed strain (hrvptm.compare)."""

from __future__ import annotations

import numpy as np
import pytest

from hrvptm.compare import (
    associate,
    green_lagrange,
    numerical_deformation_gradient,
    tensor_stats,
    vector_stats,
)


def test_associate_recovers_a_permutation_and_drops_far_points():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 500, (200, 3))
    perm = rng.permutation(200)
    det = truth[perm] + rng.normal(0, 1.0, (200, 3))
    det = np.vstack([det, [[2000.0, 2000.0, 2000.0]]])  # a spurious detection
    i_det, i_truth = associate(det, truth, radius_um=10.0)
    assert len(i_det) == 200
    np.testing.assert_array_equal(i_truth, perm[i_det])
    assert 200 not in i_det


def test_associate_is_one_to_one_when_two_detections_share_a_particle():
    truth = np.array([[0.0, 0, 0], [100.0, 0, 0]])
    det = np.array([[1.0, 0, 0], [2.0, 0, 0]])
    i_det, i_truth = associate(det, truth, radius_um=5.0)
    assert list(i_det) == [0] and list(i_truth) == [0]
    assert associate(np.zeros((0, 3)), truth, 5.0)[0].size == 0


def test_vector_stats_mean_rmsd_max():
    err = np.array([[1.0, -2.0, 0.0], [-1.0, 2.0, 3.0], [1.0, 2.0, 0.0]])
    s = vector_stats(err, "u_")
    assert s["u_n"] == 3
    assert s["u_mean_x"] == pytest.approx(1 / 3)
    assert s["u_rmsd_x"] == pytest.approx(1.0)
    assert s["u_rmsd_z"] == pytest.approx(np.sqrt(3.0))
    assert s["u_maxabs_y"] == pytest.approx(2.0)
    assert np.isnan(vector_stats(np.zeros((0, 3)))["rmsd_x"])


def test_green_lagrange_of_simple_shear_is_finite_deformation_theory():
    g = 0.3
    F = np.eye(3)
    F[0, 2] = g  # u_x = γ Z
    E = green_lagrange(F)
    assert E[0, 2] == pytest.approx(g / 2)
    assert E[2, 2] == pytest.approx(g**2 / 2)  # the paper's Fig. 7 E_zz = γ²/2
    assert E[0, 0] == pytest.approx(0.0)


def test_numerical_gradient_matches_affine_and_quadratic_fields():
    A = np.array([[0.1, 0.02, 0.3], [0.0, -0.05, 0.01], [0.04, 0.0, 0.2]])
    X = np.random.default_rng(1).uniform(-100, 100, (20, 3))
    F = numerical_deformation_gradient(lambda P: P @ A.T, X)
    np.testing.assert_allclose(F, np.broadcast_to(np.eye(3) + A, F.shape), atol=1e-10)
    Fq = numerical_deformation_gradient(lambda P: np.c_[1e-3 * P[:, 2] ** 2, 0 * P[:, :2]], X)
    np.testing.assert_allclose(Fq[:, 0, 2], 2e-3 * X[:, 2], atol=1e-9)


def test_tensor_stats_against_a_homogeneous_truth():
    truth = np.diag([0.1, -0.05, -0.05])
    rng = np.random.default_rng(2)
    meas = truth + rng.normal(0, 0.01, (4000, 3, 3))
    s = tensor_stats(meas, truth, "E_", n_independent=100)
    assert s["E_true_xx"] == pytest.approx(0.1)
    assert s["E_err_xx"] == pytest.approx(0.0, abs=1e-3)
    assert s["E_rmsd_xx"] == pytest.approx(0.01, rel=0.05)
    assert s["E_se_xx"] == pytest.approx(0.001, rel=0.05)  # σ / √n_independent
