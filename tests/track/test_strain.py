"""Per-particle deformation gradients and strain measures (track.strain)."""

from __future__ import annotations

import numpy as np
import pytest

from track.errors import InputError
from track.strain import (
    LocalFitSettings,
    component,
    engineering_shear,
    green_lagrange,
    infinitesimal,
    particle_deformation_gradient,
)


def _rot_z(deg):
    t = np.deg2rad(deg)
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


STRETCH = np.diag([1.10, 1 / np.sqrt(1.10), 1 / np.sqrt(1.10)])  # isochoric uniaxial tension
SHEAR = np.array([[1.0, 0.0, 0.25], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # gamma_xz = 0.25
ROTATION = _rot_z(30.0)
COMBINED = _rot_z(20.0) @ SHEAR @ STRETCH

CASES = {"stretch": STRETCH, "shear": SHEAR, "rotation": ROTATION, "combined": COMBINED}


def _cloud(seed=3, n=400):
    return np.random.default_rng(seed).uniform([0, 0, 0], [300, 250, 200], (n, 3))


@pytest.mark.parametrize("name", list(CASES))
def test_particle_F_matches_homogeneous_deformation(name):
    F0 = CASES[name]
    X = _cloud()
    u = X @ (F0 - np.eye(3)).T + np.array([5.0, -3.0, 2.0])
    res = particle_deformation_gradient(X, u)
    assert not res.ill_conditioned.any()
    assert res.F.shape == (X.shape[0], 3, 3)
    rmse_E = np.sqrt(np.mean((res.E - green_lagrange(F0)) ** 2))
    rmse_e = np.sqrt(np.mean((res.e - infinitesimal(F0)) ** 2))
    assert rmse_E < 1e-3 and rmse_e < 1e-3  # < 0.1 % strain
    assert np.allclose(res.F, F0, atol=1e-9)
    assert np.all(res.residual_um < 1e-8)


def test_rotation_has_zero_green_lagrange_but_nonzero_infinitesimal():
    F = _rot_z(30.0)
    assert np.allclose(green_lagrange(F), 0.0, atol=1e-12)
    e = infinitesimal(F)
    assert e[0, 0] == pytest.approx(np.cos(np.deg2rad(30)) - 1)  # about -13 % "strain"
    assert abs(e[0, 0]) > 0.1


def test_strain_helpers_values():
    F = SHEAR
    E = green_lagrange(F)
    e = infinitesimal(F)
    assert engineering_shear(e, "xz") == pytest.approx(0.25)
    assert engineering_shear(e, "zx") == pytest.approx(0.25)
    assert E[2, 2] == pytest.approx(0.5 * 0.25**2)  # finite-deformation E_zz of simple shear
    assert component(E, "xz") == pytest.approx(0.125)
    batch = np.broadcast_to(F, (4, 5, 3, 3))
    assert green_lagrange(batch).shape == (4, 5, 3, 3)
    with pytest.raises(InputError, match="component"):
        engineering_shear(e, "xx")
    with pytest.raises(InputError, match="shape"):
        green_lagrange(np.eye(2))


def test_coplanar_neighbourhood_is_flagged_not_reported():
    rng = np.random.default_rng(0)
    X = _cloud(n=200)
    flat = np.c_[rng.uniform(0, 50, (12, 2)), np.zeros(12)] + [1000.0, 1000.0, 0.0]
    X = np.vstack([X, flat])
    u = 0.01 * X
    res = particle_deformation_gradient(X, u, LocalFitSettings(n_neighbours=8))
    assert res.ill_conditioned[-12:].all()
    assert np.isnan(res.F[-12:]).all() and np.isnan(res.E[-12:]).all()
    assert not res.ill_conditioned[:200].any()


def test_weights_downweight_an_outlier():
    X = _cloud(n=300)
    u = X @ (SHEAR - np.eye(3)).T
    u[0] += 50.0
    w = np.ones(X.shape[0])
    w[0] = 0.0
    res = particle_deformation_gradient(X, u, weights=w)
    others = np.setdiff1d(np.arange(X.shape[0]), [0])
    assert np.allclose(res.F[others], SHEAR, atol=1e-8)


def test_bad_inputs():
    X = _cloud(n=10)
    with pytest.raises(InputError, match="at least 4"):
        particle_deformation_gradient(X[:3], X[:3])
    with pytest.raises(InputError, match="NaN"):
        Y = X.copy()
        Y[2, 1] = np.nan
        particle_deformation_gradient(Y, X)
    with pytest.raises(InputError, match="shape"):
        particle_deformation_gradient(X, X[:5])
    with pytest.raises(InputError, match="n_neighbours"):
        LocalFitSettings(n_neighbours=3)
