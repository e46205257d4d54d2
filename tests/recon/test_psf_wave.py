"""The wave-optics PSF bank: equal to lfsim.wave's patterns, normalised as the ray bank,
cached, an exact adjoint in the projector; the psf_model setting and its ``auto`` rule."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lfsim.optics import Optics, paper_optics
from lfsim.wave import WaveSampling, pattern_stack
from recon.errors import InputError
from recon.psf import pattern_radius_lenslets
from recon.psf_wave import (
    WAVE_SIN_THETA,
    WAVE_SPOT_PX,
    aperture_sin,
    choose_psf_model,
    compute_wave_psf_bank,
    default_wave_sampling,
    lenslet_spot_px,
    wave_bank_key,
)
from recon.settings import ReconSettings

from .test_projector import assert_adjoint_on_random_fields

ROOT = Path(__file__).resolve().parents[2]

#: The bank (complex64 FFTs, mirror-imaged sub-lenslet positions, shared native field) against
#: lfsim.wave.pattern_stack (complex128, every source on its own) at the same sampling: largest
#: pixel difference relative to the pattern's peak (measured ≤ 2e-7: float32 round-off).
DENSE_RTOL = 1e-5
#: The same where the sample grid is padded on one side (to ``λ f_l / dx²`` samples, for the
#: propagation): lfsim.wave's own patterns of mirror-image sources then differ by the far
#: diffraction tail folded back by the FFT's periodicity (measured 1.06e-4 of the peak at
#: 60×/1.2 W, 6 samples per pixel; the bank's mirror images of computed positions, 1.06e-4).
PADDED_RTOL = 2e-4

#: A fast sampling of the paper's lenslets (3 samples per pixel).
FAST = WaveSampling(oversample=3, guard_lenslets=1.0)


def _optics():
    """The paper's 4×/0.2 optics on a 5 × 5-lenslet sensor."""
    return paper_optics(sensor_xy_px=(75, 75))


def water_60x() -> Optics:
    """60×/1.2 water objective with matched 100 µm lenslets (f 2500 µm), 15 px per lenslet."""
    return Optics(
        na=1.2,
        f_objective_um=200_000.0 / 60,
        f_tube_um=200_000.0,
        mla_pitch_um=100.0,
        mla_focal_um=2500.0,
        pixel_um=100.0 / 15,
        sensor_xy_px=(150, 150),
        medium_ior=1.333,
        immersion_ior=1.333,
    )


def _dense(bank, c: int, h: int) -> np.ndarray:
    n = bank.n
    img = np.zeros(((2 * h + 1) * n,) * 2)
    dy, dx, w = bank.pattern(c)
    img[dy + h * n, dx + h * n] = w
    return img


@pytest.mark.parametrize(
    ("scope", "sampling", "s", "depths", "rtol"),
    [
        # every sub-lenslet shift a whole number of samples (one shared native field per depth)
        ("4x", FAST, 3, [0.0, 60.0], DENSE_RTOL),
        # they are not (each source's field interpolated on its own)
        ("4x", FAST, 2, [-40.0], DENSE_RTOL),
        # the small window's grid (z = 0) is padded to the propagation's sampling (λ f_l / dx²
        # samples) and reaches further from the axis than the large one's (checked: z = 0)
        ("60xW", WaveSampling(oversample=6, guard_lenslets=1.0), 3, [0.0, 2.0], PADDED_RTOL),
    ],
)
def test_patterns_equal_lfsim_wave(scope, sampling, s, depths, rtol):
    o = _optics() if scope == "4x" else water_60x()
    bank = compute_wave_psf_bank(o, depths, s, sampling=sampling, threshold=0.0, cache_dir="")
    assert bank.n_channels == len(depths) * s * s and bank.n == 15
    for k, z in enumerate(depths if scope == "4x" else depths[:1]):
        h = pattern_radius_lenslets(o, z)
        ref = pattern_stack(o, [z], s, h, sampling)
        for j in range(s * s):
            got = _dense(bank, k * s * s + j, h)
            assert np.abs(got - ref[j]).max() <= rtol * ref[j].max(), (z, j)
    # a source off the centre of its lenslet is not its mirror image: the comparison sees
    # the sub-lenslet positions (a pattern mirrored the wrong way is far off)
    assert np.abs(ref[0] - ref[0][:, ::-1]).max() > 0.1 * ref[0].max()


def test_patterns_hold_the_collected_light_as_the_ray_banks_do():
    """Both banks weigh a pixel by the fraction of the light emitted into the collection cone
    reaching it, so a pattern sums to the collected fraction: ≈ 1 for ideal optics, less the
    diffraction tail outside the window and the pixels below the threshold."""
    o = _optics()
    depths = [-60.0, 0.0, 120.0]
    bank = compute_wave_psf_bank(o, depths, 1, sampling=FAST, cache_dir="")
    sums = np.add.reduceat(bank.w.astype(np.float64), bank.offsets[:-1])
    full = compute_wave_psf_bank(o, depths, 1, sampling=FAST, threshold=0.0, cache_dir="")
    sums_full = np.add.reduceat(full.w.astype(np.float64), full.offsets[:-1])
    # the window holds all but the Airy tail of the native image (measured 0.996)
    assert np.all((sums_full > 0.99) & (sums_full < 1.0))
    # the threshold drops the faint diffraction fringes (measured 0.34–0.69 %; the ray
    # bank's: < 0.5 %, tests/recon/test_psf.py)
    assert np.all((sums > sums_full - 0.01) & (sums < sums_full - 0.002))
    # and the light lies where the ray bank's does: same centroid within a pixel
    from lfsim.backend import backend_info, init_backend
    from recon.psf import compute_psf_bank

    if backend_info() is None:
        init_backend()
    ray = compute_psf_bank(o, [120.0], 1, rays_per_pattern=20_000, cache_dir="")
    for b, c in ((bank, 2), (ray, 0)):
        dy, dx, w = b.pattern(c)
        b_centre = (np.sum(dy * w) / np.sum(w), np.sum(dx * w) / np.sum(w))
        assert b_centre == pytest.approx((7.0, 7.0), abs=1.0)


def test_cache_hit_is_identical_and_other_optics_or_model_miss(tmp_path):
    o = _optics()
    a = compute_wave_psf_bank(o, [0.0, 50.0], 1, sampling=FAST, cache_dir=tmp_path)
    files = list(tmp_path.glob("psf_*.npz"))
    assert len(files) == 1
    b = compute_wave_psf_bank(o, [0.0, 50.0], 1, sampling=FAST, cache_dir=tmp_path)
    for name in ("w", "dy", "dx", "offsets", "depths_um"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert b.optics == o.to_dict()
    # other optics: another bank
    o2 = paper_optics(sensor_xy_px=(75, 75), mla_focal_um=1100.0)
    compute_wave_psf_bank(o2, [0.0, 50.0], 1, sampling=FAST, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("psf_*.npz"))) == 2
    # the model and the sampling are in the key: the ray bank's key and another sampling's
    # differ from this one's
    from recon.psf import bank_key

    key = wave_bank_key(o, [0.0, 50.0], 1, FAST, 1e-3)
    assert files[0].name == f"psf_{key}.npz"
    assert key != bank_key(o, [0.0, 50.0], 1, 200_000, 0, 1e-3)
    assert key != wave_bank_key(o, [0.0, 50.0], 1, WaveSampling(oversample=4), 1e-3)


def test_projector_with_a_wave_bank_is_an_exact_adjoint():
    from recon.projector import LightFieldProjector

    bank = compute_wave_psf_bank(_optics(), [-30.0, 40.0], 3, sampling=FAST, cache_dir="")
    p = LightFieldProjector(bank, (6, 5))
    assert_adjoint_on_random_fields(p, np.random.default_rng(7), 2)


def test_default_sampling_resolves_the_light_behind_the_lenslets():
    """A step of at most λ / (5 (NA/M + NA_lenslet)): 6 samples per 6.67 µm pixel at the
    paper's 4×/0.2 (total image-side NA 0.1, 1.21 µm), 3 at 60×/1.2 W (0.04, 3.03 µm)."""
    assert default_wave_sampling(paper_optics()).oversample == 6
    assert default_wave_sampling(water_60x()).oversample == 3


def test_guard_planes_in_front_of_a_gel_continue_it_as_in_the_ray_bank():
    """Planes in front of a specimen's surface (guard planes) are modelled as the specimen going
    on: the wave bank's Gibson–Lanni phase continues analytically, the ray bank refracts
    virtually (tests/lfsim/test_specimen.py). A point's blur then grows across the surface at
    the gel's rate, where air in front would steepen it by 1 / axial_scale = 1.36, and the two
    banks' blurs agree at every plane."""
    from lfsim.backend import backend_info, init_backend
    from recon.psf import compute_psf_bank

    if backend_info() is None:
        init_backend()
    # The paper's gel on its glass bottom, focused 300 µm in: the surface lies 488 µm in front
    # of the native plane (z < 0), the planes in front of it are guard planes.
    o = paper_optics(
        sensor_xy_px=(225, 225),
        medium_ior=1.35,
        coverslip_thickness_um=170.0,
        coverslip_ior=1.523,
        focus_depth_um=300.0,
    )
    zs = o.surface_z_um
    depths = [zs - 40.0, zs, zs + 40.0]
    banks = {
        "wave": compute_wave_psf_bank(o, depths, 1, sampling=FAST, cache_dir=""),
        "ray": compute_psf_bank(o, depths, 1, rays_per_pattern=50_000, cache_dir=""),
    }

    def rms_radius_px(bank, c: int) -> float:
        dy, dx, w = bank.pattern(c)
        w = w.astype(np.float64)
        cy, cx = np.sum(dy * w) / w.sum(), np.sum(dx * w) / w.sum()
        return float(np.sqrt(np.sum(((dy - cy) ** 2 + (dx - cx) ** 2) * w) / w.sum()))

    r = {k: np.array([rms_radius_px(b, c) for c in range(3)]) for k, b in banks.items()}
    # same blur in both banks (measured within 1.4 %; 26–29 px)
    np.testing.assert_allclose(r["wave"], r["ray"], rtol=0.03)
    for k in banks:
        front, behind = r[k][0] - r[k][1], r[k][1] - r[k][2]
        # the blur grows across the surface at one rate (measured 1.09 wave, 0.94 ray)
        assert 0.85 < front / behind < 1.2, (k, r[k])


def test_auto_keeps_rays_at_the_papers_optics_and_picks_waves_at_60x_water():
    paper = paper_optics()
    assert lenslet_spot_px(paper) == pytest.approx(0.605 * 10 / (100 / 15))
    assert lenslet_spot_px(paper) < WAVE_SPOT_PX < lenslet_spot_px(water_60x())
    assert aperture_sin(paper) == pytest.approx(0.2)
    assert aperture_sin(water_60x()) == pytest.approx(1.2 / 1.333)
    assert choose_psf_model(paper) == "ray"
    assert choose_psf_model(water_60x()) == "wave"
    assert choose_psf_model(paper, "wave") == "wave"
    assert choose_psf_model(water_60x(), "ray") == "ray"
    # a 20×/0.95 dry objective with matched lenslets: a small spot (0.95 px), a wide
    # aperture angle (sin θ 0.95): waves by the angle alone
    dry_20x = paper_optics(na=0.95, f_objective_um=10_000.0, mla_focal_um=20 * 100 / 1.9)
    assert lenslet_spot_px(dry_20x) < WAVE_SPOT_PX
    assert aperture_sin(dry_20x) > WAVE_SIN_THETA
    assert choose_psf_model(dry_20x) == "wave"
    # the same lenslets behind a 0.5 NA: rays
    dry_20x_05 = paper_optics(na=0.5, f_objective_um=10_000.0, mla_focal_um=20 * 100 / 1.9)
    assert choose_psf_model(dry_20x_05) == "ray"


def test_psf_model_errors_are_one_line():
    assert ReconSettings().psf_model == "auto"
    with pytest.raises(InputError) as info:
        ReconSettings(psf_model="waves")
    msg = str(info.value)
    assert msg == "psf_model must be one of auto, ray, wave; got 'waves'"
    with pytest.raises(InputError, match="psf_model must be one of auto, ray, wave"):
        choose_psf_model(paper_optics(), "Wave")
    # psf_model changes the volumes only through the PSF bank, whose key the output folder's
    # fingerprint holds: "auto" and the model it picks resume each other's folders
    assert "psf_model" not in ReconSettings(psf_model="wave").result_dict()


def test_study_file_psf_model(tmp_path):
    from hrvptm.config import load_study
    from hrvptm.errors import StudyConfigError

    from ..helpers import experiment_toml

    base = experiment_toml(
        experiment={"name": "x", "scene": "{scene}", "frames": 2},
        particles={
            "kind": "box",
            "count": 5,
            "bounds_xyz_um": ((-100, 100), (-100, 100), (150, 300)),
        },
    )
    scene = (ROOT / "scenes" / "medium.xml").as_posix()
    path = tmp_path / "study.toml"
    path.write_text(base.format(scene=scene) + "[recon]\npsf_model = 'wave'\n", encoding="utf-8")
    assert load_study(path).recon.psf_model == "wave"
    path.write_text(base.format(scene=scene) + "[recon]\npsf_model = 'fft'\n", encoding="utf-8")
    with pytest.raises(StudyConfigError) as info:
        load_study(path)
    msg = str(info.value)
    assert "study.toml: [recon] psf_model must be one of auto, ray, wave" in msg
    assert "\n" not in msg


def test_recon_run_records_the_psf_model(calib, base_frame, tmp_path, capsys):
    """``--psf-model wave`` reconstructs with the wave bank and says so in recon.json; the
    same folder with the ray bank is another run (refused, naming the bank)."""
    import tifffile

    from recon.cli import main

    frame = tmp_path / "img_1.tif"
    tifffile.imwrite(frame, base_frame)
    scene = ROOT / "scenes" / "small.xml"
    out = tmp_path / "v"
    args = ["run", frame, "--scene", scene, "--calib", calib, "-o", out]
    args += "--z-range 100:150 --z-step 50 -s 1 --iterations 1".split()
    rc = main(["-q", *map(str, args), "--psf-model", "wave"])
    assert rc == 0, capsys.readouterr().err
    rec = json.loads((out / "recon.json").read_text())
    assert rec["psf_model"] == "wave" and rec["settings"]["psf_model"] == "wave"
    assert (out / "000000.tif").is_file()
    capsys.readouterr()
    rc = main(["-q", *map(str, args), "--psf-model", "ray"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "another PSF bank" in err, err
    rc = main([*map(str, args), "--psf-model", "fft"])
    err = capsys.readouterr().err
    assert rc == 2 and "--psf-model" in err and "'fft'" in err
