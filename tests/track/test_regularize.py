"""Gridded and ADMM displacement-field fits (track.regularize)."""

from __future__ import annotations

import numpy as np
import pytest

from track.errors import InputError
from track.fields import GridAxes
from track.regularize import GridDisplacement, fit_affine, fit_field, make_grid

BOUNDS = [[0.0, 100.0], [0.0, 80.0], [-20.0, 60.0]]


def analytic(x):
    return np.column_stack(
        [
            2.0 * np.sin(2 * np.pi * x[:, 0] / 100.0),
            1e-3 * (x[:, 1] - 40.0) ** 2,
            0.5 * np.cos(2 * np.pi * x[:, 2] / 80.0) + 0.01 * x[:, 0],
        ]
    )


def sample(n=1500, noise=0.02, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.array(BOUNDS).T
    x = rng.uniform(lo, hi, (n, 3))
    return x, analytic(x) + rng.normal(0, noise, x.shape)


def rmse(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


@pytest.mark.parametrize("method", ["gridded", "admm"])
def test_fit_reproduces_smooth_analytic_field(method):
    x, u = sample()
    g = fit_field(x, u, BOUNDS, 8.0, method, weight=0.01)
    lo, hi = np.array(BOUNDS).T
    xt = np.random.default_rng(5).uniform(lo + 5, hi - 5, (3000, 3))
    assert rmse(g(xt), analytic(xt)) < 0.05  # amplitude 2 µm
    if method == "admm":
        assert g.info["converged"]


@pytest.mark.parametrize("weight", [0.01, 1.0, 100.0])
def test_gridded_and_admm_agree(weight):
    x, u = sample(n=800, seed=1)
    a = fit_field(x, u, BOUNDS, 10.0, "gridded", weight)
    b = fit_field(x, u, BOUNDS, 10.0, "admm", weight, admm_tol=1e-9)
    assert np.max(np.abs(a.values_um - b.values_um)) < 1e-3


@pytest.mark.parametrize("method", ["gridded", "admm"])
def test_affine_field_is_not_biased_by_smoothness(method):
    rng = np.random.default_rng(2)
    x = rng.uniform([0, 0, -20], [100, 80, 60], (300, 3))
    f = np.array([[0.0, 0.0, 1.0], [0.2, 0.0, 0.0], [0.0, -0.1, 0.3]])
    u = x @ f.T + [3.0, -1.0, 2.0]
    g = fit_field(x, u, BOUNDS, 15.0, method, weight=1e3)
    assert rmse(g(x), u) < 1e-3


def test_grid_extrapolation_modes():
    origin, step, shape = make_grid([[0, 10], [0, 20], [0, 15]], 5.0)
    assert shape == (4, 5, 3)  # (nz, ny, nx), the array order of track.fields.GridField
    z, y, x = np.meshgrid(
        *[origin[a] + step[a] * np.arange(shape[2 - a]) for a in (2, 1, 0)], indexing="ij"
    )
    vals = np.stack([0.1 * x, 0.2 * y, 0.3 * z], axis=-1)  # u = (0.1 x, 0.2 y, 0.3 z)
    lin = GridDisplacement(origin, step, vals, "linear")
    near = GridDisplacement(origin, step, vals, "nearest")
    p = np.array([[15.0, 5.0, 5.0], [-5.0, 25.0, 5.0], [3.0, 4.0, 17.0]])
    np.testing.assert_allclose(lin(p), p * [0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(near(p), [[1.0, 1.0, 1.5], [0.0, 4.0, 1.5], [0.3, 0.8, 4.5]])
    nodes = lin.node_xyz_um()
    assert nodes.shape == (*shape, 3)
    np.testing.assert_allclose(nodes, np.stack([x, y, z], axis=-1))
    np.testing.assert_allclose(lin(nodes.reshape(-1, 3)), vals.reshape(-1, 3), atol=1e-12)
    # one grid description: GridDisplacement <-> track.fields.GridAxes
    axes = lin.axes
    assert isinstance(axes, GridAxes) and axes.shape == shape
    np.testing.assert_allclose(axes.points(), nodes.reshape(-1, 3))
    back = GridDisplacement.from_axes(axes, vals)
    np.testing.assert_allclose(back(p), lin(p), atol=1e-12)
    with pytest.raises(InputError, match="values_um must have shape"):
        GridDisplacement.from_axes(axes, vals.transpose(2, 1, 0, 3))  # (nx, ny, nz): refused
    with pytest.raises(InputError, match="evenly spaced"):
        GridDisplacement.from_axes(GridAxes([0.0, 1.0, 3.0], [0.0, 1.0], [0.0, 1.0]), vals)
    with pytest.raises(InputError, match=r"\(nz, ny, nx, 3\)"):
        GridDisplacement(origin, step, vals[..., :2])


def test_fit_affine_exact():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(20, 3))
    f = np.array([[2.0, 0, 0], [0, 0.7, 0.1], [0, 0, 0.7]])
    aff = fit_affine(x, x @ (f - np.eye(3)).T + 1.0)
    np.testing.assert_allclose(aff.matrix, f, atol=1e-12)
    with pytest.raises(InputError, match="coplanar"):
        fit_affine(np.c_[x[:, :2], np.zeros(20)], x)


@pytest.mark.parametrize(
    ("args", "kwargs", "needle"),
    [
        ((np.zeros((3, 3)), np.zeros((3, 3))), {}, "at least 4"),
        ((np.zeros((5, 2)), np.zeros((5, 2))), {}, "points_um"),
        ((np.full((5, 3), np.nan), np.zeros((5, 3))), {}, "NaN"),
        ((np.random.default_rng(0).random((9, 3)), np.zeros((9, 3))), {"method": "fem"}, "method"),
        ((np.random.default_rng(0).random((9, 3)), np.zeros((9, 3))), {"weight": -1.0}, "weight"),
    ],
)
def test_fit_field_validates(args, kwargs, needle):
    with pytest.raises(InputError, match=needle):
        fit_field(*args, bounds_xyz_um=[[0, 1]] * 3, spacing_xyz_um=0.5, **kwargs)


def test_grid_validates():
    with pytest.raises(InputError, match="spacing_xyz_um"):
        make_grid([[0, 1]] * 3, 0.0)
    with pytest.raises(InputError, match="bounds_xyz_um"):
        make_grid([[1, 0]] * 3, 1.0)
