"""The typed optics: validation, derived quantities of the paper's optics, dict round trip."""

from __future__ import annotations

import math

import pytest

from lfsim import ConfigError, Optics, paper_optics, small_optics


def test_paper_optics_derived_quantities():
    o = paper_optics()
    assert o.magnification == 4.0
    assert o.px_per_lenslet == pytest.approx(15.0)
    assert o.object_pixel_um == pytest.approx(100 / 15 / 4)  # ≈ 1.67 µm (paper: 1.64 measured)
    assert o.lenslet_object_um == pytest.approx(25.0)
    assert o.cone_fraction == pytest.approx((1 - math.sqrt(1 - 0.04)) / 2)
    x0, x1, y0, y1 = o.field_of_view_xy_um
    assert x1 - x0 == pytest.approx(1280 * o.object_pixel_um)  # ≈ 2100 µm (paper §4)
    assert y1 - y0 == pytest.approx(800 * o.object_pixel_um)  # ≈ 1300 µm
    # The axis sits on a lenslet centre and lenslet borders fall on pixel borders.
    assert (o.axis_xy_px[0] - 7.5) % 15 == pytest.approx(0)
    assert (o.axis_xy_px[1] - 7.5) % 15 == pytest.approx(0)
    # Diffraction widths: 0.21 λ / NA at the image plane and behind a lenslet (≈ 2.5 µm).
    assert o.sigma_mla_um == pytest.approx(0.21 * 0.605 / o.image_na)
    assert o.sigma_sensor_um == pytest.approx(0.21 * 0.605 / o.lenslet_na)
    assert 2.3 < o.sigma_mla_um < 2.7
    assert o.spot_spacing_px(300) == pytest.approx(15 * (1 + 1000 / (16 * 300)))
    assert o.spot_spacing_px(-300) == pytest.approx(15 * (1 - 1000 / (16 * 300)))


def test_glass_geometry():
    o = paper_optics(mla_kind="glass", mla_ior=1.5, mla_thickness_um=300.0)
    assert o.lenslet_radius_of_curvature_um == pytest.approx(500.0)
    assert o.sensor_distance_um == pytest.approx(300 * (1 - 1 / 1.5) + 1000)
    assert 4.9 < o.lenslet_sag_um < 5.1


def test_dict_round_trip():
    o = small_optics(na=0.25, wavelength_um=0.52)
    assert Optics.from_dict(o.to_dict()) == o


def test_optics_of_the_older_layout_are_read_and_hashed_under_fixed_names():
    o = small_optics(na=0.25)
    d = o.to_dict()
    assert d["sensor_xy_px"] == [300, 300] and d["axis_xy_px"] == list(o.axis_xy_px)
    older = o.fingerprint_dict()
    assert older["sensor_px"] == [300, 300] and "sensor_xy_px" not in older
    assert older["axis_px"] == d["axis_xy_px"] and "axis_xy_px" not in older
    assert Optics.from_dict(older) == o
    with pytest.raises(ConfigError, match="both 'sensor_px' and 'sensor_xy_px'"):
        Optics.from_dict({**d, "sensor_px": [300, 300]})


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("na", 0.0),
        ("na", -0.1),
        ("na", 1.2),
        ("mla_pitch_um", 0.0),
        ("mla_pitch_um", -100.0),
        ("pixel_um", float("nan")),
        ("mla_focal_um", float("inf")),
        ("sensor_xy_px", (0, 10)),
        ("mla_kind", "plastic"),
        ("wavelength_um", -0.5),
    ],
)
def test_non_physical_values_rejected_by_name(key, value):
    with pytest.raises(ConfigError, match=key):
        paper_optics(**{key: value})


def test_no_built_in_microscope():
    """`Optics(na=0.5, mla_pitch_um=150)` once kept the paper's sensor and objective."""
    with pytest.raises(TypeError, match="sensor_xy_px"):
        Optics(na=0.5, mla_pitch_um=150.0)
    with pytest.raises(ConfigError, match="missing"):
        Optics.from_dict({"na": 0.5, "mla_pitch_um": 150.0})
    with pytest.raises(ConfigError, match="too large"):
        paper_optics(sensor_xy_px=(200_000, 200_000))


def test_unknown_keys_rejected():
    with pytest.raises(ConfigError, match="numerical_aperture"):
        Optics.from_dict({"numerical_aperture": 0.2})


def test_too_few_pixels_per_lenslet():
    with pytest.raises(ConfigError, match="pixels per"):
        paper_optics(pixel_um=50.0)
