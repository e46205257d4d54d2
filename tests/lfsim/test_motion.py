"""Motions against analytic truth: translation, rotation, isochoric tension, simple shear,
schedules, user fields and the dict reader."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lfsim.errors import ConfigError, LfsimError
from lfsim.motion import (
    MOTION_TYPES,
    Rotation,
    SimpleShear,
    Translation,
    UniaxialTension,
    UserField,
    motion_from_dict,
    rotation_matrix,
)

RNG = np.random.default_rng(123)
X = RNG.uniform(-300.0, 300.0, size=(64, 3))
CENTER = (12.5, -40.0, 160.0)


def _apply(m, X, k):
    F = m.deformation_gradient(k)
    c = m.center
    return c + (X - c) @ F.T + m.translation(k)


def _pairwise(P):
    return np.linalg.norm(P[:, None, :] - P[None, :, :], axis=-1)


def test_translation():
    m = Translation(step_um=(5.0, -2.5, 20.0))
    for k in range(4):
        x = m.positions(X, k)
        assert np.array_equal(x, X + k * np.array([5.0, -2.5, 20.0]))
        np.testing.assert_allclose(
            m.displacement(X, k),
            np.broadcast_to([5.0 * k, -2.5 * k, 20.0 * k], X.shape),
            rtol=0,
            atol=1e-12,
        )
        assert np.array_equal(m.deformation_gradient(k), np.eye(3))
    assert np.array_equal(m.positions(X, 0), X)


def test_rotation_about_z_quarter_turn_exact():
    m = Rotation(axis=(0, 0, 1), step_deg=90.0)
    assert np.array_equal(m.positions([[1.0, 0.0, 0.0]], 1), [[0.0, 1.0, 0.0]])
    assert np.array_equal(m.positions([[1.0, 0.0, 0.0]], 2), [[-1.0, 0.0, 0.0]])
    m5 = Rotation(step_deg=5.0)
    x = m5.positions([[1.0, 0.0, 0.0]], 18)
    np.testing.assert_allclose(x, [[0.0, 1.0, 0.0]], rtol=0, atol=1e-15)


@pytest.mark.parametrize("axis", [(0, 0, 1), (1, 0, 0), (1.0, -2.0, 0.5)])
def test_rotation_rigid(axis):
    m = Rotation(axis=axis, step_deg=5.0, center_xyz_um=CENTER)
    for k in (1, 3, 9):
        F = m.deformation_gradient(k)
        # round-off floor: a few ulp of 1 (BLAS/LAPACK kernels differ by an ulp or two)
        np.testing.assert_allclose(F.T @ F, np.eye(3), rtol=0, atol=1e-14)
        assert abs(np.linalg.det(F) - 1.0) < 1e-14
        x = m.positions(X, k)
        np.testing.assert_allclose(_pairwise(x), _pairwise(X), rtol=1e-13, atol=1e-11)
        # the axis through the centre is fixed
        a = np.asarray(axis, float) / np.linalg.norm(axis)
        on_axis = np.asarray(CENTER) + np.outer([-100.0, 0.0, 50.0], a)
        np.testing.assert_allclose(m.positions(on_axis, k), on_axis, rtol=0, atol=1e-12)
        # angle between (x − c) and (X − c) projected off the axis is k · 5°
        d0 = X[0] - CENTER - np.dot(X[0] - CENTER, a) * a
        d1 = x[0] - CENTER - np.dot(x[0] - CENTER, a) * a
        cos = np.dot(d0, d1) / (np.linalg.norm(d0) * np.linalg.norm(d1))
        sin = np.dot(np.cross(d0, d1), a) / (np.linalg.norm(d0) * np.linalg.norm(d1))
        assert math.isclose(math.degrees(math.atan2(sin, cos)), 5.0 * k, abs_tol=1e-10)


def test_rotation_composition():
    m = Rotation(axis=(0.3, 0.4, 1.0), step_deg=5.0, center_xyz_um=CENTER)
    F1 = m.deformation_gradient(1)
    np.testing.assert_allclose(np.linalg.matrix_power(F1, 9), m.deformation_gradient(9), atol=1e-14)
    R = rotation_matrix((0, 0, 1), 30.0)
    np.testing.assert_allclose(
        R, [[math.sqrt(3) / 2, -0.5, 0], [0.5, math.sqrt(3) / 2, 0], [0, 0, 1]], atol=1e-15
    )


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_uniaxial_tension_isochoric(axis):
    m = UniaxialTension(axis=axis, step_stretch=0.05, center_xyz_um=CENTER)
    i = "xyz".index(axis)
    for k in range(6):
        F = m.deformation_gradient(k)
        lam = 1.0 + k * 0.05
        assert F[i, i] == lam
        assert m.stretch(k) == lam
        others = [j for j in range(3) if j != i]
        for j in others:
            assert F[j, j] == 1.0 / math.sqrt(lam)
        assert np.count_nonzero(F - np.diag(np.diag(F))) == 0
        assert abs(np.linalg.det(F) - 1.0) < 1e-14  # a few ulp of 1
        u = m.displacement(X, k)
        np.testing.assert_allclose(
            u[:, i], (lam - 1.0) * (X[:, i] - CENTER[i]), rtol=1e-12, atol=1e-12
        )
        for j in others:
            np.testing.assert_allclose(
                u[:, j],
                (1.0 / math.sqrt(lam) - 1.0) * (X[:, j] - CENTER[j]),
                rtol=1e-12,
                atol=1e-12,
            )
    # volume of any tetrahedron is conserved
    x = m.positions(X[:4], 5)
    v0 = np.linalg.det(X[1:4] - X[0])
    v1 = np.linalg.det(x[1:4] - x[0])
    assert math.isclose(v0, v1, rel_tol=1e-12)


def test_uniaxial_tension_bad_stretch():
    m = UniaxialTension(axis="x", step_stretch=-0.5)
    with pytest.raises(ConfigError, match="stretch"):
        m.deformation_gradient(2)


def test_simple_shear_xz():
    g = 0.025
    m = SimpleShear(plane="xz", step_gamma=g, center_xyz_um=CENTER)
    for k in range(11):
        F = m.deformation_gradient(k)
        expected = np.eye(3)
        expected[0, 2] = k * g
        assert np.array_equal(F, expected)
        assert np.linalg.det(F) == 1.0
        u = m.displacement(X, k)
        np.testing.assert_allclose(u[:, 0], k * g * (X[:, 2] - CENTER[2]), rtol=1e-12, atol=1e-12)
        assert np.all(np.abs(u[:, 1:]) <= 1e-12)  # round-off of positions ~300 µm
        # engineering shear strain γ = 2 e_xz of the infinitesimal strain sym(F − I)
        e = 0.5 * ((F - np.eye(3)) + (F - np.eye(3)).T)
        assert 2 * e[0, 2] == k * g
    # Green–Lagrange E_zz = γ²/2 (finite simple shear): 30 % shear → 4.5 %
    F = SimpleShear(step_gamma=0.3).deformation_gradient(1)
    E = 0.5 * (F.T @ F - np.eye(3))
    assert math.isclose(E[2, 2], 0.045, rel_tol=1e-14)
    assert math.isclose(E[0, 2], 0.15, rel_tol=1e-14)


@pytest.mark.parametrize("plane", ["xy", "yx", "zx", "yz", "zy"])
def test_simple_shear_other_planes(plane):
    m = SimpleShear(plane=plane, step_gamma=0.1, center_xyz_um=CENTER)
    a, b = ("xyz".index(plane[0]), "xyz".index(plane[1]))
    u = m.displacement(X, 3)
    np.testing.assert_allclose(u[:, a], 0.3 * (X[:, b] - CENTER[b]), rtol=1e-12, atol=1e-12)
    others = [j for j in range(3) if j != a]
    assert np.all(np.abs(u[:, others]) <= 1e-12)  # round-off of positions ~300 µm


def test_simple_shear_composition():
    m = SimpleShear(plane="xz", step_gamma=0.025)
    np.testing.assert_allclose(
        np.linalg.matrix_power(m.deformation_gradient(1), 10),
        m.deformation_gradient(10),
        rtol=0,
        atol=1e-14,
    )


@pytest.mark.parametrize(
    "m",
    [
        Translation(step_um=(1.0, 2.0, 3.0)),
        Rotation(axis=(1, 1, 1), step_deg=7.0, center_xyz_um=CENTER),
        UniaxialTension(axis="y", step_stretch=0.05, center_xyz_um=CENTER),
        SimpleShear(plane="xz", step_gamma=0.025, center_xyz_um=CENTER),
    ],
)
def test_positions_apply_F_exactly(m):
    for k in range(5):
        assert np.array_equal(m.positions(X, k), _apply(m, X, k))
        assert np.array_equal(m(X, k), m.positions(X, k))
        assert np.array_equal(m.displacement(X, k), m.positions(X, k) - X)
    assert m.homogeneous


def test_schedule_values():
    ramp = [0.0, 0.05, 0.15, 0.32, 0.30, 0.30]  # lag + overshoot, as in the paper's Fig. 7
    m = SimpleShear(plane="xz", values=ramp)
    assert m.n_frames == 6
    for k, g in enumerate(ramp):
        assert m.amplitude(k) == g
        assert m.deformation_gradient(k)[0, 2] == g
    for bad in (6, -1, 1.5):
        with pytest.raises(ConfigError, match="outside its 'values' schedule of 6 frames"):
            m.amplitude(bad)
    t = Translation(values=[(0, 0, 0), (0, 0, 20.0), (0, 0, 45.0)])
    np.testing.assert_array_equal(t.positions(X, 2), X + np.array([0.0, 0.0, 45.0]))
    r = Rotation(values=[0.0, 90.0])
    assert np.array_equal(r.positions([[1.0, 0.0, 0.0]], 1), [[0.0, 1.0, 0.0]])
    # linear steps: amplitude = frame * step
    assert SimpleShear(step_gamma=0.025).amplitude(4) == 4 * 0.025
    with pytest.raises(ConfigError, match="exactly one of 'step_gamma'"):
        SimpleShear(step_gamma=0.1, values=[0.0, 0.1])
    with pytest.raises(ConfigError, match="exactly one of 'step_deg'"):
        Rotation()
    with pytest.raises(ConfigError, match="values"):
        Rotation(values=[])
    with pytest.raises(ConfigError, match=r"values\[1\]"):
        Translation(values=[(0, 0, 0), (1, 2)])


USER_MODULE = """
import numpy as np

def shear_wave(X_um, frame, amplitude_um=1.0, wavelength_um=100.0):
    u = np.zeros_like(X_um)
    u[:, 0] = amplitude_um * frame * np.sin(2 * np.pi * X_um[:, 2] / wavelength_um)
    return u

def wrong_shape(X_um, frame):
    return np.zeros((len(X_um), 2))

def not_finite(X_um, frame):
    return np.full(X_um.shape, np.nan)

def boom(X_um, frame):
    raise RuntimeError("kaboom")

NOT_CALLABLE = 3
"""


@pytest.fixture
def user_file(tmp_path):
    path = tmp_path / "my_fields.py"
    path.write_text(USER_MODULE)
    return path


def test_user_field_from_file(user_file):
    m = UserField(f"{user_file}:shear_wave", params={"amplitude_um": 2.0, "wavelength_um": 50.0})
    u = m.displacement(X, 3)
    np.testing.assert_array_equal(u[:, 0], 2.0 * 3 * np.sin(2 * np.pi * X[:, 2] / 50.0))
    assert np.all(u[:, 1:] == 0)
    assert np.array_equal(m.positions(X, 3), X + u)
    assert not m.homogeneous
    with pytest.raises(LfsimError, match="not a homogeneous"):
        m.deformation_gradient(1)


def test_user_field_from_dict_relative_to_base_dir(user_file):
    d = {
        "type": "user_field",
        "function": "my_fields.py:shear_wave",
        "params": {"amplitude_um": 1.0},
    }
    m = motion_from_dict(d, base_dir=user_file.parent)
    u = m.displacement(X, 1)
    np.testing.assert_array_equal(u[:, 0], np.sin(2 * np.pi * X[:, 2] / 100.0))


def test_user_field_from_module(tmp_path, monkeypatch):
    pkg = tmp_path / "lfsim_test_userpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "fields.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    m = UserField("lfsim_test_userpkg.fields:shear_wave", params={"wavelength_um": 80.0})
    np.testing.assert_array_equal(
        m.positions(X, 2)[:, 0], X[:, 0] + 2 * np.sin(2 * np.pi * X[:, 2] / 80.0)
    )


@pytest.mark.parametrize(
    ("name", "exc", "match"),
    [
        ("wrong_shape", ConfigError, r"wrong_shape.*returned shape \(64, 2\)"),
        ("not_finite", ConfigError, "not_finite.*non-finite"),
        ("boom", LfsimError, "boom.*kaboom"),
    ],
)
def test_user_field_bad_returns(user_file, name, exc, match):
    m = UserField(f"{user_file}:{name}")
    with pytest.raises(exc, match=match):
        m.displacement(X, 1)


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("no_colon", "module:function"),
        ("/does/not/exist.py:f", "does not exist"),
        ("lfsim_no_such_module_xyz:f", "cannot import module"),
        ("numpy:no_such_function_xyz", "no attribute 'no_such_function_xyz'"),
    ],
)
def test_user_field_bad_spec(spec, match):
    with pytest.raises(ConfigError, match=match):
        UserField(spec)


def test_user_field_not_callable(user_file):
    with pytest.raises(ConfigError, match=r"NOT_CALLABLE.*not callable"):
        UserField(f"{user_file}:NOT_CALLABLE")


def test_motion_from_dict_round_trip():
    cases = [
        {"type": "translation", "step_um": [5.0, 0.0, 0.0]},
        {"type": "rotation", "axis": [0, 0, 1], "step_deg": 5.0, "center_xyz_um": list(CENTER)},
        {"type": "uniaxial_tension", "axis": "x", "step_stretch": 0.05},
        {"type": "simple_shear", "plane": "xz", "step_gamma": 0.025},
        {"type": "simple_shear", "plane": "xz", "values": [0.0, 0.1, 0.31, 0.3]},
        {"type": "translation", "values": [[0, 0, 0], [0, 0, 20]]},
    ]
    for d in cases:
        m = motion_from_dict(d)
        assert isinstance(m, MOTION_TYPES[d["type"]])
        again = motion_from_dict(m.to_dict())
        assert again == m
        assert np.array_equal(again.positions(X, 1), m.positions(X, 1))
    m = motion_from_dict({"type": "simple_shear", "plane": "xz", "step_gamma": 0.025})
    np.testing.assert_allclose(m.displacement(X, 4)[:, 0], 0.1 * X[:, 2], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    ("d", "match"),
    [
        ({"type": "twist", "step_deg": 1.0}, r"unknown motion type 'twist'.*rotation"),
        ({"step_deg": 1.0}, "needs the key 'type'"),
        (
            {"type": "rotation", "step_deg": 1.0, "centre_xyz_um": [0, 0, 0]},
            r"unknown key\(s\) \['centre_xyz_um'\].*center_xyz_um",
        ),
        (
            {"type": "rotation", "step_deg": 1.0, "center_um": [0, 0, 0]},
            r"^motion type 'rotation': 'center_um' is named 'center_xyz_um' \(the centre "
            r"\(x, y, z\) in µm\); rename the key$",
        ),
        (
            {"type": "simple_shear", "step_gamma": 0.1, "centre_um": [0, 0, 0]},
            r"'centre_um' is named 'center_xyz_um'",
        ),
        ({"type": "simple_shear", "step_gamma": 0.1, "gamma": 0.1}, r"\['gamma'\]"),
        ({"type": "simple_shear", "plane": "xx", "step_gamma": 0.1}, "plane"),
        ({"type": "simple_shear", "plane": "xw", "step_gamma": 0.1}, "plane"),
        ({"type": "uniaxial_tension", "axis": "w", "step_stretch": 0.1}, "axis"),
        ({"type": "rotation", "axis": [0, 0, 0], "step_deg": 1.0}, "non-zero"),
        ({"type": "rotation", "step_deg": "five"}, "step_deg"),
        ({"type": "translation", "step_um": [1, 2]}, "step_um"),
        ({"type": "translation"}, "exactly one of 'step_um'"),
        ({"type": "user_field"}, "user_field"),
        ({"type": "user_field", "function": "numpy:zeros_like", "params": 3}, "params"),
    ],
)
def test_motion_from_dict_errors(d, match):
    with pytest.raises(ConfigError, match=match):
        motion_from_dict(d)


def test_bad_points_and_frames():
    m = Translation(step_um=(1, 0, 0))
    with pytest.raises(ConfigError, match=r"shape \(N, 3\)"):
        m.positions(np.zeros((3, 2)), 1)
    with pytest.raises(ConfigError, match="frame"):
        m.positions(X, "1")
    with pytest.raises(ConfigError, match="finite"):
        m.positions(X, math.nan)


# -- known heterogeneous fields ---------------------------------------------------------------
HETERO = [
    {
        "type": "stiff_inclusion",
        "axis": "x",
        "radius_um": 130.0,
        "center_xyz_um": [0.0, 0.0, 260.0],
        "step_strain": 0.05,
    },
    {"type": "stiff_inclusion", "axis": "z", "radius_um": 80.0, "values": [0.0, 0.02, -0.03]},
    {
        "type": "gaussian_indentation",
        "surface_z_um": 400.0,
        "width_um": 150.0,
        "decay_um": 120.0,
        "center_xy_um": [20.0, -10.0],
        "step_um": 4.0,
    },
]


@pytest.mark.parametrize("d", HETERO, ids=lambda d: d["type"] + "_" + str(len(d)))
def test_heterogeneous_motions_scale_with_the_schedule_and_have_exact_gradients(d):
    m = motion_from_dict(d)
    assert isinstance(m, MOTION_TYPES[d["type"]]) and not m.homogeneous
    assert motion_from_dict(m.to_dict()) == m
    np.testing.assert_array_equal(m.displacement(X, 0), 0.0)  # frame 0: the reference
    u1, u2 = m.displacement(X, 1), m.displacement(X, 2)
    a1, a2 = m.amplitude(1), m.amplitude(2)
    np.testing.assert_allclose(a1 * u2, a2 * u1, atol=1e-9)  # linear in the amplitude
    np.testing.assert_allclose(m.positions(X, 2), X + u2)
    h = 1e-3
    num = np.stack([(m.displacement(X + h * e, 2) - m.displacement(X - h * e, 2)) / (2 * h)
                    for e in np.eye(3)], axis=2)  # fmt: skip
    np.testing.assert_allclose(m.displacement_gradient(X, 2), num, atol=1e-7)
    np.testing.assert_allclose(m.deformation_gradient_at(X, 2), np.eye(3) + num, atol=1e-7)
    with pytest.raises(LfsimError, match="not a homogeneous motion"):
        m.deformation_gradient(2)


def test_stiff_inclusion_is_rigid_inside_and_stretched_far_away():
    m = motion_from_dict(HETERO[0])  # ε = 5 % per frame along x around a 130 µm sphere
    c = np.array([0.0, 0.0, 260.0])
    inside = c + np.array([[0.0, 0.0, 0.0], [60.0, -40.0, 30.0]])
    G = m.displacement_gradient(inside, 2)  # ε = 10 %: 5 % of it inside the sphere
    np.testing.assert_allclose(G, np.broadcast_to(np.diag([0.005, -0.0025, -0.0025]), G.shape))
    far = c + np.array([[1e5, 0.0, 0.0], [0.0, 1e5, 0.0]])
    G = m.displacement_gradient(far, 2)
    np.testing.assert_allclose(G, np.broadcast_to(np.diag([0.1, -0.05, -0.05]), G.shape), atol=1e-6)
    pole = c + np.array([[130.0, 0.0, 0.0]])  # the strain concentration at the pole: ≈ 3 ε
    assert 2.5 * 0.1 < m.displacement_gradient(pole, 2)[0, 0, 0] < 3.2 * 0.1


def test_gaussian_indentation_is_the_track_synthetic_field():
    """One field definition (hrvbase.known_fields) for lfsim's motion and track's test field."""
    from track.synthetic import GaussianIndentation as TrackIndentation
    from track.synthetic import StiffInclusion as TrackInclusion

    m = motion_from_dict(HETERO[2])
    t = TrackIndentation("g", 8.0, centre_xy_um=np.array([20.0, -10.0]), top_um=400.0,
                         width_um=150.0, depth_um=120.0)  # fmt: skip
    np.testing.assert_array_equal(m.displacement(X, 2), t(X))
    m = motion_from_dict(HETERO[0])
    t = TrackInclusion("s", 1.0, center_xyz_um=np.array([0.0, 0.0, 260.0]), strain=0.15,
                       radius_um=130.0)  # fmt: skip
    np.testing.assert_allclose(m.displacement(X, 3), t(X), rtol=1e-12)  # 3 · 0.05 vs 0.15


@pytest.mark.parametrize(
    ("d", "match"),
    [
        ({"type": "stiff_inclusion", "step_strain": 0.1}, "radius_um"),
        ({"type": "stiff_inclusion", "radius_um": 0, "step_strain": 0.1}, "radius_um must be > 0"),
        ({"type": "stiff_inclusion", "radius_um": 9, "axis": "w", "step_strain": 0.1}, "axis"),
        (
            {"type": "stiff_inclusion", "radius_um": 9, "inner_fraction": 1.0, "step_strain": 0.1},
            r"inner_fraction must be in \[0, 1\)",
        ),
        ({"type": "stiff_inclusion", "radius_um": 9}, "exactly one of 'step_strain'"),
        (
            {"type": "gaussian_indentation", "surface_z_um": 1, "width_um": -1, "decay_um": 1,
             "step_um": 1},
            "width_um must be > 0",
        ),
        (
            {"type": "gaussian_indentation", "surface_z_um": 1, "width_um": 1, "decay_um": 1,
             "center_xy_um": [0, 0, 0], "step_um": 1},
            r"center_xy_um must be two numbers \(x, y\)",
        ),
        (
            {"type": "gaussian_indentation", "surface_z_um": "top", "width_um": 1, "decay_um": 1,
             "step_um": 1},
            "surface_z_um must be a finite number",
        ),
    ],
)  # fmt: skip
def test_heterogeneous_motion_errors(d, match):
    with pytest.raises(ConfigError, match=match):
        motion_from_dict(d)
