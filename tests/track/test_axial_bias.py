"""track.axial_bias: the offsets of a reference volume's spheres from the detected positions
are found, and subtracted (z only by default) with the particle table's σ kept."""

from __future__ import annotations

import numpy as np
import pytest

from track.axial_bias import AxialCalibration, apply_bias, correct_table, reference_bias
from track.errors import InputError
from track.tables import read_point_sigmas, read_points_csv, write_points_csv

VOXEL = (5.0, 2.0, 2.0)  # dz, dy, dx µm
ORIGIN = (-60.0, -50.0, 40.0)  # x, y, z µm of voxel (0, 0, 0)
SHAPE = (60, 60, 70)


def _reference(true_xyz: np.ndarray) -> np.ndarray:
    """Anisotropic Gaussian blobs (σ 12 µm in z, 3 µm laterally) centred at ``true_xyz``."""
    z, y, x = np.meshgrid(*[np.arange(n, dtype=float) for n in SHAPE], indexing="ij")
    zu, yu, xu = ORIGIN[2] + z * VOXEL[0], ORIGIN[1] + y * VOXEL[1], ORIGIN[0] + x * VOXEL[2]
    vol = np.zeros(SHAPE)
    for px, py, pz in true_xyz:
        vol += np.exp(-((xu - px) ** 2 + (yu - py) ** 2) / (2 * 3.0**2) - (zu - pz) ** 2 / 288)
    return vol.astype(np.float32)


def _case():
    rng = np.random.default_rng(3)
    detected = np.array([[-20.0, -20.0, 100.0], [20.0, 10.0, 180.0], [40.0, -25.0, 260.0]])
    detected += rng.uniform(-0.9, 0.9, detected.shape)  # off the voxel grid
    offset = np.array([[0.3, -0.2, -4.0], [-0.25, 0.15, 2.5], [0.1, 0.3, 6.0]])
    return detected, offset


def test_reference_bias_finds_the_offsets():
    detected, offset = _case()
    vol = _reference(detected + offset)
    got = reference_bias(vol, VOXEL, ORIGIN, detected, (8, 4, 4))
    assert got.shape == (3, 3)
    np.testing.assert_allclose(got[:, 2], offset[:, 2], atol=0.25)  # 5 % of a 5 µm voxel
    np.testing.assert_allclose(got[:, :2], offset[:, :2], atol=0.1)


def test_reference_bias_empty_and_bad_positions():
    vol = np.zeros(SHAPE, np.float32)
    assert reference_bias(vol, VOXEL, ORIGIN, np.zeros((0, 3)), (8, 4, 4)).shape == (0, 3)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        reference_bias(vol, VOXEL, ORIGIN, np.array([[0.0, np.nan, 100.0]]), (8, 4, 4))


def test_apply_bias_every_axis_by_default_and_unknown_left_alone():
    pos = np.array([[1.0, 2.0, 100.0], [3.0, 4.0, 200.0]])
    bias = np.array([[0.5, -0.5, 3.0], [np.nan, np.nan, np.nan]])
    np.testing.assert_array_equal(apply_bias(pos, bias), [[0.5, 2.5, 97.0], [3.0, 4.0, 200.0]])
    np.testing.assert_array_equal(
        apply_bias(pos, bias, lateral=False), [[1.0, 2.0, 97.0], [3.0, 4.0, 200.0]]
    )
    with pytest.raises(InputError, match="1 offsets for 2 positions"):
        apply_bias(pos, bias[:1])


def test_correct_table_keeps_sigma_and_intensity(tmp_path):
    pos = np.array([[1.0, 2.0, 100.0], [3.0, 4.0, 200.0]])
    sig = np.array([[0.1, 0.2, 1.0], [0.3, 0.4, 2.0]])
    src = write_points_csv(tmp_path / "a.csv", pos, np.array([5.0, 6.0]), sigma_xyz_um=sig)
    info = correct_table(src, tmp_path / "b.csv", np.array([[0, 0, 2.0], [0, 0, -1.0]]))
    np.testing.assert_allclose(read_points_csv(tmp_path / "b.csv")[:, 2], [98.0, 201.0])
    np.testing.assert_array_equal(read_point_sigmas(tmp_path / "b.csv"), sig)
    assert "intensity" in (tmp_path / "b.csv").read_text().splitlines()[0]
    assert info["corrected"] == 2 and info["applied_axes"] == "xyz"
    assert info["mean_offset_xyz_um"][2] == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"method": "fitted"}, "method must be one of"),
        ({"sphere_diameter_um": 0}, "sphere_diameter_um"),
        ({"rays_per_particle": 10}, "rays_per_particle"),
        ({"lateral": "yes"}, "lateral must be true or false"),
        ({"steps": 0}, r"steps must be an integer in 1\.\.5"),
        ({"steps": 6}, r"steps must be an integer in 1\.\.5"),
        ({"steps": 1.5}, "steps must be an integer from 1 to 5"),
        ({"steps": True}, "steps must be an integer from 1 to 5"),
    ],
)
def test_axial_calibration_settings_are_checked(kwargs, message):
    with pytest.raises(InputError, match=message):
        AxialCalibration(**kwargs)
    assert not AxialCalibration().enabled
    assert AxialCalibration(method="simulated").enabled
