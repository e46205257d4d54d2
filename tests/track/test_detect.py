"""Particle PSF estimate, secondary deconvolution and the detect_particles pipeline."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from scipy.spatial import cKDTree

from track.deconvolve import DeconvolveSettings, deconvolve
from track.detect import (
    PHASE_SIGMA_TOL,
    DetectSettings,
    detect_particles,
    equalize_lenslet_phases,
)
from track.errors import InputError, TrackingError
from track.psf_estimate import (
    box_shape_vox,
    estimate_psf,
    find_isolated_peaks,
    load_psf,
    particle_fwhm_vox,
)

from .conftest import random_centres, render_blobs

SIGMA = (2.5, 1.2, 1.2)  # voxels, elongated along z
VOXEL = (5.0, 1.64, 1.64)  # µm (dz, dy, dx)
PSF_BOX_UM = (80.0, 16.0, 16.0)  # 17 × 11 × 11 voxels


def _moment_sigmas(img):
    w = img / img.sum()
    g = np.indices(img.shape)
    mean = [float((w * g[a]).sum()) for a in range(3)]
    return np.array([np.sqrt((w * (g[a] - mean[a]) ** 2).sum()) for a in range(3)]), mean


def _true_psf(shape):
    c = [n // 2 for n in shape]
    psf = render_blobs(shape, c, SIGMA)
    return psf / psf.sum()


# -- PSF estimate ----------------------------------------------------------------------------
def test_estimate_psf_recovers_blob_shape_and_skips_crowded(rng):
    shape = (64, 96, 96)
    centres = random_centres(rng, shape, 20, (18, 12, 12), (10, 7, 7))
    crowd = np.array([[32.2, 48.3, 46.1], [32.0, 48.1, 50.4]])  # 4.3 voxels apart along x
    keep = np.any(np.abs(centres - crowd.mean(axis=0)) > (12, 8, 8), axis=1)
    vol = render_blobs(shape, centres[keep], SIGMA, rng.uniform(0.7, 1.0, keep.sum()), 0.05)
    vol += render_blobs(shape, crowd, SIGMA, 1.0)
    vol += rng.normal(0, 0.02, shape)  # SNR 50
    box = box_shape_vox(PSF_BOX_UM, VOXEL)
    assert box == (17, 11, 11)
    isolated, crowded = find_isolated_peaks(vol, box)
    assert len(crowded) >= 1
    near_pair = np.linalg.norm((isolated - crowd.mean(axis=0)) * VOXEL, axis=1) < 10
    assert not near_pair.any()
    assert len(isolated) >= 10
    psf = estimate_psf(vol, VOXEL, n_particles=10, box_um=PSF_BOX_UM)
    assert psf.shape == box and psf.dtype == np.float32
    assert psf.sum() == pytest.approx(1.0, abs=1e-5) and psf.min() >= 0
    sig, mean = _moment_sigmas(psf.astype(float))
    true_sig, _ = _moment_sigmas(_true_psf(box))
    print(f"PSF σ z/y/x = {sig.round(3)} voxel, true (same box) {true_sig.round(3)}")
    np.testing.assert_allclose(sig, true_sig, rtol=0.10)
    np.testing.assert_allclose(mean, [n // 2 for n in box], atol=0.1)


def test_estimate_psf_errors():
    with pytest.raises(TrackingError, match="isolated"):
        estimate_psf(np.zeros((30, 30, 30)), VOXEL, box_um=PSF_BOX_UM)
    with pytest.raises(InputError, match="box_um"):
        estimate_psf(np.zeros((10, 30, 30)), VOXEL, box_um=PSF_BOX_UM)
    with pytest.raises(InputError, match="n_particles"):
        estimate_psf(np.zeros((30, 30, 30)), VOXEL, n_particles=0)


def test_load_psf(tmp_path):
    psf = _true_psf((9, 7, 7)).astype(np.float32) * 5
    tifffile.imwrite(tmp_path / "psf.tif", psf)
    got = load_psf(tmp_path / "psf.tif")
    np.testing.assert_allclose(got, psf / psf.sum(), rtol=1e-5)
    with pytest.raises(InputError, match="does not exist"):
        load_psf(tmp_path / "missing.tif")
    tifffile.imwrite(tmp_path / "even.tif", np.ones((8, 7, 7), np.float32))
    with pytest.raises(InputError, match="odd"):
        load_psf(tmp_path / "even.tif")
    tifffile.imwrite(tmp_path / "flat.tif", np.ones((7, 7), np.float32))
    with pytest.raises(InputError, match="3-D"):
        load_psf(tmp_path / "flat.tif")
    (tmp_path / "junk.tif").write_bytes(b"not a tiff")
    with pytest.raises(InputError, match="TIFF"):
        load_psf(tmp_path / "junk.tif")


# -- deconvolution ---------------------------------------------------------------------------
def test_deconvolution_sharpens_conserves_flux_and_stays_positive(rng):
    shape = (48, 48, 48)
    centres = random_centres(rng, shape, 6, (14, 8, 8), (12, 10, 10))
    vol = render_blobs(shape, centres, SIGMA)
    psf = _true_psf((21, 11, 11))
    out = deconvolve(vol, psf, DeconvolveSettings(5))
    assert out.shape == shape and out.dtype == np.float32 and out.min() >= 0
    assert out.sum() == pytest.approx(vol.sum(), rel=0.01)
    assert out.max() > 2.0 * vol.max()
    p = np.rint(centres[0]).astype(int)
    sl = tuple(slice(p[i] - 6, p[i] + 7) for i in range(3))
    before, _ = _moment_sigmas(vol[sl])
    after, _ = _moment_sigmas(out[sl].astype(float))
    assert np.all(after < 0.8 * before)
    # noisy data with negative voxels and zero regions: no blow-ups, still non-negative
    noisy = vol + rng.normal(0, 0.05, shape)
    noisy[:, :, :10] = 0.0
    out2 = deconvolve(noisy, psf, DeconvolveSettings(5))
    assert np.all(np.isfinite(out2)) and out2.min() >= 0 and out2.max() < 10 * out.max()
    assert np.all(out2[:, :, :4] == 0)
    np.testing.assert_array_equal(
        deconvolve(vol, psf, DeconvolveSettings(0)), vol.astype(np.float32)
    )
    with pytest.raises(InputError, match="iterations"):
        deconvolve(vol, psf, DeconvolveSettings(-1))
    with pytest.raises(InputError, match="odd"):
        deconvolve(vol, np.ones((4, 3, 3)))


def test_deconvolution_keeps_a_uniform_background_uniform_at_the_faces():
    """Bertero–Boccacci boundaries: a constant volume stays constant up to the faces (estimating
    the object on the volume alone piled it onto the faces, ×2 per iteration)."""
    vol = np.full((40, 30, 30), 3.0, dtype=np.float32)
    out = deconvolve(vol, _true_psf((21, 11, 11)), DeconvolveSettings(5))
    assert out.max() < 1.05 * 3.0 and out.min() > 0.95 * 3.0


def test_deconvolution_operator_is_adjoint():
    from track.deconvolve import _Convolver

    rng = np.random.default_rng(5)
    conv = _Convolver((12, 10, 9), rng.random((5, 3, 3)))
    x = rng.random(conv.ext_shape)
    y = rng.random((12, 10, 9))
    assert np.vdot(conv.forward(x), y) == pytest.approx(np.vdot(x, conv.adjoint(y)), rel=1e-10)


def test_psf_estimate_ignores_bright_face_artefacts(rng):
    shape = (48, 48, 48)
    centres = random_centres(rng, shape, 4, (14, 8, 8), (14, 12, 12))
    vol = render_blobs(shape, centres, SIGMA)
    vol[:, 0, :] += 10.0 * vol.max()  # a light-field reconstruction's boundary artefact
    isolated, crowded = find_isolated_peaks(vol, (21, 11, 11))
    assert len(isolated) >= 2
    # every isolated peak is one of the particles (at its centre's voxel), none on the face
    dist, _ = cKDTree(centres).query(isolated)
    assert np.all(dist < 1.0), isolated
    assert np.all(isolated[:, 1] >= 12), isolated  # the particles' margin from y = 0
    for found in (isolated, crowded):  # the face is not even a candidate
        assert found.size == 0 or np.all(found[:, 1] > 0)


# -- the pipeline ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    shape = (64, 96, 96)
    centres = random_centres(rng, shape, 30, (14, 9, 9), (8, 5, 5))
    clean = render_blobs(shape, centres, SIGMA, rng.uniform(0.7, 1.0, 30), background=0.05)
    vol = (clean + rng.normal(0, 1.0 / 30, shape)).astype(np.float32)  # SNR 30
    return vol, centres


def _match(found_vox, truth_vox):
    dist, idx = cKDTree(truth_vox).query(found_vox)
    return dist, idx


@pytest.mark.parametrize("method", ["radial", "centroid"])
def test_detect_particles_end_to_end(scene, method):
    vol, truth = scene
    origin = (-100.0, 20.0, 300.0)
    det = detect_particles(
        vol, VOXEL, DetectSettings(psf_box_um=PSF_BOX_UM, method=method), origin_xyz_um=origin
    )
    assert not det.empty and not det.report["empty"]
    dist, idx = _match(det.positions_vox, truth)
    assert np.all(dist < 1.5), "false positive"
    assert len(set(idx)) == det.n  # no particle found twice
    assert det.n >= 0.95 * len(truth)
    err = det.positions_vox - truth[idx]
    rms = np.sqrt(np.mean(err**2, axis=0))
    print(f"{method}: RMS error z/y/x = {rms.round(4)} voxel over {det.n} particles")
    assert np.all(rms < (0.2 if method == "radial" else 0.3))
    if method == "radial":
        assert np.all(rms[1:] < 0.05)
    # the reported σ (x, y, z µm) is of the size of the actual error (white noise here)
    sig_zyx_vox = det.sigma_xyz_um[:, ::-1] / np.array([5.0, 1.64, 1.64])
    ratio = rms / np.sqrt(np.mean(sig_zyx_vox**2, axis=0))
    print(f"{method}: RMS error / RMS σ (z, y, x) = {ratio.round(2)}")
    assert np.all((ratio > 0.5) & (ratio < 2.0))
    np.testing.assert_array_equal(det.sigma_random_xyz_um, det.sigma_xyz_um)  # no systematic part
    # (z, y, x) voxels -> (x, y, z) µm with anisotropic voxels and the origin
    p = det.positions_vox
    expected_um = np.column_stack(
        [origin[0] + p[:, 2] * 1.64, origin[1] + p[:, 1] * 1.64, origin[2] + p[:, 0] * 5.0]
    )
    np.testing.assert_allclose(det.positions_um, expected_um, rtol=0, atol=1e-9)
    t = truth[idx]
    truth_um = np.column_stack(
        [origin[0] + t[:, 2] * 1.64, origin[1] + t[:, 1] * 1.64, origin[2] + t[:, 0] * 5.0]
    )
    err_um = det.positions_um - truth_um
    assert np.all(np.sqrt(np.mean(err_um**2, axis=0)) < np.array([1.64, 1.64, 5.0]) * 0.2)
    assert det.intensities.shape == (det.n,) and det.sizes_vox.shape == (det.n,)
    r = det.report
    assert r["counts"]["localized"] == det.n and r["deconvolution_iterations"] == 5
    assert "estimated" in r["psf"] and r["threshold"] > 0
    assert all(b["reason"] for b in r["rejected"])


def test_detect_with_given_psf_and_without_deconvolution(scene):
    vol, truth = scene
    psf = _true_psf((17, 11, 11))
    for settings, p in [
        (DetectSettings(), psf),
        (DetectSettings(deconvolution_iterations=0), None),
    ]:
        det = detect_particles(vol, VOXEL, settings, psf=p)
        dist, _ = _match(det.positions_vox, truth)
        assert det.n >= 0.95 * len(truth) and np.all(dist < 1.5)


def test_detect_empty_volume_returns_empty_detection(rng):
    for vol in (np.zeros((20, 30, 30)), rng.normal(0, 1, (20, 30, 30))):
        det = detect_particles(vol, VOXEL)
        assert det.empty and det.report["empty"]
        assert det.positions_um.shape == (0, 3) and det.intensities.shape == (0,)
        assert "not available" in det.report["psf"]


@pytest.mark.parametrize(
    ("volume", "voxel", "kwargs", "name"),
    [
        (np.zeros((10, 10)), VOXEL, {}, "volume"),
        (np.zeros((0, 10, 10)), VOXEL, {}, "volume"),
        (np.full((5, 5, 5), np.inf), VOXEL, {}, "non-finite"),
        (np.zeros((5, 5, 5)), (5.0, 0.0, 1.64), {}, "voxel_size_um"),
        (np.zeros((5, 5, 5)), (5.0, 1.64), {}, "voxel_size_um"),
        (np.zeros((5, 5, 5)), VOXEL, {"origin_xyz_um": (0, np.nan, 0)}, "origin_xyz_um"),
        (np.zeros((5, 5, 5)), VOXEL, {"settings": "fast"}, "settings"),
        (np.zeros((5, 5, 5)), VOXEL, {"psf": np.ones((2, 3, 3))}, "psf"),
    ],
)
def test_detect_rejects_bad_input(volume, voxel, kwargs, name):
    with pytest.raises(InputError, match=name):
        detect_particles(volume, voxel, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"threshold": 0.0}, "threshold"),
        ({"threshold": "otsu"}, "threshold"),
        ({"deconvolution_iterations": -1}, "deconvolution_iterations"),
        ({"method": "gauss"}, "method"),
        ({"blob_min_vox": 10, "blob_max_vox": 5}, "blob_min_vox"),
        ({"edge_margin_um": -1.0}, "edge_margin_um"),
        ({"half_box_vox": (3, 0, 2)}, "half_box_vox"),
        ({"localize_on": "raw"}, "localize_on"),
        ({"auto_size_factors": (2.0, 3.0)}, "auto_size_factors"),
        ({"psf_box_um": (10.0, -1.0, 1.0)}, "psf_box_um"),
        ({"sigma_noise_factor": 0.0}, "sigma_noise_factor"),
        ({"sigma_noise_factor": (1.0, 0.0, 1.0)}, "sigma_noise_factor"),
        ({"sigma_noise_factor": (1.0, 2.0)}, "sigma_noise_factor"),
        ({"sigma_noise_factor": "5"}, "sigma_noise_factor"),
        ({"sigma_systematic_um": (1.0, -0.1, 0.0)}, "sigma_systematic_um"),
        ({"sigma_snr_um": (1.0, 0.0, -0.2)}, "sigma_snr_um"),
        ({"smooth_fwhm": -0.1}, "smooth_fwhm"),
        ({"smooth_fwhm": 0.5, "background_fwhm": 0.4}, "background_fwhm"),
    ],
)
def test_detect_settings_validation(kwargs, name):
    with pytest.raises(InputError, match=name):
        DetectSettings(**kwargs)


# -- independence of the reconstruction settings ---------------------------------------------
def _rippled_scene(rng, sigma, ripple, pedestal, snr=30.0, shape=(60, 64, 64)):
    """Particles as reconstructions with few or many iterations make them: Gaussians of
    ``sigma`` voxels, their axial profile modulated by ``1 + ripple · cos(2π z / 3 voxels)``
    (the depth ripple that many Richardson–Lucy iterations sharpen into separate maxima),
    on an axial pedestal of relative height ``pedestal`` that spans the whole depth (the
    out-of-focus cone of few iterations), plus Gaussian noise."""
    truth = random_centres(rng, shape, 6, (100.0, 12.0, 12.0), (shape[0] // 2 - 4, 8, 8))
    vol = render_blobs(shape, truth, sigma)
    z = np.arange(shape[0])[:, None, None]
    vol *= 1.0 + ripple * np.cos(2.0 * np.pi * (z - truth[0, 0]) / 3.0)
    if pedestal:
        vol += pedestal * render_blobs(shape, truth, (1000.0, sigma[1], sigma[2]))
    return vol + rng.normal(0.0, vol.max() / snr, shape), truth


@pytest.mark.parametrize(
    ("sigma", "ripple", "pedestal"),
    [
        ((3.0, 1.2, 1.2), 0.0, 0.0),  # a paper-like reconstruction (3 iterations)
        ((6.0, 0.6, 0.6), 0.6, 0.0),  # many iterations: sharp, rippled along z
        ((12.0, 2.0, 2.0), 0.0, 0.7),  # one iteration: long and on a pedestal to both faces
    ],
)
def test_detection_follows_the_particle_scale(rng, sigma, ripple, pedestal):
    vol, truth = _rippled_scene(rng, sigma, ripple, pedestal)
    det = detect_particles(vol, VOXEL)
    dist, idx = _match(det.positions_vox, truth)
    assert det.n == len(truth) and len(set(idx)) == det.n, det.report["rejections"]
    assert np.all(dist < 2.0 * max(sigma))
    # the band-pass scale is the particles' own (measured on the volume segmented: without
    # the secondary deconvolution, the input)
    plain = detect_particles(vol, VOXEL, DetectSettings(deconvolution_iterations=0))
    assert plain.n == len(truth), plain.report["rejections"]
    fwhm = np.asarray(plain.report["particle_fwhm_vox"])
    assert fwhm[1] == pytest.approx(2.355 * sigma[1], abs=1.5)
    r = det.report
    # every rejected blob is counted under its filter
    assert set(r["rejections"]) == {
        "edge",
        "too_small",
        "specks",
        "too_large",
        "elongated",
        "clump",
        "insignificant",
        "localization",
    }
    assert r["rejections"]["specks"] == r["rejected_specks"]
    listed = sum(v for k, v in r["rejections"].items() if k not in ("specks", "localization"))
    assert listed == len(r["rejected"])


def test_particle_fwhm_measures_the_blobs_not_the_faces(rng):
    """The width is the count of voxels above half the peak on the lines through the peak
    voxel of the volume smoothed with a 0.7-voxel Gaussian: for a blob centred on a voxel,
    the odd count ``2 floor(W / 2) + 1`` of the analytic FWHM ``W = 2 sqrt(2 ln 2) σ'``,
    ``σ'² = σ² + 0.7²``. The σ put ``W / 2`` mid-way between integers, so the count is
    exact and a width off by one voxel fails."""
    shape = (40, 40, 48)
    sigma = np.array([2.0, 1.06, 2.9])
    truth = np.round(random_centres(rng, shape, 5, (1.0, 12.0, 17.0), (10, 8, 10)))
    vol = render_blobs(shape, truth, sigma)
    vol[:, :, 0] += 5.0  # a bright boundary artefact
    half_w = np.sqrt(2 * np.log(2)) * np.sqrt(sigma**2 + 0.7**2)
    assert np.all(np.abs(half_w - np.round(half_w)) > 0.45)  # far from a count's edge
    expected = 2 * np.floor(half_w) + 1
    np.testing.assert_array_equal(expected, [5, 3, 7])
    np.testing.assert_array_equal(particle_fwhm_vox(vol), expected)
    assert particle_fwhm_vox(np.zeros(shape)) is None


def test_unresolved_particles_get_no_automatic_psf(rng):
    vol, truth = _rippled_scene(rng, (2.0, 0.4, 0.4), 0.0, 0.0, snr=100.0)
    det = detect_particles(vol, VOXEL)
    assert "not estimated" in det.report["psf"] and det.report["deconvolution_iterations"] == 0
    dist, _ = _match(det.positions_vox, truth)
    assert det.n == len(truth) and np.all(dist < 1.5)


def test_a_volume_of_pure_noise_has_no_particle(tmp_path):
    """A threshold set as a fraction of the range finds blobs in any volume: deconvolved
    with the PSF of a real frame, pure noise forms particle-sized blobs, which the
    significance test (``min_peak_snr``) rejects."""
    from track.volumes import read_volume, scan_volumes

    from .test_cli import _volumes

    _volumes(tmp_path, n_frames=2, empty=(1,))  # frame 1: noise only
    real, noise = (read_volume(v) for v in scan_volumes(tmp_path))
    vs = scan_volumes(tmp_path)[0].voxel_size_um
    psf = estimate_psf(real, vs)
    assert detect_particles(real, vs, DetectSettings(), psf).n == 20
    det = detect_particles(noise, vs, DetectSettings(), psf)
    assert det.n == 0 and det.report["rejections"]["insignificant"] > 10
    assert detect_particles(noise, vs, DetectSettings(min_peak_snr=0.0), psf).n > 10


def test_sigma_noise_factor_per_axis(scene):
    """A (z, y, x) factor scales each axis's random σ; a scalar all three alike."""
    vol, _ = scene
    base = detect_particles(vol, VOXEL, DetectSettings(deconvolution_iterations=0))
    per_axis = detect_particles(
        vol,
        VOXEL,
        DetectSettings(
            deconvolution_iterations=0,
            sigma_noise_factor=[4.0, 3.0, 2.0],
            sigma_systematic_um=(1.0, 0.0, 0.0),
        ),
    )
    np.testing.assert_allclose(
        per_axis.sigma_random_xyz_um, base.sigma_random_xyz_um * [2.0, 3.0, 4.0]
    )
    np.testing.assert_allclose(
        per_axis.sigma_xyz_um[:, 2], np.hypot(4.0 * base.sigma_random_xyz_um[:, 2], 1.0)
    )
    assert DetectSettings(sigma_noise_factor=[4, 3, 2]).sigma_noise_factor == (4.0, 3.0, 2.0)
    assert DetectSettings(sigma_noise_factor=5).sigma_noise_factor == 5


def test_sigma_snr_term_falls_as_one_over_the_frame_snr(scene):
    """sigma_snr_um / SNR joins the random part of every particle's σ (x, y, z columns from
    the (z, y, x) setting); set, it needs the frame's SNR."""
    vol, _ = scene
    base = detect_particles(vol, VOXEL, DetectSettings(deconvolution_iterations=0))
    st = DetectSettings(deconvolution_iterations=0, sigma_snr_um=(20.0, 4.0, 2.0))
    for snr in (5.0, 50.0):
        det = detect_particles(vol, VOXEL, st, snr=snr)
        want = np.hypot(base.sigma_random_xyz_um, np.array([2.0, 4.0, 20.0]) / snr)
        np.testing.assert_allclose(det.sigma_random_xyz_um, want)
        np.testing.assert_allclose(det.positions_um, base.positions_um)  # σ only
        assert det.report["snr"] == snr
    with pytest.raises(InputError, match="sigma_snr_um is set but the volume has no camera SNR"):
        detect_particles(vol, VOXEL, st)
    with pytest.raises(InputError, match="snr must be a finite number > 0"):
        detect_particles(vol, VOXEL, st, snr=0.0)
    # off (the default), a known SNR changes nothing
    off = detect_particles(vol, VOXEL, DetectSettings(deconvolution_iterations=0), snr=5.0)
    np.testing.assert_array_equal(off.sigma_xyz_um, base.sigma_xyz_um)


def test_particles_in_front_of_the_specimens_surface_are_rejected(scene):
    """The guard planes in front of a specimen's surface hold no particle: a detection more
    than one depth step in front of it is rejected and counted; the others are unchanged."""
    vol, _ = scene
    st = DetectSettings(deconvolution_iterations=0)
    origin = (3.0, -2.0, -100.0)
    base = detect_particles(vol, VOXEL, st, origin_xyz_um=origin)
    z = base.positions_um[:, 2]
    surface = float(np.median(z))  # about half of them in front of it
    det = detect_particles(vol, VOXEL, st, origin_xyz_um=origin, surface_z_um=surface)
    keep = z >= surface - VOXEL[0]
    assert 5 <= np.count_nonzero(~keep) and np.count_nonzero(keep) >= base.n // 2
    np.testing.assert_array_equal(det.positions_um, base.positions_um[keep])
    np.testing.assert_array_equal(det.sigma_xyz_um, base.sigma_xyz_um[keep])
    np.testing.assert_array_equal(det.intensities, base.intensities[keep])
    assert det.report["rejections"]["in_front_of_surface"] == np.count_nonzero(~keep)
    assert det.report["surface_z_um"] == surface
    # a surface in front of every particle changes nothing
    det = detect_particles(vol, VOXEL, st, origin_xyz_um=origin, surface_z_um=z.min() - 1.0)
    np.testing.assert_array_equal(det.positions_um, base.positions_um)
    with pytest.raises(InputError, match="surface_z_um must be a finite number"):
        detect_particles(vol, VOXEL, st, surface_z_um=float("nan"))


def test_resolved_neighbours_are_split_not_rejected(rng):
    """Two particles 1.7 FWHM apart along z join at the threshold of the band-passed volume
    (one elongated blob); they are resolved, so both are found, each where it is."""
    from .conftest import render_blobs

    shape = (40, 40, 40)
    truth = np.array([[14.0, 20.3, 19.6], [24.3, 19.4, 20.8], [20.0, 8.0, 30.0]])
    vol = render_blobs(shape, truth, (2.5, 1.2, 1.2), 100.0, 1.0) + rng.normal(0, 0.5, shape)
    det = detect_particles(vol, (2.0, 1.0, 1.0), DetectSettings(deconvolution_iterations=0))
    assert det.n == 3 and det.report["split_components"] == 1
    dist, idx = _match(truth, det.positions_vox)  # nearest detection of each particle
    # the neighbour's tail in the localisation patch pulls each of the pair by about
    # 0.5 voxel (0.2 σ_z) towards the other; the isolated one is exact
    assert sorted(idx) == [0, 1, 2] and np.all(dist[:2] < 1.0) and dist[2] < 0.1
    # closer than one FWHM (6 planes): one blob, not split
    close = truth.copy()
    close[1, 0] = 18.5
    vol = render_blobs(shape, close, (2.5, 1.2, 1.2), 100.0, 1.0) + rng.normal(0, 0.5, shape)
    det = detect_particles(vol, (2.0, 1.0, 1.0), DetectSettings(deconvolution_iterations=0))
    assert det.report["split_components"] == 0 and det.n <= 2
    # as far apart but half as bright (as a particle's axial side lobe is): not split
    amps = [100.0, 50.0, 100.0]
    vol = render_blobs(shape, truth, (2.5, 1.2, 1.2), amps, 1.0) + rng.normal(0, 0.5, shape)
    det = detect_particles(vol, (2.0, 1.0, 1.0), DetectSettings(deconvolution_iterations=0))
    assert det.report["split_components"] == 0


# -- lenslet-phase noise ---------------------------------------------------------------------
def _phase_noise_scene(seed=1, s=5, spike=0.8):
    """Six particles (peak 1) in white noise (σ 0.03) whose voxels at one sub-lenslet phase
    (rows 2 mod s, columns 4 mod s) carry noise of σ ``spike`` at every depth: the 1-voxel
    spikes at fixed phases of a light-field reconstruction."""
    rng = np.random.default_rng(seed)
    shape = (40, 60, 60)
    truth = random_centres(rng, shape, 6, (100.0, 12.0, 12.0), (12, 10, 10))
    vol = render_blobs(shape, truth, (3.0, 1.5, 1.5)) + rng.normal(0, 0.03, shape)
    sub = vol[:, 2::s, 4::s]
    sub += rng.normal(0, spike, sub.shape)
    return vol, truth, s


def test_equalize_lenslet_phases_scales_the_noisy_phase_down_only():
    vol, _, s = _phase_noise_scene()
    eq, info = equalize_lenslet_phases(vol, s, (0, 0))
    assert info["equalized"] and info["max_sigma_ratio"] > 15
    assert eq.dtype == np.float32 and eq.shape == vol.shape and eq.min() >= vol.min()

    def mad(v):
        return 1.4826 * np.median(np.abs(v - np.median(v)))

    assert mad(vol[:, 2::s, 4::s]) > 15 * mad(vol[:, 0::s, 0::s])
    # brought down to PHASE_SIGMA_TOL × the typical phase's σ
    assert mad(eq[:, 2::s, 4::s]) == pytest.approx(
        PHASE_SIGMA_TOL * mad(eq[:, 0::s, 0::s]), rel=0.2
    )
    quiet = np.ones(vol.shape, bool)
    quiet[:, 2::s, 4::s] = False
    # the other phases only lose their (tiny) offsets: the particles keep their heights
    assert np.abs(eq[quiet] - vol[quiet]).max() < 0.02
    # the phase labels do not change the partition into phases
    assert np.allclose(equalize_lenslet_phases(vol, s, (3, 1))[0], eq)
    # fewer than 3 × 3 lenslets per phase, or s = 1: left as it is
    for small, period in ((vol[:, :10, :10], s), (vol, 1)):
        out, info = equalize_lenslet_phases(small, period)
        assert not info["equalized"] and np.array_equal(out, small.astype(np.float32))


def test_detection_with_the_lenslet_period_ignores_phase_noise():
    vol, truth, s = _phase_noise_scene()
    # without the period the spikes set the particle width (1 voxel) and pass for particles
    plain = detect_particles(vol, VOXEL)
    assert plain.report["particle_fwhm_vox"][1] < 1.5
    assert plain.n > len(truth)
    det = detect_particles(vol, VOXEL, lenslet_period_vox=s)
    assert det.report["lenslet_phases"]["equalized"]
    assert det.n == len(truth)
    dist, _ = _match(det.positions_vox, truth)
    assert np.all(dist < 0.5)
    # lenslet_period_vox=None is the same as leaving it out
    same = detect_particles(vol, VOXEL, lenslet_period_vox=None)
    assert np.array_equal(same.positions_vox, plain.positions_vox)
    for kwargs in ({"lenslet_period_vox": 0}, {"lenslet_period_vox": 2.5}):
        with pytest.raises(InputError, match="lenslet_period_vox"):
            detect_particles(vol, VOXEL, **kwargs)
    with pytest.raises(InputError, match="lenslet_phase_vox"):
        detect_particles(vol, VOXEL, lenslet_period_vox=s, lenslet_phase_vox=(1,))


def test_light_piled_on_the_outer_lenslets_is_kept_out_of_the_band_pass():
    """Long particles (one RL iteration) in a volume whose outer lenslet (s voxels) and two
    outer planes hold light from outside the field, 2.5× the particles' peak: without the
    lenslet period the band-pass spreads that light over the volume and no particle stands
    out; with it all 6 are found, and the same volume without particles gives none."""
    rng = np.random.default_rng(0)
    shape, s, voxel = (57, 60, 60), 5, (5.0, 5.0, 5.0)
    truth = random_centres(rng, shape, 6, (100.0, 10.0, 10.0), (22, 12, 12))
    noise = rng.normal(0, 0.1, shape) + 2.0
    faces = np.zeros(shape)
    faces[:2] = faces[-2:] = 5.0
    faces[:, :s] += 5.0
    faces[:, -s:] += 5.0
    faces[:, :, :s] += 5.0
    faces[:, :, -s:] += 5.0
    vol = render_blobs(shape, truth, (14.0, 2.5, 2.5)) + noise + faces
    assert detect_particles(vol, voxel).n == 0
    det = detect_particles(vol, voxel, lenslet_period_vox=s)
    assert det.report["face_fill_vox"] == [2, s, s]
    assert det.n == len(truth)
    _, idx = _match(det.positions_vox, truth)
    err = np.abs(det.positions_vox - truth[idx])
    assert len(set(idx)) == len(truth)
    # axial within a tenth of the 33-voxel FWHM, lateral within half a voxel
    assert np.all(err[:, 0] < 3.3) and np.all(err[:, 1:] < 0.5), err
    assert detect_particles(noise + faces, voxel, lenslet_period_vox=s).n == 0
