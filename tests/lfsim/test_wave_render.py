"""lfsim.wave_render: wave-optics particle images against the point light fields of
lfsim.wave, the ray tracer's photometry, and the reconstruction with either PSF bank."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lfsim.errors import ConfigError
from lfsim.optics import WATER_40X_OPTICS, small_optics
from lfsim.particles import Particles
from lfsim.render import render_particles
from lfsim.tracer import RenderSettings, Sources, trace_paraxial
from lfsim.wave import light_field
from lfsim.wave_render import (
    SphereSampling,
    render_wave,
    sphere_points,
    wave_render_sampling,
)

N_RAYS = 100_000
EXPECTED = RenderSettings(rays_per_particle=N_RAYS, mode="expected", model="wave")


def _paper(lenslets: int = 8, **kw):
    """The paper's 4×/0.2 optics on ``lenslets`` × ``lenslets`` lenslets (15 px each)."""
    side = 15 * lenslets
    return small_optics(sensor_xy_px=(side, side), axis_xy_px=(side / 2, side / 2), **kw)


def _rel(a, b) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_point_particle_is_the_light_field_of_its_centre():
    o = _paper(6)
    p = np.array([[0.45 * 25.0, -0.3 * 25.0, 60.0], [-20.0, 13.0, -40.0]])
    img = render_wave(o, Sources.spheres(p, 0.0, [1.0, 0.5]), EXPECTED)
    assert img.dtype == np.float32
    lf = light_field(o, p, replace(wave_render_sampling(o), guard_lenslets=1.0))
    want = N_RAYS * (lf[0] + 0.5 * lf[1])
    assert _rel(img, want) < 3e-3
    assert img.sum() == pytest.approx(want.sum(), rel=5e-3)


def test_a_whole_lenslet_further_is_the_image_shifted_by_its_pixels():
    o = _paper(6)
    c = np.array([3.1, -4.7, 50.0])
    shift = np.array([25.0, -25.0, 0.0])  # one lenslet in x and −1 in y (object space)
    a = render_wave(o, Sources.spheres(c[None], 8.0), EXPECTED)
    b = render_wave(o, Sources.spheres((c + shift)[None], 8.0), EXPECTED)
    # b[row, col] = a[row + 15, col − 15] wherever both are on the sensor
    np.testing.assert_allclose(b[:-15, 15:], a[15:, :-15], rtol=1e-5, atol=1e-6 * a.max())
    # half a lenslet is not a pixel shift: the lenslets sample another part of the light
    c_half = render_wave(o, Sources.spheres((c + shift / 2)[None], 8.0), EXPECTED)
    assert _rel(c_half[:-7, 7:], a[7:, :-7]) > 0.2


def test_sphere_quadrature_weights_and_moments():
    o = _paper(6)
    ctr = np.array([[4.2, -7.9, 30.0]])
    for k, lateral_rtol in ((10, 0.05), (20, 0.015)):
        pts, w, own = sphere_points(o, ctr, 15.0, SphereSampling(cells_per_lenslet=k), 4)
        assert np.all(own == 0) and w.sum() == pytest.approx(1.0, abs=1e-12)
        d = pts - ctr
        np.testing.assert_allclose(w @ d, 0.0, atol=0.02)  # µm
        # a uniform ball of radius r: <x²> = r² / 5 on every axis; Gauss–Legendre layers
        # give z's exactly, the lattice x's and y's to O(step²)
        second = w @ d**2
        assert second[2] == pytest.approx(7.5**2 / 5, rel=1e-9)
        np.testing.assert_allclose(second[:2], 7.5**2 / 5, rtol=lateral_rtol)
    # a point-size sphere is its centre
    pts0, w0, _ = sphere_points(o, ctr, 0.0)
    np.testing.assert_array_equal(pts0, ctr)
    assert w0.tolist() == [1.0]


def test_sphere_sampling_converges():
    """Images of a 10 µm particle 40 µm from focus at the paper's optics: the default sampling
    (10 cells per lenslet, 5 layers) is within 1.5 % of one twice as fine laterally, and
    over twice as close to it as a coarse one (5 cells, 3 layers) is."""
    o = _paper(5)
    src = Sources.spheres([[2.3, -3.1, 40.0]], 10.0)
    assert SphereSampling().cells(o, wave_render_sampling(o).oversample) == 10
    default = render_wave(o, src, EXPECTED)
    coarse = render_wave(o, src, EXPECTED, sphere=SphereSampling(cells_per_lenslet=5, min_layers=3))
    fine = render_wave(o, src, EXPECTED, sphere=SphereSampling(cells_per_lenslet=20))
    d_default = _rel(default, fine)
    d_coarse = _rel(coarse, fine)
    assert d_default < 0.015
    assert d_coarse > 2 * d_default
    assert default.sum() == pytest.approx(fine.sum(), rel=1e-4)


def test_photometry_agrees_with_the_ray_tracer(backend):
    """The paper's 4×/0.2 optics: the total signal of 15 µm particles within 1 % of the
    paraxial tracer's expected photons, and the light per lenslet within 12 % (RMS over the
    lenslets, relative; diffraction against the tracer's Gaussian blur)."""
    o = _paper(8)
    centres = np.array([[10.0, -15.0, 60.0], [-30.0, 25.0, -100.0], [0.0, 0.0, 200.0]])
    coarse = SphereSampling(cells_per_lenslet=5, min_layers=3)
    for c in centres:
        src = Sources.spheres(c[None], 15.0)
        wave = render_wave(o, src, EXPECTED, sphere=coarse).astype(np.float64)
        ray = trace_paraxial(o, src, RenderSettings(rays_per_particle=400_000, mode="expected"))
        ray = ray.astype(np.float64) * (N_RAYS / 400_000)
        assert wave.sum() == pytest.approx(ray.sum(), rel=0.01)
        per_lenslet = [x.reshape(8, 15, 8, 15).sum(axis=(1, 3)) for x in (wave, ray)]
        assert _rel(*per_lenslet) < 0.12


def test_photon_mode_is_poisson_counts_of_the_expected_image():
    o = _paper(5)
    p = Particles.from_arrays([[1.0, 2.0, 30.0]], diameter_um=1.0)
    settings = RenderSettings(rays_per_particle=50_000, model="wave", seed=3)
    counts = render_particles(o, p, settings)
    assert counts.dtype == np.uint32
    again = render_particles(o, p, settings)
    np.testing.assert_array_equal(counts, again)
    mean = render_particles(
        o, p, RenderSettings(rays_per_particle=50_000, mode="expected", model="wave")
    )
    total = float(mean.sum())
    assert float(counts.sum()) == pytest.approx(total, abs=5 * np.sqrt(total))


def test_refuses_what_it_does_not_model():
    with pytest.raises(ConfigError, match="model must be one of"):
        RenderSettings(model="waves")
    glass = _paper(5, mla_kind="glass")
    with pytest.raises(ConfigError, match="ideal lenslets only; got mla_kind='glass'"):
        render_wave(glass, Sources.spheres([[0.0, 0.0, 10.0]], 1.0), EXPECTED)
    odd = small_optics(sensor_xy_px=(100, 100), pixel_um=7.0)
    with pytest.raises(ConfigError, match="integer number of pixels per lenslet"):
        render_wave(odd, Sources.spheres([[0.0, 0.0, 10.0]], 1.0), EXPECTED)
    with pytest.raises(ConfigError, match="draws spheres"):
        render_wave(_paper(5), Sources.boxes([[0.0, 0.0, 10.0]], 2.0), EXPECTED)


def test_experiment_and_command_line_select_the_wave_model(backend, tmp_path, capsys):
    """``[render] model = "wave"`` renders a dataset's frames with the wave model and records
    it; ``lfsim render --model wave`` does so for one image; both refuse glass lenslets."""
    import json
    from pathlib import Path

    from lfsim.cli import main
    from lfsim.dataset import frame_path, generate_dataset
    from lfsim.experiment import load_experiment
    from lfsim.io import read_tiff

    from ..helpers import experiment_toml

    scenes = Path(__file__).resolve().parents[2] / "scenes"
    text = experiment_toml(
        experiment={"name": "w", "scene": "{scene}", "seed": 1, "frames": 1},
        particles={
            "kind": "box",
            "count": 2,
            "bounds_xyz_um": ((-100, 100), (-100, 100), (20, 40)),
            "diameter_um": 2.0,
        },
        render={"rays_per_particle": 5000, "model": "wave"},
        noise={"model": "none"},
        white={"enabled": False},
    )
    path = tmp_path / "w.toml"
    path.write_text(text.replace("{scene}", str(scenes / "small.xml")))
    exp = load_experiment(path)
    assert exp.render.model == "wave" and exp.render.settings(0).model == "wave"
    as_ray = tmp_path / "r.toml"
    as_ray.write_text(path.read_text().replace('model = "wave"', 'model = "ray"'))
    assert load_experiment(as_ray).fingerprint() != exp.fingerprint()
    out = generate_dataset(exp, tmp_path / "ds", progress=False)
    img, meta = read_tiff(frame_path(out, 0))
    assert meta["model"] == "wave"
    assert json.loads((out / "dataset.json").read_text())["experiment"]["render"]["model"] == "wave"
    assert img.dtype == np.uint8 and img.max() > 0
    glass = tmp_path / "g.toml"
    glass.write_text(text.replace("{scene}", str(scenes / "small_glass.xml")))
    with pytest.raises(ConfigError, match="model 'wave' models ideal lenslets only"):
        load_experiment(glass)

    csv = tmp_path / "p.csv"
    Particles.from_arrays([[10.0, -5.0, 30.0]], diameter_um=2.0).to_csv(csv)
    tif = tmp_path / "one.tif"
    argv = ["-q", "render", str(scenes / "small.xml"), "--particles", str(csv), "-o", str(tif)]
    assert main([*argv, "--model", "wave", "--float", "--rays", "1000"]) == 0
    clean, meta = read_tiff(tif)
    assert meta["model"] == "wave" and clean.sum() == pytest.approx(1000, rel=0.01)
    argv[2] = str(scenes / "small_glass.xml")
    assert main([*argv, "--model", "wave", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mla_kind='glass'" in err[0], err


def test_a_study_rendered_with_the_wave_model_is_free_of_the_inverse_crime(tmp_path):
    """A study whose frames are rendered with the wave model through the reconstruction's own
    scene, reconstructed with the ray bank: no inverse crime; its matched variant renders
    with rays."""
    from pathlib import Path

    from hrvptm.config import load_study

    root = Path(__file__).resolve().parents[2]
    text = (root / "scenes" / "experiments" / "fig5a_translation_x_test.toml").read_text()
    medium = str(root / "scenes" / "medium.xml")
    text = text.replace('"../medium_glass.xml"', f'"{medium}"').replace(
        '"../medium.xml"', f'"{medium}"'
    )
    text = text.replace("[render]\n", '[render]\nmodel = "wave"\n').replace(
        "[study]\n", "[study]\nmatched = true\n"
    )
    path = tmp_path / "s.toml"
    path.write_text(text)
    study = load_study(path)
    assert study.renders_other_model and study.is_crime_free
    assert {k: e.render.model for k, e in study.variants().items()} == {
        "mismatched": "wave",
        "matched": "ray",
    }
    path.write_text(text.replace("[recon]\n", '[recon]\npsf_model = "wave"\n'))
    study = load_study(path)
    assert not study.is_crime_free and list(study.variants()) == ["matched"]


# -- cross-validation: render with one model, reconstruct with the other ------------------------
#: At the 40×/0.8 water optics (lfsim.optics.WATER_40X_OPTICS) the objective's aperture and the
#: lenslets' diffraction make the ray bank's Gaussian blur a poor stand-in.


class _CrossModel:
    """Both PSF banks of the 40× water optics on ``lenslets`` × ``lenslets`` lenslets, and the
    localisation of a bead rendered with either model and reconstructed with either bank."""

    def __init__(self, lenslets: int, depths, s: int, rays: int):
        from recon.filters import DepthFilter
        from recon.geometry import ReconGrid
        from recon.projector import SparseProjector
        from recon.psf import compute_psf_bank
        from recon.psf_wave import compute_wave_psf_bank

        side = 15 * lenslets
        self.optics = small_optics(
            sensor_xy_px=(side, side), axis_xy_px=(side / 2, side / 2), **WATER_40X_OPTICS
        )
        o, self.depths, self.s = self.optics, np.asarray(depths), s
        banks = {
            "wave": compute_wave_psf_bank(o, depths, s, cache_dir=""),
            "ray": compute_psf_bank(o, depths, s, rays_per_pattern=rays, cache_dir=""),
        }
        self.proj = {k: SparseProjector(b, (lenslets, lenslets)) for k, b in banks.items()}
        self.filt = DepthFilter.for_optics(o, depths, s)
        origin = (-o.axis_xy_px[0] * o.object_pixel_um, -o.axis_xy_px[1] * o.object_pixel_um)
        self.grid = ReconGrid(o.lenslet_object_um, depths, s, (lenslets, lenslets), origin)

    def render(self, model: str, xyz, diameter_um: float) -> np.ndarray:
        src = Sources.spheres(np.asarray(xyz)[None], diameter_um)
        if model == "wave":
            return render_wave(self.optics, src, EXPECTED)
        return trace_paraxial(
            self.optics, src, RenderSettings(rays_per_particle=400_000, mode="expected")
        )

    def error(self, image, bank: str, xyz) -> np.ndarray:
        """Found minus true position (µm, x, y, z) of the detection nearest the bead."""
        from recon.deconvolve import richardson_lucy
        from track.detect import detect_particles

        vol = richardson_lucy(
            image.astype(np.float32), self.proj[bank], 8, depth_filter=self.filt, track_kl=False
        ).volume
        g, d = self.grid, self.depths
        det = detect_particles(
            vol,
            (d[1] - d[0], g.voxel_um, g.voxel_um),
            origin_xyz_um=(g.x_um()[0], g.y_um()[0], d[0]),
            lenslet_period_vox=self.s,
        )
        found = np.asarray(det.positions_um)
        assert len(found), f"no detection for a bead at {xyz} ({bank} bank)"
        diff = found - np.asarray(xyz)
        return diff[np.argmin(np.sum(diff**2, axis=1))]


def _cross_errors(model: _CrossModel, beads, diameter_um: float, pairs) -> dict:
    """RMS lateral and axial errors (µm) of each (render model, bank) pair over ``beads``."""
    out = {}
    images = {m: [model.render(m, b, diameter_um) for b in beads] for m in {r for r, _ in pairs}}
    for render, bank in pairs:
        err = np.array(
            [model.error(img, bank, b) for img, b in zip(images[render], beads, strict=True)]
        )
        out[render, bank] = (
            float(np.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2))),
            float(np.sqrt(np.mean(err[:, 2] ** 2))),
        )
    return out


@pytest.mark.studies
def test_cross_validation_at_high_na_both_directions(backend):
    """Four 1 µm beads 4–7.5 µm from focus at the 40×/0.8 water optics, each rendered with
    both models and reconstructed with both banks: with wave renders the wave bank's RMS
    axial error is below 0.35 µm and the ray bank's is 1.3 times larger or more; ray renders
    reconstructed with the wave bank stay below 0.35 µm; lateral errors below 0.3 µm."""
    model = _CrossModel(7, np.arange(-10.0, 10.01, 0.5), 3, 50_000)
    beads = [(0.6, -0.9, -5.0), (-0.8, 0.4, 4.0), (0.3, 0.7, 7.0), (-0.4, -0.2, -7.5)]
    pairs = (("wave", "wave"), ("wave", "ray"), ("ray", "wave"), ("ray", "ray"))
    e = _cross_errors(model, beads, 1.0, pairs)
    for pair, (lat, _) in e.items():
        assert lat < 0.3, (pair, e)
    assert e["wave", "wave"][1] < 0.35, e
    assert e["wave", "ray"][1] > 1.3 * e["wave", "wave"][1], e
    assert e["ray", "wave"][1] < 0.35, e
