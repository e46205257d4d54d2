"""Gridded displacement and strain fields (track.fields)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from track.errors import InputError
from track.fields import (
    GridField,
    GridSettings,
    fit_displacement,
    grid_axes,
    gridded_field,
    strain_from_displacement,
)
from track.strain import green_lagrange, infinitesimal

from .test_strain import CASES


def _cloud(seed=5, n=250):
    return np.random.default_rng(seed).uniform([0, 0, 0], [300, 250, 200], (n, 3))


def test_default_grid_has_about_50000_nodes():
    ax = grid_axes(_cloud())
    n = int(np.prod(ax.shape))
    assert 40_000 < n < 65_000
    dx, dy, dz = ax.spacing_um
    assert dx == pytest.approx(dy) == pytest.approx(dz)
    X = _cloud()
    assert np.all(ax.x_um[0] <= X[:, 0].min()) and ax.x_um[-1] >= X[:, 0].max()


def test_user_spacing_and_flat_cloud():
    ax = grid_axes(_cloud(), 25.0)
    assert ax.spacing_um == pytest.approx((25.0, 25.0, 25.0))
    assert ax.shape == (9, 11, 13)
    flat = _cloud()
    flat[:, 2] = 7.0
    with pytest.raises(InputError, match="extent along z"):
        grid_axes(flat)


@pytest.mark.parametrize(("name", "method"), [*((n, "rbf") for n in CASES), ("combined", "linear")])
def test_gridded_strain_matches_homogeneous_deformation(name, method):
    F0 = CASES[name]
    X = _cloud()
    u = X @ (F0 - np.eye(3)).T + np.array([1.0, 2.0, 3.0])
    g = gridded_field(X, u, GridSettings(target_nodes=3000, method=method))
    m = g.mask
    assert m.mean() > 0.5
    if method == "linear":  # nearest-value fill outside the hull: skip the hull's edge nodes
        m = ndimage.binary_erosion(m)
    rmse_E = np.sqrt(np.mean((g.E[m] - green_lagrange(F0)) ** 2))
    rmse_e = np.sqrt(np.mean((g.e[m] - infinitesimal(F0)) ** 2))
    assert rmse_E < 1e-3 and rmse_e < 1e-3  # < 0.1 % strain RMSE on supported nodes
    if method == "rbf":  # the thin-plate spline reproduces affine fields everywhere
        assert np.allclose(g.F, F0, atol=1e-8)


def test_mask_marks_nodes_far_from_particles():
    X = _cloud()
    X = X[X[:, 0] < 150]  # particles fill only half of the box ...
    X = np.vstack([X, [[299.0, 240.0, 190.0]]])  # ... plus one far corner particle
    g = gridded_field(X, 0.01 * X, GridSettings(spacing_um=20.0))
    xs = g.x_um
    assert g.mask[:, :, xs < 140].mean() > 0.6
    assert g.mask[:, :, xs > 200].mean() < 0.3


def test_gradient_of_interpolant_and_grid_agree():
    X = _cloud()
    u = np.c_[1e-4 * X[:, 2] ** 2, np.sin(X[:, 0] / 80.0), 0.02 * X[:, 1]]
    it = fit_displacement(X, u, GridSettings(smoothing=0.0))
    ax = grid_axes(X, 20.0)
    pts = ax.points()
    U = it(pts).reshape(*ax.shape, 3)
    F, _, _ = strain_from_displacement(ax, U)
    G = it.gradient(pts, ax.spacing_um).reshape(*ax.shape, 3, 3)
    inner = (slice(1, -1),) * 3
    assert np.allclose((np.eye(3) + G)[inner], F[inner], atol=1e-10)


def test_gridfield_validates_shapes():
    ax = grid_axes(_cloud(), 50.0)
    u = np.zeros((*ax.shape, 3))
    F, E, e = strain_from_displacement(ax, u)
    g = GridField(ax.x_um, ax.y_um, ax.z_um, u, F, E, e, np.ones(ax.shape, bool))
    assert g.shape == ax.shape and g.origin_um == ax.origin_um
    with pytest.raises(InputError, match=r"GridField\.u"):
        GridField(ax.x_um, ax.y_um, ax.z_um, u[:, :, :2], F, E, e, np.ones(ax.shape, bool))


def test_bad_inputs_and_settings():
    X = _cloud()
    with pytest.raises(InputError, match="at least 4"):
        fit_displacement(X[:3], X[:3])
    with pytest.raises(InputError, match="method"):
        GridSettings(method="cubic")
    with pytest.raises(InputError, match="spacing_um"):
        GridSettings(spacing_um=-1.0)
    Y = X.copy()
    Y[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        gridded_field(Y, X)
