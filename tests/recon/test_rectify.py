"""Rectification onto a whole number of pixels per lenslet."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recon import InputError, LensletGrid, RectifiedGeometry, calibrate_white, rectify

from .synthetic import synthetic_white as white


def test_identity_crop_odd_pitch():
    """lfsim-like geometry: pitch 15 px, rotation 0, lenslet centres on pixel centres
    (``axis_xy_px = 157.5``): rectifying with n = 15 is an exact crop, whatever the content."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 4096, size=(300, 310)).astype(np.uint16)
    grid = LensletGrid(15.0, 0.0, (157.5, 142.5), (300, 310))
    out, geom = rectify(image, grid, 15)
    assert geom.n_lenslets_xy == (20, 20)  # 310 px hold 20 whole lenslets from x = 0
    assert geom.first_lenslet_xy == (-10, -9)
    x0 = round(grid.center(*geom.first_lenslet_xy)[0] - 7.5)
    y0 = round(grid.center(*geom.first_lenslet_xy)[1] - 7.5)
    assert (x0, y0) == (0, 0)
    assert out.shape == geom.shape == (300, 300)
    assert np.array_equal(out, image[y0 : y0 + 300, x0 : x0 + 300])
    assert out.sum() == image[:, :300].sum()


def test_identity_crop_even_pitch_and_lenslet_white():
    """Even n: lenslet centres on pixel corners; a white image of the same geometry."""
    grid = LensletGrid(16.0, 0.0, (160.0, 152.0), (300, 330))
    image = white((300, 330), grid, noise_sigma=0.02, rng=1)
    out, geom = rectify(image, grid, 16)
    x0 = round(grid.center(*geom.first_lenslet_xy)[0] - 8)
    y0 = round(grid.center(*geom.first_lenslet_xy)[1] - 8)
    ny, nx = out.shape
    assert np.array_equal(out, image[y0 : y0 + ny, x0 : x0 + nx])
    assert geom.n_lenslets_xy == (20, 18)


def test_rotated_non_integer_pitch_recalibrates_to_n():
    """Calibrate a rotated, non-integer-pitch white image, rectify it with n = 15, and
    calibrate the result: pitch n, rotation 0, lenslet (u0 + U, v0 + V) at the centre of
    output block (U, V)."""
    shape = (400, 600)
    truth = LensletGrid(14.7, 1.3, (300.37, 200.81), shape)
    image = white(shape, truth, noise_sigma=0.03, vignetting=0.5, dead_fraction=0.02, rng=3)
    fit = calibrate_white(image)
    out, geom = rectify(image, fit, 15)
    assert out.shape == geom.shape == (geom.n_lenslets_xy[1] * 15, geom.n_lenslets_xy[0] * 15)
    again = calibrate_white(out)
    print(
        f"\nrectified: pitch {again.pitch_px:.5f} px, rotation {again.rotation_deg:+.5f} deg, "
        f"residual {again.rms_residual_px:.3f} px"
    )
    assert again.pitch_px == pytest.approx(15.0, abs=0.01)
    assert abs(again.rotation_deg) < 0.02
    # block centres: ((U + 0.5) n, (V + 0.5) n) in the rectified image
    u, v = np.rint(again.lenslet_index(np.array(again.origin_xy_px))).astype(int)
    assert (u, v) == (0, 0)
    ox, oy = again.origin_xy_px
    assert ox % 15 == pytest.approx(7.5, abs=0.05)
    assert oy % 15 == pytest.approx(7.5, abs=0.05)
    # every block holds a whole lenslet: the samples all lie inside the raw image
    pts = geom.sample_points_xy()
    assert pts.shape == (*out.shape, 2)
    assert pts[..., 0].min() >= 0.5 and pts[..., 0].max() <= shape[1] - 0.5
    assert pts[..., 1].min() >= 0.5 and pts[..., 1].max() <= shape[0] - 0.5
    # the block is as large as the image allows (at most one lenslet row/column lost to
    # the rotation on each side)
    assert geom.n_lenslets_xy[0] >= int(600 / 14.7) - 2
    assert geom.n_lenslets_xy[1] >= int(400 / 14.7) - 2
    # flux: the rectified sum, scaled, matches the raw sum over the same lenslets
    assert out.sum() * geom.flux_scale == pytest.approx(
        _raw_sum_over_lenslets(image, fit, geom), rel=0.01
    )


def _raw_sum_over_lenslets(image, grid, geom):
    h, w = image.shape
    yy, xx = np.mgrid[0:h, 0:w]
    uv = np.rint(grid.lenslet_index(np.stack([xx + 0.5, yy + 0.5], axis=-1)))
    (u0, v0), (nx, ny) = geom.first_lenslet_xy, geom.n_lenslets_xy
    inside = (uv[..., 0] >= u0) & (uv[..., 0] < u0 + nx)
    inside &= (uv[..., 1] >= v0) & (uv[..., 1] < v0 + ny)
    return float(image[inside].sum())


def test_downsampling_and_lenslet_lookup():
    truth = LensletGrid(17.3, -0.8, (250.2, 151.9), (300, 500))
    image = white((300, 500), truth, noise_sigma=0.01, rng=4)
    out, geom = rectify(image, truth, 9, order=3)
    again = calibrate_white(out)
    assert again.pitch_px == pytest.approx(9.0, abs=0.01)
    assert abs(again.rotation_deg) < 0.03
    u, v = geom.lenslet_of_output_pixel(np.array([0, 9, 17]), np.array([0, 8, 9]))
    u0, v0 = geom.first_lenslet_xy
    assert list(u) == [u0, u0, u0 + 1]
    assert list(v) == [v0, v0 + 1, v0 + 1]


def test_geometry_round_trip():
    grid = LensletGrid(14.7, 1.3, (300.37, 200.81), (400, 600), 0.05, 900)
    geom = RectifiedGeometry(grid, 15, (-19, -12), (39, 25))
    assert RectifiedGeometry.from_dict(json.loads(json.dumps(geom.to_dict()))) == geom
    with pytest.raises(InputError, match="unknown keys"):
        RectifiedGeometry.from_dict({**geom.to_dict(), "n": 3})


@pytest.mark.parametrize(
    ("image", "n", "kw", "match"),
    [
        (np.zeros((300, 301)), 15, {}, "shape"),
        (np.zeros((300, 300)), 0, {}, "px_per_lenslet"),
        (np.zeros((300, 300)), 7.5, {}, "px_per_lenslet"),
        (np.zeros((300, 300)), True, {}, "px_per_lenslet"),
        (np.zeros((300, 300)), 15, {"order": 6}, "order"),
        (np.full((300, 300), np.nan), 15, {}, "non-finite"),
        (np.zeros((2, 300, 300)), 15, {}, "2-D"),
    ],
)
def test_rectify_errors(image, n, kw, match):
    grid = LensletGrid(15.0, 0.0, (157.5, 157.5), (300, 300))
    with pytest.raises(InputError, match=match):
        rectify(image, grid, n, **kw)


def test_no_whole_lenslet():
    grid = LensletGrid(15.0, 0.0, (5.5, 5.5), (12, 12))
    with pytest.raises(InputError, match="no whole lenslet"):
        rectify(np.ones((12, 12)), grid, 15)
